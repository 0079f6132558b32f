"""Simulated runs shared by the tests of several modules, each made once for the whole session.

* :func:`launched` — **the one launch of each built-in scenario**: ``python -m
  ubf_async.launch mini-whegs --scenario S --seed N --speed max --trajectory DIR/trajectory.csv
  --summary F --quiet`` in a subprocess (``--record DIR`` for those of :data:`RECORDED`), with
  ``N`` from :data:`LAUNCH_SEEDS`. tests/test_experiment.py
  compares it byte for byte with the in-process run; tests/test_scenarios.py judges it and
  checks what it wrote; tests/test_summary.py and tests/test_verdict.py what it printed.
* :func:`launched_once` — any other launch whose outputs several tests check.
* :func:`ran` — a simulated run in this process (:func:`ubf_async.experiment.run`, with
  ``out_dir``) of a robot, a scenario and a seed, for every test that asks for the same three.

Under pytest-xdist each worker is a process of its own, so a run is cached on disk for the
session (the xdist documentation's pattern): in a folder under the session's temporary root,
made by whichever worker asks first while it holds an exclusive ``flock`` on the run's lock
file; a worker asking meanwhile waits on that lock (the maker's work is bounded: the launch by
its subprocess timeout, the in-process run by its own end), then reads the folder. A run that
failed is cached as failed, with why, so no other worker repeats a failure.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import subprocess
import sys
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from components.sim.outputs.trajectory import TrajectorySample, read_trajectory_csv
from components.sim.scenarios.scenario import builtin_names, load_scenario
from tests.conftest import REPOSITORY, free_port, repository_env

DEFAULT_ROBOT = REPOSITORY / "ubf_async" / "robots" / "mini-whegs.yaml"
"""The shipped robot file (``mini-whegs``), for tests that write variants of it."""

LAUNCH_SEEDS: dict[str, int] = {
    "ball-behind": 2,
    "ball-held-close": 1,  # not the file's (5): the seeds 1 to 5 are all judged in-process
    "ball-in-sight": 1,
    "ball-in-sight-orange": 7,  # not the file's (1)
    "busy-room": 8,
    "dance": 11,  # not the file's (4)
    "fleet-search": 3,
    "keep-away": 3,
    "obstacle-course": 6,  # the file's: the thesis's tree pushes against the box
}
"""The seed each built-in scenario is launched with, once for the suite. The file's own
seed where a test checks that launch's outcome against the scenario's ``expect``; another one
for some, so that the identity with the in-process run is shown for a seed given on the
command line too."""

RECORD_EVERY_S = 10.0
"""The launches' ``--record-every-s``: a frame every 10 simulated seconds and the last one (the
frames hold simulated time while they are drawn; what the tests check of them is that they are
there and readable)."""

LAUNCH_TIMEOUT_S = 300.0
"""Wall time one launch may take, flat out, on a loaded 2-core machine (the longest scenario
is 90 simulated seconds)."""


def session_root(factory: pytest.TempPathFactory) -> Path:
    """The folder every worker of this session sees: the parent of the worker's own temporary
    root under xdist, that root itself without xdist (its parent holds other sessions')."""
    base = factory.getbasetemp()
    folder = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "shared-runs"
    folder.mkdir(exist_ok=True)
    return folder


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    with path.open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)  # released by the kernel if this process dies
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


_made: dict[Path, Path] = {}


def _shared(factory: pytest.TempPathFactory, key: str, make: Callable[[Path], None]) -> Path:
    """The folder of the run ``key``, made by ``make(folder)`` once for the session."""
    root = session_root(factory)
    folder = root / key
    if folder in _made:
        return folder
    done, failed = root / f"{key}.done", root / f"{key}.failed"
    with _locked(root / f"{key}.lock"):
        if not done.exists() and not failed.exists():
            folder.mkdir()
            try:
                make(folder)
            except BaseException:
                failed.write_text(traceback.format_exc(), "utf-8")
                raise
            done.touch()
    if failed.exists():
        pytest.fail(f"the shared run {key} failed in another test:\n"
                    f"{failed.read_text('utf-8')}", pytrace=False)
    _made[folder] = folder
    return folder


@dataclass(frozen=True)
class Launch:
    """What a shared launch left: its exit status, what it printed, its summary
    (``summary.json``) and, with ``--record``, its recording (``trajectory.csv``,
    ``trajectory.png``, frames)."""

    folder: Path
    returncode: int
    output: str
    """stdout, then stderr."""
    scenario: str | None = None
    seed: int | None = None

    @property
    def summary_path(self) -> Path:
        return self.folder / "summary.json"

    def summary(self) -> dict[str, Any]:
        summary: dict[str, Any] = json.loads(self.summary_path.read_text("utf-8"))
        return summary

    def samples(self) -> list[TrajectorySample]:
        return read_trajectory_csv(self.folder / "trajectory.csv")


