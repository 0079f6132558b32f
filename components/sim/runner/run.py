"""One simulated run of the Mini-WHEGS, as launch drives it through the simulator seam.

:class:`SimulationRun` implements :class:`ubf_async.assembly.simulation.OpenSimulation` (the
:class:`~components.sim.plugin.MiniWhegsSimulator` plug-in's ``open()`` builds it from
:class:`~ubf_async.assembly.simulation.SimulationOptions`): the world the simulated device backends
are given, the simulator component, simulated time, the status-line suffix and, at the end, the
summary (``summary_path``) and recording (``record_dir``: trajectory.csv, trajectory.png,
annotated camera frames). Launch builds the devices (from the robot file, through the
registry) and hands them over with :meth:`SimulationRun.add_devices`.

Memory stays bounded however long a run lasts (docs/resources.md): the trajectory is sampled
every ``SAMPLE_PERIOD_S`` into a :class:`~components.sim.outputs.trajectory.TrajectoryBuffer` (a
decimated history of the whole run plus the last minute at full rate: what the plot and the
summary need), and with ``trajectory_path`` or ``record_dir`` every sample is also streamed to a
``trajectory.csv`` as the run goes, in batches written by a worker thread.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import statistics
import threading
import time
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, TextIO

import cv2

from components.camera.component import CameraComponent
from components.camera.seekcolor import seekcolor
from components.encoders.component import EncodersComponent
from components.sim.backends.devices import SimCameraBackend
from components.sim.outputs.trajectory import (
    BallView,
    TrajectoryBuffer,
    TrajectoryCsvWriter,
    TrajectorySample,
    annotate_frame,
    camera_to_ball,
    motion_over,
    trajectory_sample,
)
from components.sim.runner.disturbances import HeadingAudit
from components.sim.runner.stepper import RTF_WINDOW_S, SimulatorComponent
from components.sim.scenarios.scenario import Scenario, load_scenario
from components.sim.world.config import RobotConfig
from components.sim.world.physics import World, wrap_angle
from components.sim.world.snapshot import WorldSnapshot
from ubf_async import __version__
from ubf_async.assembly.simulation import FLAT_OUT, SimulationOptions, describe_speed
from ubf_async.clocks.clock import SimClock, every
from ubf_async.errors import ConfigurationError
from ubf_async.runtime.bus import Bus, Subscription
from ubf_async.runtime.component import Component
from ubf_async.runtime.controller import Controller
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import LED_STATE, LedState

__all__ = ["CSV_BATCH_SAMPLES", "DEFAULT_SCENARIO", "LISTED_FRAMES", "SAMPLE_PERIOD_S",
           "SIGNIFICANT_DIGITS", "SLOW_SHARE", "SimulationRun", "check_options", "lateness_summary",
           "rounded", "save_run_plot", "window_summary"]


def save_run_plot(path: Path, samples: Sequence[TrajectorySample], world: WorldSnapshot, *,
                  title: str, events: Sequence[tuple[float, str]] = ()) -> Any:
    """:func:`components.sim.outputs.plots.save_run_plot`, matplotlib imported when a plot is first
    drawn: a run that draws none (no ``--record``, a library run) does not pay for its import
    (a third of a second, half of what launching the simulator imports). Returns the
    :class:`~matplotlib.figure.Figure`."""
    from components.sim.outputs import plots

    return plots.save_run_plot(path, samples, world, title=title, events=events)


SLOW_SHARE = 0.95
"""A run is reported slow when it reached less than this share of the speed asked for."""
SIGNIFICANT_DIGITS = 6
"""Numbers in the summary keep this many significant digits."""


def rounded(value: Any) -> Any:
    """``value`` with every float rounded to :data:`SIGNIFICANT_DIGITS` significant digits."""
    if isinstance(value, float):
        return float(f"{value:.{SIGNIFICANT_DIGITS}g}") if math.isfinite(value) else value
    if isinstance(value, dict):
        return {k: rounded(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [rounded(v) for v in value]
    return value

log = logging.getLogger(__name__)

DEFAULT_SCENARIO = "ball-in-sight"
SAMPLE_PERIOD_S = 0.05
CSV_BATCH_SAMPLES = 100
"""Samples handed to the writer thread at a time (5 s of simulated time)."""
LISTED_FRAMES = 1000
"""Most recorded frame names the summary lists (the last ones; ``frames_written`` counts all)."""


def check_options(options: SimulationOptions) -> Scenario:
    """The run's scenario, loaded and validated, once ``options`` are checked. Raises
    :class:`ConfigurationError` or :class:`~ubf_async.errors.ScenarioError`."""
    if not options.speed > 0:
        raise ConfigurationError(f"speed must be > 0 (or math.inf: flat out), got "
                                 f"{options.speed}")
    if options.duration_s is not None and not options.duration_s > 0:
        raise ConfigurationError(f"duration must be > 0 simulated seconds, got "
                                 f"{options.duration_s}")
    if options.lockstep_participants < 0:
        raise ConfigurationError(f"lockstep participants must be >= 0, got "
                                 f"{options.lockstep_participants}")
    if not options.record_every_s > 0:
        raise ConfigurationError(f"record_every_s must be > 0, got {options.record_every_s}")
    return load_scenario(options.scenario or DEFAULT_SCENARIO)


def window_summary(windows: Sequence[float]) -> dict[str, Any] | None:
    """Median, 1st percentile and worst of the per-window real-time factors
    (``RTF_WINDOW_S`` of wall time each)."""
    if not windows:
        return None
    ordered = sorted(windows)
    return {"window_s": RTF_WINDOW_S, "count": len(ordered),
            "median": statistics.median(ordered), "p1": ordered[int(0.01 * (len(ordered) - 1))],
            "min": ordered[0]}


def lateness_summary(lateness_s: Sequence[float]) -> dict[str, Any] | None:
    """Median, 99th percentile and worst of the steps' lateness (wall time after their due
    time, :attr:`~components.sim.runner.stepper.SimulatorComponent.step_lateness_s`), in ms."""
    if not lateness_s:
        return None
    ordered = sorted(lateness_s)
    return {"steps": len(ordered), "median_ms": statistics.median(ordered) * 1e3,
            "p99_ms": ordered[int(0.99 * (len(ordered) - 1))] * 1e3, "max_ms": ordered[-1] * 1e3}


class SimulationRun:
    """Everything the simulated Mini-WHEGS adds to a launch (see the module docstring).

    Raises :class:`~ubf_async.errors.ConfigurationError` for a bad speed, duration or
    recording period, and :class:`~ubf_async.errors.ScenarioError` for an unknown or invalid
    scenario.
    """

    def __init__(self, *, bus: Bus, clock: SimClock, options: SimulationOptions) -> None:
        self.scenario = check_options(options)
        self.options = options
        self.bus = bus
        self.clock = clock
        self._seed = self.scenario.seed if options.seed is None else options.seed
        config = self.scenario.world
        if options.seed is not None:
            config = replace(config, seed=options.seed)
        if options.body is not None:  # the robot file's body (the default: the Mini-WHEGS)
            config = replace(config, robot=RobotConfig.from_body(
                options.body, camera_x_m=options.camera_x_m))
        self._world = World(config)
        self.scenario.install(self._world)
        self.simulator = SimulatorComponent(
            bus=bus, world=self._world, clock=clock, speed=options.speed,
            lockstep_participants=options.lockstep_participants)
        self.devices: list[Component] = []
        self.trajectory_buffer = TrajectoryBuffer()
        self.ball_view = BallView(camera_x_m=config.robot.camera_x_m)
        self._every_sample: list[TrajectorySample] | None = (
            [] if options.keep_trajectory else None)
        self.frames: deque[Path] = deque(maxlen=LISTED_FRAMES)
        """The last ``LISTED_FRAMES`` frames written (``frames_written`` counts them all)."""
        self.frames_written = 0
        self._last_frame: Path | None = None
        """The last frame begun (frames are taken in time order)."""
        self._csv: TrajectoryCsvWriter | None = None
        self._csv_write: asyncio.Future[None] | None = None
        self._recording_errors: list[str] = []
        self._frames_lock = threading.Lock()
        self._tasks: list[asyncio.Task[None]] = []
        self._wall_start = time.monotonic()
        self.audit = HeadingAudit()
        """Contacts and pushes, and the odometry's heading against the truth, sample by
        sample (the summary's ``contacts`` and ``odometry``): at every odometry update of
        the encoders in this process, else with the trajectory's samples."""
        self._audited_encoders: EncodersComponent | None = None
        self._audited_s = -math.inf
        self.leds: dict[str, LedState] = {}
        """What each LED device reports lit (``sensor/leds/<name>``), while recording."""
        self._leds_malformed: dict[str, int] = {}
        self._led_sub: Subscription | None = None

    # -- what launch asks ---------------------------------------------------------------------
    @property
    def samples(self) -> list[TrajectorySample]:
        """The trajectory kept in memory: the whole run decimated, the last minute at full
        rate (:class:`~components.sim.outputs.trajectory.TrajectoryBuffer`). A copy: build it
        sparingly."""
        return self.trajectory_buffer.samples()

    def trajectory(self) -> list[dict[str, Any]]:
        """Every sample, as ``trajectory.csv``'s rows (``options.keep_trajectory``)."""
        return [asdict(s) for s in self._every_sample or ()]

    @property
    def seed(self) -> int:
        """The seed of every random source: ``options.seed``, else the scenario's."""
        return self._seed

    @property
    def world(self) -> World:
        """The world simulated backends read and drive (``DeviceContext.simulation``)."""
        return self._world

    @property
    def duration_s(self) -> float | None:
        """Simulated seconds to run: ``options.duration_s``, else the scenario's when one was
        named, else ``None`` (until stopped)."""
        if self.options.duration_s is not None:
            return self.options.duration_s
        return self.scenario.duration_s if self.options.scenario else None

    def components(self) -> list[Component]:
        """The simulator component (the devices are launch's, see :meth:`add_devices`)."""
        return [self.simulator]

    def add_devices(self, devices: Iterable[Component]) -> None:
        """The robot's device components, for the summary's counts (camera frames)."""
        self.devices.extend(devices)

    def elapsed_s(self) -> float:
        """Simulated time, as the robot's clock has it (whole nanoseconds: no float drift)."""
        return self.clock.now_ns() / 1e9

    async def until_elapsed(self, duration_s: float) -> None:
        """Return once simulated time has reached ``duration_s``."""
        await self.clock.sleep_until_ns(round(duration_s * 1e9))

    def describe(self) -> str:
        return (f"simulated Mini-WHEGS, scenario {self.scenario.name!r} ({self.scenario.source}), "
                f"{describe_speed(self.options.speed)}, seed {self.seed}")

    def status_suffix(self) -> str:
        rtf = self.simulator.real_time_factor()
        return f"sim {self.world.time_s:.1f}s x{rtf:.2f}" if rtf else ""

    def start(self, controller: Controller) -> None:
        """Begin sampling the trajectory (and frames) once the controller exists."""
        if self.duration_s is not None:
            # Simulated time stops exactly at the end, however late launch notices it, so a
            # run ends in the same state at any speed.
            self.clock.hold(round(self.duration_s * 1e9))
        if self.options.record_dir is not None:
            self.options.record_dir.mkdir(parents=True, exist_ok=True)
        if (csv_path := self.trajectory_path()) is not None:
            self._csv = TrajectoryCsvWriter(csv_path)
        self._audited_encoders = self._encoders()
        if self._audited_encoders is not None:
            self._audit()  # where both headings start
            self._audited_encoders.update_hooks.append(self._audit)
        self._tasks.append(asyncio.create_task(self._sample(controller), name="sim:record"))
        if self.options.record_dir is not None:
            # The LEDs as their devices report them (in this process or another): drawn on
            # the recorded frames.
            self._led_sub = self.bus.subscribe_topic(LED_STATE.key_expr(self.bus.keys),
                                                     LED_STATE, self._on_leds,
                                                     self._leds_malformed)
            self._tasks.append(asyncio.create_task(self._record_frames(), name="sim:frames"))

    def trajectory_path(self) -> Path | None:
        """Where every trajectory sample is streamed: ``options.trajectory_path``, else
        ``trajectory.csv`` of the recording, else nowhere."""
        if self.options.trajectory_path is not None:
            return self.options.trajectory_path
        folder = self.options.record_dir
        return folder / "trajectory.csv" if folder is not None else None

    def _encoders(self) -> EncodersComponent | None:
        return next((d for d in self.devices if isinstance(d, EncodersComponent)), None)

    def _audit(self) -> None:
        """One sample of the heading audit: the world now, the encoders' odometry (when
        they are in this process, called right after they read the wheels from this very
        world state, so both headings are of the same instant) and what touched the robot
        since the previous sample."""
        snap = self.world.snapshot()
        if snap.time_s == self._audited_s:
            return
        encoders = self._audited_encoders
        self.audit.add(
            t_s=snap.time_s, true_heading_rad=snap.robot.heading_unwrapped_rad,
            odometry_heading_rad=(encoders.odometry.heading_unwrapped_rad
                                  if encoders is not None else None),
            touched=[self._contact_name(label)
                     for label, t_s in self.world.contacts().items() if t_s > self._audited_s])
        self._audited_s = snap.time_s

    def _take_sample(self, controller: Controller) -> None:
        snap = self.world.snapshot()
        last_sample = self.trajectory_buffer.last
        if last_sample is not None and last_sample.t_s == snap.time_s:
            return
        if self._audited_encoders is None:
            self._audit()  # without encoders here: contacts and the true turn only
        last = controller.last_action
        trace = controller.last_trace
        sample = trajectory_sample(
            snap, speed_cmd=last.speed if last else None, turn_cmd=last.turn if last else None,
            winners="+".join(trace.winning_leaves()) if trace else "")
        self.trajectory_buffer.append(sample)
        self.ball_view.add(sample)
        if self._every_sample is not None:
            self._every_sample.append(sample)
        if self._csv is not None:
            self._csv.add(sample)

    async def _sample(self, controller: Controller) -> None:
        while True:
            self._take_sample(controller)
            if self._csv is not None and self._csv.pending >= CSV_BATCH_SAMPLES:
                await self._write_csv_batch()
            await self.clock.sleep(SAMPLE_PERIOD_S)

    async def _write_csv_batch(self) -> None:
        """Hand the pending samples to a writer thread. At most one batch is in flight: a
        slow disk makes sampling wait (bounded memory) rather than batches pile up."""
        await self._csv_written()
        if self._csv is not None:
            self._csv_write = asyncio.ensure_future(asyncio.to_thread(self._csv.write,
                                                                      self._csv.take()))

    async def _csv_written(self) -> None:
        """Wait for the batch in flight. A failed write stops the streaming (logged, and
        reported in the summary); the run goes on."""
        if self._csv_write is None:
            return
        try:
            # Shielded: cancelling the sampler must not cancel (and so lose) a batch.
            await asyncio.shield(self._csv_write)
        except OSError as exc:
            if self._csv is not None:
                log.error("trajectory.csv: %s; no more samples are written to it", exc)
                self._recording_errors.append(f"trajectory.csv: {exc}")
                self._csv.take()
                self._csv = None
        finally:
            if self._csv_write.done():
                self._csv_write = None

    async def _record_frames(self) -> None:
        camera = SimCameraBackend(self.world)
        folder = self.options.record_dir
        assert folder is not None
        async for now_ns in every(self.clock, self.options.record_every_s):
            t_s = now_ns / 1e9
            camera.expose()  # the picture shows this instant, however late the thread runs
            leds = dict(self.leds)  # and the LEDs as lit at this instant, not when it runs
            # Simulated time waits for the frame (a lockstep barrier does not see a thread's
            # work): frames fall on the same instants at any speed, on any machine.
            hold = self.clock.hold(now_ns)
            try:
                await asyncio.to_thread(self._write_frame, camera, folder, t_s, leds)
            finally:
                hold.release()

    def _on_leds(self, key: str, message: Message[LedState], received_ns: int) -> None:
        self.leds[key.rsplit("/", 1)[-1]] = message.data

    def _write_frame(self, camera: SimCameraBackend, folder: Path, t_s: float,
                     leds: dict[str, LedState]) -> None:
        path = folder / f"frame_{t_s:07.2f}s.png"
        with self._frames_lock:  # the final frame may overlap a cancelled periodic one
            # A run that ends on a recording instant has its periodic frame of that instant
            # already: the final view would be the same file, listed and counted again.
            if path == self._last_frame:
                return
            self._last_frame = path
        frame = camera.capture()
        image = annotate_frame(frame, seekcolor(frame), t_s=t_s, leds=leds)
        cv2.imwrite(str(path), image)
        with self._frames_lock:
            self.frames.append(path)
            self.frames_written += 1

    async def finish(self, controller: Controller, out: TextIO) -> dict[str, Any]:
        """Stop sampling; write the summary, then the recording; return the summary. What
        it reports goes to ``out`` once everything is written: the summary first (the result a
        script waits for), the recording after, so a run stopped while its end writes loses
        the least."""
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        if self._led_sub is not None:
            self._led_sub.close()
        await self.simulator.aclose()  # freeze the world: summary and trajectory end together
        if self._audited_encoders is not None:
            self._audited_encoders.update_hooks.remove(self._audit)
        self._take_sample(controller)
        summary = self.summary(controller)
        folder = self.options.record_dir
        await self._csv_written()  # the batch in flight lands before the rest
        if folder is not None:
            summary["recording"] = self._recording_summary(folder)
        summary = rounded(summary)
        await self._write_summary(summary)
        report = []
        rest = self._csv.take() if self._csv is not None else []
        if folder is not None:
            try:
                await asyncio.to_thread(self._write_recording, folder, rest)
            except OSError as exc:  # the summary is written
                log.error("recording in %s: %s", folder, exc)
                self._recording_errors.append(str(exc))
            summary["recording"] = self._recording_summary(folder)
            await self._write_summary(summary)  # again: with the last frame, and what failed
            report.append(f"  recorded {self.trajectory_buffer.count} samples and "
                          f"{self.frames_written} frames in {folder}")
        elif self._csv is not None:
            try:
                await asyncio.to_thread(self._finish_csv, rest)
                report.append(f"  trajectory written to {self._csv.path}")
            except OSError as exc:  # the summary is written
                log.error("%s: %s", self._csv.path, exc)
                report.append(f"  warning: the trajectory could not be written: {exc}")
        expected = summary.get("expected")
        if expected is not None:
            failed = [c["criterion"] for c in expected["criteria"] if not c["pass"]]
            verdict = (f"not applicable ({expected['why']})" if not expected["applicable"]
                       else f"not judged ({expected['why']})" if not expected["judged"]
                       else "not checked (the scenario gives no criteria)"
                       if expected["pass"] is None
                       else "met" if not failed else f"NOT met ({', '.join(failed)})")
            report.append(f"  expected: {expected['outcome']} — {verdict}")
        report += [f"  warning: {warning}" for warning in summary["warnings"]]
        if self.options.summary_path is not None:
            report.append(f"  summary written to {self.options.summary_path}")
        for line in report:
            print(line, file=out)
        return summary

    def _recording_summary(self, folder: Path) -> dict[str, Any]:
        return {"dir": str(folder), "trajectory_csv": "trajectory.csv",
                "trajectory_png": "trajectory.png",
                "frames": [p.name for p in self.frames],
                "frames_written": self.frames_written, "errors": list(self._recording_errors)}

    async def _write_summary(self, summary: dict[str, Any]) -> None:
        if self.options.summary_path is not None:
            text = json.dumps(summary, indent=2, ensure_ascii=False)
            await asyncio.to_thread(self.options.summary_path.write_text, text, "utf-8")

    def _finish_csv(self, rest: list[TrajectorySample]) -> None:
        if self._csv is not None:
            self._csv.write(rest)
            self._csv.close()

    def _write_recording(self, folder: Path, rest: list[TrajectorySample]) -> None:
        self._finish_csv(rest)
        events = [(step.at_s, f"ball: {step.kind}") for step in self.scenario.ball_script]
        save_run_plot(folder / "trajectory.png", self.samples, self.world.snapshot(),
                      title=f"{self.scenario.title} (seed {self.seed})", events=events)
        camera = SimCameraBackend(self.world)
        self._write_frame(camera, folder, self.world.time_s, dict(self.leds))  # the final view

    def _contact_name(self, label: str) -> str:
        """A world's contact label with the scenario's name for a distractor."""
        if label.startswith("distractors["):
            index = int(label[len("distractors["):-1])
            names = self.scenario.distractor_names
            if index < len(names):
                return names[index]
        return label

    def odometry_summary(self) -> dict[str, Any] | None:
        """The encoders' odometry against the true pose (None without an encoders device in
        this process): odometry starts at the origin of its own frame, which is the robot's
        start pose. The heading error compares the unwrapped headings (full turns count);
        ``heading_error_fraction`` is it over the total angle the robot turned, and
        ``undisturbed`` the same over the sample intervals in which nothing touched or pushed
        the robot (docs/scenarios.md, Outputs)."""
        encoders = self._encoders()
        if encoders is None:
            return None
        odo = encoders.odometry.pose
        start = self.scenario.world.robot_start
        c, s = math.cos(start.heading_rad), math.sin(start.heading_rad)
        x = start.x_m + c * odo.x_m - s * odo.y_m
        y = start.y_m + s * odo.x_m + c * odo.y_m
        heading = wrap_angle(start.heading_rad + odo.heading_rad)
        robot = self.world.snapshot().robot
        return {"x_m": x, "y_m": y, "heading_rad": heading,
                "effective_track_m": encoders.odometry.track_m,
                "position_error_m": math.hypot(x - robot.x_m, y - robot.y_m),
                **self.audit.heading_summary()}

    def interrupted(self) -> dict[str, float] | None:
        """``{"at_s", "of_s"}`` for a run with a duration that ended before simulated time
        reached it (stopped by a signal, or by whoever drives the run), else ``None``. Its
        expectation is then not judged: the outcome describes the end of a whole run."""
        duration = self.duration_s
        if duration is None or self.clock.now_ns() >= round(duration * 1e9):
            return None
        return {"at_s": self.elapsed_s(), "of_s": duration}

    def summary(self, controller: Controller) -> dict[str, Any]:
        snap = self.world.snapshot()
        robot = snap.robot
        wall_s = time.monotonic() - self._wall_start
        samples = self.samples
        out: dict[str, Any] = {
            "scenario": self.scenario.name,
            "title": self.scenario.title,
            "source": self.scenario.source,
            "seed": self.seed,
            "sim_time_s": snap.time_s,
            "wall_time_s": wall_s,
            "real_time_factor": self.simulator.real_time_factor(),
            "real_time_factor_windows": window_summary(self.simulator.rtf_windows),
            "speed_requested": (FLAT_OUT if self.options.speed == math.inf
                                else self.options.speed),
            "interrupted": self.interrupted(),
            "robot": {"x_m": robot.x_m, "y_m": robot.y_m, "heading_rad": robot.heading_rad},
            "ball": None,
            "ball_distance_m": None,
            "ball_bearing_deg": None,
            "motion_last_2s": motion_over(samples, 2.0),
            "ball_view": self.ball_view.summary(),
            "ticks": controller.stats.summary(),
            "camera_frames": sum(d.frames for d in self.devices
                                 if isinstance(d, CameraComponent)),
            "trajectory_samples": self.trajectory_buffer.count,
            "trajectory_samples_kept": len(samples),
        }
        out["contacts"] = self.audit.contacts_summary()
        out["odometry"] = self.odometry_summary()
        if snap.ball is not None:
            distance, bearing = camera_to_ball(robot.x_m, robot.y_m, robot.heading_rad,
                                               snap.ball.x_m, snap.ball.y_m,
                                               camera_x_m=self.world.config.robot.camera_x_m)
            out["ball"] = {"x_m": snap.ball.x_m, "y_m": snap.ball.y_m}
            out["ball_distance_m"] = distance
            out["ball_bearing_deg"] = bearing
        out["distractors"] = {}
        for name, d in zip(self.scenario.distractor_names, snap.distractors, strict=False):
            distance, bearing = camera_to_ball(robot.x_m, robot.y_m, robot.heading_rad,
                                               d.x_m, d.y_m,
                                               camera_x_m=self.world.config.robot.camera_x_m)
            out["distractors"][name] = {"x_m": d.x_m, "y_m": d.y_m, "distance_m": distance,
                                        "bearing_deg": bearing}
        won = out["ticks"].get("winner_share") or {}
        expect = self.scenario.expect
        open_ended = self.duration_s is None and not self.options.judge_open_ended
        out["expected"] = (expect.judge(out, ran=lambda name: controller.runs(name) or
                                        name in won,
                                        open_ended_s=self.elapsed_s() if open_ended else None)
                           if expect is not None else None)
        out["quarantined"] = controller.quarantined()
        out["tree_changes"] = list(controller.tree_changes)
        out["warnings"] = []
        if out["quarantined"]:
            out["warnings"].append(
                f"quarantined (they kept failing, and stopped voting): "
                f"{', '.join(out['quarantined'])}")
        if out["tree_changes"]:
            first = out["tree_changes"][0]
            out["warnings"].append(
                f"the tree was changed during the run ({len(out['tree_changes'])} change(s), "
                f"the first at {first['at_s']:.2f} s: {first['what']}): the run is not the "
                f"robot file's")
        rtf = out["real_time_factor"]
        if rtf is not None and math.isfinite(self.options.speed) \
                and rtf < SLOW_SHARE * self.options.speed:
            out["warnings"].append(
                f"the run reached {rtf:.2f}x real time, short of the {self.options.speed:g}x "
                f"asked for (--speed): the machine could not keep up")
        out["command_line"] = list(self.options.command_line)
        out["version"] = __version__
        return out
