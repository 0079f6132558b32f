"""``python -m components.camera.calibrate ROBOT_FILE``: fit the camera's colour range to your
ball under your light, and write it into the robot file (docs/hardware.md, "The camera's
colour").

Frames come from image files (``--frames F1.png F2.png …``) or from the robot file's camera
(``--camera``: its backend, opened as launch would, ``--count`` frames, saved in ``--out`` so
that a later run can use them with ``--frames``). ``--rect X,Y,W,H`` marks the ball, in the
frames' pixels; without it ``--camera`` only saves the frames, for you to find the ball's
rectangle in. The range is fitted to the ball's pixels (:mod:`components.camera.colorfit`) and
printed with what it counts of the ball and of the rest, beside the range the file had; a
picture of what each counts is saved in ``--out``; the range is written as the camera's
``seek_color`` into the robot file, the rest of the file as it was
(:func:`ubf_async.assembly.robotedit.set_device_param`). ``--dry-run`` prints the change
instead of making it.
"""

from __future__ import annotations

import argparse
import difflib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from components.camera.colorfit import (
    DEFAULT_MARGIN,
    Coverage,
    Rect,
    ball_pixels,
    coverage,
    draw_fit,
    fit_color,
)
from components.camera.seekcolor import PINK, ColorRange
from ubf_async.assembly.robotedit import flow_yaml, set_device_param
from ubf_async.assembly.robotfile import ResolvedDevice, Robot, load_robot_text, read_robot_file
from ubf_async.cli.run import run_sync
from ubf_async.errors import ConfigurationError, DeviceError

__all__ = ["PROG", "build_parser", "main"]

PROG = "python -m components.camera.calibrate"
DEFAULT_COUNT = 5
REST_WARNING = 0.005
"""A range counting more than this share of the pixels outside the ball's rectangle is
said to count the background too."""


def _rect(text: str) -> Rect:
    try:
        return Rect.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description=" ".join(__doc__.split("\n\n")[0].split(": ", 1)[1].split()),
        epilog=f"examples:\n  {PROG} my-robot.yaml --camera      # saves the frames\n"
               f"  {PROG} my-robot.yaml --frames calibration/frame-*.png "
               f"--rect 493,650,294,294 --dry-run",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("robot_file", metavar="ROBOT_FILE")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--frames", nargs="+", type=Path, metavar="IMAGE",
                        help="frames with the ball in the same place (PNG, JPEG …)")
    source.add_argument("--camera", action="store_true",
                        help="take the frames from the robot file's camera")
    parser.add_argument("--rect", type=_rect, metavar="X,Y,W,H",
                        help="the ball's rectangle in the frames' pixels (its inscribed "
                             "ellipse is sampled)")
    parser.add_argument("--device", metavar="NAME",
                        help="the camera device (default: the robot file's only camera)")
    parser.add_argument("--count", type=int, default=DEFAULT_COUNT, metavar="N",
                        help=f"frames to take with --camera (default: {DEFAULT_COUNT})")
    parser.add_argument("--margin", type=int, default=DEFAULT_MARGIN, metavar="LEVELS",
                        help=f"levels (of 255) the range is widened by on each side "
                             f"(default: {DEFAULT_MARGIN})")
    parser.add_argument("--out", type=Path, default=Path("calibration"), metavar="DIR",
                        help="where frames and the picture are saved (default: calibration)")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the change to the robot file instead of making it")
    return parser


def _camera(robot: Robot, name: str | None) -> tuple[int, ResolvedDevice]:
    cameras = [(i, device) for i, device in enumerate(robot.devices) if device.kind == "camera"
               and (name is None or device.name == name)]
    if len(cameras) == 1:
        return cameras[0]
    if not cameras:
        raise ConfigurationError(f"{robot.source}: no camera device"
                                 + (f" named {name!r}" if name is not None else ""))
    names = ", ".join(device.name for _, device in cameras)
    raise ConfigurationError(f"{robot.source}: cameras {names}: say which with --device")


