"""What every command-line entry point does around its asyncio main.

* The first Ctrl-C (SIGINT) or SIGTERM stops it cleanly: the main task is cancelled, so its
  ``finally`` blocks close components and sessions (and launch saves the run's results).
* The stop is bounded: a program still running :data:`STOP_BOUND_S` after the first signal
  exits as a second signal makes it.
* A second Ctrl-C or SIGTERM exits at once with status 130, whatever the shutdown is stuck on
  — a write that blocks, a zenoh call that never returns, a thread the interpreter would wait
  for at exit — after giving what must be finished (a recording's index:
  :func:`ubf_async.cli.ending.on_exit_now`) :data:`EXIT_NOW_BUDGET_S`. It is noticed by a thread
  of its own (through :func:`signal.set_wakeup_fd`), so it works even when the main thread is
  stuck inside a C call.
* stdout and stderr cannot fail the program (:class:`~ubf_async.cli.ending.SafeStream`): when
  their reader goes away the output is dropped, the run goes on, its end writes its results,
  and the exit status is 2.
* A connection or configuration problem (any :class:`~ubf_async.errors.UbfError`) is one
  clear line on stderr with exit status 2 (:func:`said_error`). This module is the only place an
  error becomes an exit status: :func:`run_main` for asyncio programs, :func:`run_sync` for the
  synchronous ones (robotfile, secure, sweep, evolve, tune).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Awaitable, Callable, Coroutine, Iterator
from types import FrameType
from typing import Any, TextIO, TypeVar, cast

from ubf_async import extras
from ubf_async.cli import ending, trim
from ubf_async.errors import ConfigurationError, UbfError
from ubf_async.runtime import lending

__all__ = ["DEFAULT_LOOP", "EXIT_ERROR", "EXIT_INTERRUPTED", "EXIT_NOW_BUDGET_S", "LOOP_CHOICES",
           "LOOP_ENV", "LOOP_HELP", "SAY_WAIT_S", "SECOND_SIGNAL_AFTER_S", "STOP_BOUND_S",
           "STOP_SIGNALS", "StopGuard", "check_lockstep_loop", "loop_factory", "run_loop",
           "run_main", "run_sync", "said_error", "say_error"]

T = TypeVar("T")

EXIT_ERROR = 2
"""A user's mistake or a problem the program explains (one line on stderr)."""
EXIT_INTERRUPTED = 130
"""Stopped at once by a second Ctrl-C/SIGTERM (the shell's 128 + SIGINT)."""

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

STOP_BOUND_S = 5.0
"""How long a program may take to stop after the first Ctrl-C/SIGTERM (docs: README)."""
EXIT_NOW_BUDGET_S = 1.0
"""Wall time an immediate exit gives to what must be finished (a recording's index)."""
SECOND_SIGNAL_AFTER_S = 0.25
"""A stop signal within this long of the first is the same request, not a second one: tools
send one signal twice at once (``timeout -s INT`` to the command and to its process group, a
terminal's Ctrl-C to a wrapper that forwards it), while a person pressing Ctrl-C again to quit
at once takes longer than this between the two."""
SAY_WAIT_S = 0.5
"""How long the stop waits for the watcher thread to finish saying that it stops."""


