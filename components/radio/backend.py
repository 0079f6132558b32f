"""What the radio component talks through: a plain-text link (the thesis used a socket)."""

from __future__ import annotations

from ubf_async.assembly.backend import Backend

__all__ = ["RadioBackend"]


class RadioBackend(Backend):
    def send(self, text: str) -> None:
        """Send one text message out (non-blocking)."""
        raise NotImplementedError

    def receive(self) -> list[str]:
        """Messages that arrived since the previous call, oldest first (non-blocking)."""
        raise NotImplementedError