def _read_frames(paths: Sequence[Path]) -> list[np.ndarray]:
    frames = []
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise ConfigurationError(f"{path}: not an image OpenCV can read")
        frames.append(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
    return frames


def _take_frames(device: ResolvedDevice, count: int, out: Path) -> list[np.ndarray]:
    """``count`` frames from the device's backend, each saved in ``out``."""
    name = f"camera/{device.name}"
    if device.requires_simulator:
        raise ConfigurationError(f"{name}: its {device.backend} backend is the simulator's: "
                                 f"give --frames")
    backend = device.backend_factory(context=None, **device.backend_params)
    try:
        backend.prepare()
        frames = [backend.capture() for _ in range(count)]
    except DeviceError as exc:
        raise ConfigurationError(f"{name}: {exc}") from None
    finally:
        backend.close()
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"frame-{i}.png" for i in range(1, count + 1)]
    for path, frame in zip(paths, frames, strict=True):
        cv2.imwrite(str(path), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    height, width = frames[0].shape[:2]
    print(f"{name}: {count} frames {width}×{height} saved: {' '.join(map(str, paths))}")
    return frames


def _range_text(color: ColorRange) -> str:
    rule = " with R > B > G" if color.require_r_gt_b_gt_g else " (no R > B > G)"
    return f"lo {list(color.lo)}, hi {list(color.hi)}{rule}"


def _report(before: Coverage, after: Coverage) -> list[str]:
    lines = [f"counts {after.ball:.0%} of the ball (before: {before.ball:.0%}) and "
             f"{after.rest:.2%} of the rest (before: {before.rest:.2%})",
             f"seekcolor counts {after.seek_total} pixels in the first frame (before: "
             f"{before.seek_total}): chase's min_pixels and flee's start_pixels are counts "
             f"like these"]
    if after.rest > REST_WARNING:
        lines.append(f"warning: it counts {after.rest:.1%} of the rest of the frames: a "
                     f"tighter rectangle, a smaller --margin or a background without the "
                     f"ball's colour")
    return lines


def _seek_color(fitted: ColorRange, written_before: Any) -> dict[str, Any]:
    """The ``seek_color`` value to write: the rule said only if the file said it before."""
    value: dict[str, Any] = {"lo": list(fitted.lo), "hi": list(fitted.hi)}
    if isinstance(written_before, dict) and "require_r_gt_b_gt_g" in written_before:
        value["require_r_gt_b_gt_g"] = fitted.require_r_gt_b_gt_g
    return value


def _main(args: argparse.Namespace) -> int:
    text, source = read_robot_file(args.robot_file)
    if not args.dry_run and not Path(source).is_file():
        raise ConfigurationError(f"{source} is a shipped robot file: copy it and calibrate the "
                                 f"copy (or look with --dry-run)")
    robot = load_robot_text(text, source=source)
    index, device = _camera(robot, args.device)
    frames = (_take_frames(device, args.count, args.out) if args.camera
              else _read_frames(args.frames))
    if args.rect is None:
        print(f"find the ball's rectangle X,Y,W,H in these frames, then: {PROG} "
              f"{args.robot_file} --frames {args.out}/frame-*.png --rect X,Y,W,H")
        return 0
    try:
        pixels = ball_pixels(frames, args.rect)
        fit = fit_color(pixels, margin=args.margin)
    except ValueError as exc:
        raise ConfigurationError(f"--rect {args.rect}: {exc}") from None
    existing = device.params.get("seek_color")
    before = existing.color_range() if existing is not None else PINK
    height, width = frames[0].shape[:2]
    print(f"camera/{device.name}: {len(frames)} frames {width}×{height}, the ball in the "
          f"ellipse of {args.rect}: {fit.sampled} pixels, {fit.passing / fit.sampled:.0%} "
          f"with R > B > G")
    print(f"seek_color: {_range_text(fit.color)} (before: {_range_text(before)})")
    for line in _report(coverage(frames, args.rect, before),
                        coverage(frames, args.rect, fit.color)):
        print(line)
    args.out.mkdir(parents=True, exist_ok=True)
    picture = args.out / f"seek-color-{device.name}.png"
    cv2.imwrite(str(picture), draw_fit(frames[0], args.rect, before=before, after=fit.color))
    print(f"picture: {picture} (what each range counts: before left, after right)")
    value = _seek_color(fit.color, robot.spec.devices[index].params.get("seek_color"))
    edited = set_device_param(text, kind="camera", name=device.name, key="seek_color",
                              value=value, source=source)
    if args.dry_run:
        print(f"dry run: {source} is left as it was; the change would be:")
        print("".join(difflib.unified_diff(text.splitlines(keepends=True),
                                           edited.splitlines(keepends=True),
                                           fromfile=source, tofile=source, n=0)), end="")
        return 0
    Path(source).write_text(edited, encoding="utf-8")
    print(f"written: {source} (devices[{index}].params.seek_color: {flow_yaml(value)})")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.rect is None and not args.camera:
        parser.error("--frames needs --rect X,Y,W,H (the ball's rectangle)")
    if args.count < 1:
        parser.error(f"--count must be ≥ 1, got {args.count}")
    if not 0 <= args.margin <= 64:
        parser.error(f"--margin must be 0..64, got {args.margin}")
    return run_sync(lambda: _main(args), prog=PROG)


if __name__ == "__main__":
    raise SystemExit(main())
