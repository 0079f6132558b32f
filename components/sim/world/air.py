"""The air between a fleet's radios: what one robot's ``radio.air`` sends, every other robot
of the same world receives (a broadcast; the thesis's radio was a plain-text link).

Thread-safe; each robot's inbox keeps the newest :data:`MAX_QUEUED` messages (a radio that is
not read loses the oldest, as a real one would).
"""

from __future__ import annotations

import threading
from collections import deque

__all__ = ["MAX_QUEUED", "RadioAir"]

MAX_QUEUED = 64


class RadioAir:
    def __init__(self, robots: int) -> None:
        if robots < 1:
            raise ValueError(f"robots must be ≥ 1, got {robots}")
        self._lock = threading.Lock()
        self._inboxes = [deque[str](maxlen=MAX_QUEUED) for _ in range(robots)]
        self.sent = 0

    def broadcast(self, sender: int, text: str) -> None:
        """``text`` from robot ``sender`` reaches every other robot."""
        with self._lock:
            self.sent += 1
            for robot, inbox in enumerate(self._inboxes):
                if robot != sender:
                    inbox.append(text)

    def take(self, robot: int) -> list[str]:
        """What reached ``robot`` since its last call, oldest first."""
        with self._lock:
            inbox = self._inboxes[robot]
            arrived = list(inbox)
            inbox.clear()
        return arrived
