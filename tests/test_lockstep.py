"""Lockstep simulated time: the same run, byte for byte, at any speed, on any machine.

That a run does not depend on how fast it goes is a property of the simulator and its
lockstep, shown on runs in this process (:mod:`ubf_async.runs.inprocess`, flat out): idle and
beside a busy loop, rendering in a render process and in a thread. Pacing (``--speed``) exists
only in launch: one launch at a paced speed is compared with the same run in this process.
What crosses processes — a remote behaviour, a participant that vanishes or falls silent,
motors in another process — runs as processes (the fleet's controllers in their processes:
tests/test_fleet.py). Trajectories are compared byte for byte and summaries in full, apart
from the fields that measure wall time (:data:`WALL_FIELDS`).
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import json
import logging
import os
import re
import select
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any
from unittest import mock

import pytest

from bench.cpu_hog import available_cpus, hogs, pin_to
from components.sim.backends import devices as backends
from components.sim.backends.devices import RENDER_DELAY_ENV
from components.sim.outputs.trajectory import read_trajectory_csv
from components.sim.render.process import RenderProcess
from components.sim.scenarios.scenario import load_scenario
from tests.conftest import REPOSITORY, free_port, repository_env
from ubf_async.runs.fleet import run_fleet
from ubf_async.runs.inprocess import plan_run, run_plan
from ubf_async.runtime import lending

SCENARIOS = {"ball-in-sight": 15.0, "keep-away": 30.0, "dance": 20.0}
"""The thesis's scenarios and how many simulated seconds of each are compared: ball-in-sight
has settled by 15 s, keep-away's search has picked its random turns several times by 30 s,
dance's ball has moved nearer and farther by 20 s."""
SHORT_S = 3.0
"""Simulated seconds of the shorter runs that must be the beginning of the longer ones."""

WALL_FIELDS = (("wall_time_s",), ("real_time_factor",), ("real_time_factor_windows",),
               ("command_line",), ("ticks", "periodic_jitter_ms_p99"),
               ("ticks", "tick_us_p50"), ("ticks", "tick_us_max"), ("speed_requested",))
"""Summary fields measured in wall time, naming this run's paths, or the speed asked for."""

ROBOT = "mini-whegs"
"""The robot file of every run here (launch's default)."""


class Run:
    def __init__(self, folder: Path, output: str) -> None:
        self.folder = folder
        self.output = output
        self.trajectory = (folder / "trajectory.csv").read_bytes()
        self.summary: dict[str, Any] = json.loads((folder / "summary.json").read_text())

    def simulated_summary(self, *, without: tuple[tuple[str, ...], ...] = ()
                          ) -> dict[str, Any]:
        """The summary without its wall-time fields (and the fields ``without``)."""
        out = json.loads(json.dumps(self.summary))
        # Where launch's --record put its files and pictures (a run in this process draws
        # none): the trajectory they hold is compared byte for byte instead.
        out.pop("recording", None)
        for path in (*WALL_FIELDS, *without):
            parent = out
            for key in path[:-1]:
                parent = parent[key]
            del parent[path[-1]]
        # Whether the machine kept up with --speed is measured in wall time, too.
        out["warnings"] = [w for w in out["warnings"] if "asked for (--speed)" not in w]
        return out


