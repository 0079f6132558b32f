"""The radio component: plain-text messages in and out (the thesis's wireless link).

Outgoing: ``cmd/radio`` (schema ``radio.send``) → ``backend.send(text)``.
Incoming: every ``period_s`` the backend's new messages are published, each as one sample on
``sensor/radio/<name>`` (schema ``radio.message``), so the last one is in the state.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from components.radio.backend import RadioBackend
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import RADIO, RADIO_SEND, RadioSend

__all__ = ["RadioComponent", "build_device"]


class RadioComponent(Component):
    def __init__(
        self,
        *,
        bus: Bus,
        backend: RadioBackend,
        name: str = "link",
        period_s: float = 0.05,
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=f"radio-{name}", **component_options)
        self.source_name = name
        self.backend = backend
        self.period_s = period_s
        self.malformed: dict[str, int] = {}
        self.sent = 0

    async def run(self) -> None:
        keys = self.bus.keys
        pub = self.publisher(RADIO, self.source_name)
        self.subscribe_topic(RADIO_SEND.key(keys), RADIO_SEND, self._on_send, self.malformed,
                             latest=False)
        clock = self.bus.clock
        while True:
            for text in self.backend.receive():
                pub.publish({"text": text[:256]})
            await clock.sleep(self.period_s)

    def _on_send(self, key: str, message: Message[RadioSend], received_ns: int) -> None:
        self.backend.send(message.data.text)
        self.sent += 1


def build_device(
    *,
    bus: Bus,
    name: str,
    backend: RadioBackend,
    period_s: Annotated[float, msgspec.Meta(gt=0)] = 0.05,
) -> RadioComponent:
    """The ``radio`` device kind: ``cmd/radio`` out through ``backend``; what arrives is
    published on ``sensor/radio/<name>``, polled every ``period_s`` (robot clock)."""
    return RadioComponent(bus=bus, backend=backend, name=name, period_s=period_s)
