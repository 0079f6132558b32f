"""Issue 55, item 3: ``inspector conform COMPONENT`` finds each planted deviation from the
protocol in a component's traffic — on the pure judge here, parametrised; against real
processes in tests/test_inspector.py."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import msgpack
import pytest

from ubf_async.tools.inspector.conform import Conformance
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import encode
from ubf_async.wire.topics import CAMERA, HEARTBEAT, RANGE

KEYS = Keys("mini")
S = 10**9
RANGE_KEY = RANGE.key(KEYS, "ext")
GOOD = {"range_mm": 300, "status": "ok"}


def raw(schema: str, data: Any, *, stamp_ns: int, seq: int, **envelope: Any) -> bytes:
    """A payload built by hand, as a foreign implementer would (nothing checked)."""
    return msgpack.packb({"schema": schema, "v": 1, "stamp_ns": stamp_ns, "seq": seq,
                          "data": data, **envelope})


class Traffic:
    """A component named ``ext`` as the judge sees it: a simulated robot at 10 s of robot
    time, on a host up for an hour."""

    def __init__(self, *, given_keys: tuple[str, ...] = ()) -> None:
        self.judge = Conformance(KEYS, "ext", given_keys=given_keys, simulated=True)
        self.now_ns = 10 * S
        self.host_ns = 3600 * S

    def token(self) -> None:
        self.judge.token(True)

    def heartbeats(self, *, every_s: float = 0.5, period_s: float = 0.5, count: int = 6,
                   component: str = "ext", token: bool = True,
                   announce: tuple[str, ...] = (RANGE_KEY,), pub: int = 7) -> None:
        for i in range(count):
            payload = encode(HEARTBEAT, {"component": component, "publishes": [
                {"key": key, "pub": pub} for key in announce]}, stamp_ns=self.now_ns, seq=i + 1,
                period_s=period_s)
            self.judge.heartbeat(payload, i * every_s, token_alive=token)

    def samples(self, *, key: str = RANGE_KEY, count: int = 10, every_s: float = 0.04,
                period_s: float | None = 0.04, pub: int | None = 7,
                payload: Callable[[int, int], bytes] | None = None,
                stamp: Callable[[int], int] | None = None) -> None:
        for i in range(count):
            stamp_ns = stamp(i) if stamp is not None else self.now_ns + round(i * every_s * S)
            envelope: dict[str, Any] = {"pub": pub} if pub is not None else {}
            if period_s is not None:
                envelope["period_s"] = period_s
            data = (payload(i, stamp_ns) if payload is not None
                    else raw("range", GOOD, stamp_ns=stamp_ns, seq=i + 1, **envelope))
            self.judge.sample(key, data, i * every_s,
                              now_ns=self.now_ns + round(i * every_s * S),
                              host_monotonic_ns=self.host_ns + round(i * every_s * S))

    def failures(self) -> list[str]:
        return [f.text for f in self.judge.findings(5.0) if not f.ok]


def conforming() -> Traffic:
    traffic = Traffic()
    traffic.token()
    traffic.heartbeats()
    traffic.samples()
    return traffic


def test_a_conforming_component_has_no_deviation() -> None:
    traffic = conforming()
    assert traffic.failures() == []
    lines = [f.line() for f in traffic.judge.findings(5.0)]
    assert any("10 valid range samples" in line for line in lines), lines


def test_a_token_only_component_is_checked_on_the_keys_named() -> None:
    traffic = Traffic(given_keys=(RANGE_KEY,))
    traffic.token()
    traffic.samples(pub=None)
    assert traffic.failures() == []


def no_token(t: Traffic) -> None:
    t.heartbeats()
    t.samples()


def named_otherwise(t: Traffic) -> None:
    t.token()
    t.heartbeats(component="ext2")
    t.samples()


def heartbeat_without_token(t: Traffic) -> None:
    t.token()
    t.heartbeats(token=False)
    t.samples()


def malformed_heartbeat(t: Traffic) -> None:
    t.token()
    t.judge.heartbeat(raw("heartbeat", {"restarts": 1}, stamp_ns=t.now_ns, seq=1), 0.0,
                      token_alive=True)


def slow_heartbeats(t: Traffic) -> None:
    t.token()
    t.heartbeats(every_s=2.0, period_s=0.5)
    t.samples()


def malformed_samples(t: Traffic) -> None:
    t.token()
    t.heartbeats()
    t.samples(payload=lambda i, stamp: raw("range", {"range_mm": "near", "status": "ok"},
                                           stamp_ns=stamp, seq=i + 1, pub=7, period_s=0.04))


def wrong_schema_for_the_kind(t: Traffic) -> None:
    t.token()
    t.heartbeats(announce=(CAMERA.key(KEYS, "ext"),))
    t.samples(key=CAMERA.key(KEYS, "ext"))


def stamped_ahead(t: Traffic) -> None:
    t.token()
    t.heartbeats()
    t.samples(stamp=lambda i: t.now_ns + 5 * S + i)


def stamped_on_the_host_clock(t: Traffic) -> None:
    t.token()
    t.heartbeats()
    t.samples(stamp=lambda i: t.host_ns + i * S // 25)


def seq_going_back(t: Traffic) -> None:
    t.token()
    t.heartbeats()
    t.samples(payload=lambda i, stamp: raw("range", GOOD, stamp_ns=stamp, seq=10 - i, pub=7,
                                           period_s=0.04))


def period_not_kept(t: Traffic) -> None:
    t.token()
    t.heartbeats()
    t.samples(every_s=0.2, period_s=0.04)


def bad_key(t: Traffic) -> None:
    t.token()
    t.heartbeats(announce=("ubf/mini/sensor/range",))


def no_keys(t: Traffic) -> None:
    t.token()
    t.heartbeats(announce=())


@pytest.mark.parametrize(("plant", "said"), [
    (no_token, "no liveliness token ubf/mini/alive/ext"),
    (named_otherwise, "names the component 'ext2', not 'ext'"),
    (heartbeat_without_token, "heartbeat(s) while no token"),
    (malformed_heartbeat, "not a valid heartbeat"),
    (slow_heartbeats, "heartbeats every 2 s"),
    (malformed_samples, "10 of 10 samples invalid, the first: "),
    (wrong_schema_for_the_kind, "10 of 10 samples invalid, the first: "),
    (stamped_ahead, "stamped ahead of the robot clock"),
    (stamped_on_the_host_clock, "stamped on the host monotonic clock"),
    (seq_going_back, "seq did not increase 9 time(s)"),
    (period_not_kept, "samples every 0.2 s (median of 9), period_s 0.04"),
    (bad_key, "a sensor key is sensor/<kind>/<name>"),
    (no_keys, "no keys to check"),
], ids=lambda value: value.__name__ if callable(value) else "")
def test_each_planted_deviation_is_reported(plant: Callable[[Traffic], None],
                                            said: str) -> None:
    traffic = Traffic()
    plant(traffic)
    failures = traffic.failures()
    assert any(said in failure for failure in failures), failures
