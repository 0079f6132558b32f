"""A peer's ``connect`` endpoints that nothing answers at, reported as warnings.

A ``client`` fails to open when nothing answers; a ``peer`` opens all the same and zenoh keeps
trying in the background (:data:`~ubf_async.net.options.RECONNECT_RETRY`): say so, as a robot
should. :class:`~ubf_async.net.transport.ZenohTransport` runs :func:`watch_connect_endpoints`
for the session it opened, until its connection closes.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable

from ubf_async.net.options import START_ROBOT_HINT, endpoint_locators, listening

__all__ = ["CONNECT_GRACE_S", "CONNECT_REMIND_S", "watch_connect_endpoints"]

log = logging.getLogger(__name__)

CONNECT_GRACE_S = 2.0
"""How long a peer's ``connect`` endpoint may stay unanswered before it is reported."""
CONNECT_REMIND_S = 60.0
"""While an endpoint stays unanswered, the warning is repeated this often."""


async def watch_connect_endpoints(links: Callable[[], list[str]], changed: asyncio.Event,
                                  endpoints: list[str], *,
                                  grace_s: float = CONNECT_GRACE_S,
                                  remind_s: float = CONNECT_REMIND_S) -> None:
    """Report, as warnings, the ``connect`` endpoints of a peer session that nothing answers
    at (after ``grace_s``, then every ``remind_s``), and when one answers after all or its link
    is lost; zenoh retries them meanwhile. ``links()`` gives the remote locator of each link the
    session has now; ``changed`` is set whenever a link comes or goes (zenoh's link events), and
    the watch looks again then, or when a warning is due. Runs until cancelled (the connection
    closes)."""
    locators = {e: await asyncio.to_thread(endpoint_locators, e) for e in endpoints}
    loop = asyncio.get_running_loop()
    opened = loop.time()
    up: dict[str, bool] = dict.fromkeys(endpoints, False)
    warned_at: dict[str, float] = {}  # endpoints reported unanswered, and when last
    ever_up: set[str] = set()
    while True:
        changed.clear()
        try:
            destinations = set(links())
        except Exception:  # a closing session: nothing left to watch
            return
        now = loop.time()
        for endpoint in endpoints:
            reached = bool(locators[endpoint] & destinations)
            if reached and not up[endpoint]:
                if endpoint in warned_at:
                    log.warning("connected to %s%s", endpoint, " again" if endpoint in ever_up
                                else f" after {now - opened:.0f} s")
                    del warned_at[endpoint]
                ever_up.add(endpoint)
            elif not reached and up[endpoint]:
                log.warning("lost the connection to %s: retrying until it answers again",
                            endpoint)
                warned_at[endpoint] = now
            elif not reached and (
                    (endpoint not in warned_at and now - opened >= grace_s)
                    or (endpoint in warned_at and now - warned_at[endpoint] >= remind_s)):
                if await asyncio.to_thread(listening, endpoint):
                    # Something accepts TCP there and still no link: it refuses this session.
                    log.warning("%s (--connect) does not let this session in after %.0f s: "
                                "something listens there, as a robot in secure mode does to a "
                                "process without valid credentials (docs/security.md); "
                                "retrying every second", endpoint, now - opened)
                else:
                    log.warning("nothing answers at %s (--connect) after %.0f s: retrying "
                                "every second until it does (%s)", endpoint, now - opened,
                                START_ROBOT_HINT)
                warned_at[endpoint] = now
            up[endpoint] = reached
        due = [(warned_at[e] + remind_s) if e in warned_at else opened + grace_s
               for e in endpoints if not up[e]]
        wait_s = max(0.0, min(due) - loop.time()) if due else None
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(changed.wait(), wait_s)
