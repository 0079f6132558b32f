"""A simulated run as a library call, ``ubf_async.experiment.run`` (issue 34, item 1).

* It is launch's run byte for byte: for every built-in scenario, the run in this process gives
  the same ``trajectory.csv`` and the same summary figures as ``python -m ubf_async.launch
  mini-whegs --scenario S --seed N --speed max`` in a process of its own (the one launch of
  each scenario the suite makes, tests/shared_runs.py).
* Runs repeat in one process: the same arguments give the same result, whatever ran before,
  and a run leaves no thread, no child process and no changed global state behind.
* Mistakes are refused before anything runs.
"""

from __future__ import annotations

import asyncio
import doctest
import io
import json
import logging
import math
import multiprocessing
import os
import random
import re
import signal
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import components.sim.backends.devices
import components.sim.render.process
import ubf_async.runs.inprocess
from components.sim.scenarios.scenario import builtin_names, load_scenario
from tests.conftest import REPOSITORY
from tests.shared_runs import DEFAULT_ROBOT, LAUNCH_SEEDS, RECORDED, launched, ran
from ubf_async import experiment
from ubf_async.assembly.robotfile import load_robot_text
from ubf_async.errors import ConfigurationError, RobotFileError, ScenarioError, UbfError

NOT_COMPARED: dict[str, str] = {
    "wall_time_s": "the wall time the run took",
    "real_time_factor": "simulated seconds per wall second",
    "real_time_factor_windows": "the same, over windows of wall time",
    "ticks.periodic_jitter_ms_p99": "how late the periodic ticks came, in wall time",
    "ticks.tick_us_p50": "the wall time a tick took (the median)",
    "ticks.tick_us_max": "the wall time a tick took (the longest)",
    "command_line": "how the run was started: launch's argv, run()'s call",
}
"""The summary's fields that measure the machine, not the run — left out of the comparison,
and why. Everything else is compared exactly, ``speed_requested`` (flat out both), ``version``
and ``warnings`` included."""


def without(summary: dict[str, Any], paths: dict[str, str]) -> dict[str, Any]:
    """``summary`` without the fields at the dotted ``paths`` (each must be there)."""
    copy: dict[str, Any] = json.loads(json.dumps(summary))
    for path in paths:
        *parents, last = path.split(".")
        holder = copy
        for key in parents:
            holder = holder[key]
        assert last in holder, (path, "no longer in the summary: update NOT_COMPARED")
        del holder[last]
    return copy


def test_every_built_in_scenario_has_its_launch() -> None:
    assert sorted(LAUNCH_SEEDS) == builtin_names()
    [compared] = test_the_run_in_this_process_is_the_launch_byte_for_byte \
        .pytestmark  # type: ignore[attr-defined]
    assert compared.name == "parametrize" and compared.args[1] == builtin_names()
    assert len(builtin_names()) == 9
    assert sum(load_scenario(name).duration_s for name in builtin_names()) == 412.0
    # A seed given on the command line, other than the scenario's, for some of them.
    assert sum(seed != load_scenario(name).seed for name, seed in LAUNCH_SEEDS.items()) >= 3


@pytest.mark.parametrize("scenario", builtin_names())
def test_the_run_in_this_process_is_the_launch_byte_for_byte(
        scenario: str, tmp_path_factory: pytest.TempPathFactory) -> None:
    launch = launched(tmp_path_factory, scenario)
    assert launch.returncode == 0, launch.output
    inprocess = ran(tmp_path_factory, scenario, seed=launch.seed)
    csv = (inprocess.folder / "trajectory.csv").read_bytes()
    assert csv == (launch.folder / "trajectory.csv").read_bytes()
    duration_s = load_scenario(scenario).duration_s
    assert len(inprocess.samples) == round(duration_s * 20) + 1  # 20 samples a second
    assert inprocess.samples[-1].t_s == pytest.approx(duration_s)
    ours, theirs = inprocess.summary, dict(launch.summary())
    assert ours["seed"] == theirs["seed"] == launch.seed
    # A launch with --record says where its recording went (the plot, the frames): the
    # recorder listening to every key made it publish everything, and the run is the same.
    recording = theirs.pop("recording", None)
    assert "recording" not in ours and (recording is not None) == (scenario in RECORDED)
    if recording is not None:
        assert recording["errors"] == [] and recording["frames"], recording
    assert without(ours, NOT_COMPARED) == without(theirs, NOT_COMPARED)
    # The figures left out are the machine's: the run's own are there in both.
    assert ours["real_time_factor"] > 0 and theirs["real_time_factor"] > 0
    assert theirs["command_line"][:3] == ["python", "-m", "ubf_async.launch"]
    assert ours["command_line"][0] == "ubf_async.experiment.run"