def launched_once(factory: pytest.TempPathFactory, key: str,
                  arguments: Callable[[Path], list[str]]) -> Launch:
    """``python -m ubf_async.launch ARGUMENTS --summary FOLDER/summary.json`` in a subprocess,
    once for the session under ``key``: ``arguments(FOLDER)`` gives the arguments (FOLDER is
    the launch's own, for ``--record``)."""

    def make(folder: Path) -> None:
        proc = subprocess.run(
            [sys.executable, "-m", "ubf_async.launch", *arguments(folder), "--summary",
             str(folder / "summary.json")],
            cwd=REPOSITORY, env=repository_env(), capture_output=True, text=True,
            timeout=LAUNCH_TIMEOUT_S)
        (folder / "launch.json").write_text(json.dumps(
            {"returncode": proc.returncode, "output": proc.stdout + proc.stderr}), "utf-8")

    folder = _shared(factory, key, make)
    printed = json.loads((folder / "launch.json").read_text("utf-8"))
    return Launch(folder=folder, returncode=printed["returncode"], output=printed["output"])


RECORDED = frozenset({"ball-in-sight"})
"""The scenarios launched with ``--record`` (the bus recorded to MCAP, the plot, the camera
frames): the recorder listens to every key, so the simulator publishes its clock, truth and
world and the camera draws its view at every frame — the same run all the same, which the
identity test shows on it. The others write their trajectory alone (``--trajectory``), at a
quarter of the cost."""


def launch_arguments(scenario: str, seed: int, folder: Path) -> list[str]:
    """A built-in scenario's shared launch (without ``--summary``, which
    :func:`launched_once` adds)."""
    robot = f"shared{os.getpid()}{builtin_names().index(scenario)}"
    outputs = (["--record", str(folder), "--record-every-s", f"{RECORD_EVERY_S:g}"]
               if scenario in RECORDED else ["--trajectory", str(folder / "trajectory.csv")])
    return ["mini-whegs", "--scenario", scenario, "--seed", str(seed), "--speed", "max",
            *outputs, "--quiet", "--listen", f"tcp/127.0.0.1:{free_port()}", "--robot", robot]


def launched(factory: pytest.TempPathFactory, scenario: str) -> Launch:
    """The one launch of the built-in ``scenario`` (with its seed of :data:`LAUNCH_SEEDS`):
    ``python -m ubf_async.launch mini-whegs --scenario S --seed N --speed max --trajectory
    DIR/trajectory.csv --summary DIR/summary.json --quiet`` (``--record DIR`` for those of
    :data:`RECORDED`)."""
    seed = LAUNCH_SEEDS[scenario]
    launch = launched_once(factory, f"launch-{scenario}-seed{seed}",
                           lambda folder: launch_arguments(scenario, seed, folder))
    return Launch(folder=launch.folder, returncode=launch.returncode, output=launch.output,
                  scenario=scenario, seed=seed)


@dataclass(frozen=True)
class Ran:
    """A shared in-process run: its summary and every trajectory sample, as
    :func:`ubf_async.experiment.run` wrote them into ``folder`` (``out_dir``)."""

    summary: dict[str, Any]
    samples: list[TrajectorySample]
    folder: Path


def ran(factory: pytest.TempPathFactory, scenario: str, *, seed: int | None = None,
        robot_text: str | None = None) -> Ran:
    """The in-process run of ``scenario`` (a built-in's name) with ``seed`` (default: the
    scenario's, given explicitly) on the shipped robot (``"mini-whegs"``), or on the robot file
    ``robot_text``; made once for the session."""
    seed = load_scenario(scenario).seed if seed is None else seed
    digest = hashlib.sha256(robot_text.encode()).hexdigest()[:12] if robot_text else "shipped"
    key = f"run-{scenario}-seed{seed}-robot-{digest}"

    def make(folder: Path) -> None:
        from ubf_async import experiment

        robot_file = folder / "robot.yaml"
        if robot_text is not None:
            robot_file.write_text(robot_text, "utf-8")
        experiment.run("mini-whegs" if robot_text is None else robot_file, scenario, seed=seed,
                       out_dir=folder / "out")

    folder = _shared(factory, key, make) / "out"
    summary = json.loads((folder / "summary.json").read_text("utf-8"))
    return Ran(summary=summary, samples=read_trajectory_csv(folder / "trajectory.csv"),
               folder=folder)