class StopGuard:
    """SIGINT/SIGTERM handling for one command: the first signal calls ``on_first`` (cancel
    the main task), the second exits the process at once (``os._exit``) after flushing what
    can be flushed.

    Install it with ``with guard.installed():`` from the main thread (elsewhere it does
    nothing: Python only lets the main thread handle signals). When the block ends without
    any signal received the previous handlers are restored; after one, the guard stays in
    place, so a second signal still exits if the interpreter hangs on its way out.
    """

    def __init__(self, *, prog: str, flush_timeout_s: float = 0.5,
                 stop_bound_s: float = STOP_BOUND_S) -> None:
        self.prog = prog
        self.flush_timeout_s = flush_timeout_s
        self.stop_bound_s = stop_bound_s
        self.signals = 0
        """Stop signals received so far (counted by the watcher thread)."""
        self.unsaid: OSError | None = None
        """Why a message of the guard could not be written to stderr (the exit status says so)."""
        self._on_first: Callable[[], None] | None = None
        self._first_handled = False
        self._stopping_claimed = False
        self._stopping_said = threading.Event()
        self._lock = threading.Lock()
        self._exiting = threading.Lock()
        self._first_at = 0.0
        """When the watcher read the first stop signal (``time.monotonic``)."""
        self.overdue: threading.Timer | None = None
        """Exits the process if the stop the first signal began is not over within
        ``stop_bound_s``."""

    def arm(self, on_first: Callable[[], None]) -> None:
        """What the first signal does (typically: cancel the main task, thread-safely)."""
        self._on_first = on_first

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopGuard]:
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)  # the C-level handler must never block
        previous = {sig: signal.getsignal(sig) for sig in STOP_SIGNALS}
        for sig in STOP_SIGNALS:
            signal.signal(sig, self._handle)
        old_wakeup = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        watcher = threading.Thread(target=self._watch, args=(read_fd,), daemon=True,
                                   name="ubf-stop-guard")
        watcher.start()
        try:
            yield self
        finally:
            if self.signals == 0 and not self._first_handled:
                signal.set_wakeup_fd(old_wakeup)
                for sig, handler in previous.items():
                    signal.signal(sig, handler)
                os.close(write_fd)  # the watcher reads EOF and ends
                watcher.join(timeout=1.0)
                with contextlib.suppress(OSError):
                    os.close(read_fd)

    # main thread: Python-level handler ------------------------------------------------------
    def _handle(self, signum: int, frame: FrameType | None) -> None:
        with self._lock:
            first = not self._first_handled
            self._first_handled = True
        if not first:
            if self.signals > 1:  # a second request, as the watcher counts them
                self.exit_now(signum)  # (the watcher normally got there first)
            return
        # Said before the stop begins, so that it comes before whatever the stop prints.
        self._say_stopping(wait=True)
        if self._on_first is None:
            raise KeyboardInterrupt  # before the loop runs: nothing to stop cleanly yet
        self._on_first()

    # watcher thread --------------------------------------------------------------------------
    def _watch(self, read_fd: int) -> None:
        while True:
            try:
                data = os.read(read_fd, 64)
            except OSError:
                return
            if not data:
                return
            # When the signals came, as near as this process can tell: this thread waits
            # for them in read(), on no lock, whatever the main thread is doing.
            now = time.monotonic()
            for signum in data:
                if signum not in STOP_SIGNALS:
                    continue
                if self.signals and now - self._first_at < SECOND_SIGNAL_AFTER_S:
                    continue  # the first request, sent twice at once
                self.signals += 1
                if self.signals == 1:
                    self._first_at = now
                    self._say_stopping(wait=False)  # the main thread may be stuck in C
                    self.overdue = threading.Timer(self.stop_bound_s, self._overdue,
                                                   args=(signum,))
                    self.overdue.daemon = True
                    self.overdue.start()
                else:
                    self.exit_now(signum)

    def _say_stopping(self, *, wait: bool) -> None:
        """Say once, from whichever thread comes first, that the command is stopping.
        ``wait``: if the other thread is saying it, wait (a bounded while) until it has."""
        with self._lock:
            claimed, self._stopping_claimed = self._stopping_claimed, True
        if not claimed:
            self._say(f"{self.prog}: stopping (press Ctrl-C again to quit at once)\n")
            self._stopping_said.set()
        elif wait:
            self._stopping_said.wait(SAY_WAIT_S)

    def _overdue(self, signum: int) -> None:
        self._say(f"{self.prog}: not stopped {self.stop_bound_s:g} s after "
                  f"{signal.Signals(signum).name}: exiting now\n")
        self.exit_now(signum, again=False)

    def _say(self, text: str) -> None:
        try:
            os.write(2, text.encode(errors="replace"))  # no Python-level lock to get stuck on
        except OSError as exc:
            self.unsaid = exc

    def exit_now(self, signum: int, *, again: bool = True) -> None:
        """Finish what must be (:func:`ubf_async.cli.ending.exit_now`, within
        :data:`EXIT_NOW_BUDGET_S`), flush stdout/stderr (giving up after ``flush_timeout_s``)
        and ``os._exit(130)``."""
        if not self._exiting.acquire(blocking=False):
            threading.Event().wait()  # another thread is exiting the process right now
        if again:
            name = signal.Signals(signum).name
            self._say(f"{self.prog}: {name} again: exiting now, without finishing the "
                      f"shutdown\n")
        ending.exit_now(EXIT_NOW_BUDGET_S)

        def flush() -> None:
            for stream in (sys.stdout, sys.stderr):
                with contextlib.suppress(Exception):
                    stream.flush()

        flusher = threading.Thread(target=flush, daemon=True, name="ubf-stop-flush")
        flusher.start()
        flusher.join(self.flush_timeout_s)  # a stream stuck on a full pipe must not hold us
        os._exit(EXIT_INTERRUPTED)


