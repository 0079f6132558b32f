"""How a program ends: one ordered path that nothing can skip.

A run is judged by its end as much as by its run: the results written, the recording finished,
the session closed — whatever went wrong before (an exception, a console that went away, a stop
signal during the end). Three pieces:

* :class:`Ending` runs the steps of an end in order. Each is bounded in wall time; one that
  fails or overruns is logged and counted, and the next runs anyway. A stop
  signal that arrives during the end does not cut it short (the end is bounded; a second signal
  exits at once, :mod:`ubf_async.cli.run`).
* :class:`SafeStream` is stdout or stderr that cannot make an end fail: a write to a console
  whose reader went away is dropped, noted once, and counted against the exit status — never
  raised into the code that was saving the results.
* :func:`on_exit_now` registers what must still be finished when the process exits at once
  (a second signal, or the stop bound passed): a recording's index, say. :func:`exit_now`'s
  caller gives them one shared, short budget.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import ctypes
import functools
import itertools
import logging
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Awaitable, Callable
from typing import Any, TextIO, TypeVar

__all__ = ["PR_SET_PDEATHSIG", "CallThread", "DaemonExecutor", "Ending", "SafeStream",
           "die_with_parent", "exit_now", "on_exit_now"]

log = logging.getLogger(__name__)

T = TypeVar("T")


PR_SET_PDEATHSIG = 1
"""Linux's ``prctl`` option: a signal the kernel sends this process when its parent dies."""


def die_with_parent() -> None:
    """Have the kernel kill this process (SIGKILL) when its parent dies, however it dies: a
    worker or a busy loop left running unseen would hold a machine for hours. A no-op but on
    Linux."""
    if sys.platform == "linux":
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


class Ending:
    """The ordered steps of one end (see the module docstring).

    ``await ending.step(name, action, bound_s=…)`` runs ``action()`` and returns its result,
    or ``None`` when it failed, overran ``bound_s`` (it is then cancelled and left behind) or
    raised; :attr:`failures` says which and why, in order."""

    def __init__(self, logger: logging.Logger = log) -> None:
        self.log = logger
        self.failures: list[str] = []

    @property
    def ok(self) -> bool:
        return not self.failures

    def fail(self, name: str, reason: str) -> None:
        """Count a failure that happened outside a step (e.g. a result that was not made)."""
        self.failures.append(f"{name}: {reason}")
        self.log.error("%s: %s", name, reason)

    async def step(self, name: str, action: Callable[[], Awaitable[T]], *,
                   bound_s: float, overrun_is_failure: bool = True) -> T | None:
        """``overrun_is_failure=False``: a step the process's exit does anyway (closing a
        zenoh session: the kernel closes its sockets) is only warned about when it overruns —
        e.g. a peer that stopped answering holds a session's close for its lease."""
        task = asyncio.ensure_future(action())
        deadline = time.monotonic() + bound_s
        while not task.done() and (left := deadline - time.monotonic()) > 0:
            try:
                await asyncio.wait({task}, timeout=left)
            except asyncio.CancelledError:
                # A stop signal: the end goes on (it is bounded), and the task stays usable.
                current = asyncio.current_task()
                if current is not None:
                    current.uncancel()
        if not task.done():
            task.cancel()
            task.add_done_callback(_retrieve)  # its late outcome is not an unhandled error
            if overrun_is_failure:
                self.fail(name, f"did not finish within {bound_s:g} s (left behind)")
            else:
                self.log.warning("%s: did not finish within %g s (left behind)", name, bound_s)
            return None
        if task.cancelled():
            self.fail(name, "cancelled")
            return None
        exc = task.exception()
        if exc is not None:
            self.log.debug("%s failed", name, exc_info=exc)  # the trace, for --log-level DEBUG
            self.fail(name, f"failed: {type(exc).__name__}: {exc}")
            return None
        return task.result()


def _retrieve(task: asyncio.Future[Any]) -> None:
    if not task.cancelled():
        task.exception()


