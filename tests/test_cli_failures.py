"""Command lines that fail well (issue 13, item 6): each mistake is one clear line on stderr
and an exit status other than 0, before the robot starts; results are never lost at the end
of a run; nothing hangs — a second Ctrl-C or SIGTERM always exits.

The commands run for real in subprocesses, with a timeout; of a refusal made before anything
starts, one case does, and the other cases run the command's main in this process
(tests/cli_inprocess.py); how an argument is refused is parsed in this process."""

from __future__ import annotations

import argparse
import json
import os
import queue
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.cli_inprocess import launch_main
from tests.conftest import free_port
from ubf_async.cli import run as cli_run
from ubf_async.cli.args import add_connection_arguments, connection_options
from ubf_async.cli.attach import wait_for_robot
from ubf_async.errors import ConfigurationError
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.bus import Bus
from ubf_async.tools.launch import build_parser as launch_parser
from ubf_async.tools.replay import build_parser as replay_parser

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}
LAUNCH = ("-m", "ubf_async.launch")
RUST_TRACES = (".rs:", "/.cargo/", "Traceback")


def run(*argv: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *argv], cwd=ROOT, env=ENV, capture_output=True,
                          text=True, timeout=timeout_s)


def assert_clear_error(proc: subprocess.CompletedProcess[str], *expected: str) -> None:
    """Status ≠ 0, one ``error:`` line saying ``expected``, no trace, no robot output."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    errors = [line for line in proc.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1, proc.stderr
    for text in expected:
        assert text in errors[0], (text, proc.stderr)
    for trace in RUST_TRACES:
        assert trace not in proc.stderr, proc.stderr
    assert proc.stdout == "", proc.stdout  # the robot never started


class Child:
    """A command in a subprocess; its stdout and stderr lines are collected by threads."""

    def __init__(self, *argv: str) -> None:
        self.proc = subprocess.Popen([sys.executable, *argv], cwd=ROOT, env=ENV, text=True,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.out: list[str] = []
        self.err: list[str] = []
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._readers = [threading.Thread(target=self._read, args=(stream, lines), daemon=True)
                         for stream, lines in ((self.proc.stdout, self.out),
                                               (self.proc.stderr, self.err))]
        for reader in self._readers:
            reader.start()

    def _read(self, stream: object, lines: list[str]) -> None:
        assert stream is not None
        with stream:  # type: ignore[attr-defined]
            for line in stream:  # type: ignore[attr-defined]
                lines.append(line.rstrip("\n"))
                self._lines.put(line)
        self._lines.put(None)

    def wait_for(self, pattern: str, *, timeout_s: float = 30.0) -> str:
        """Block until a line (stdout or stderr) matches the regular expression ``pattern``."""
        deadline = time.monotonic() + timeout_s
        seen = [line for line in self.out + self.err if re.search(pattern, line)]
        if seen:
            return seen[0]
        while True:
            try:
                line = self._lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(
                    f"no {pattern!r} within {timeout_s}s:\n{self.text()}") from None
            if line is None and self.proc.poll() is not None and all(
                    not r.is_alive() for r in self._readers):
                raise AssertionError(f"exited ({self.proc.returncode}) before {pattern!r}:\n"
                                     f"{self.text()}")
            if line is not None and re.search(pattern, line):
                return line

    def wait(self, timeout_s: float) -> int:
        code = self.proc.wait(timeout=timeout_s)
        for reader in self._readers:
            reader.join(timeout=5)
        return code

    def text(self) -> str:
        return "\n".join(self.out) + "\n--- stderr ---\n" + "\n".join(self.err)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)


@pytest.fixture
def children() -> list[Child]:
    started: list[Child] = []
    yield started
    for child in started:
        child.kill()


def started_robot(children: list[Child], *argv: str) -> Child:
    robot = Child(*LAUNCH, *argv)
    children.append(robot)
    robot.wait_for("controller:")  # printed once every component runs
    return robot


# ---------------------------------------------------------------------------------------------
# Output files


@pytest.mark.parametrize("flag, where, expected", [
    ("--summary", "a-file/s.json", "a-file is not a directory"),
    ("--record", "a-file/frames", "a-file is not a directory"),
    ("--summary", "a-folder", "is a directory"),
    ("--record", "a-file", "is not a directory"),
])
def test_an_output_that_cannot_be_written_is_refused_before_the_robot_starts(
    tmp_path: Path, endpoint: str, flag: str, where: str, expected: str,
    capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "a-file").write_text("in the way")
    (tmp_path / "a-folder").mkdir()
    argv = ("--listen", endpoint, "--duration", "1", flag, str(tmp_path / where))
    # The first case through the real command; the others through its main, here (the
    # robot's start fails the test: tests/cli_inprocess.py).
    proc = (run(*LAUNCH, *argv) if (flag, where) == ("--summary", "a-file/s.json")
            else launch_main(argv, capfd, monkeypatch))
    assert_clear_error(proc, flag, expected)


@pytest.mark.parametrize("check", [True, False], ids=["--check", "the run"])
@pytest.mark.parametrize("flags, expected", [
    (("--scenario", "keepaway"), "unknown scenario 'keepaway'"),
    (("--scenario", "nowhere/x.json"), "no scenario file nowhere/x.json"),
    (("--record-every-s", "0"), "record_every_s must be > 0"),
])
def test_what_launch_refuses_is_refused_before_the_bus_opens_and_by_check(
    endpoint: str, check: bool, flags: tuple[str, ...], expected: str,
    capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--check`` runs exactly the checks the run makes before it opens zenoh: what the run
    would refuse, ``--check`` refuses too (status 2, the same line), and the run refuses it
    before printing anything (no ``attach with:`` for a robot that never starts). The unknown
    scenario through the real command; the others through its main, here (the robot's start
    fails the test: tests/cli_inprocess.py)."""
    argv = ("--listen", endpoint, *flags, *(["--check"] if check else []))
    proc = (run(*LAUNCH, *argv) if flags == ("--scenario", "keepaway")
            else launch_main(argv, capfd, monkeypatch))
    assert_clear_error(proc, expected)


