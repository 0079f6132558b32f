"""Issue 50, item 2: colour calibration — ``python -m components.camera.calibrate`` on frames
the simulator renders of the pink ball, under the thesis's light and a brighter one: the range
fitted from a rectangle on the ball counts most of the ball's pixels (known from a frame
rendered without it) and next to none of the rest; it is written into the robot file as the
camera's ``seek_color``, the rest of the file byte for byte, and the file still passes
``launch --check``; bad rectangles are refused in one line; frames are taken from the robot
file's camera (a video file here)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from components.camera import calibrate
from components.camera.colorfit import Rect
from components.camera.seekcolor import PINK, ColorRange, color_mask
from components.sim.render.calibrate import ball_ahead_world
from components.sim.render.camera import DEFAULT_CAMERA, render_camera
from components.sim.world.config import Lighting, WorldConfig
from components.sim.world.physics import World
from ubf_async.assembly.robotfile import load_robot

ROOT = Path(__file__).resolve().parent.parent
PI_WHEGS = ROOT / "examples" / "robots" / "pi-whegs.yaml"
CAMERA_LINE = "    params: {latency_s: 0.11}\n"
"""pi-whegs's camera parameters: the one line calibration changes."""
LIGHTS = {"the thesis's light": Lighting(), "a brighter room": Lighting(brightness=1.5)}


@dataclass(frozen=True)
class Scene:
    """Frames of the ball 45 cm ahead, saved as PNG, and where the ball is in them."""

    frames: list[Path]
    ball: np.ndarray
    """Which pixels are the ball's (they differ from a frame rendered without it)."""
    rect: Rect
    """The ball's bounding rectangle: what a user marks."""


def rendered(light: Lighting, folder: Path) -> Scene:
    world = ball_ahead_world(0.45, lighting=light)
    frames = [render_camera(world.snapshot(), DEFAULT_CAMERA, np.random.default_rng(seed))
              for seed in range(3)]
    empty = render_camera(World(WorldConfig(lighting=light)).snapshot(), DEFAULT_CAMERA,
                          np.random.default_rng(0))
    ball = np.abs(frames[0].astype(int) - empty.astype(int)).sum(axis=2) > 30
    ys, xs = np.nonzero(ball)
    rect = Rect(int(xs.min()), int(ys.min()), int(np.ptp(xs)) + 1, int(np.ptp(ys)) + 1)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"frame-{i}.png" for i in range(len(frames))]
    for path, frame in zip(paths, frames, strict=True):
        cv2.imwrite(str(path), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    return Scene(paths, ball, rect)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Scene]:
    folder = tmp_path_factory.mktemp("frames")
    return {name: rendered(light, folder / name.replace(" ", "-").replace("'", ""))
            for name, light in LIGHTS.items()}


@pytest.fixture
def robot_file(tmp_path: Path) -> Path:
    copy = tmp_path / "my-robot.yaml"
    copy.write_text(PI_WHEGS.read_text("utf-8"), "utf-8")
    return copy


def run(capsys: pytest.CaptureFixture[str], *argv: str | Path) -> tuple[int, str, str]:
    code = calibrate.main([str(arg) for arg in argv])
    out, err = capsys.readouterr()
    return code, out, err


def shares(scene: Scene, color: ColorRange) -> tuple[float, float]:
    """The share of the ball's pixels ``color`` counts, and of the others, in every frame."""
    counted = [color_mask(cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB), color)
               for path in scene.frames]
    ball = np.mean([np.count_nonzero(mask & scene.ball) for mask in counted])
    rest = np.mean([np.count_nonzero(mask & ~scene.ball) for mask in counted])
    return float(ball / scene.ball.sum()), float(rest / (~scene.ball).sum())


