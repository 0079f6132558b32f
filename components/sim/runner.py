"""The simulated Mini-WHEGS for ``python -m ubf_async.launch`` (its default ``--simulator``).

Launch loads this module by name, calls :func:`add_arguments` on its parser and builds a
:class:`SimulationRun`, which provides the simulator and device components, the status-line
suffix, the run's simulated time, and at the end the summary (``--summary FILE.json``) and
recording (``--record DIR``: trajectory.csv, trajectory.png, annotated camera frames).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, TextIO

import cv2

from components.camera.seekcolor import seekcolor
from components.sim.backends import SimCameraBackend
from components.sim.component import (
    DEVICES,
    RTF_WINDOW_S,
    SimulatorComponent,
    simulated_devices,
)
from components.sim.record import (
    TrajectorySample,
    annotate_frame,
    camera_to_ball,
    motion_over,
    plot_trajectory,
    write_trajectory_csv,
)
from components.sim.scenarios import ScenarioError, builtin_names, load_scenario
from components.sim.world import World
from ubf_async.bus import Bus
from ubf_async.clock import SimClock
from ubf_async.component import Component
from ubf_async.controller import Controller

DEFAULT_SCENARIO = "ball-in-sight"
SAMPLE_PERIOD_S = 0.05


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sim = parser.add_argument_group("simulated robot (components.sim)")
    sim.add_argument("--scenario", default=None, metavar="NAME|PATH",
                     help=f"world and scripted ball to run: a built-in "
                          f"({', '.join(builtin_names())}) or a scenario .json file "
                          f"(docs/scenarios.md); default: {DEFAULT_SCENARIO}, run until stopped")
    sim.add_argument("--speed", type=float, default=1.0, metavar="K",
                     help="run the simulation K times faster than real time (every component, "
                          "camera latency included, follows the simulated clock)")
    sim.add_argument("--devices", default=",".join(DEVICES),
                     help="comma-separated simulated devices to start; others can attach later")
    sim.add_argument("--camera-latency-s", type=float, default=0.11,
                     help="capture latency of the simulated OV9655 camera")
    sim.add_argument("--seed", type=int, default=None,
                     help="seed for every random source (default: the scenario's)")
    sim.add_argument("--summary", type=Path, default=None, metavar="FILE.json",
                     help="write a JSON summary of the run when it ends")
    sim.add_argument("--record", type=Path, default=None, metavar="DIR",
                     help="write trajectory.csv, trajectory.png and annotated camera frames")
    sim.add_argument("--record-every-s", type=float, default=2.0, metavar="S",
                     help="simulated seconds between recorded camera frames")


def parse_devices(text: str) -> list[str]:
    devices = [d.strip() for d in text.split(",") if d.strip()]
    unknown = sorted(set(devices) - set(DEVICES))
    if unknown:
        raise SystemExit(f"error: --devices: unknown {unknown}; choose from {list(DEVICES)}")
    return devices


def window_summary(windows: list[float]) -> dict[str, Any] | None:
    """Median, 1st percentile and worst of the per-window real-time factors
    (``RTF_WINDOW_S`` of wall time each)."""
    if not windows:
        return None
    ordered = sorted(windows)
    return {"window_s": RTF_WINDOW_S, "count": len(ordered),
            "median": statistics.median(ordered), "p1": ordered[int(0.01 * (len(ordered) - 1))],
            "min": ordered[0]}


class SimulationRun:
    """Everything the simulated robot adds to a launch."""

    def __init__(self, *, bus: Bus, clock: SimClock, args: argparse.Namespace) -> None:
        if not args.speed > 0:
            raise SystemExit(f"error: --speed must be > 0, got {args.speed}")
        try:
            self.scenario = load_scenario(args.scenario or DEFAULT_SCENARIO)
        except ScenarioError as exc:
            raise SystemExit(f"error: --scenario: {exc}") from None
        self.args = args
        self.bus = bus
        self.clock = clock
        self.seed = self.scenario.seed if args.seed is None else args.seed
        config = self.scenario.world
        if args.seed is not None:
            config = replace(config, seed=args.seed)
        self.world = World(config)
        self.scenario.install(self.world)
        self.devices = parse_devices(args.devices)
        self.simulator = SimulatorComponent(bus=bus, world=self.world, clock=clock,
                                            speed=args.speed)
        self.device_components = simulated_devices(
            bus=bus, world=self.world, devices=self.devices,
            camera_latency_s=args.camera_latency_s, seed=self.seed,
        )
        self.samples: list[TrajectorySample] = []
        self.frames: list[Path] = []
        self._tasks: list[asyncio.Task[None]] = []
        self._wall_start = time.monotonic()

    # -- what launch asks ---------------------------------------------------------------------
    @property
    def search_period_s(self) -> float:
        return self.scenario.search_period_s

    @property
    def duration_s(self) -> float | None:
        """Simulated seconds to run: ``--duration``, else the scenario's when one was named."""
        if self.args.duration is not None:
            return self.args.duration
        return self.scenario.duration_s if self.args.scenario else None

    def components(self) -> list[Component]:
        return [*self.device_components, self.simulator]

    def elapsed_s(self) -> float:
        """Simulated time, as the robot's clock has it (whole nanoseconds: no float drift)."""
        return self.clock.now_ns() / 1e9

    async def until_elapsed(self, duration_s: float) -> None:
        """Return once simulated time has reached ``duration_s``."""
        await self.clock.sleep_until_ns(round(duration_s * 1e9))

    def describe(self) -> str:
        return (f"simulated Mini-WHEGS, scenario {self.scenario.name!r} ({self.scenario.source}), "
                f"{self.args.speed:g}x real time, seed {self.seed}, devices: "
                f"{', '.join(self.devices) or 'none'}")

    def status_suffix(self) -> str:
        rtf = self.simulator.real_time_factor()
        return f"sim {self.world.time_s:.1f}s x{rtf:.2f}" if rtf else ""

    def start(self, controller: Controller) -> None:
        """Begin sampling the trajectory (and frames) once the controller exists."""
        if self.duration_s is not None:
            # Simulated time stops exactly at the end, however late launch notices it, so a
            # run ends in the same state at any speed.
            self.clock.hold(round(self.duration_s * 1e9))
        self._tasks.append(asyncio.create_task(self._sample(controller), name="sim:record"))
        if self.args.record is not None:
            self.args.record.mkdir(parents=True, exist_ok=True)
            self._tasks.append(asyncio.create_task(self._record_frames(), name="sim:frames"))

    def _take_sample(self, controller: Controller) -> None:
        snap = self.world.snapshot()
        if self.samples and self.samples[-1].t_s == snap.time_s:
            return
        last = controller.last_action
        trace = controller.last_trace
        self.samples.append(TrajectorySample(
            t_s=snap.time_s, robot_x_m=snap.robot.x_m, robot_y_m=snap.robot.y_m,
            robot_heading_rad=snap.robot.heading_rad,
            ball_x_m=snap.ball.x_m if snap.ball else None,
            ball_y_m=snap.ball.y_m if snap.ball else None,
            speed_cmd=last.speed if last else None, turn_cmd=last.turn if last else None,
            winners="+".join(trace.winning_leaves()) if trace else "",
        ))

    async def _sample(self, controller: Controller) -> None:
        while True:
            self._take_sample(controller)
            await self.clock.sleep(SAMPLE_PERIOD_S)

    async def _record_frames(self) -> None:
        camera = SimCameraBackend(self.world)
        folder = self.args.record
        while True:
            t_s = self.world.time_s
            camera.expose()  # the picture shows this instant, however late the thread runs
            await asyncio.to_thread(self._write_frame, camera, folder, t_s)
            await self.clock.sleep(self.args.record_every_s)

    def _write_frame(self, camera: SimCameraBackend, folder: Path, t_s: float) -> None:
        frame = camera.capture()
        image = annotate_frame(frame, seekcolor(frame), t_s=t_s)
        path = folder / f"frame_{t_s:07.2f}s.png"
        cv2.imwrite(str(path), image)
        self.frames.append(path)

    async def finish(self, controller: Controller, out: TextIO) -> dict[str, Any]:
        """Stop sampling; write the summary and recording; return the summary."""
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        await self.simulator.aclose()  # freeze the world: summary and trajectory end together
        self._take_sample(controller)
        summary = self.summary(controller)
        if self.args.record is not None:
            folder = self.args.record
            await asyncio.to_thread(self._write_recording, folder)
            summary["recording"] = {"dir": str(folder), "trajectory_csv": "trajectory.csv",
                                    "trajectory_png": "trajectory.png",
                                    "frames": [p.name for p in self.frames]}
            print(f"  recorded {len(self.samples)} samples and {len(self.frames)} frames "
                  f"in {folder}", file=out)
        if self.args.summary is not None:
            text = json.dumps(summary, indent=2)
            await asyncio.to_thread(self.args.summary.write_text, text, "utf-8")
            print(f"  summary written to {self.args.summary}", file=out)
        return summary

    def _write_recording(self, folder: Path) -> None:
        write_trajectory_csv(folder / "trajectory.csv", self.samples)
        image = plot_trajectory(self.samples, self.world.snapshot(),
                                title=f"{self.scenario.title} (seed {self.seed})")
        cv2.imwrite(str(folder / "trajectory.png"), image)
        camera = SimCameraBackend(self.world)
        self._write_frame(camera, folder, self.world.time_s)  # the final view

    def summary(self, controller: Controller) -> dict[str, Any]:
        snap = self.world.snapshot()
        robot = snap.robot
        wall_s = time.monotonic() - self._wall_start
        out: dict[str, Any] = {
            "scenario": self.scenario.name,
            "title": self.scenario.title,
            "source": self.scenario.source,
            "seed": self.seed,
            "sim_time_s": snap.time_s,
            "wall_time_s": wall_s,
            "real_time_factor": self.simulator.real_time_factor(),
            "real_time_factor_windows": window_summary(self.simulator.rtf_windows),
            "speed_requested": self.args.speed,
            "robot": {"x_m": robot.x_m, "y_m": robot.y_m, "heading_rad": robot.heading_rad},
            "ball": None,
            "ball_distance_m": None,
            "ball_bearing_deg": None,
            "motion_last_2s": motion_over(self.samples, 2.0),
            "ticks": controller.stats.summary(),
            "camera_frames": sum(getattr(d, "frames", 0) for d in self.device_components),
            "trajectory_samples": len(self.samples),
        }
        if snap.ball is not None:
            distance, bearing = camera_to_ball(robot.x_m, robot.y_m, robot.heading_rad,
                                               snap.ball.x_m, snap.ball.y_m)
            out["ball"] = {"x_m": snap.ball.x_m, "y_m": snap.ball.y_m}
            out["ball_distance_m"] = distance
            out["ball_bearing_deg"] = bearing
        return out