def test_results_that_cannot_be_written_at_the_end_are_printed_and_fail(
    tmp_path: Path, endpoint: str, children: list[Child]
) -> None:
    out = tmp_path / "out"
    robot = started_robot(children, "--listen", endpoint, "--status-period-s", "0.1",
                          "--summary", str(out / "summary.json"), "--record", str(out / "rec"))
    robot.wait_for(r"\| sim [1-9]")  # the status line: a simulated second has passed
    shutil.rmtree(out)  # e.g. cleaned away during the run: nowhere to write at the end
    robot.proc.send_signal(signal.SIGINT)
    code = robot.wait(timeout_s=30)
    assert code == 2, robot.text()
    errors = [line for line in robot.err if "error:" in line]
    assert any("could not save the run's results" in e and str(out) in e for e in errors), errors
    assert not any(trace in robot.text() for trace in RUST_TRACES), robot.text()
    # The summary is on stdout, whole: the run's results are not lost.
    start = robot.out.index("ubf_async: the run's summary, not saved:")
    end = next(i for i in range(start, len(robot.out))  # (the bus recording's line follows)
               if robot.out[i].startswith(("  recorded ", "ubf_async: stopped")))
    summary = json.loads("\n".join(robot.out[start + 1:end]))
    assert summary["sim_time_s"] > 0 and summary["ticks"]["ticks"] > 0
    assert not out.exists()


# ---------------------------------------------------------------------------------------------
# Signals


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_second_signal_exits_at_once_whatever_the_shutdown_is_stuck_on(
    tmp_path: Path, endpoint: str, children: list[Child], sig: signal.Signals
) -> None:
    """The summary goes to a named pipe nobody reads: writing it blocks forever (as a stuck
    disk or network share would). The first signal starts the shutdown, which then hangs;
    the second exits at once with status 130."""
    fifo = tmp_path / "summary.fifo"
    os.mkfifo(fifo)
    robot = started_robot(children, "--listen", endpoint, "--quiet", "--summary", str(fifo))
    robot.proc.send_signal(sig)
    robot.wait_for("saving the run's results")
    robot.wait_for("press Ctrl-C again to quit at once")
    with pytest.raises(subprocess.TimeoutExpired):  # stuck, as the FIFO makes it
        robot.proc.wait(timeout=2)
    robot.proc.send_signal(sig)
    sent = time.monotonic()
    code = robot.wait(timeout_s=10)
    assert code == 130, robot.text()
    assert time.monotonic() - sent < 5
    assert any(f"{sig.name} again: exiting now" in line for line in robot.err), robot.text()


WAITS_FOR_A_STOP = """\
import asyncio, sys
from ubf_async.cli.run import run_main

async def main() -> int:
    print("ready", flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        await asyncio.sleep(1.0)  # a stop that takes a while: a second signal may come meanwhile
        print("stopped cleanly", flush=True)

sys.exit(run_main(main, prog="waits"))
"""