def child_processes() -> set[int]:
    """The pids of this process's children (from /proc: psutil is no dependency)."""
    me, children = os.getpid(), set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:  # ended meanwhile
            continue
        if int(text.rpartition(")")[2].split()[1]) == me:  # pid (comm) state ppid ...
            children.add(int(stat.parent.name))
    return children


def logging_state() -> dict[str, tuple[Any, ...]]:
    loggers = [logging.getLogger(), *(logger for logger in logging.Logger.manager.loggerDict
                                      .values() if isinstance(logger, logging.Logger))]
    return {logger.name: (logger.level, tuple(logger.handlers), logger.propagate,
                          logger.disabled, tuple(logger.filters)) for logger in loggers}


def figures(result: experiment.RunResult) -> dict[str, Any]:
    """The run's figures: its summary but for :data:`NOT_COMPARED`."""
    return without(result.summary, NOT_COMPARED)


REPEATED = ("keep-away", 47.0)
"""47 simulated seconds of keep-away: the camera's noise and, from 42 s (the ball lifted away),
search's random directions, all drawn from the run's seed."""


def test_runs_repeat_in_one_process_and_leave_nothing_behind(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A run made again in the same process gives the same result, after a run of another
    robot, scenario and seed in between, and after this process's global random generators
    were drawn from and reseeded. No run starts a thread that outlives it, a child process,
    or the render process (the camera renders in a thread of the run), and none changes the
    loggers or the SIGINT handler."""
    render_requests: list[object] = []
    shared = components.sim.backends.devices.shared_render_process

    def spy() -> components.sim.render.process.RenderProcess:
        render_requests.append(object())
        return shared()

    monkeypatch.setattr(components.sim.backends.devices, "shared_render_process", spy)
    render_process_before = components.sim.render.process._SHARED
    threads, children = set(threading.enumerate()), child_processes()
    sigint = signal.getsignal(signal.SIGINT)
    scenario, duration_s = REPEATED

    first = experiment.run("mini-whegs", scenario, duration_s=duration_s,
                           out_dir=tmp_path / "first")
    loggers = logging_state()  # after the first run: the modules it imports have theirs
    with_avoid = DEFAULT_ROBOT.read_text("utf-8").replace(
        "    - remote: avoid_obstacles\n", "    - behavior: avoid\n")
    other = experiment.run(load_robot_text(with_avoid, source="with-avoid.yaml"),
                           "obstacle-course", seed=1, duration_s=5.0)
    random.seed(1234)
    random.random()
    np.random.seed(1234)
    np.random.random(10)
    third = experiment.run("mini-whegs", scenario, seed=load_scenario(scenario).seed,
                           duration_s=duration_s)
    another_seed = experiment.run("mini-whegs", scenario, seed=99, duration_s=10.0)

    assert set(threading.enumerate()) <= threads
    assert child_processes() <= children and multiprocessing.active_children() == []
    assert render_requests == [] and components.sim.render.process._SHARED is render_process_before
    assert logging_state() == loggers
    assert signal.getsignal(signal.SIGINT) == sigint

    assert len(first.trajectory) == round(duration_s * 20) + 1
    assert third.trajectory == first.trajectory
    assert figures(third) == figures(first)
    assert first.verdicts == third.verdicts and first.passed is third.passed
    assert other.summary["scenario"] == "obstacle-course" and other.summary["seed"] == 1
    assert other.trajectory[-1]["t_s"] == pytest.approx(5.0)
    # Not the same whatever the seed: another seed's run differs from its first 10 s on.
    assert another_seed.trajectory != first.trajectory[:len(another_seed.trajectory)]
    # What run() returns is what it wrote (out_dir).
    written = json.loads((tmp_path / "first" / "summary.json").read_text("utf-8"))
    assert written == json.loads(json.dumps(first.summary))
    lines = (tmp_path / "first" / "trajectory.csv").read_text("utf-8").splitlines()
    assert lines[0].split(",") == list(first.trajectory[0])
    assert len(lines) == 1 + len(first.trajectory)


def test_a_robot_scenario_or_duration_that_cannot_run_is_refused_before_anything_runs(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    started: list[object] = []

    async def run_plan(plan: object) -> None:
        started.append(plan)

    monkeypatch.setattr(ubf_async.runs.inprocess, "run_plan", run_plan)
    threads = set(threading.enumerate())
    with pytest.raises(ScenarioError, match="unknown scenario 'no-such-scenario'"):
        experiment.run("mini-whegs", "no-such-scenario", out_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()  # a refusal leaves nothing behind
    bad = tmp_path / "bad.yaml"
    bad.write_text(DEFAULT_ROBOT.read_text("utf-8").replace("behavior: chase",
                                                            "behavior: chaes"), "utf-8")
    with pytest.raises(RobotFileError, match=rf"{bad}:\d+: .*chaes"):
        experiment.run(bad, "ball-in-sight")
    with pytest.raises(RobotFileError, match="no such file"):
        experiment.run(tmp_path / "missing.yaml", "ball-in-sight")
    for duration_s in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ConfigurationError, match="duration_s must be > 0"):
            experiment.run("mini-whegs", "ball-in-sight", duration_s=duration_s)
    for error in (ScenarioError, RobotFileError, ConfigurationError):
        assert issubclass(error, UbfError)
    assert started == [] and set(threading.enumerate()) <= threads


@pytest.mark.asyncio
async def test_run_refuses_a_running_event_loop_and_run_async_runs_there(
        monkeypatch: pytest.MonkeyPatch) -> None:
    planned: list[object] = []
    plan_run = ubf_async.runs.inprocess.plan_run

    def spy(*args: Any, **kwargs: Any) -> Any:
        planned.append(args)
        return plan_run(*args, **kwargs)

    monkeypatch.setattr(ubf_async.runs.inprocess, "plan_run", spy)
    with pytest.raises(RuntimeError, match=r"running event loop.*await "
                                           r"ubf_async\.experiment\.run_async"):
        experiment.run("mini-whegs", "ball-in-sight", duration_s=2.0)
    assert planned == []  # refused before anything
    result = await experiment.run_async("mini-whegs", "ball-in-sight", duration_s=2.0)
    assert len(planned) == 1
    assert result.summary["sim_time_s"] == pytest.approx(2.0)
    assert len(result.trajectory) == 41
    assert result.passed is False  # 2 s is too short to settle
    # The same run as from synchronous code.
    same = await asyncio.to_thread(experiment.run, "mini-whegs", "ball-in-sight",
                                   duration_s=2.0)
    assert same.trajectory == result.trajectory and figures(same) == figures(result)


def test_instants_passed_without_a_round_of_the_loop_change_nothing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Flat out, the simulator steps through the instants at which nothing of its process is
    due without a round of the event loop (components/sim/runner/stepper.py, Lockstep). The same
    run with a barrier at every instant is the same, sample for sample: a launch recorded with
    --record (its recorder makes the simulator publish at every step) shows it too."""
    from components.sim.runner.stepper import SimulatorComponent

    rounds = {"barriers": 0, "steps": 0}
    barrier, step = SimulatorComponent._barrier, SimulatorComponent._step

    async def counted_barrier(self: SimulatorComponent, *args: Any, **kwargs: Any) -> bool:
        rounds["barriers"] += 1
        return await barrier(self, *args, **kwargs)

    def counted_step(self: SimulatorComponent, *args: Any) -> bool:
        rounds["steps"] += 1
        return step(self, *args)

    monkeypatch.setattr(SimulatorComponent, "_barrier", counted_barrier)
    monkeypatch.setattr(SimulatorComponent, "_step", counted_step)
    skipping = experiment.run("mini-whegs", "keep-away", seed=5, duration_s=12)
    assert rounds["barriers"] < 0.5 * rounds["steps"], rounds  # most instants skipped
    monkeypatch.setattr(SimulatorComponent, "_barrier_is_idle", lambda self, *args: False)
    rounds.update(barriers=0, steps=0)
    every_instant = experiment.run("mini-whegs", "keep-away", seed=5, duration_s=12)
    assert rounds["barriers"] >= rounds["steps"], rounds  # (and the start's)
    assert skipping.trajectory == every_instant.trajectory
    assert figures(skipping) == figures(every_instant)


def python_blocks(page: Path) -> list[str]:
    """The ``python`` code blocks of a page that make runs in this process."""
    blocks = re.findall(r"^```python\n(.*?)^```", page.read_text("utf-8"), re.M | re.S)
    return [block for block in blocks if "experiment.run(" in block or "run_fleet(" in block]


def doctest_blocks(page: Path) -> list[str]:
    """The ``pycon`` code blocks of a page: interactive sessions, run as doctests."""
    return re.findall(r"^```pycon\n(.*?)^```", page.read_text("utf-8"), re.M | re.S)


def test_the_library_calls_the_docs_show_run_as_they_say(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """README.md's and docs/experiments.md's blocks of Python, run (from the repository's
    root, where their paths start); what their comments claim, checked; the sessions
    (``pycon``) run as doctests, so what they show printed is what the objects hold."""
    monkeypatch.chdir(REPOSITORY)
    made: dict[tuple[Any, ...], experiment.RunResult] = {}
    run = experiment.run

    def run_once(*args: Any, **kwargs: Any) -> experiment.RunResult:
        # Both pages show the same call: one run serves both (a run is a pure function of
        # its arguments: tests above).
        key = (args, tuple(sorted(kwargs.items())))
        if key not in made:
            made[key] = run(*args, **kwargs)
        return made[key]

    monkeypatch.setattr(experiment, "run", run_once)
    sessions = doctest_blocks(REPOSITORY / "docs" / "experiments.md")
    assert len(sessions) == 1, sessions
    for session in sessions:
        test = doctest.DocTestParser().get_doctest(session, {}, "docs/experiments.md",
                                                   "docs/experiments.md", 0)
        runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
        shown = io.StringIO()
        runner.run(test, out=shown.write)
        assert runner.failures == 0 and runner.tries >= 6, shown.getvalue()
    blocks = [*python_blocks(REPOSITORY / "README.md"),
              *python_blocks(REPOSITORY / "docs" / "experiments.md")]
    assert len(blocks) == 2, blocks
    for block in blocks:
        names: dict[str, Any] = {}
        exec(compile(block, "<docs>", "exec"), names)
        if "result" in names:  # "True: the scenario's expected outcome was met"
            result = names["result"]
            assert result.passed is True and result.verdicts, result.expected
            assert result.trajectory[-1]["t_s"] == pytest.approx(40.0)  # ball-behind's 40 s
        if "world" in names:  # the world's summary of a fleet in this process
            assert set(names["world"]["robots"]) == {"r1", "r2"}
            assert names["world"]["sim_time_s"] == pytest.approx(20.0)
    assert len(made) == 1  # the two pages' calls were the same
