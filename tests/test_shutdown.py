"""Every way out finishes (issue 25): whatever goes wrong at the end — the console's reader
gone, stderr closed, a signal during start-up or during the end's writing, a component whose
``aclose`` raises — the process is gone within its stop bound, its exit status says what
happened, and what it was saving is saved: ``summary.json`` whole, the MCAP file finished with
its summary section. No entry point leaves a non-daemon thread behind its ``main()``.

Every test runs the real command in a subprocess (real zenoh on loopback, the real simulator),
through ``tests.exit_probe``, which reports the threads alive when ``main()`` returned."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import pytest
from mcap.reader import make_reader

from tests.conftest import REPOSITORY, free_port, repository_env
from ubf_async.cli import ending
from ubf_async.cli.run import EXIT_ERROR, EXIT_NOW_BUDGET_S, SECOND_SIGNAL_AFTER_S, STOP_BOUND_S
from ubf_async.net.options import ConnectionOptions
from ubf_async.net.transport import ZenohConnection
from ubf_async.runtime.bus import Bus
from ubf_async.tools.fleet import FLEET_STOP_BOUND_S

SIMULATED_SECOND = "| sim 1."
"""In launch's status line: a simulated second has passed (there is a run to save)."""
SLACK_S = 3.0
"""Beyond a stop bound: the interpreter's own exit and the reaping, on a loaded machine."""
START_S = 90.0
"""How long a command may take to be up, on a loaded 2-core machine (imports, the render
process, zenoh)."""


