"""An asyncio event loop that lends itself to the transport's threads while it waits.

zenoh runs subscriber callbacks on its own threads. The usual bridge
(:class:`~ubf_async.runtime.bus.Subscription`) hands each sample to the event loop with
``call_soon_threadsafe``: the loop thread, asleep in ``epoll``, is woken through its
self-pipe and handles the sample. On a small machine that wake-up is the largest single part
of a reflex's time in the controller (``docs/latency.md``): a second thread must be
scheduled, often on an idle CPU.

:class:`LendingEventLoop` skips it when it can. The loop thread holds the loop's *run lock*
whenever it runs anything, and lets go of it only while it waits in ``select()`` for I/O or
a timer. A transport thread that brings a sample may take the lock **if it is free** — the
loop is idle — and run the subscription's handler itself, at once, as the loop thread would
have run it:

* nothing else runs loop code meanwhile: should the loop thread's ``select()`` return, it
  waits for the lock before running anything;
* :func:`asyncio.get_running_loop` answers this loop;
* whatever the handler schedules (``call_soon``, ``call_later``, a future's done callbacks,
  an :class:`asyncio.Event` set) is run by the loop thread, which is woken for it as soon as
  the handler returns.

When the loop is busy the sample takes the usual road. Either way one handler runs at a time
and never beside loop code, so code written for the loop needs nothing new, with two
exceptions: it must not rely on the identity of the thread it runs on
(``threading.get_ident()``; a publisher that does simply takes the thread-safe road), and it
should not add or remove the loop's readers and writers.

Lending is opt-in (``UBF_LOOP=lending``, :func:`new_event_loop`): the entry points' default
is its base, :class:`IdleEventLoop` (:func:`new_idle_event_loop`), asyncio's selector loop plus
:meth:`~IdleEventLoop.idle` — no other thread ever runs loop code. Measured in
``python -m bench.latency --only loops`` (docs/latency.md, "Which event loop"), lending takes
5-9 % off a reflex's median and nothing off its p99 (worse on a busy host): not worth being
the mechanism every maintainer of async code must understand first.

The same moment — the loop about to wait — is what :meth:`IdleEventLoop.idle` reports:
every task is blocked and no callback is ready, so whatever the caller's last step set off
has run to its end. The simulator's lockstep barrier is built on it
(:mod:`components.sim.runner.stepper`); asyncio's loop decides it (it asks its selector to wait
only when nothing is ready), so no loop iterations are counted and no private attribute read.

Only subscriptions that ask for it are handled this way (``Bus.subscribe(..., direct=True)``):
the state aggregator's, for its samples that do not take the controller's reflex lane (which
answers a reflex on the thread that brought its sample without borrowing the loop, on any
loop: :mod:`ubf_async.runtime.controller`). Keep
it to short handlers on a latency path, in processes where little else runs Python: a
borrower holds the loop for the whole handler, and when it waits for the GIL (a ``put``
lets go of it) the loop waits too — in a busy simulator process with a render thread that
costs more than the hand-off saves. Lending is off in asyncio's debug mode
(its thread checks would refuse it) and on any other loop (uvloop, a test framework's):
:func:`run_if_idle` then gives ``None`` and every sample goes the usual way.
"""

from __future__ import annotations

import asyncio
import contextvars
import selectors
import threading
from collections.abc import Awaitable, Callable
from typing import Any, TypeVarTuple

Ts = TypeVarTuple("Ts")

__all__ = ["LOOP_ENV", "LOOP_HELP", "IdleEventLoop", "LendingEventLoop", "idle_waiter",
           "new_event_loop", "new_idle_event_loop", "run_if_idle"]

