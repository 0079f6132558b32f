"""Revocation that bites while the robot runs: a secure robot re-opens its session when its
set-up changes.

zenoh (1.10) reads the password dictionary and the access control once, when a session opens,
and keeps every link it admitted: after ``secure revoke`` or ``secure rotate`` the robot would
let the old files in until it restarted. :class:`SetupWatch` reads the set-up's files
(:func:`~ubf_async.net.secure.fingerprint`) every :data:`POLL_S` seconds; when they changed
(and have settled), it has the transport close the session and open it again on the files as
they are now, with the same zenoh id and every declaration made again
(:meth:`~ubf_async.net.transport.ZenohTransport.reopen`). Every link goes with the old session:
a revoked or rotated identity's client is cut off and cannot come back with its old
credentials; every other identity's comes back by itself (zenoh clients retry). The robot —
its controller, simulator and devices — runs on throughout; what it published during the swap
(a fraction of a second) is not sent. docs/security.md, "Revoking and rotating while the robot
runs", gives the bound.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

from ubf_async.errors import ConfigurationError, SessionError
from ubf_async.net.secure import changes, fingerprint, passwords_of
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component

__all__ = ["POLL_S", "SETTLE_S", "SetupWatch"]

log = logging.getLogger(__name__)

POLL_S = 1.0
"""How often the set-up's files are read (wall time): with :data:`SETTLE_S` and the swap, a
change takes effect within 2 s."""
SETTLE_S = 0.1
"""A change is acted on once two reads this far apart agree (``rotate`` writes several
files)."""


class SetupWatch(Component):
    """Watches the secure set-up in ``directory`` and calls ``reopen`` (the transport's) when it
    changed. ``reopened`` counts the swaps; ``said`` gets a line for the console on each.

    Lifecycle: :meth:`start` takes the set-up's state as the one the session was opened on;
    the watch runs until :meth:`aclose`."""

    def __init__(self, *, bus: Bus, directory: Path, reopen: Callable[[], Awaitable[None]],
                 said: Callable[[str], None] | None = None, poll_s: float = POLL_S,
                 name: str = "secure-setup") -> None:
        super().__init__(bus=bus, name=name)
        self.directory = directory
        self._reopen = reopen
        self._said = said
        self.poll_s = poll_s
        self.reopened = 0

    async def run(self) -> None:
        seen = await asyncio.to_thread(fingerprint, self.directory)
        passwords = await asyncio.to_thread(passwords_of, self.directory)
        while True:
            await asyncio.sleep(self.poll_s)
            now = await asyncio.to_thread(fingerprint, self.directory)
            if now == seen:
                continue
            while True:  # until the files have settled
                await asyncio.sleep(SETTLE_S)
                again = await asyncio.to_thread(fingerprint, self.directory)
                if again == now:
                    break
                now = again
            after = await asyncio.to_thread(passwords_of, self.directory)
            started = time.monotonic()
            try:
                await self._reopen()
            except ConfigurationError as exc:  # a set-up that no longer reads: keep the old
                log.warning("the secure set-up in %s changed but does not read (%s): the "
                            "robot's session stays as it was; fix the set-up", self.directory,
                            exc)
                seen = now
                continue
            except SessionError as exc:
                log.error("the secure set-up in %s changed and the robot's session could not "
                          "be opened again: %s — the robot is off the network until it is "
                          "restarted", self.directory, exc)
                raise
            seen, what = now, changes(passwords, after)
            passwords = after
            self.reopened += 1
            line = (f"ubf_async: the secure set-up changed ({what}): the robot's session was "
                    f"re-opened in {time.monotonic() - started:.2f} s — every link closed, "
                    f"only the set-up's identities as they are now get back in")
            log.info(line)
            if self._said is not None:
                self._said(line)