LOOP_ENV = lending.LOOP_ENV
DEFAULT_LOOP = "asyncio"
"""The event loop without ``UBF_LOOP``: asyncio's own (the figures that decided it:
docs/latency.md, "Which event loop")."""
LOOP_CHOICES = (DEFAULT_LOOP, "lending", "uvloop")
LOOP_HELP = lending.LOOP_HELP


def loop_factory() -> Callable[[], asyncio.AbstractEventLoop]:
    """The event loop programs run on, chosen by ``UBF_LOOP``:

    * unset or ``asyncio`` (the default): asyncio's selector loop, which lends itself to no
      other thread; it only tells a simulation's lockstep when it has nothing left to run
      (:func:`ubf_async.runtime.lending.new_idle_event_loop`);
    * ``lending`` (opt-in): the same loop lending itself to zenoh's threads while it waits,
      so a reflex is answered on the thread that brought its sample
      (:func:`ubf_async.runtime.lending.new_event_loop`);
    * ``uvloop`` (opt-in, ``pip install 'ubf-async[fast]'``): hands samples to the loop a
      few µs faster than asyncio, cannot run a lockstep, and under it a second Ctrl-C does
      not cut a stuck shutdown short.

    Anything else raises :class:`~ubf_async.errors.ConfigurationError`."""
    given = os.environ.get(LOOP_ENV, "")
    choice = given.strip().lower() or DEFAULT_LOOP
    if choice not in LOOP_CHOICES:
        raise ConfigurationError(f"{LOOP_ENV}={given!r}: unknown event loop; expected one of "
                                 f"{DEFAULT_LOOP} (the default), "
                                 f"{', '.join(LOOP_CHOICES[1:])}")
    if choice == "asyncio":
        return lending.new_idle_event_loop
    if choice == "lending":
        return lending.new_event_loop
    uvloop = extras.require("fast", "uvloop", who=f"{LOOP_ENV}=uvloop")
    factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
    return factory


def check_lockstep_loop() -> None:
    """Refuse, before anything starts, a simulation on a loop that cannot run it: simulated
    time advances in lockstep, which needs to know when the loop has nothing left to run
    (:meth:`~ubf_async.runtime.lending.IdleEventLoop.idle`: the default loop and the lending
    loop; not uvloop)."""
    if loop_factory() not in (lending.new_idle_event_loop, lending.new_event_loop):
        raise ConfigurationError(
            f"a simulation advances in lockstep, which needs to know when the event loop is "
            f"idle: {LOOP_ENV}={os.environ.get(LOOP_ENV)!r} cannot tell; unset {LOOP_ENV} "
            f"(asyncio, the default) or set {LOOP_ENV}=lending")