LOOP_ENV = "UBF_LOOP"
"""The environment variable that chooses the event loop (:func:`ubf_async.cli.run.loop_factory`)."""
LOOP_HELP = (
    f"{LOOP_ENV} chooses the event loop. Unset or {LOOP_ENV}=asyncio (the default): asyncio's "
    f"own selector loop; no other thread ever runs loop code. Opt-in: {LOOP_ENV}=lending, "
    f"while the loop is idle zenoh's threads run a sample's handler (a reflex) themselves "
    f"instead of waking the loop thread: 5-9 % off a reflex's median, a worse p99 on a busy "
    f"host; {LOOP_ENV}=uvloop (pip install 'ubf-async[fast]'): no steady gain, cannot run a "
    f"simulation in lockstep. Figures: docs/latency.md, \"Which event loop\"")
"""What every entry point's ``--help`` says about the event loop
(:func:`ubf_async.cli.args.add_event_loop_help`)."""


def _take(lock: threading.Lock) -> None:
    """``lock.acquire()`` that always ends holding the lock: a signal handler that raises
    while it waits (Ctrl-C's ``KeyboardInterrupt``) is re-raised once the lock is held."""
    interrupted: BaseException | None = None
    while True:
        try:
            lock.acquire()
            break
        except BaseException as exc:  # a signal handler raised while we waited
            interrupted = exc
    if interrupted is not None:
        raise interrupted


class _IdleSelector(selectors.DefaultSelector):
    """The platform's default selector, telling its loop when it is about to wait."""

    def __init__(self, loop: IdleEventLoop) -> None:
        super().__init__()
        self._loop = loop

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        if timeout is not None and timeout <= 0:  # a poll, not a wait: nothing to tell
            return super().select(timeout)
        # asyncio asks to wait only when no callback is ready: every task is blocked. Those
        # waiting for that moment (the simulator's step barrier) are woken instead of waiting.
        if self._loop._wake_idle_waiters():
            return super().select(0)
        return self._wait(timeout)

    def _wait(self, timeout: float | None) -> list[tuple[selectors.SelectorKey, int]]:
        return super().select(timeout)


class _LendingSelector(_IdleSelector):
    """:class:`_IdleSelector`, letting go of the run lock while it waits."""

    def __init__(self, loop: LendingEventLoop) -> None:
        super().__init__(loop)
        self._lender = loop

    def _wait(self, timeout: float | None) -> list[tuple[selectors.SelectorKey, int]]:
        loop = self._lender
        loop._wanted = False
        loop._run_lock.release()
        try:
            return super()._wait(timeout)
        finally:
            # No new borrower from now on: the loop thread waits for one at most, however
            # many threads bring samples (a flood must not starve the loop).
            loop._wanted = True
            _take(loop._run_lock)


class IdleEventLoop(asyncio.SelectorEventLoop):
    """asyncio's selector event loop that tells when it is idle (:meth:`idle`), nothing more:
    the entry points' default (:func:`new_idle_event_loop`); no other thread ever runs loop
    code."""

    lends = False
    """Whether other threads may borrow the loop (:class:`LendingEventLoop`)."""

    def __init__(self, *, selector: selectors.BaseSelector | None = None) -> None:
        self._idle_waiters: list[asyncio.Future[None]] = []
        super().__init__(selector=selector or _IdleSelector(self))

    async def idle(self) -> None:
        """Return once the loop has had nothing ready to run: every task is blocked (on a
        timer, a future, I/O or another thread's work) and no callback is due.

        What the caller's last step woke has then run to its end — every chain of callbacks,
        however long and however slow the machine — which is what makes a simulator's
        step barrier exact (:mod:`components.sim.runner.stepper`). A timer or I/O still to come
        does not count: it belongs to a later time. Only the loop's thread may await it."""
        waiter: asyncio.Future[None] = self.create_future()
        self._idle_waiters.append(waiter)
        await waiter

    def _wake_idle_waiters(self) -> bool:
        """Called by the selector when the loop is about to wait: wake :meth:`idle`'s
        waiters; ``True`` if there were any (the loop then polls instead of waiting)."""
        if not self._idle_waiters:
            return False
        waiters, self._idle_waiters = self._idle_waiters, []
        for waiter in waiters:
            if not waiter.done():
                waiter.set_result(None)
        return True