class SafeStream:
    """A text stream (stdout, stderr) whose ``write`` and ``flush`` never raise.

    The first failure (``EPIPE`` when the reader went away, ``ValueError`` on a closed file)
    is kept in :attr:`error`; from then on the file descriptor is pointed at ``/dev/null`` so
    that nothing — this program, a library writing to the raw descriptor, the interpreter's
    own flush at exit — fails on it again, and the output is dropped. Everything else is the
    wrapped stream's."""

    def __init__(self, stream: TextIO, name: str) -> None:
        self.stream = stream
        self.name = name
        self.error: BaseException | None = None

    def write(self, text: str) -> int:
        if self.error is None:
            try:
                return self.stream.write(text)
            except (OSError, ValueError) as exc:
                self._lost(exc)
        return len(text)

    def flush(self) -> None:
        if self.error is None:
            try:
                self.stream.flush()
            except (OSError, ValueError) as exc:
                self._lost(exc)

    def _lost(self, exc: BaseException) -> None:
        self.error = exc
        with contextlib.suppress(OSError, ValueError, AttributeError):
            fd = self.stream.fileno()
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, fd)
            os.close(null)
        # stderr may be the stream that failed: logging falls back to nothing, quietly.
        log.warning("%s: %s; output to it is dropped from now on", self.name,
                    getattr(exc, "strerror", None) or exc)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


_EXIT_NOW: dict[int, Callable[[float], None]] = {}
_EXIT_NOW_KEYS = itertools.count()
_EXIT_NOW_LOCK = threading.Lock()


def on_exit_now(finish: Callable[[float], None]) -> Callable[[], None]:
    """Register ``finish(timeout_s)``, called from another thread when the process is about to
    exit at once; it must return within ``timeout_s``. Returns the function that unregisters
    it (call it once the resource closed normally)."""
    with _EXIT_NOW_LOCK:
        key = next(_EXIT_NOW_KEYS)
        _EXIT_NOW[key] = finish

    def unregister() -> None:
        with _EXIT_NOW_LOCK:
            _EXIT_NOW.pop(key, None)

    return unregister


def exit_now(budget_s: float) -> None:
    """Run what :func:`on_exit_now` registered, sharing ``budget_s`` of wall time, each in a
    daemon thread (one that hangs is given up on at the deadline)."""
    with _EXIT_NOW_LOCK:
        finishers = list(_EXIT_NOW.values())
    deadline = time.monotonic() + budget_s
    threads = []
    for finish in finishers:
        thread = threading.Thread(target=_run_quietly, args=(finish, budget_s), daemon=True,
                                  name="ubf-exit-now")
        thread.start()
        threads.append(thread)
    for thread in threads:
        thread.join(max(0.0, deadline - time.monotonic()))


def _run_quietly(finish: Callable[[float], None], timeout_s: float) -> None:
    with contextlib.suppress(Exception):
        finish(timeout_s)


def _run_call(job: list[tuple[concurrent.futures.Future[T], Callable[[], T]]]) -> None:
    """Run the call ``job`` holds for its future, letting go of it before the result is
    published (:class:`DaemonExecutor`). (Taken out of the list here, not unpacked into
    arguments: the caller's argument tuple would hold the call until this returns.)"""
    future, call = job.pop()
    if not future.set_running_or_notify_cancel():
        return
    try:
        result = call()
    except BaseException as exc:
        del call
        future.set_exception(exc)
    else:
        del call
        future.set_result(result)


