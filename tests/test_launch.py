"""`python -m ubf_async.launch` as users run it, in separate processes (its help and a refusal
made before anything starts: its main, in the test's process)."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli_inprocess import launch_main
from tests.conftest import eventually
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode

ROOT = Path(__file__).resolve().parent.parent


def launch(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "ubf_async.launch", *args],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def test_help_explains_every_option(capfd: pytest.CaptureFixture[str],
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    # launch's main, here (tests/test_doc_commands.py runs `python -m ubf_async.launch --help`)
    helped = launch_main(["--help"], capfd, monkeypatch)
    assert helped.returncode == 0, helped.stderr
    out = helped.stdout
    for flag in ("--connect", "--listen", "--mode", "--config", "--robot", "--rate-hz",
                 "--tick", "--duration"):
        assert flag in out


def test_launch_gives_numpy_one_blas_thread_unless_told_otherwise(
        capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    # set before the devices import numpy, which starts OpenBLAS's threads then
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    assert launch_main(["--check"], capfd, monkeypatch).returncode == 0
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")  # the user's own choice
    assert launch_main(["--check"], capfd, monkeypatch).returncode == 0
    assert os.environ["OPENBLAS_NUM_THREADS"] == "3"


def test_launch_without_sensors_runs_and_says_so(endpoint: str, robot: str) -> None:
    # (--devices motors: the one device left needs the simulator, so none runs here)
    proc = launch("--no-sim", "--devices", "motors", "--listen", endpoint, "--robot", robot,
                  "--duration", "1.5")
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    assert f"listening on {endpoint}" in out
    assert "no sensors yet" in out
    assert "tick " in out and "Hz" in out
    assert "ubf_async: stopped" in out


def test_bad_config_path_is_a_clear_error(tmp_path: Path, capfd: pytest.CaptureFixture[str],
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    # launch's main, here: refused before the robot starts (tests/cli_inprocess.py)
    proc = launch_main(["--config", str(tmp_path / "missing.json5"), "--duration", "1"], capfd,
                       monkeypatch)
    assert proc.returncode != 0
    assert "no such file" in proc.stdout + proc.stderr


@pytest.mark.asyncio
async def test_plain_script_sample_shows_in_running_controller_state(
    endpoint: str, robot: str
) -> None:
    """A component written from docs/protocol.md alone (zenoh + msgpack, no ubf_async)."""
    robot_proc = launch("--no-sim", "--listen", endpoint, "--robot", robot, "--quiet")
    sensor = subprocess.Popen(
        [sys.executable, str(ROOT / "examples" / "plain_range_sensor.py"), "--connect", endpoint,
         "--robot", robot, "--name", "plain", "--range-mm", "321"],
        stdout=subprocess.DEVNULL,
    )
    statuses: list[dict] = []
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    try:
        bus.subscribe(bus.keys.status("controller"),
                      lambda k, p, t: statuses.append(decode(p).data))

        def shows_plain() -> bool:
            return any(s["source"] == "range/plain" and not s["stale"]
                       for status in statuses[-1:] for s in status["sources"])

        await eventually(shows_plain, timeout_s=20, what="range/plain in the controller state")
        assert statuses[-1]["rate_hz"] > 0
    finally:
        await bus.aclose()
        sensor.terminate()
        sensor.wait(timeout=10)
        robot_proc.send_signal(signal.SIGTERM)
        out, _ = await asyncio.to_thread(robot_proc.communicate, timeout=20)
    assert robot_proc.returncode == 0, out
    assert "ubf_async: stopped" in out