@pytest.mark.parametrize("apart", ["at once", "later"])
def test_one_signal_sent_twice_at_once_is_one_stop(apart: str) -> None:
    """``timeout -s INT`` sends its signal to the command and to its process group: the
    command gets two SIGINTs within microseconds. That is one request to stop, not "SIGINT
    again: exiting now"; a second signal that comes later (a second Ctrl-C) still exits at
    once, status 130."""
    proc = subprocess.Popen([sys.executable, "-c", WAITS_FOR_A_STOP], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
        proc.send_signal(signal.SIGINT)
        if apart == "later":
            time.sleep(cli_run.SECOND_SIGNAL_AFTER_S + 0.1)  # a person's second Ctrl-C, later
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    if apart == "at once":
        assert proc.returncode == 0, err
        assert out == "stopped cleanly\n" and "exiting now" not in err, err
    else:
        assert proc.returncode == 130, err
        assert "SIGINT again: exiting now" in err and "stopped cleanly" not in out, (out, err)


def test_stop_signals_read_together_are_one_request_and_a_later_one_a_second() -> None:
    """The stop guard's watcher, fed as the signal handler feeds it (a byte per signal on its
    wake-up pipe): two signals that came together are the first request; one that comes
    SECOND_SIGNAL_AFTER_S later is the second, which exits."""
    guard = cli_run.StopGuard(prog="t", stop_bound_s=3600)
    exits: list[int] = []
    guard.exit_now = lambda signum, **_: exits.append(signum)  # type: ignore[method-assign]
    read_fd, write_fd = os.pipe()
    watcher = threading.Thread(target=guard._watch, args=(read_fd,), daemon=True)
    watcher.start()
    try:
        os.write(write_fd, bytes([signal.SIGINT, signal.SIGINT]))  # timeout -s INT's pair
        deadline = time.monotonic() + 30
        while guard.signals < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert guard.signals == 1 and exits == []
        time.sleep(cli_run.SECOND_SIGNAL_AFTER_S + 0.05)  # a person's second Ctrl-C, later
        os.write(write_fd, bytes([signal.SIGINT]))
        os.close(write_fd)
        watcher.join(30)
        assert guard.signals == 2 and exits == [signal.SIGINT]
    finally:
        assert guard.overdue is not None
        guard.overdue.cancel()
        os.close(read_fd)


# ---------------------------------------------------------------------------------------------
# Connections


@pytest.mark.asyncio
async def test_the_config_files_listen_endpoint_is_kept(
    tmp_path: Path, endpoint: str, robot: str, children: list[Child]
) -> None:
    config = tmp_path / "zenoh.json5"
    config.write_text(json.dumps({"listen": {"endpoints": [endpoint]}}))
    launched = started_robot(children, "--config", str(config), "--no-sim", "--quiet",
                             "--robot", robot)
    assert f"listening on {endpoint}" in launched.out[0], launched.text()
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    try:
        await wait_for_robot(bus, timeout_s=10)  # really there
    finally:
        await bus.aclose()
    # A --listen flag given does replace it.
    other = f"tcp/127.0.0.1:{free_port()}"
    flagged = started_robot(children, "--config", str(config), "--listen", other, "--no-sim",
                            "--quiet", "--robot", robot + "b")
    assert f"listening on {other}" in flagged.out[0], flagged.text()


@pytest.mark.asyncio
async def test_listening_on_port_0_prints_the_port_bound(
    robot: str, children: list[Child]
) -> None:
    launched = started_robot(children, "--listen", "tcp/127.0.0.1:0", "--no-sim", "--quiet",
                             "--robot", robot)
    banner = launched.out[0]
    endpoint = banner.rsplit("listening on ", 1)[1]
    port = int(endpoint.rsplit(":", 1)[1])
    assert port != 0, banner
    assert f"--connect {endpoint} --robot {robot}" in launched.out[1]
    bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    try:
        await wait_for_robot(bus, timeout_s=10)  # the printed endpoint reaches the robot
    finally:
        await bus.aclose()


@pytest.mark.parametrize(("parser", "argv", "usage", "error"), [
    (launch_parser, ["--speed", "fast"], "python -m ubf_async.launch [options] [ROBOT_FILE]",
     "argument --speed: expected a number > 0 or 'max', got 'fast'"),
    (replay_parser, ["x.mcap", "--speed", "fast"],
     "python -m ubf_async.replay [options] FILE.mcap",
     "argument --speed: invalid float value: 'fast'"),
])
def test_a_wrong_value_is_one_usage_line_and_the_error(
        parser: Callable[[], argparse.ArgumentParser], argv: list[str], usage: str, error: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 35: the error came after twenty lines of usage listing every option (--help
    explains them); each tool of the shared help formatter gives two lines."""
    prog = usage.split(" [", 1)[0]
    with pytest.raises(SystemExit) as exited:
        parser().parse_args(argv)
    assert exited.value.code == 2
    assert capsys.readouterr().err.splitlines() == [f"usage: {usage}", f"{prog}: error: {error}"]


def test_a_port_in_use_is_one_clear_line(endpoint: str) -> None:
    host, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    with socket.socket() as taken:
        taken.bind((host, int(port)))
        taken.listen()
        proc = run(*LAUNCH, "--listen", endpoint, "--duration", "1")
        device = run("-m", "components.range", "--listen", endpoint, "--duration", "1")
    assert_clear_error(proc, f"cannot listen on {endpoint}", "already in use", "--listen")
    assert_clear_error(device, f"cannot listen on {endpoint}", "already in use")


@pytest.mark.parametrize("command", [
    ("-m", "components.range", "--wait-for-robot-s", "1"),
    ("-m", "ubf_async.inspector", "components", "--timeout", "1"),
])
def test_no_robot_to_connect_to_is_one_clear_line(command: tuple[str, ...]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = run(*command, "--connect", endpoint)
    assert proc.returncode == 2, proc
    assert f"no robot to connect to: nothing answered at {endpoint}" in proc.stderr
    assert "is the robot running?" in proc.stderr
    assert proc.stdout == ""
    for trace in RUST_TRACES:
        assert trace not in proc.stderr


def test_a_component_name_already_on_the_robot_is_refused(
    endpoint: str, robot: str, children: list[Child]
) -> None:
    """The robot has range/front (token ``range-front``); a standalone range finder named
    ``front`` would merge its samples with it: refused. A wrong --robot is said too."""
    started_robot(children, "--listen", endpoint, "--robot", robot, "--quiet")
    same = run("-m", "components.range", "--connect", endpoint, "--robot", robot,
               "--name", "front")
    assert_clear_error(same, "'range-front' is already alive", f"robot {robot!r}", "--name")
    wrong = run("-m", "components.range", "--connect", endpoint, "--robot", robot + "x",
                "--wait-for-robot-s", "1")
    assert_clear_error(wrong, f"no robot {robot + 'x'!r} answered", f"robots there: {robot}")


def test_only_the_flags_given_override_the_config_file(tmp_path: Path) -> None:
    """How the options are merged (parsing only; the launch test above runs it for real)."""
    config = tmp_path / "zenoh.json5"
    config.write_text('{mode: "client", connect: {endpoints: ["tcp/127.0.0.1:7001"]},'
                      ' listen: {endpoints: {peer: ["tcp/127.0.0.1:7002"]}}}')
    parser = argparse.ArgumentParser()
    add_connection_arguments(parser, default_listen=["tcp/127.0.0.1:7447"])
    parser.set_defaults(mode=None)  # as if --mode had no default: the file's mode applies

    def options(*argv: str) -> ConnectionOptions:
        return connection_options(parser.parse_args(["--config", str(config), *argv]))

    kept = options()
    assert (kept.mode, kept.connect, kept.listen) == ("client", ["tcp/127.0.0.1:7001"], [])
    flags = options("--mode", "peer", "--connect", "tcp/127.0.0.1:7003",
                    "--listen", "tcp/127.0.0.1:7004")
    assert (flags.mode, flags.connect, flags.listen) == (
        "peer", ["tcp/127.0.0.1:7003"], ["tcp/127.0.0.1:7004"])
    # peer mode picks the file's peer listen endpoints, not launch's default
    assert options("--mode", "peer").listen == ["tcp/127.0.0.1:7002"]
    no_file = connection_options(parser.parse_args([]))
    assert (no_file.mode, no_file.listen) == ("peer", ["tcp/127.0.0.1:7447"])
    # A file that sets no endpoints leaves launch's default (zenoh reports its own defaults,
    # tcp/[::]:0 on every interface, as if the file had set them).
    silent = tmp_path / "silent.json5"
    silent.write_text('{mode: "peer"}')
    assert connection_options(parser.parse_args(["--config", str(silent)])).listen == [
        "tcp/127.0.0.1:7447"]
    broken = tmp_path / "broken.json5"
    broken.write_text("{mode: ")
    with pytest.raises(ConfigurationError, match=r"--config .*broken\.json5"):
        connection_options(parser.parse_args(["--config", str(broken)]))