class DaemonExecutor(concurrent.futures.ThreadPoolExecutor):
    """An event loop's default executor (``asyncio.to_thread``) whose work cannot keep the
    process alive: each call runs in a daemon thread of its own, and shutting down waits for
    them at most ``bound_s`` in all. asyncio's own executor waits for its threads for ever, so
    one write stuck on a FIFO nobody reads or a dead network share would hang the exit; here
    the end (:class:`Ending`) has bounded and reported it, and the process goes on to exit.
    A thread per call: the calls that leave the loop are few (file writes, zenoh queries);
    ``one_at_a_time`` runs them one after another (CPU work that would only fight for the GIL).
    (A ``ThreadPoolExecutor`` only because asyncio accepts nothing else; none of its pool is
    used.)

    A call's thread lets go of the call — the function, its arguments and whatever they hold —
    before its result is published, never after: otherwise a thread still finishing when the
    program returns can drop the last reference to a zenoh session while the interpreter
    finalizes, and the session's close, re-entering Python then, aborts the process
    (``FATAL: exception not rethrown``). The stdlib's own workers ``del`` their work item for
    the same reason."""

    def __init__(self, *, bound_s: float, name: str = "ubf-io",
                 one_at_a_time: bool = False) -> None:
        super().__init__(max_workers=1)
        self.bound_s = bound_s
        self.name = name
        self._one_at_a_time = threading.Lock() if one_at_a_time else contextlib.nullcontext()
        self._calls: set[threading.Thread] = set()
        self._calls_lock = threading.Lock()
        self._closed = False

    def submit(self, fn: Callable[..., T], /, *args: Any,
               **kwargs: Any) -> concurrent.futures.Future[T]:
        future: concurrent.futures.Future[T] = concurrent.futures.Future()
        job: list[tuple[concurrent.futures.Future[T], Callable[[], T]]] = [
            (future, functools.partial(fn, *args, **kwargs))]  # the thread empties it

        def work() -> None:
            try:
                with self._one_at_a_time:
                    _run_call(job)
            finally:
                with self._calls_lock:
                    self._calls.discard(thread)

        thread = threading.Thread(target=work, name=self.name, daemon=True)
        with self._calls_lock:
            if self._closed:
                raise RuntimeError("cannot schedule new work after shutdown")
            self._calls.add(thread)
        thread.start()
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        with self._calls_lock:
            self._closed = True
            threads = list(self._calls)
        if wait:
            deadline = time.monotonic() + self.bound_s
            for thread in threads:
                thread.join(max(0.0, deadline - time.monotonic()))
            stuck = [t for t in threads if t.is_alive()]
            if stuck:
                log.warning("%d call(s) still running in a thread after %g s: left behind",
                            len(stuck), self.bound_s)


class CallThread(concurrent.futures.Executor):
    """One daemon thread that runs the calls submitted to it one after another, for as long
    as its users need it: work that comes often (a simulated camera's render, every frame)
    pays for one thread instead of a thread per call (:class:`DaemonExecutor`), and the calls
    take turns instead of contending for the GIL.

    Shared by reference count: each user :meth:`enter`\\ s it when it starts and
    :meth:`leave`\\ s it when it stops; the thread starts with the first user and ends with
    the last (after the call in progress, waited for at most ``bound_s``), so nothing is left
    running once every user has stopped. Its calls let go of what they hold before their
    result is published, as :class:`DaemonExecutor`'s do; a daemon thread, it cannot keep the
    process alive."""

    def __init__(self, *, name: str, bound_s: float = 1.0) -> None:
        self.name = name
        self.bound_s = bound_s
        self._lock = threading.Lock()
        self._users = 0
        self._queue: queue.SimpleQueue[list[Any] | None] | None = None
        self._thread: threading.Thread | None = None

    def enter(self) -> CallThread:
        with self._lock:
            self._users += 1
            if self._thread is None:
                calls: queue.SimpleQueue[list[Any] | None] = queue.SimpleQueue()
                self._queue = calls
                self._thread = threading.Thread(target=self._serve, args=(calls,),
                                                name=self.name, daemon=True)
                self._thread.start()
        return self

    def leave(self) -> None:
        with self._lock:
            self._users -= 1
            if self._users > 0 or self._thread is None:
                return
            thread, calls = self._thread, self._queue
            self._thread = self._queue = None
        assert calls is not None
        calls.put(None)  # after the calls already queued
        thread.join(self.bound_s)
        if thread.is_alive():
            log.warning("%s: a call still running %g s after its last user stopped: left "
                        "behind", self.name, self.bound_s)

    def submit(self, fn: Callable[..., T], /, *args: Any,
               **kwargs: Any) -> concurrent.futures.Future[T]:
        future: concurrent.futures.Future[T] = concurrent.futures.Future()
        with self._lock:
            if self._queue is None:
                raise RuntimeError(f"{self.name}: no user has entered it")
            self._queue.put([(future, functools.partial(fn, *args, **kwargs))])
        return future

    @staticmethod
    def _serve(calls: queue.SimpleQueue[list[Any] | None]) -> None:
        while (job := calls.get()) is not None:
            _run_call(job)
            del job