def launch(folder: Path, scenario: str, duration_s: float, *, speed: str = "max",
           seed: int | None = None, more: tuple[str, ...] = ("--quiet",)) -> Run:
    """One run through the real launch path (``more``: its further options)."""
    folder.mkdir(parents=True)
    proc = subprocess.run(
        [sys.executable, "-m", "ubf_async.launch", "--scenario", scenario, "--speed", speed,
         "--duration", f"{duration_s:g}", "--listen", f"tcp/127.0.0.1:{free_port()}",
         "--robot", "lockstep", *(() if seed is None else ("--seed", str(seed))),
         "--summary", str(folder / "summary.json"), "--record", str(folder),
         "--record-every-s", "5", *more],
        cwd=REPOSITORY, env=repository_env(), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return Run(folder, proc.stdout + proc.stderr)


def in_process(folder: Path, scenario: str, duration_s: float, *, seed: int | None = None,
               render_process: RenderProcess | None = None) -> Run:
    """The same run in this process (:func:`ubf_async.runs.inprocess.run`: flat out, the
    in-process transport), its trajectory and summary written to ``folder``; its camera
    frames rendered in ``render_process`` (the render process launch's cameras use) if
    given, else in a thread of this process."""
    plan = plan_run(ROBOT, scenario, seed=seed, duration_s=duration_s, out_dir=folder)
    with contextlib.ExitStack() as stack:
        if render_process is not None:
            plan.helper_processes = True
            stack.enter_context(mock.patch.object(backends, "shared_render_process",
                                                  lambda: render_process))
        runner = stack.enter_context(asyncio.Runner(loop_factory=lending.new_idle_event_loop))
        runner.run(run_plan(plan))
    return Run(folder, "")


def assert_same(run: Run, reference: Run, label: str, *,
                without: tuple[tuple[str, ...], ...] = ()) -> None:
    assert run.trajectory == reference.trajectory, f"{label}: trajectories differ"
    assert (run.simulated_summary(without=without)
            == reference.simulated_summary(without=without)), label


@contextlib.contextmanager
def this_process_pinned_to(cpus: list[int]) -> Iterator[None]:
    """Every thread of this process — and so every thread they start — on ``cpus`` only
    (what :func:`bench.cpu_hog.pin_to` does to a child process); each thread's own cores
    back afterwards."""
    def threads() -> list[int]:
        return [int(tid) for tid in os.listdir("/proc/self/task")]

    before = {tid: os.sched_getaffinity(tid) for tid in threads()}
    for tid in before:
        with contextlib.suppress(ProcessLookupError):  # a thread that has just ended
            os.sched_setaffinity(tid, cpus)
    try:
        yield
    finally:
        for tid in threads():
            with contextlib.suppress(ProcessLookupError):
                os.sched_setaffinity(tid, before.get(tid, before[threading.get_native_id()]))


@pytest.fixture(scope="module")
def render_process() -> Iterator[RenderProcess]:
    """A render process of this test module's own (not the worker's shared one): ended with
    the module, leaving no process behind."""
    renderer = RenderProcess()
    yield renderer
    renderer.close()


@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_a_scenario_runs_the_same_however_rendered_and_under_load(
        tmp_path: Path, scenario: str, render_process: RenderProcess) -> None:
    """In this process, flat out: camera frames rendered in a render process (as launch
    renders them), and rendered in a thread with the whole process pinned to one core beside
    a busy loop on it — the same trajectory and summary; and a shorter run is the longer
    one's beginning. (At a paced speed, through launch: the next test.)"""
    duration = SCENARIOS[scenario]
    rendered_before = render_process.rendered
    reference = in_process(tmp_path / "render-process", scenario, duration,
                           render_process=render_process)
    assert render_process.rendered - rendered_before >= reference.summary["camera_frames"]
    core = available_cpus()[:1]
    with this_process_pinned_to(core), hogs(core) as busy:
        assert os.sched_getaffinity(0) == set(core) == os.sched_getaffinity(busy[0].pid)
        loaded = in_process(tmp_path / "loaded", scenario, duration)
    assert_same(loaded, reference, "in a thread, pinned beside a busy loop")
    # (That the busy loop is real: test_the_cpu_hog_loads_the_cores_it_is_given. Which run
    # was faster in wall time is not asserted: beside other tests, the idle one may not be.)

    short = in_process(tmp_path / "short", scenario, SHORT_S)
    # A longer run passes through the same states: a shorter one is its beginning.
    assert reference.trajectory.startswith(short.trajectory)
    assert short.summary["sim_time_s"] == pytest.approx(SHORT_S)


PACED_SPEED = 5
# 1.2 s of wall time at that speed: each 0.25-s real-time-factor window closes at the first
# step at or after its quarter, so a run of exactly 1 s holds 3 or 4 of them by chance.
PACED_S = 6.0


def test_a_paced_launch_is_the_run_flat_out_in_this_process(tmp_path: Path) -> None:
    """The real launch path at ``--speed 5`` (its camera frames rendered in its render
    process) and the same robot, scenario and seed flat out in this process (rendered in a
    thread): the same trajectory, to the last bit, and the same summary — every command and
    camera frame at the same simulated instants whatever rendering and scheduling cost in
    wall time. The launch kept to the speed asked: never ahead of it (a busy machine only
    slows it: how fast it gets is bench.realtime's figure), and says so in its summary and
    its status line."""
    paced = launch(tmp_path / "paced", "ball-in-sight", PACED_S, speed=str(PACED_SPEED),
                   seed=3, more=("--status-period-s", "0.5"))
    flat_out = in_process(tmp_path / "flat-out", "ball-in-sight", PACED_S, seed=3)
    assert paced.trajectory.count(b"\n") > 20 * PACED_S  # a row every 50 ms simulated
    assert_same(paced, flat_out, f"at --speed {PACED_SPEED}")
    assert (paced.summary["speed_requested"], flat_out.summary["speed_requested"]) == (
        PACED_SPEED, "max")
    factor = paced.summary["real_time_factor"]
    windows = paced.summary["real_time_factor_windows"]
    last = [line for line in paced.output.splitlines() if " x" in line and "sim " in line][-1]
    status = re.search(r"sim [\d.]+s x([\d.]+)", last)
    assert status is not None, last
    print(f"achieved real-time factor at --speed {PACED_SPEED}: {factor:.2f} (status line "
          f"{status.group(1)}; 0.25 s windows: median {windows['median']:.2f}, "
          f"min {windows['min']:.2f}); python -m bench.realtime measures it properly")
    assert 0 < factor <= PACED_SPEED * 1.01, paced.summary
    assert windows["count"] >= 4 and windows["median"] <= PACED_SPEED * 1.05, windows
    assert float(status.group(1)) > 0, last


def test_slow_camera_renders_cost_no_simulated_time(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    """Every camera frame made to take 300 ms of wall time (the render backend's test hook):
    the same run, and no safety limit taken in by the waiting — no watchdog stop, no stale
    source, no warning at all."""
    duration = 3.0
    normal = in_process(tmp_path / "normal", "ball-in-sight", duration)
    monkeypatch.setenv(RENDER_DELAY_ENV, "0.3")
    caplog.set_level(logging.INFO)
    slow = in_process(tmp_path / "slow", "ball-in-sight", duration)
    assert_same(slow, normal, "300 ms renders")
    frames = slow.summary["camera_frames"]
    assert frames >= 25  # every 0.11 s of 3 s simulated
    assert slow.summary["wall_time_s"] >= 0.3 * frames  # the renders did take that long
    ours = [r for r in caplog.records if r.name.startswith(("ubf_async", "components"))]
    logged = [f"{r.levelname} {r.name}: {r.getMessage()}" for r in ours]
    assert ours, "nothing logged: the capture is not seeing the run"
    assert not [r for r in ours if r.levelno >= logging.WARNING], logged
    for words in ("no drive command", "stale"):
        assert not [line for line in logged if words in line.lower()], logged
    assert slow.summary["warnings"] == []


def test_the_cpu_hog_loads_the_cores_it_is_given() -> None:
    """The load the tests and ``python -m bench.cpu_hog`` put beside a run is real."""
    core = available_cpus()[:1]
    with hogs(core) as procs:
        assert len(procs) == 1
        assert os.sched_getaffinity(procs[0].pid) == set(core)
        assert procs[0].poll() is None
    assert procs[0].poll() is not None  # stopped with the block


@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_stopped_cpu_hog_leaves_no_busy_loop_behind(how: signal.Signals) -> None:
    """``python -m bench.cpu_hog -- CMD`` stopped from outside, even by SIGKILL: its busy
    loops go with it (one left behind would load the machine unnoticed)."""
    hog = subprocess.Popen([sys.executable, "-m", "bench.cpu_hog", "--cpus",
                            str(available_cpus()[0]), "--", sys.executable, "-c",
                            "import sys; sys.stdin.read()"],  # ends when the test lets it
                           cwd=REPOSITORY, env=repository_env(), stdin=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    assert hog.stdin is not None and hog.stderr is not None
    with hog.stdin, hog.stderr:
        assert "busy loop(s)" in hog.stderr.readline()
        loops = busy_loops_of(hog.pid)
        assert len(loops) == 1
        hog.send_signal(how)
        hog.wait(timeout=30)
    for pidfd in loops:  # readable once that process has exited
        with contextlib.closing(select.epoll()) as waiting:
            waiting.register(pidfd, select.EPOLLIN)
            assert waiting.poll(30), "a busy loop outlived its hog"
        os.close(pidfd)


def busy_loops_of(parent: int) -> list[int]:
    """A pidfd (``os.pidfd_open``) for each busy loop ``parent`` started."""
    children = Path(f"/proc/{parent}/task/{parent}/children").read_text().split()
    return [os.pidfd_open(int(pid)) for pid in children
            if "while True" in Path(f"/proc/{pid}/cmdline").read_text(errors="replace")]


# ---------------------------------------------------------------------------------------------
# Participants in other processes


def launch_with_participant(folder: Path, *, duration_s: float, participant: list[str],
                            cpus: list[int] | None = None, speed: str = "max",
                            launch_args: tuple[str, ...] = (),
                            while_running: Callable[[subprocess.Popen[str],
                                                     subprocess.Popen[str]], None]
                            | None = None) -> Run:
    """obstacle-course (flat out unless ``speed``), holding its start for one lockstep
    participant: the command ``participant`` (given ``--connect EP --robot R``), in its own
    process; ``while_running(participant, robot)`` is called once both are started."""
    folder.mkdir(parents=True)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    pin = None if cpus is None else (lambda: pin_to(cpus))
    robot = subprocess.Popen(
        [sys.executable, "-m", "ubf_async.launch", "--scenario", "obstacle-course", "--speed",
         speed, "--duration", f"{duration_s:g}", "--listen", endpoint, "--robot", "lockstep",
         "--quiet", "--summary", str(folder / "summary.json"),
         # The trajectory alone, without recording the bus: recording every message of a 40 s
         # run flat out (camera frames converted for the live view's channels) more than
         # doubled its CPU; recording beside the lockstep is shown the same run by the paced
         # launch above and tests/test_experiment.py.
         "--trajectory", str(folder / "trajectory.csv"), "--lockstep-participants", "1",
         *launch_args],
        cwd=REPOSITORY, env=repository_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, preexec_fn=pin)
    other = subprocess.Popen(
        [sys.executable, *participant, "--connect", endpoint, "--robot", "lockstep"],
        cwd=REPOSITORY, env=repository_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True, preexec_fn=pin)
    try:
        if while_running is not None:
            while_running(other, robot)
        output, _ = robot.communicate(timeout=600)
        assert robot.returncode == 0, output
    finally:
        for proc in (robot, other):
            if proc.poll() is None:
                proc.kill()
            proc.communicate()
    return Run(folder, output)


AVOID = [str(REPOSITORY / "examples" / "avoid_obstacles.py"), "--clock", "sim", "--lockstep",
         "--quiet"]
IDLE_S = 40.0
"""Simulated seconds of the idle run of the remote behaviour: round the box (the example's
turns away from it end by 21.5 s) and settled facing the ball (by 38 s)."""
LOADED_S = 6.0
"""Simulated seconds of the loaded run of the remote behaviour: past the example's first turn
away from the box (it wins from 3.45 s to 4.95 s, then search again), which is what a lost or
late vote would change. (Pinned to one core beside a busy loop, the two processes pass their
lockstep to and fro at about half real time.)"""


def test_a_remote_behaviour_in_lockstep_gives_the_same_run_under_load(tmp_path: Path) -> None:
    """examples/avoid_obstacles.py in its own process, joined with --lockstep, on
    obstacle-course: the example is what gets the robot round the box (the scenario's expected
    outcome, judged after IDLE_S; alone, the robot pushes against the box to the end:
    tests/test_scenarios.py); and run again with both processes pinned to one core beside a
    busy loop, the run's first LOADED_S simulated seconds (the example steering away from the
    box) are byte-identical. (The example attached without lockstep, as the README shows it,
    changes the robot's drive too: tests/test_remote.py, tests/test_doc_commands.py.)"""
    idle = launch_with_participant(tmp_path / "idle", duration_s=IDLE_S, participant=AVOID)
    core = available_cpus()[:1]
    with hogs(core):
        loaded = launch_with_participant(tmp_path / "loaded", duration_s=LOADED_S,
                                         participant=AVOID, cpus=core)
    assert loaded.summary["sim_time_s"] == pytest.approx(LOADED_S)
    assert loaded.trajectory.count(b"\n") >= 20 * LOADED_S  # a row every 50 ms simulated
    assert idle.trajectory.startswith(loaded.trajectory), "under load: trajectories differ"
    assert loaded.summary["ticks"]["winner_share"]["avoid_obstacles"] > 0, loaded.summary
    # Round the box: the course's expect met (settled at the ball, never more than 2 s against
    # the box), the example acting, the robot past the box's far face.
    assert idle.summary["expected"]["pass"], idle.summary["expected"]
    assert idle.summary["ticks"]["winner_share"]["avoid_obstacles"] > 0.05
    box = load_scenario("obstacle-course").world.boxes[0]
    samples = read_trajectory_csv(idle.folder / "trajectory.csv")
    assert max(sample.robot_x_m for sample in samples) > box.x_m + box.length_m / 2
    assert set(idle.summary["contacts"]["by"]) <= {"obstacles[0]"}
    assert "dropped from the barrier" not in idle.output + loaded.output


PARTICIPANT_RUN_S = 5.0
"""Simulated seconds of the runs whose participant vanishes or falls silent, at
:data:`PARTICIPANT_SPEED`: it is gone within a fraction of a wall second of its first votes, the
run takes PARTICIPANT_RUN_S / PARTICIPANT_SPEED wall seconds at least."""
PARTICIPANT_SPEED = 2


def test_a_participant_that_vanishes_or_falls_silent_is_dropped_and_the_run_goes_on(
        tmp_path: Path) -> None:
    """Killed: its token goes, the barrier lets go of it at once (no wait, no warning).
    Stopped (SIGSTOP): silent, dropped after lockstep.SILENCE_S of wall time with a warning
    naming the simulated instant. Either way while the run was going on (it is paced, so
    that the participant goes well before its end; checked), and the run ends normally and its
    summary is written. The two runs side by side."""
    def after_its_first_votes(then: Callable[[subprocess.Popen[str]], None]
                              ) -> Callable[[subprocess.Popen[str], subprocess.Popen[str]],
                                            None]:
        def wait_and_act(proc: subprocess.Popen[str], robot: subprocess.Popen[str]) -> None:
            assert proc.stdout is not None
            for line in proc.stdout:  # its status line: it has seen the robot drive, so
                # simulated time runs, which it does only once this participant has joined
                if line.startswith("[avoid_obstacles] votes") and "robot drive" in line:
                    break
            assert robot.poll() is None, "the run ended before its participant went"
            then(proc)

        return wait_and_act

    chatty = [*(arg for arg in AVOID if arg != "--quiet"), "--status-period-s", "0.1"]

    def run(name: str, then: Callable[[subprocess.Popen[str]], None]) -> Run:
        return launch_with_participant(
            tmp_path / name, duration_s=PARTICIPANT_RUN_S, participant=chatty,
            speed=str(PARTICIPANT_SPEED), launch_args=("--log-level", "INFO"),
            while_running=after_its_first_votes(then))

    with ThreadPoolExecutor(2) as both:
        killing = both.submit(run, "killed", lambda proc: proc.kill())
        stopping = both.submit(run, "silent", lambda proc: os.kill(proc.pid, signal.SIGSTOP))
        killed, silent = killing.result(), stopping.result()
    assert killed.summary["sim_time_s"] == pytest.approx(PARTICIPANT_RUN_S)
    assert "lockstep: avoid_obstacles of robot lockstep left" in killed.output, killed.output
    assert "dropped from the barrier" not in killed.output

    assert silent.summary["sim_time_s"] == pytest.approx(PARTICIPANT_RUN_S)
    dropped = re.search(r"avoid_obstacles of robot lockstep did not acknowledge ([\d.]+) s",
                        silent.output)
    assert dropped is not None, silent.output
    assert float(dropped.group(1)) < PARTICIPANT_RUN_S  # dropped while the run went on
    assert "dropped from the barrier, the run goes on" in silent.output


# ---------------------------------------------------------------------------------------------
# The fleet (its controllers in processes of their own: tests/test_fleet.py)


FLEET = """
world: {scenario: ball-in-sight, speed: max, duration_s: 10}
robots:
  - {name: l1, start: {x_m: 0.0, y_m: 0.0, heading_deg: 0}}
  - {name: l2, start: {x_m: -0.4, y_m: 0.5, heading_deg: -45}}
  - {name: l3, start: {x_m: -0.4, y_m: -0.5, heading_deg: 45}}
  - {name: l4, start: {x_m: -0.8, y_m: 0.0, heading_deg: 180}}
"""


def test_a_four_robot_fleet_in_lockstep_is_the_same_run_twice(tmp_path: Path) -> None:
    """One world and four robots' controllers in this process (ubf_async.runs.fleet), flat
    out: twice — the second with the whole process pinned to one core beside a busy loop on
    it — the same summary (the real-time factor and the steps' wall-time lateness aside), and
    every robot's periodic ticks 20 ms apart in simulated time: jitter 0."""
    fleet = tmp_path / "fleet.yaml"
    fleet.write_text(FLEET, "utf-8")
    first = run_fleet(fleet)
    core = available_cpus()[:1]
    with this_process_pinned_to(core), hogs(core):
        second = run_fleet(fleet)
    for run in (first, second):
        assert run.pop("real_time_factor") > 0
        run.pop("step_lateness")  # how late in wall time each step started
    assert second == first
    assert first["sim_time_s"] == pytest.approx(10.0)
    assert set(first["robots"]) == {"l1", "l2", "l3", "l4"}
    for name, robot in first["robots"].items():
        controller = robot["controller"]
        assert controller["periodic_jitter_robot_ms_p99"] == 0.0, name
        assert controller["periodic_rate_hz"] == pytest.approx(50.0), name
        assert controller["overruns"] == 0 and controller["ticks"] > 400, (name, robot)


def test_motors_elsewhere_do_not_stop_while_the_simulator_waits_on_purpose(
        tmp_path: Path) -> None:
    """Camera frames of 0.7 s of wall time each — longer than the 0.5 s after which a silent
    simulator counts as dead: the robot's motors run in another process, following its
    clock (in lockstep, so that time starts once they are there), and never stop on their
    watchdog while the simulator waits for the frames (it sends its time again meanwhile).
    Once the robot has ended, they stop in wall time."""
    folder = tmp_path / "run"
    folder.mkdir()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = subprocess.Popen(
        [sys.executable, "-m", "ubf_async.launch", "--scenario", "ball-in-sight", "--speed",
         "max", "--duration", "1", "--listen", endpoint, "--robot", "held", "--quiet",
         "--devices", "camera,encoders,range", "--summary", str(folder / "summary.json"),
         "--lockstep-participants", "1"],
        cwd=REPOSITORY, env={**repository_env(), RENDER_DELAY_ENV: "0.7"},
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    # The motors attach once the robot's components run (it says so with its controller's
    # line; simulated time waits for the motors): started together, a busy machine may take
    # longer to start the robot than the motors wait for one to answer.
    started = []
    assert robot.stdout is not None
    for line in robot.stdout:
        started.append(line)
        if line.startswith("  controller:"):
            break
    motors = subprocess.Popen(
        [sys.executable, "-m", "components.motors", "--connect", endpoint, "--robot", "held",
         "--lockstep"],
        cwd=REPOSITORY, env=repository_env(), stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)
    try:
        rest, _ = robot.communicate(timeout=300)
        output = "".join(started) + rest
        assert robot.returncode == 0, output
        summary = json.loads((folder / "summary.json").read_text())
        assert summary["camera_frames"] >= 9  # 1 s simulated: ≥ 6 s of held time
        assert summary["ticks"]["winner_share"], summary["ticks"]  # it drove meanwhile
        # The robot has gone: its watchdog stops the wheels now, in wall time (the timer
        # only keeps a broken run from hanging the test).
        printed = []
        guard = threading.Timer(60, motors.kill)
        guard.start()
        assert motors.stdout is not None
        for line in motors.stdout:
            printed.append(line)
            if "no drive command" in line:
                break
        guard.cancel()
    finally:
        motors.terminate()
        assert motors.stdout is not None
        with motors.stdout:
            rest = motors.stdout.read()  # through the buffer the lines above came from
        motors.wait(timeout=60)
        if robot.poll() is None:
            robot.kill()
            robot.communicate()
    text = "".join(printed) + rest
    assert "attached to robot 'held'" in text, text
    # Stopped once — after the robot had gone, never while the simulator waited.
    assert text.count("no drive command") == 1, text
    # ... saying what passed its limit, in the clock it was measured in (issue 28, item 2).
    assert "of wall time with the clock's source silent" in text, text


@pytest.mark.skipif(importlib.util.find_spec("uvloop") is None, reason="uvloop not installed")
def test_a_simulation_on_a_loop_that_cannot_tell_when_it_is_idle_is_refused() -> None:
    """UBF_LOOP=uvloop cannot run the lockstep: refused before the bus opens."""
    proc = subprocess.run(
        [sys.executable, "-m", "ubf_async.launch", "--duration", "1", "--listen",
         f"tcp/127.0.0.1:{free_port()}"], cwd=REPOSITORY,
        env={**repository_env(), "UBF_LOOP": "uvloop"}, capture_output=True, text=True,
        timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "needs to know when the event loop is idle: UBF_LOOP='uvloop' cannot tell" in (
        proc.stderr)
    assert "listening" not in proc.stdout
