"""The C range sensor of ``examples/c_range_sensor`` (issue 55, item 4): built against
zenoh-pico with its Makefile, attached to ``python -m ubf_async.launch`` as a token-only
client, its samples fresh in the robot's state, healthy in every status line, and passing
``inspector conform``.

zenoh-pico comes from no package registry: the test needs it installed where ``ZENOH_PICO``
(an install prefix) or ``/usr/local`` holds ``include/zenoh-pico.h`` (the example's README
says how), and says so in its skip reason otherwise. The same page's recipe in Python (raw
zenoh, hand-built msgpack: ``examples/plain_range_sensor.py``) runs on every run of the
suite in ``tests/test_clock_domain.py``."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.remote_robot import Process

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "c_range_sensor"
PREFIX = Path(os.environ.get("ZENOH_PICO", "/usr/local"))


def built(tmp_path: Path) -> Path:
    if shutil.which("make") is None or shutil.which(os.environ.get("CC", "cc")) is None:
        pytest.skip("no make or C compiler on this machine")
    if not (PREFIX / "include" / "zenoh-pico.h").is_file():
        pytest.skip(f"zenoh-pico is not installed under {PREFIX} (no package registry carries "
                    f"it: build it as {EXAMPLE.relative_to(ROOT)}/README.md says, then set "
                    f"ZENOH_PICO=PREFIX)")
    out = tmp_path / "build"
    shutil.copytree(EXAMPLE, out)
    made = subprocess.run(["make", f"ZENOH_PICO={PREFIX}"], cwd=out, capture_output=True,
                          text=True, timeout=120)
    assert made.returncode == 0, made.stdout + made.stderr  # -Wall -Wextra -Werror
    return out / "range_sensor"


@pytest.mark.slow
def test_the_c_sensor_attaches_stays_healthy_and_conforms(
        tmp_path: Path, endpoint: str, robot: str) -> None:
    binary = built(tmp_path)
    robot_proc = Process("-m", "ubf_async.launch", "--listen", endpoint, "--robot", robot,
                         "--status-period-s", "0.25")
    procs = [robot_proc]
    try:
        robot_proc.wait_for_line("controller", timeout_s=40)
        sensor = Process("-e", endpoint, "-r", robot, "-n", "cpico", "-d", "700", "-z", "25",
                         program=str(binary))
        procs.append(sensor)
        assert "simulated time" in sensor.wait_for_line("stamping", timeout_s=30)
        sensor.wait_for_line(f"publishing ubf/{robot}/sensor/range/cpico")
        # Its source in the status line, with an age (it is fresh: no STALE after it) ...
        seen = robot_proc.wait_for_match(r"range/cpico \d+ms(?! STALE)", timeout_s=30)
        first = robot_proc.lines.index(seen)
        checked = subprocess.run(
            [sys.executable, "-m", "ubf_async.inspector", "conform", "cpico", "--key",
             "sensor/range/cpico", "--seconds", "2", "--connect", endpoint, "--robot", robot],
            cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert checked.returncode == 0, checked.stdout + checked.stderr
        assert "conforms: no deviation seen" in checked.stdout
        # ... and healthy in every status line from then on, with a token and no heartbeat.
        later = [line for line in robot_proc.lines[first:] if "tick" in line]
        assert len(later) >= 4, robot_proc.lines[first:]
        assert not [line for line in later if "UNHEALTHY" in line], later
        state = subprocess.run(
            [sys.executable, "-m", "ubf_async.inspector", "state", "--connect", endpoint,
             "--robot", robot], cwd=ROOT, capture_output=True, text=True, timeout=30)
        assert state.returncode == 0, state.stderr
        assert "range/cpico" in state.stdout and "refused" not in state.stdout.split(
            "range/cpico", 1)[1].splitlines()[0], state.stdout
    finally:
        for proc in reversed(procs):
            proc.kill()