class LendingEventLoop(IdleEventLoop):
    """:class:`IdleEventLoop`, which other threads may borrow while it waits (module
    docstring): opt-in, ``UBF_LOOP=lending`` (:func:`new_event_loop`)."""

    lends = True

    def __init__(self) -> None:
        self._run_lock = threading.Lock()
        self._run_lock.acquire()  # held except while the loop waits in select()
        self._wanted = True
        """The loop thread runs, or wants to: borrowers keep away."""
        self._lent = False
        self._scheduled_while_lent = False
        self.lent_runs = 0
        """Callbacks run by a borrowing thread so far."""
        super().__init__(selector=_LendingSelector(self))

    # What a borrower schedules must wake the loop thread: it sleeps in select() with a
    # timeout computed before the borrower came. (call_later goes through call_at.)
    def call_soon(self, callback: Callable[[*Ts], object], *args: *Ts,
                  context: contextvars.Context | None = None) -> asyncio.Handle:
        if self._lent:
            self._scheduled_while_lent = True
        return super().call_soon(callback, *args, context=context)

    def call_at(self, when: float, callback: Callable[[*Ts], object], *args: *Ts,
                context: contextvars.Context | None = None) -> asyncio.TimerHandle:
        if self._lent:
            self._scheduled_while_lent = True
        return super().call_at(when, callback, *args, context=context)

    def run_if_idle(self, callback: Callable[..., object], *args: Any) -> bool:
        """Run ``callback(*args)`` now, on the calling thread, as the loop would run it — if
        the loop waits in ``select()`` — and return ``True``; return ``False`` at once if
        the loop is busy, not running, closed or in debug mode. On the loop's own thread it
        always returns ``False`` (the loop is busy: it is running the caller). An exception
        from ``callback`` propagates to the caller, after the loop is given back."""
        if (self._wanted or self.get_debug()
                or not self._run_lock.acquire(blocking=False)):
            return False
        if self._wanted:  # the loop thread woke meanwhile: it goes first
            self._run_lock.release()
            return False
        previous = asyncio._get_running_loop()
        asyncio._set_running_loop(self)
        self._lent = True
        self.lent_runs += 1
        try:
            callback(*args)
        finally:
            self._lent = False
            asyncio._set_running_loop(previous)
            wake = self._scheduled_while_lent
            self._scheduled_while_lent = False
            self._run_lock.release()
            if wake and not self.is_closed():
                self.call_soon_threadsafe(_nothing)  # wakes select() through the self-pipe
        return True


def _nothing() -> None:
    """A callback that only wakes the loop."""


def new_event_loop() -> LendingEventLoop:
    """A new :class:`LendingEventLoop` that lends itself (``UBF_LOOP=lending``,
    :func:`ubf_async.cli.run.loop_factory`)."""
    return LendingEventLoop()


def new_idle_event_loop() -> IdleEventLoop:
    """A new :class:`IdleEventLoop`, which lends itself to no thread: asyncio's selector
    loop plus :meth:`~IdleEventLoop.idle`, which simulated time's lockstep needs — the
    default of every entry point (:func:`ubf_async.cli.run.loop_factory`)."""
    return IdleEventLoop()


def idle_waiter(loop: asyncio.AbstractEventLoop) -> Callable[[], Awaitable[None]] | None:
    """``loop.idle`` for an :class:`IdleEventLoop` (a :class:`LendingEventLoop` too),
    ``None`` for any other loop (which cannot tell when it has nothing left to run)."""
    return loop.idle if isinstance(loop, IdleEventLoop) else None


def run_if_idle(loop: asyncio.AbstractEventLoop) -> Callable[..., bool] | None:
    """``loop.run_if_idle`` for a :class:`LendingEventLoop`, ``None`` for any other loop."""
    return loop.run_if_idle if isinstance(loop, LendingEventLoop) else None
