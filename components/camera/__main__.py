"""``python -m components.camera``: the camera (capture + seekcolor) as its own process."""

from __future__ import annotations

import argparse

from components.camera.component import OV9655_LATENCY_S, CameraComponent
from components.camera.videocapture import VideoCaptureBackend
from components.sim.backends import SimCameraBackend
from components.sim.remote import RemoteWorld
from components.standalone import run_device
from ubf_async.bus import Bus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("camera")
    group.add_argument("--name", default="front",
                       help="publishes ubf/<robot>/sensor/camera/<name>")
    group.add_argument("--backend", choices=["sim", "video"], default="sim",
                       help="sim: render the running simulator's world; video: read frames "
                            "with OpenCV from --source")
    group.add_argument("--source", default="0",
                       help="with --backend video: a camera index or a video file")
    group.add_argument("--latency-s", type=float, default=None,
                       help=f"capture latency (default: {OV9655_LATENCY_S} s simulated, "
                            "0 for --backend video, whose device has its own)")
    group.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (sim)")


def build(bus: Bus, world: RemoteWorld | None, args: argparse.Namespace) -> CameraComponent:
    if args.backend == "video":
        source: int | str = int(args.source) if args.source.isdigit() else args.source
        latency = 0.0 if args.latency_s is None else args.latency_s
        return CameraComponent(bus=bus, backend=VideoCaptureBackend(source), name=args.name,
                               latency_s=latency)
    assert world is not None
    latency = OV9655_LATENCY_S if args.latency_s is None else args.latency_s
    return CameraComponent(bus=bus, backend=SimCameraBackend(world), name=args.name,
                           latency_s=latency)


def main() -> int:
    return run_device(prog="python -m components.camera",
                      description="The OV9655 camera with seekcolor as its own process.",
                      add_arguments=add_arguments, build=build,
                      uses_simulator=lambda args: args.backend == "sim")


if __name__ == "__main__":
    raise SystemExit(main())