def run_loop(main: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run`` on the loop :func:`loop_factory` chooses."""
    with asyncio.Runner(loop_factory=loop_factory()) as runner:
        return runner.run(main)


def say_error(prog: str, message: object) -> None:
    """Say ``message`` as every entry point says an error: the one line ``PROG: error: …`` on
    stderr (argparse's own format, so a usage mistake and a refusal read alike)."""
    print(f"{prog}: error: {message}", file=sys.stderr)


def said_error(prog: str, exc: BaseException) -> int:
    """Say ``exc`` as the one line ``PROG: error: …`` on stderr; return :data:`EXIT_ERROR`."""
    say_error(prog, exc)
    return EXIT_ERROR


def run_sync(main: Callable[[], int], *, prog: str) -> int:
    """Run a synchronous program's ``main()``; return its status, or :data:`EXIT_ERROR` after
    one line for a :class:`UbfError` it raises (the rule :func:`run_main` applies)."""
    try:
        return main()
    except UbfError as exc:
        return said_error(prog, exc)


def run_main(main: Callable[[], Awaitable[int]], *, prog: str,
             stop_bound_s: float = STOP_BOUND_S) -> int:
    """Run ``main()`` in a new event loop under a :class:`StopGuard`, with stdout and stderr
    as :class:`~ubf_async.cli.ending.SafeStream` (``main`` reads ``sys.stdout`` when called, not
    at import); return the exit status: ``main``'s, 0 when stopped by a first signal, 2 for a
    :class:`UbfError` (or a ``ConnectionError``/``ValueError``, printed as one line) or when
    stdout or stderr could not be written, 130 when interrupted before the loop ran."""
    streams = (ending.SafeStream(sys.stdout, "stdout"), ending.SafeStream(sys.stderr, "stderr"))
    saved = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = cast(TextIO, streams[0]), cast(TextIO, streams[1])
    # The log goes to stderr too: through the same stream, so a lost log line counts.
    handlers = [h for h in logging.getLogger().handlers
                if isinstance(h, logging.StreamHandler) and h.stream is saved[1]]
    for handler in handlers:
        handler.setStream(sys.stderr)
    guard = StopGuard(prog=prog, stop_bound_s=stop_bound_s)
    try:
        code = _run_guarded(main, guard, prog=prog)
        for stream in streams:
            stream.flush()
    finally:
        sys.stdout, sys.stderr = saved
        for handler in handlers:
            handler.setStream(saved[1])
    errors = [(s.name, s.error) for s in streams if s.error is not None]
    if guard.unsaid is not None and streams[1].error is None:
        errors.append(("stderr", guard.unsaid))
    lost = [f"{name}: {getattr(error, 'strerror', None) or error}" for name, error in errors]
    if lost and code == 0:
        with contextlib.suppress(OSError, ValueError):
            print(f"{prog}: output lost ({'; '.join(lost)})", file=sys.stderr)
        return EXIT_ERROR
    return code


def _run_guarded(main: Callable[[], Awaitable[int]], guard: StopGuard, *, prog: str) -> int:

    async def runner() -> int:
        loop = asyncio.get_running_loop()
        # A thread stuck in a write cannot hold the exit (asyncio's own executor would).
        loop.set_default_executor(ending.DaemonExecutor(bound_s=EXIT_NOW_BUDGET_S))
        task = asyncio.current_task()
        assert task is not None

        def cancel() -> None:
            with contextlib.suppress(RuntimeError):  # the loop has closed meanwhile
                loop.call_soon_threadsafe(task.cancel)

        guard.arm(cancel)
        trimmer = asyncio.create_task(trim.every(), name="malloc_trim")
        try:
            return await main()
        except asyncio.CancelledError:
            return 0
        except (UbfError, ConnectionError, ValueError) as exc:
            return said_error(prog, exc)
        finally:
            trimmer.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await trimmer

    try:
        factory = loop_factory()
    except ConfigurationError as exc:
        return said_error(prog, exc)
    with guard.installed():
        try:
            with asyncio.Runner(loop_factory=factory) as loop_runner:
                return loop_runner.run(runner())
        except KeyboardInterrupt:
            return EXIT_INTERRUPTED
