"""``python -m components.camera``: the camera (capture + seekcolor) as its own process."""

from __future__ import annotations

import argparse
from typing import Any

from components.camera.component import OV9655_LATENCY_S
from components.standalone import add_backend_argument, run_device


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("camera")
    group.add_argument("--name", default="front",
                       help="publishes ubf/<robot>/sensor/camera/<name>")
    add_backend_argument(group, "camera", default="sim",
                         help="sim: render the running simulator's world; video: read frames "
                              "with OpenCV from --source")
    group.add_argument("--source", default="0",
                       help="with --backend video: a camera index or a video file")
    group.add_argument("--latency-s", type=float, default=None,
                       help=f"capture latency (default: {OV9655_LATENCY_S} s simulated, "
                            "0 for --backend video, whose device has its own)")
    group.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (sim)")


def device_params(args: argparse.Namespace) -> dict[str, Any]:
    if args.latency_s is not None:
        return {"latency_s": args.latency_s}
    return {"latency_s": 0.0} if args.backend == "video" else {}


def backend_params(args: argparse.Namespace) -> dict[str, Any]:
    return {"source": args.source} if args.backend == "video" else {}


def main() -> int:
    return run_device(kind="camera", prog="python -m components.camera",
                      description="The OV9655 camera with seekcolor as its own process.",
                      add_arguments=add_arguments, device_params=device_params,
                      backend_params=backend_params, seed=lambda args: args.seed)


if __name__ == "__main__":
    raise SystemExit(main())