@pytest.mark.parametrize("light", list(LIGHTS))
def test_the_range_fitted_to_the_ball_counts_the_ball_and_little_else(
        scenes: dict[str, Scene], robot_file: Path, tmp_path: Path, light: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    scene = scenes[light]
    before = robot_file.read_text("utf-8")
    code, out, err = run(capsys, robot_file, "--frames", *scene.frames, "--rect", scene.rect,
                         "--out", tmp_path / "out")
    assert (code, err) == (0, ""), err
    camera = next(d for d in load_robot(robot_file).devices if d.kind == "camera")
    fitted = camera.params["seek_color"].color_range()
    assert fitted.require_r_gt_b_gt_g  # the thesis's rule stays
    ball, rest = shares(scene, fitted)
    thesis_ball, _ = shares(scene, PINK)
    assert ball > 0.6 and ball > 1.5 * thesis_ball, (ball, thesis_ball)
    assert rest < 0.0005, rest
    # Written as the camera's seek_color, the rest of the file byte for byte.
    after = robot_file.read_text("utf-8")
    written = (f"    params: {{latency_s: 0.11, seek_color: {{lo: {list(fitted.lo)}, "
               f"hi: {list(fitted.hi)}}}}}\n")
    assert after == before.replace(CAMERA_LINE, written)
    assert f"written: {robot_file} (devices[4].params.seek_color: " in out
    picture = cv2.imread(str(tmp_path / "out" / "seek-color-front.png"))
    assert picture is not None and picture.shape[1] == 2 * picture.shape[0] * 1280 // 1024


def test_the_written_robot_file_passes_launch_check(scenes: dict[str, Scene], robot_file: Path,
                                                    tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    scene = scenes["a brighter room"]
    assert run(capsys, robot_file, "--frames", *scene.frames, "--rect", scene.rect, "--out",
               tmp_path)[0] == 0
    checked = subprocess.run([sys.executable, "-m", "ubf_async.launch", str(robot_file),
                              "--check"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert checked.returncode == 0, checked.stderr
    assert checked.stdout.startswith(f"{robot_file}: robot 'pi-whegs' — OK")
    # Calibrated again, the value is replaced where it stands.
    text = robot_file.read_text("utf-8")
    assert run(capsys, robot_file, "--frames", *scenes["the thesis's light"].frames, "--rect",
               scene.rect, "--out", tmp_path)[0] == 0
    again = robot_file.read_text("utf-8")
    assert again.count("seek_color") == 1 and again != text
    assert [a for a, b in zip(text.splitlines(), again.splitlines(), strict=True) if a != b] \
        == [line for line in text.splitlines() if "seek_color" in line]


def test_a_dry_run_prints_the_change_and_writes_nothing(
        scenes: dict[str, Scene], robot_file: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    scene = scenes["the thesis's light"]
    before = robot_file.read_text("utf-8")
    code, out, _ = run(capsys, robot_file, "--frames", *scene.frames, "--rect", scene.rect,
                       "--out", tmp_path, "--dry-run")
    assert code == 0 and robot_file.read_text("utf-8") == before
    assert f"dry run: {robot_file} is left as it was; the change would be:" in out
    assert f"-{CAMERA_LINE}+    params: {{latency_s: 0.11, seek_color: {{lo: [" in out
    assert "counts " in out and "% of the ball (before: " in out


@pytest.mark.parametrize(("rect", "said"), [
    ("1200,900,200,200", "--rect 1200,900,200,200: the rectangle 1200,900,200,200 (x "
                         "1200..1400, y 900..1100) is not inside the 1280×1024 frame"),
    ("-5,10,50,50", "is not inside the 1280×1024 frame"),
    ("10,10,0,40", "--rect 10,10,0,40: the rectangle 10,10,0,40 is empty: give it a width and "
                   "a height of at least 1 pixel"),
    ("10,10,200,200", "--rect 10,10,200,200: only 0% of the 94284 pixels in the rectangle "
                      "pass seekcolor's rule R > B > G: is it on the ball?"),
], ids=["outside the frame", "left of it", "empty", "not on the ball"])
def test_a_bad_rectangle_is_refused_in_one_line(scenes: dict[str, Scene], robot_file: Path,
                                                tmp_path: Path, rect: str, said: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    before = robot_file.read_text("utf-8")
    code, out, err = run(capsys, robot_file, "--frames", *scenes["the thesis's light"].frames,
                         f"--rect={rect}", "--out", tmp_path)
    assert (code, out) == (2, "")
    assert err.startswith(f"{calibrate.PROG}: error: ") and said in err, err
    assert err.count("\n") == 1
    assert robot_file.read_text("utf-8") == before


@pytest.mark.parametrize(("argv", "said"), [
    (["--rect", "1,2,3"], "argument --rect: a rectangle is X,Y,W,H in pixels (e.g. "
                          "600,650,300,300), got '1,2,3'"),
    ([], "--frames needs --rect X,Y,W,H (the ball's rectangle)"),
], ids=["not four numbers", "no rectangle"])
def test_a_malformed_command_is_a_usage_error(scenes: dict[str, Scene], robot_file: Path,
                                              argv: list[str], said: str,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as ended:
        calibrate.main([str(robot_file), "--frames",
                        *map(str, scenes["the thesis's light"].frames), *argv])
    assert ended.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(said)


def test_frames_from_the_robot_files_camera(scenes: dict[str, Scene], robot_file: Path,
                                            tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """``--camera`` opens the file's camera backend (here a video of the rendered frames):
    without ``--rect`` it saves the frames and says how to go on; with it, it calibrates."""
    scene = scenes["the thesis's light"]
    video = tmp_path / "ball.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (1280, 1024))
    for path in scene.frames:
        writer.write(cv2.imread(str(path)))
    writer.release()
    robot_file.write_text(robot_file.read_text("utf-8").replace(
        'backend_params: {source: "0", width: 1280, height: 1024}',
        f"backend_params: {{source: '{video}', width: 1280, height: 1024}}"), "utf-8")
    code, out, err = run(capsys, robot_file, "--camera", "--count", "3", "--out", tmp_path)
    assert (code, err) == (0, ""), err
    saved = [tmp_path / f"frame-{i}.png" for i in (1, 2, 3)]
    assert out.splitlines() == [
        f"camera/front: 3 frames 1280×1024 saved: {' '.join(map(str, saved))}",
        f"find the ball's rectangle X,Y,W,H in these frames, then: {calibrate.PROG} "
        f"{robot_file} --frames {tmp_path}/frame-*.png --rect X,Y,W,H"]
    code, out, err = run(capsys, robot_file, "--camera", "--count", "3", "--rect", scene.rect,
                         "--out", tmp_path)
    assert (code, err) == (0, ""), err
    assert "seek_color: {lo: [" in robot_file.read_text("utf-8")


def test_a_simulated_camera_needs_frames(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    robot_file = tmp_path / "mini.yaml"
    robot_file.write_text((ROOT / "ubf_async" / "robots" / "mini-whegs.yaml").read_text())
    code, _, err = run(capsys, robot_file, "--camera", "--out", tmp_path)
    assert code == 2
    assert err == (f"{calibrate.PROG}: error: camera/front: its sim backend is the "
                   f"simulator's: give --frames\n")
