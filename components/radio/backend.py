"""What the radio component talks through: a plain-text link (the thesis used a socket)."""

from __future__ import annotations

from typing import Protocol


class RadioBackend(Protocol):
    def send(self, text: str) -> None:
        """Send one text message out (non-blocking)."""
        ...

    def receive(self) -> list[str]:
        """Messages that arrived since the previous call, oldest first (non-blocking)."""
        ...
