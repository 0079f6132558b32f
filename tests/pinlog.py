"""``python -m tests.pinlog OUT.json MODULE [ARGS ...]``: run ``python -m MODULE ARGS`` in this
process and, however it ends (normally, by an exception, by the SIGTERM or Ctrl-C it handles),
write the state history of every pin of gpiozero's mock pin factory to ``OUT.json`` — so a test
can see from outside what a process did to its (mock) pins, and when.

Run it with ``GPIOZERO_PIN_FACTORY=mock GPIOZERO_MOCK_PIN_CLASS=mockpwmpin``: the backends then
use gpiozero's default factory, a :class:`~gpiozero.pins.mock.MockFactory`, whose pins record
every change as ``PinState(timestamp, state)``, the timestamp being the seconds since the
previous change. This records them; it fakes nothing.

The JSON maps pin names (``GPIO12``) to ``[[timestamp, state], ...]``; :func:`holds` turns
either form into how long each state was held.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from tests import exit_probe


def holds(history: Iterable[Sequence[Any]]) -> list[tuple[float, float]]:
    """``(state, seconds held)`` for every state of a mock pin's history but the last (still
    held): a state is held until the next change, whose timestamp is that time."""
    entries = [(float(t), float(s)) for t, s in history]
    return [(state, entries[i + 1][0]) for i, (_, state) in enumerate(entries[:-1])]


def load(path: Path) -> dict[str, list[list[float]]]:
    data: dict[str, list[list[float]]] = json.loads(path.read_text())
    return data


def _dump(out: Path) -> None:
    from gpiozero import Device
    from gpiozero.pins.mock import MockFactory

    factory = Device.pin_factory
    pins: dict[str, list[list[float]]] = {}
    if isinstance(factory, MockFactory):
        for info, pin in factory.pins.items():
            pins[info.name] = [[float(t), float(s)] for t, s in pin.states]
    out.write_text(json.dumps(pins))


def main() -> None:
    out, module, *args = sys.argv[1:]
    try:
        code = exit_probe.run_as_main(module, args)
    finally:
        _dump(Path(out))
    raise SystemExit(code)


if __name__ == "__main__":
    main()
