"""Lockstep simulated time: the same run, byte for byte, at any speed, on any machine.

Each run is the real main job (``python -m ubf_async.launch --scenario S ... --summary
--record``) in its own process. The trajectory is compared byte for byte and the summary in
full, apart from the fields that measure wall time (:data:`WALL_FIELDS`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from bench.cpu_hog import available_cpus, hogs, pin_to
from components.sim.backends import RENDER_DELAY_ENV
from components.sim.render_process import ENV_VAR as RENDER_PROCESS_ENV
from tests.conftest import REPOSITORY, free_port, repository_env

SCENARIOS = {"ball-in-sight": 25.0, "keep-away": 40.0, "dance": 30.0}
"""The thesis's scenarios and how many simulated seconds of each are compared: keep-away's
search has picked its random turns several times by 40 s, dance's ball has come and gone."""
SHORT_S = 3.0
"""Simulated seconds of the real-time (``--speed 1``) runs."""

WALL_FIELDS = (("wall_time_s",), ("real_time_factor",), ("real_time_factor_windows",),
               ("command_line",), ("recording", "dir"), ("ticks", "periodic_jitter_ms_p99"),
               ("ticks", "tick_us_p50"), ("ticks", "tick_us_max"), ("speed_requested",))
"""Summary fields measured in wall time, naming this run's paths, or the speed asked for."""


class Run:
    def __init__(self, folder: Path, output: str) -> None:
        self.folder = folder
        self.output = output
        self.trajectory = (folder / "trajectory.csv").read_bytes()
        self.summary: dict[str, Any] = json.loads((folder / "summary.json").read_text())

    def simulated_summary(self) -> dict[str, Any]:
        """The summary without its wall-time fields."""
        out = json.loads(json.dumps(self.summary))
        for path in WALL_FIELDS:
            parent = out
            for key in path[:-1]:
                parent = parent[key]
            del parent[path[-1]]
        return out


def launch(folder: Path, scenario: str, duration_s: float, *, speed: str = "max",
           env: dict[str, str] | None = None, cpus: list[int] | None = None) -> Run:
    """One run through the real launch path, optionally pinned to ``cpus``."""
    folder.mkdir(parents=True)
    proc = subprocess.run(
        [sys.executable, "-m", "ubf_async.launch", "--scenario", scenario, "--speed", speed,
         "--duration", f"{duration_s:g}", "--listen", f"tcp/127.0.0.1:{free_port()}",
         "--robot", "lockstep", "--quiet", "--summary", str(folder / "summary.json"),
         "--record", str(folder), "--record-every-s", "5"],
        cwd=REPOSITORY, env={**repository_env(), **(env or {})}, capture_output=True,
        text=True, timeout=600, preexec_fn=None if cpus is None else lambda: pin_to(cpus))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return Run(folder, proc.stdout + proc.stderr)


def assert_same(run: Run, reference: Run, label: str) -> None:
    assert run.trajectory == reference.trajectory, f"{label}: trajectories differ"
    assert run.simulated_summary() == reference.simulated_summary(), label


@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_a_scenario_runs_the_same_at_any_speed_and_under_load(tmp_path: Path,
                                                              scenario: str) -> None:
    """Flat out, in-thread rendering, and pinned to one core beside a busy loop on it: the
    same trajectory and summary; and at ``--speed 1`` the same as flat out."""
    duration = SCENARIOS[scenario]
    flat_out = launch(tmp_path / "flat-out", scenario, duration)
    assert flat_out.summary["expected"]["pass"], flat_out.summary["expected"]
    in_thread = launch(tmp_path / "in-thread", scenario, duration,
                       env={RENDER_PROCESS_ENV: "0"})
    assert_same(in_thread, flat_out, "rendering in a thread")
    core = available_cpus()[:1]
    with hogs(core):
        loaded = launch(tmp_path / "loaded", scenario, duration, cpus=core)
    assert_same(loaded, flat_out, "pinned beside a busy loop")
    # The loaded run was slower in wall time: what it reached says so, not its results.
    assert loaded.summary["real_time_factor"] < flat_out.summary["real_time_factor"]

    short = launch(tmp_path / "flat-out-short", scenario, SHORT_S)
    real_time = launch(tmp_path / "real-time", scenario, SHORT_S, speed="1")
    assert_same(real_time, short, "at --speed 1")
    assert 0.8 < real_time.summary["real_time_factor"] <= 1.05
    # A longer run passes through the same states: a shorter one is its beginning.
    assert flat_out.trajectory.startswith(short.trajectory)


def test_slow_camera_renders_cost_no_simulated_time(tmp_path: Path) -> None:
    """Every camera frame made to take 300 ms of wall time (the render backend's test hook):
    the same run, and no safety limit taken in by the waiting — no watchdog stop, no stale
    source."""
    duration = 3.0
    normal = launch(tmp_path / "normal", "ball-in-sight", duration)
    slow = launch(tmp_path / "slow", "ball-in-sight", duration,
                  env={RENDER_DELAY_ENV: "0.3"})
    assert_same(slow, normal, "300 ms renders")
    frames = slow.summary["camera_frames"]
    assert frames >= 25  # every 0.11 s of 3 s simulated
    assert slow.summary["wall_time_s"] >= 0.3 * frames  # the renders did take that long
    for words in ("no drive command", "stale", "STALE", "WARNING"):
        assert words not in slow.output, slow.output
    assert slow.summary["warnings"] == []


def test_the_cpu_hog_loads_the_cores_it_is_given() -> None:
    """The load the tests and ``python -m bench.cpu_hog`` put beside a run is real."""
    core = available_cpus()[:1]
    with hogs(core) as procs:
        assert len(procs) == 1
        assert os.sched_getaffinity(procs[0].pid) == set(core)
        assert procs[0].poll() is None
    assert procs[0].poll() is not None  # stopped with the block
