"""What every device backend is: :class:`Backend`, the one closing contract.

A device owns its backend (:func:`ubf_async.assembly.devices.build_device`): it awaits the
backend's :meth:`~Backend.aclose` once, when it closes (after its last command or sample), or
at once when the device cannot be built. Each device package's backend interface
(``components/<device>/backend.py``) derives from :class:`Backend` and adds what that kind
reads or drives, each optional capability a member with its default, so a device reads them
without probing.
"""

from __future__ import annotations

__all__ = ["Backend"]


class Backend:
    """The base of every device backend.

    :meth:`aclose` is what its device awaits when it closes; it calls :meth:`close`, which
    does nothing by default. A backend holding pins, a bus or a thread releases them in
    :meth:`close` (sync, returning at once); one whose release must wait may also override
    :meth:`aclose`, its :meth:`close` still releasing what it can at once: a device refused
    while it is built (no event loop awaiting) gets only :meth:`close`.
    """

    def close(self) -> None:
        """Release what the backend holds; nothing by default. Called (through
        :meth:`aclose`) once, when its device closes."""

    async def aclose(self) -> None:
        """Release what the backend holds: :meth:`close` by default."""
        self.close()