class Command:
    """``python -m tests.exit_probe THREADS.json ARGS`` with stdout and stderr on pipes read
    line by line; :meth:`close_reader` plays a reader that went away (the pipe's read end is
    closed: the program's next write to it fails)."""

    def __init__(self, tmp: Path, *args: str, env: dict[str, str] | None = None,
                 stdout_file: IO[str] | None = None) -> None:
        self.threads_file = tmp / f"threads-{free_port()}.json"
        self.out: list[str] = []
        self.err: list[str] = []
        self._cond = threading.Condition()
        self._gone: dict[str, threading.Event] = {}
        ends = {name: os.pipe() for name in ("out", "err")
                if name == "err" or stdout_file is None}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.exit_probe", str(self.threads_file), *args],
            cwd=REPOSITORY, env={**repository_env(), **(env or {})},
            stdout=ends["out"][1] if "out" in ends else stdout_file,
            stderr=ends["err"][1])
        self._readers = {}
        for name, (read_fd, write_fd) in ends.items():
            os.close(write_fd)
            self._gone[name] = threading.Event()
            self._readers[name] = threading.Thread(
                target=self._read, args=(read_fd, name), daemon=True)
            self._readers[name].start()

    def _read(self, fd: int, name: str) -> None:
        lines = self.out if name == "out" else self.err
        pending = b""
        try:
            while not self._gone[name].is_set():
                ready, _, _ = select.select([fd], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(fd, 65536)
                if not data:
                    return
                pending += data
                *complete, pending = pending.split(b"\n")
                with self._cond:
                    lines.extend(line.decode(errors="replace") for line in complete)
                    self._cond.notify_all()
        finally:
            os.close(fd)

    def close_reader(self, name: str) -> None:
        """The reader of std``name`` goes away."""
        self._gone[name].set()
        self._readers[name].join()

    def text(self) -> str:
        return "\n".join(["-- stdout", *self.out, "-- stderr", *self.err])

    def wait_for(self, text: str, *, on: str = "out", timeout_s: float = START_S) -> None:
        lines = self.out if on == "out" else self.err
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not any(text in line for line in lines):
                left = deadline - time.monotonic()
                assert left > 0 and self.proc.poll() is None, (
                    f"no {text!r} on std{on}; exit status {self.proc.poll()}\n{self.text()}")
                self._cond.wait(min(left, 0.5))

    def stopped_within(self, bound_s: float, sig: int = signal.SIGTERM) -> int:
        """Send ``sig``; the exit status, once the process is gone (AssertionError if it is
        not within ``bound_s``, plus :data:`SLACK_S`)."""
        self.proc.send_signal(sig)
        try:
            code = self.proc.wait(timeout=bound_s + SLACK_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise AssertionError(f"still running {bound_s + SLACK_S:g} s after "
                                 f"{signal.Signals(sig).name}\n{self.text()}") from None
        for reader in self._readers.values():
            reader.join(timeout=5)
        return code

    def threads_left(self) -> list[dict[str, Any]]:
        """The threads alive when ``main()`` returned."""
        assert self.threads_file.exists(), f"main() did not return\n{self.text()}"
        threads: list[dict[str, Any]] = json.loads(self.threads_file.read_text())
        return threads

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)


@pytest.fixture
def commands() -> Iterator[list[Command]]:
    started: list[Command] = []
    yield started
    for command in started:
        command.kill()


def assert_no_non_daemon_thread(command: Command) -> None:
    alive = [t["name"] for t in command.threads_left() if not t["daemon"]]
    assert not alive, f"non-daemon threads outlived main(): {alive}\n{command.text()}"


def assert_mcap_finished(path: Path) -> int:
    """The file has its summary section (a finished MCAP, not a recovered one); its count of
    messages."""
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None, f"{path}: no summary"
    assert summary.statistics.message_count > 0
    return summary.statistics.message_count


def assert_summary_saved(path: Path) -> dict[str, Any]:
    summary: dict[str, Any] = json.loads(path.read_text("utf-8"))
    assert summary["sim_time_s"] > 0 and summary["ticks"]["ticks"] > 0
    return summary


def second_signal_later(first: float) -> None:
    """Let :data:`~ubf_async.cli.run.SECOND_SIGNAL_AFTER_S` pass since the first signal was
    sent at ``first`` (``time.monotonic``), and half a second more for the process to have
    read it: a signal sent sooner would be the same request sent twice, not a second one."""
    time.sleep(max(0.0, first + SECOND_SIGNAL_AFTER_S + 0.5 - time.monotonic()))


def launch(commands: list[Command], tmp: Path, *args: str, env: dict[str, str] | None = None,
           stdout_file: IO[str] | None = None, fault: str | None = None,
           slow_fsync_s: float | None = None) -> Command:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    probe = ["--fault-aclose", fault] if fault else []
    if slow_fsync_s is not None:
        probe += ["--slow-fsync", str(slow_fsync_s)]
    command = Command(tmp, *probe, "ubf_async.launch", "--listen", endpoint,
                      "--status-period-s", "0.2", *args,
                      env=env, stdout_file=stdout_file)
    commands.append(command)
    return command


def recorded_launch(commands: list[Command], tmp: Path, *extra: str,
                    stdout_file: IO[str] | None = None) -> tuple[Command, Path]:
    out = tmp / "out"
    command = launch(commands, tmp, "--summary", str(out / "summary.json"), "--record",
                     str(out / "rec"), *extra, stdout_file=stdout_file)
    return command, out


# ---------------------------------------------------------------------------------------------
# launch


def test_a_launch_whose_stdout_reader_died_saves_everything_on_sigterm(
        tmp_path: Path, commands: list[Command]) -> None:
    robot, out = recorded_launch(commands, tmp_path)
    robot.wait_for(SIMULATED_SECOND)
    robot.close_reader("out")
    code = robot.stopped_within(STOP_BOUND_S)
    assert code == EXIT_ERROR, robot.text()  # the output was lost: said, and not 0
    assert any("stdout: Broken pipe" in line for line in robot.err), robot.text()
    assert any("output lost" in line for line in robot.err), robot.text()
    assert_summary_saved(out / "summary.json")
    assert_mcap_finished(out / "rec" / "mini.mcap")
    assert (out / "rec" / "trajectory.png").exists()
    assert_no_non_daemon_thread(robot)


def test_a_launch_whose_stderr_is_closed_saves_everything_on_sigterm(
        tmp_path: Path, commands: list[Command]) -> None:
    printed = tmp_path / "stdout.txt"
    with printed.open("w") as stdout:
        robot, out = recorded_launch(commands, tmp_path, stdout_file=stdout)
    deadline = time.monotonic() + START_S
    while SIMULATED_SECOND not in printed.read_text():
        assert time.monotonic() < deadline and robot.proc.poll() is None, printed.read_text()
        time.sleep(0.05)  # polling a file the process writes: nothing to wait on instead
    robot.close_reader("err")
    code = robot.stopped_within(STOP_BOUND_S)
    # Its "stopping" line could not be written: the exit status says output was lost.
    assert code == EXIT_ERROR, printed.read_text()
    assert_summary_saved(out / "summary.json")
    assert_mcap_finished(out / "rec" / "mini.mcap")
    assert "ubf_async: stopped" in printed.read_text()  # the report still printed, last
    assert_no_non_daemon_thread(robot)


def test_a_sigterm_half_a_second_after_start_stops_it_within_the_bound(
        tmp_path: Path, commands: list[Command]) -> None:
    robot, _ = recorded_launch(commands, tmp_path)
    time.sleep(0.5)  # the moment the issue names: during imports or the bus's opening
    code = robot.stopped_within(STOP_BOUND_S)
    # Before the stop guard is in place the default action ends it (-SIGTERM); after it, a
    # clean stop (0). Either way: gone within the bound, no traceback.
    assert code in (0, -signal.SIGTERM), robot.text()
    assert not any("Traceback" in line for line in robot.err), robot.text()
    if code == 0:
        assert_no_non_daemon_thread(robot)


def test_a_sigterm_while_the_end_writes_lets_it_finish(
        tmp_path: Path, commands: list[Command]) -> None:
    """Camera frames take 0.4 s of wall time each (the render hook), the last one too, which
    the end writes into the recording: the SIGTERM arrives while it does."""
    out = tmp_path / "out"
    robot = launch(commands, tmp_path, "--duration", "0.3", "--summary",
                   str(out / "summary.json"), "--record", str(out / "rec"),
                   env={"UBF_TEST_RENDER_DELAY_S": "0.4"})
    robot.wait_for("saving the run's results")
    code = robot.stopped_within(STOP_BOUND_S)
    assert code == 0, robot.text()
    assert any("stopping" in line for line in robot.err), robot.text()
    summary = assert_summary_saved(out / "summary.json")
    # The whole recording, the final frame included: the signal did not cut the end short.
    assert summary["recording"]["errors"] == []
    assert any(name.startswith("frame_0000.30") for name in summary["recording"]["frames"])
    assert (out / "rec" / "trajectory.png").exists()
    assert_mcap_finished(out / "rec" / "mini.mcap")
    assert_no_non_daemon_thread(robot)


@pytest.mark.parametrize("disk", ["idle", "slow"])
def test_a_second_signal_exits_at_once_and_still_finishes_the_recording(
        tmp_path: Path, commands: list[Command], disk: str) -> None:
    """The summary goes to a FIFO nobody reads: the end's writing is stuck. The second
    SIGTERM exits at once (130) — and the MCAP file is finished all the same (within
    cli.EXIT_NOW_BUDGET_S), readable with its summary section. So it is on a disk whose
    every fsync of the file takes 20 s (beside the whole suite, one took more than the second
    the exit gives, and the file was left without its footer: the writer waited in it)."""
    fifo = tmp_path / "summary.fifo"
    os.mkfifo(fifo)
    robot = launch(commands, tmp_path, "--summary", str(fifo), "--record",
                   str(tmp_path / "rec"), slow_fsync_s=20.0 if disk == "slow" else None)
    robot.wait_for(SIMULATED_SECOND)
    robot.proc.send_signal(signal.SIGTERM)
    first = time.monotonic()
    robot.wait_for("saving the run's results")
    second_signal_later(first)
    code = robot.stopped_within(EXIT_NOW_BUDGET_S + 1.0)
    assert code == 130, robot.text()
    assert any("SIGTERM again: exiting now" in line for line in robot.err), robot.text()
    assert_mcap_finished(tmp_path / "rec" / "mini.mcap")


def test_a_component_whose_aclose_raises_does_not_skip_the_rest_of_the_end(
        tmp_path: Path, commands: list[Command]) -> None:
    out = tmp_path / "out"
    robot = launch(commands, tmp_path, "--duration", "1", "--summary",
                   str(out / "summary.json"), "--record", str(out / "rec"),
                   fault="ubf_async.services.live.TreeService")
    code = robot.proc.wait(timeout=START_S)
    for reader in robot._readers.values():
        reader.join(timeout=5)
    assert code == EXIT_ERROR, robot.text()
    assert any("closing tree" in line and "failed" in line for line in robot.err), robot.text()
    assert any("error: the run ended, but closing tree" in line for line in robot.err), \
        robot.text()
    # Closed after it (last started first): the recorder, the session.
    assert_summary_saved(out / "summary.json")
    assert_mcap_finished(out / "rec" / "mini.mcap")
    assert "ubf_async: stopped" in robot.out
    assert_no_non_daemon_thread(robot)


# ---------------------------------------------------------------------------------------------
# the other entry points


def test_a_recorder_whose_stdout_reader_died_finishes_its_file_on_sigterm(
        tmp_path: Path, commands: list[Command]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = Command(tmp_path, "ubf_async.launch", "--listen", endpoint, "--quiet")
    commands.append(robot)
    robot.wait_for("  controller:")
    recorder = Command(tmp_path, "ubf_async.record", "--connect", endpoint, "--out",
                       str(tmp_path / "rec.mcap"), "--progress", "--flush-s", "0.2")
    commands.append(recorder)
    recorder.wait_for("recording robot")
    recorder.close_reader("out")
    # Its next progress line finds the pipe gone; the recording goes on.
    recorder.wait_for("stdout: Broken pipe", on="err")
    size = (tmp_path / "rec.mcap").stat().st_size
    deadline = time.monotonic() + START_S
    while (tmp_path / "rec.mcap").stat().st_size == size:  # it flushes every 0.2 s
        assert time.monotonic() < deadline and recorder.proc.poll() is None, recorder.text()
        time.sleep(0.05)  # polling a file the process writes: nothing to wait on instead
    code = recorder.stopped_within(STOP_BOUND_S)
    assert code == EXIT_ERROR, recorder.text()
    assert_mcap_finished(tmp_path / "rec.mcap")
    assert_no_non_daemon_thread(recorder)
    code = robot.stopped_within(STOP_BOUND_S)
    assert code == 0, robot.text()
    assert_no_non_daemon_thread(robot)


def test_every_entry_point_stops_within_its_bound_and_leaves_no_thread(
        tmp_path: Path, commands: list[Command]) -> None:
    """A robot, then each program that attaches to it (and the router, on its own): started,
    SIGTERM once it is up, gone within the bound with status 0, no non-daemon thread left."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = Command(tmp_path, "ubf_async.launch", "--listen", endpoint, "--quiet", "--record",
                    str(tmp_path / "rec"))
    commands.append(robot)
    robot.wait_for("  controller:")
    attach = ["--connect", endpoint]
    programs = {
        "record": (["ubf_async.record", *attach, "--name", "r2", "--out",
                    str(tmp_path / "r2.mcap")],
                   "recording robot"),
        "liveview": (["ubf_async.liveview", *attach, "--port", str(free_port())], "live on"),
        "range": (["components.range", *attach, "--name", "probe"], "attached to robot"),
        "remote": (["examples.avoid_obstacles", *attach], "votes in"),
        "router": (["ubf_async.router", "--listen", f"tcp/127.0.0.1:{free_port()}"],
                   "router: listening on"),
    }
    for name, (args, ready) in programs.items():
        program = Command(tmp_path, *args)
        commands.append(program)
        program.wait_for(ready)
        code = program.stopped_within(STOP_BOUND_S)
        assert code == 0, f"{name}: {program.text()}"
        assert_no_non_daemon_thread(program)
    code = robot.stopped_within(STOP_BOUND_S)
    assert code == 0, robot.text()
    assert_no_non_daemon_thread(robot)
    # The recording, replayed into a controller that follows its clock.
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    controller = Command(tmp_path, "ubf_async.launch", "--no-sim", "--sim-time", "--listen",
                         endpoint, "--quiet")
    commands.append(controller)
    controller.wait_for("  controller:")
    replay = Command(tmp_path, "ubf_async.replay", str(tmp_path / "rec" / "mini.mcap"),
                     "--connect", endpoint)
    commands.append(replay)
    replay.wait_for("replaying")
    for program in (replay, controller):
        code = program.stopped_within(STOP_BOUND_S)
        assert code == 0, program.text()
        assert_no_non_daemon_thread(program)
    # Not even its reading thread, daemon though it is: killed inside the decompressor as
    # the interpreter finalizes, it would abort the process.
    assert not [t for t in replay.threads_left() if t["name"].startswith("replay:")], \
        replay.threads_left()


# ---------------------------------------------------------------------------------------------
# the threads calls leave the loop on


class Held:
    """Something a call holds (as ``_close`` held the zenoh session) whose release is seen."""

    def __call__(self) -> str:
        return "done"


def published_while_held(future: concurrent.futures.Future[Any],
                         ref: weakref.ref[Held]) -> threading.Event:
    """Set if, when ``future``'s outcome is published (in the thread publishing it), the
    object ``ref`` names was still alive."""
    held = threading.Event()

    def check(_: concurrent.futures.Future[Any]) -> None:
        if ref() is not None:
            held.set()

    future.add_done_callback(check)
    return held


def test_a_call_thread_lets_go_of_the_call_before_its_result_is_published() -> None:
    """A call's daemon thread may still be finishing when the program returns; it must not
    hold the last reference to anything then — a zenoh session freed in it while the
    interpreter finalizes aborts the process (``FATAL: exception not rethrown``: the session's
    close re-enters Python). So by the time the result is out, the call is let go of."""
    executor = ending.DaemonExecutor(bound_s=5.0)
    start = threading.Event()
    call, argument = Held(), Held()
    refs = weakref.ref(call), weakref.ref(argument)
    future = executor.submit(lambda f, a: (start.wait(), f())[1], call, argument)
    held = [published_while_held(future, ref) for ref in refs]
    del call, argument
    start.set()
    assert future.result(timeout=5.0) == "done"
    assert [h.is_set() for h in held] == [False, False]
    executor.shutdown()


def test_a_call_cancelled_before_it_ran_is_let_go_of_too() -> None:
    executor = ending.DaemonExecutor(bound_s=5.0, one_at_a_time=True)
    start = threading.Event()
    first = executor.submit(start.wait)
    waiting = Held()
    ref = weakref.ref(waiting)
    second = executor.submit(waiting)
    assert second.cancel()
    del waiting
    start.set()
    first.result(timeout=5.0)
    executor.shutdown()  # waits for both threads
    assert ref() is None


@pytest.mark.asyncio
@pytest.mark.parametrize("ordered", [False, True], ids=["own-threads", "zenoh-threads"])
async def test_a_closed_zenoh_bus_has_no_callback_left_to_run(ordered: bool) -> None:
    """Samples still streaming in when a bus closes: once ``aclose`` returns, every
    declaration's callback is done with (zenoh-python ran its ``drop``) and the callback
    threads have ended — nothing is left to enter Python from zenoh as the interpreter exits."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = await Bus.open(ConnectionOptions(robot="ends", listen=[endpoint]), ordered=ordered)
    sender = await Bus.open(ConnectionOptions(robot="ends", connect=[endpoint]))
    try:
        heard = asyncio.Event()
        for n in range(3):
            robot.subscribe(f"ubf/ends/t{n}", lambda key, payload, received_ns: heard.set())
        robot.watch_liveliness("ubf/ends/alive/**", lambda key, up: None)
        publisher = sender.raw_publisher("ubf/ends/t1")
        deadline = time.monotonic() + START_S
        while not heard.is_set():  # until the link carries samples (no fixed wait)
            assert time.monotonic() < deadline, "no sample crossed the link"
            publisher.put(b"x")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(heard.wait(), 0.05)
        streaming = asyncio.create_task(keep_publishing(publisher))
        ends = list(transport_of(robot)._callback_ends)
        assert len(ends) == 4
        await robot.aclose()
        assert all(end.dropped.is_set() for end in ends)
        threads = [end.thread for end in ends]
        if ordered:
            assert threads == [None] * 4  # they ran on zenoh's threads: nothing to join
        else:
            assert all(t is not None and not t.is_alive() for t in threads), threads
        streaming.cancel()
    finally:
        await robot.aclose()
        await sender.aclose()


async def keep_publishing(publisher: Any) -> None:
    while True:
        publisher.put(b"x")
        await asyncio.sleep(0)


def transport_of(bus: Bus) -> ZenohConnection:
    connection = bus._connection
    assert isinstance(connection, ZenohConnection)
    return connection


# ---------------------------------------------------------------------------------------------
# the fleet


def test_the_fleet_launcher_stopped_while_it_runs_stops_every_child(
        tmp_path: Path, commands: list[Command]) -> None:
    logs = tmp_path / "logs"
    fleet_file = tmp_path / "pair.yaml"  # the example's, on a free port, running for long
    fleet_file.write_text(f"""
world: {{scenario: ball-in-sight, speed: 1, duration_s: 600}}
router: tcp/127.0.0.1:{free_port()}
robots:
  - {{name: f1, start: {{x_m: 0.0, y_m: 0.0, heading_deg: 0}}}}
  - {{name: f2, start: {{x_m: -0.4, y_m: 0.5, heading_deg: -45}}}}
""")
    fleet = Command(tmp_path, "ubf_async.fleet", str(fleet_file), "--log-dir", str(logs),
                    "--status-period-s", "0.5")
    commands.append(fleet)
    fleet.wait_for("Hz")  # a controller reports, on the world's clock: every child is up
    children = [pid for pid in _pids_mentioning(str(logs)) if pid != fleet.proc.pid]
    assert children, fleet.text()
    code = fleet.stopped_within(FLEET_STOP_BOUND_S)
    assert code == 0, fleet.text()
    assert not [pid for pid in children if _alive(pid)], "children left running"
    assert (logs / "world-summary.json").exists()  # the world saved its results
    assert not any("killed (SIGKILL)" in line for line in fleet.err), fleet.text()
    assert_no_non_daemon_thread(fleet)


def _pids_mentioning(text: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError):
                if text in (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode():
                    found.append(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return False
    return state != "Z"
