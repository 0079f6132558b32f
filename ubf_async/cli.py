"""What every command-line entry point does around its asyncio main: SIGTERM and Ctrl-C stop
it cleanly (its ``finally`` blocks close components and sessions), and a connection or
configuration problem (any :class:`~ubf_async.errors.UbfError`) is one clear line on stderr
with exit status 2. This is the only place an error becomes an exit status."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sys
from collections.abc import Awaitable, Callable

from ubf_async.errors import UbfError


def run_main(main: Callable[[], Awaitable[int]], *, prog: str) -> int:
    async def runner() -> int:
        task = asyncio.current_task()
        assert task is not None
        with contextlib.suppress(NotImplementedError):  # no signal handlers on some platforms
            asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, task.cancel)
        try:
            return await main()
        except asyncio.CancelledError:
            return 0
        except (UbfError, ConnectionError, ValueError) as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 2

    try:
        return asyncio.run(runner())
    except KeyboardInterrupt:
        return 130
