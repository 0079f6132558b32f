"""``conform``: watch one component's traffic for a while and report each way it departs from
the protocol (docs/protocol.md) — what a C or Rust author runs instead of reading the robot's
logs.

Checked, one line each (``ok`` or ``FAIL``; exit status 1 if any failed):

* its **liveliness token** ``ubf/<robot>/alive/<component>`` is there;
* its **heartbeats**, if it sends any (they are optional): valid ``heartbeat`` messages whose
  ``component`` is the token's name, arriving about as often as their ``period_s`` says, and
  never without the token;
* each of its **keys** — those its heartbeats announce (``publishes``), or those named with
  ``--key`` for a component that announces nothing: the key's form, every sample valid for
  the schema the key takes, stamped on the robot clock (not ahead of it, not on another clock
  domain), ``seq`` increasing per publisher, and samples arriving about as often as their
  ``period_s`` declares.

The judging (:class:`Conformance`) is pure: it is given each message with the times it came,
and is tested without a bus; :func:`cmd_conform` listens and feeds it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import statistics
from dataclasses import dataclass, field
from typing import Any, TextIO

import msgspec

from ubf_async.clocks import clockdomain, follow
from ubf_async.errors import ProtocolError
from ubf_async.runtime.bus import Bus, Subscription
from ubf_async.runtime.ordering import ahead_of_clock
from ubf_async.tools.inspector import common
from ubf_async.wire import topics
from ubf_async.wire.keys import Keys, check_segment
from ubf_async.wire.protocol import MAX_PAYLOAD_BYTES, Message, decode

__all__ = ["DEFAULT_SECONDS", "FUTURE_TOLERANCE_S", "PERIOD_SLACK", "Conformance", "Finding",
           "add_conform_parser", "cmd_conform"]

DEFAULT_SECONDS = 5.0
"""How long ``conform`` listens by default: ten heartbeats of a ubf_async component."""
FUTURE_TOLERANCE_S = 0.5
"""A stamp this far ahead of the robot clock is refused by the robot (its default)."""
PERIOD_SLACK = 2.0
"""A key's median interval may be this many times its declared ``period_s`` (or that many
times shorter) before the check fails: a busy host is late, not a deviation."""
MIN_INTERVALS = 3
"""Intervals a period check needs (fewer: not judged)."""


@dataclass(frozen=True, slots=True)
class Finding:
    ok: bool
    text: str

    def line(self) -> str:
        return f"{'ok  ' if self.ok else 'FAIL'}  {self.text}"


@dataclass(slots=True)
class _Key:
    """What was heard on one key of the component."""

    samples: int = 0
    invalid: int = 0
    why_invalid: str = ""
    """The first invalid sample's error."""
    ahead: list[float] = field(default_factory=list)
    foreign: dict[str, int] = field(default_factory=dict)
    backwards: int = 0
    last_seq: dict[int | None, int] = field(default_factory=dict)
    arrivals_s: list[float] = field(default_factory=list)
    period_s: float | None = None
    schema: str | None = None


class Conformance:
    """The judge of one component's traffic (module docstring). Feed it with
    :meth:`token`, :meth:`heartbeat` and :meth:`sample`; :meth:`findings` says what it saw.
    Times: ``arrival_s`` on the host's monotonic clock; ``now_ns`` the robot clock at arrival."""

    def __init__(self, keys: Keys, component: str, *, given_keys: tuple[str, ...] = (),
                 simulated: bool) -> None:
        self.keys = keys
        self.component = component
        self.given_keys = given_keys
        self.simulated = simulated
        self.token_seen = False
        self.heartbeats: list[float] = []
        self.heartbeat_period_s: float | None = None
        self.heartbeat_errors: list[str] = []
        self.named_otherwise: set[str] = set()
        self.heartbeat_without_token = 0
        self.announced: dict[str, set[int]] = {}
        self.heard: dict[str, dict[int | None, _Key]] = {}

    # -- what comes in ------------------------------------------------------------------------
    def token(self, alive: bool) -> None:
        self.token_seen = self.token_seen or alive

    def heartbeat(self, payload: bytes, arrival_s: float, *, token_alive: bool) -> None:
        try:
            message = decode(payload, topic=topics.HEARTBEAT)
        except ProtocolError as exc:
            self.heartbeat_errors.append(str(exc))
            return
        self.heartbeats.append(arrival_s)
        self.heartbeat_period_s = message.period_s
        if message.data.component != self.component:
            self.named_otherwise.add(message.data.component)
        if not token_alive:
            self.heartbeat_without_token += 1
        for published in message.data.publishes:
            self.announced.setdefault(published.key, set()).add(published.pub)

    def sample(self, key: str, payload: bytes, arrival_s: float, *, now_ns: int,
               host_monotonic_ns: int) -> None:
        """One message on any key of the robot (those that are not the component's are
        sorted out in :meth:`findings`, once its heartbeats have said which are)."""
        pub = _pub_of(payload)
        heard = self.heard.setdefault(key, {})
        entry = heard.get(pub)
        if entry is None:
            if len(heard) >= 16:  # bounded: a key with many publishers is judged on 16
                return
            entry = heard[pub] = _Key()
        entry.samples += 1
        entry.arrivals_s.append(arrival_s)
        try:
            message: Message[Any] = common.decode_for(self.keys, key, payload)
        except ProtocolError as exc:
            entry.invalid += 1
            entry.why_invalid = entry.why_invalid or str(exc)
            return
        entry.period_s, entry.schema = message.period_s, message.schema
        if ahead_of_clock(message.stamp_ns, now_ns, round(FUTURE_TOLERANCE_S * 1e9)):
            entry.ahead.append((message.stamp_ns - now_ns) / 1e9)
        clock = clockdomain.foreign_clock(message.stamp_ns, now_ns=now_ns,
                                          simulated=self.simulated,
                                          host_monotonic_ns=host_monotonic_ns)
        if clock is not None:
            entry.foreign[clock] = entry.foreign.get(clock, 0) + 1
        last = entry.last_seq.get(message.pub)
        if last is not None and message.seq <= last:
            entry.backwards += 1
        entry.last_seq[message.pub] = message.seq

    # -- what it makes of them ----------------------------------------------------------------
    def its_keys(self) -> dict[str, set[int] | None]:
        """The component's keys: with the ``pub`` ids its heartbeats announce (``None``: any
        publisher on a key given with ``--key``)."""
        mine: dict[str, set[int] | None] = {key: None for key in self.given_keys}
        for key, pubs in self.announced.items():
            mine.setdefault(key, set(pubs))
        return mine

    def findings(self, seconds: float) -> list[Finding]:
        out = [self._token_finding()]
        out += self._heartbeat_findings(seconds)
        mine = self.its_keys()
        if not mine:
            out.append(Finding(False, f"no keys to check: {self.component} announces none in "
                                      f"a heartbeat (publishes) — name them with --key KEY"))
        for key, pubs in sorted(mine.items()):
            out += self._key_findings(key, pubs, seconds)
        return out

    def _token_finding(self) -> Finding:
        alive = self.keys.alive(self.component)
        if self.token_seen:
            return Finding(True, f"liveliness token {alive}")
        return Finding(False, f"no liveliness token {alive}: declare it for as long as the "
                              f"component runs (docs/protocol.md, 'Liveliness and health')")

    def _heartbeat_findings(self, seconds: float) -> list[Finding]:
        key = self.keys.heartbeat(self.component)
        out = [Finding(False, f"{key}: not a valid heartbeat: {error}")
               for error in self.heartbeat_errors[:3]]
        if not self.heartbeats:
            if not out:
                out.append(Finding(True, f"no heartbeat on {key} in {seconds:g} s (optional: "
                                         f"the component is judged by its token)"))
            return out
        for name in sorted(self.named_otherwise):
            out.append(Finding(False, f"{key}: its heartbeat names the component {name!r}, "
                                      f"not {self.component!r} (the token's name)"))
        if self.heartbeat_without_token:
            out.append(Finding(False, f"{key}: {self.heartbeat_without_token} heartbeat(s) "
                                      f"while no token {self.keys.alive(self.component)} was "
                                      f"there"))
        out.append(_period_finding(key, "heartbeats", self.heartbeats,
                                   self.heartbeat_period_s, default_s=1.0))
        return out

    def _key_findings(self, key: str, pubs: set[int] | None, seconds: float) -> list[Finding]:
        form = _key_form(self.keys, key)
        if form is not None:
            return [Finding(False, f"{key}: {form}")]
        heard = {pub: entry for pub, entry in self.heard.get(key, {}).items()
                 if pubs is None or pub in pubs}
        if not heard:
            return [Finding(True, f"{key}: announced, nothing sent in {seconds:g} s")]
        out: list[Finding] = []
        for pub, entry in sorted(heard.items(), key=lambda item: item[0] or 0):
            who = f"{key}" + (f" (pub {pub})" if pub is not None else " (no pub)")
            failures = [f"{entry.invalid} of {entry.samples} samples invalid, the first: "
                        f"{entry.why_invalid}"] if entry.invalid else []
            if entry.ahead:
                failures.append(f"{len(entry.ahead)} stamped ahead of the robot clock (by up "
                                f"to {max(entry.ahead):.3g} s; the robot refuses them)")
            for clock, count in entry.foreign.items():
                failures.append(f"{count} stamped on {clockdomain.the(clock)}: "
                                + clockdomain.how_to_stamp(self.keys.robot, self.simulated))
            if entry.backwards:
                failures.append(f"seq did not increase {entry.backwards} time(s) (the robot "
                                f"refuses a sample not newer than the last from its publisher)")
            out += [Finding(False, f"{who}: {text}") for text in failures]
            if not failures:
                out.append(Finding(True, f"{who}: {entry.samples} valid {entry.schema} "
                                         f"samples, stamped on the robot clock, seq increasing"))
            if entry.period_s is not None:
                out.append(_period_finding(who, "samples", entry.arrivals_s, entry.period_s))
        return out


class _PubOnly(msgspec.Struct):
    pub: int | None = None


_PUB_ONLY = msgspec.msgpack.Decoder(_PubOnly)


def _pub_of(payload: bytes) -> int | None:
    """The envelope's ``pub`` without judging the rest (a malformed sample is still counted
    against its publisher)."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        return None
    try:
        return _PUB_ONLY.decode(payload).pub
    except msgspec.MsgspecError:
        return None


def _key_form(keys: Keys, key: str) -> str | None:
    """What is wrong with the form of a component's key, or ``None``."""
    head = f"{keys.prefix}/"
    if not key.startswith(head):
        return f"not under {head}"
    parts = key[len(head):].split("/")
    try:
        for part in parts:
            check_segment("key segment", part)
    except ProtocolError as exc:
        return str(exc)
    if parts[0] == "sensor" and len(parts) != 3:
        return "a sensor key is sensor/<kind>/<name>"
    if not any(True for _ in topics.matching(keys, key)) and parts[0] != "sensor":
        return "no topic of the protocol has this key (docs/protocol.md, 'Key expressions')"
    return None


def _period_finding(who: str, what: str, arrivals_s: list[float], period_s: float | None,
                    *, default_s: float | None = None) -> Finding:
    declared = period_s if period_s is not None else default_s
    intervals = [b - a for a, b in itertools.pairwise(arrivals_s)]
    if declared is None or len(intervals) < MIN_INTERVALS:
        return Finding(True, f"{who}: {len(arrivals_s)} {what}, too few to judge their period")
    measured = statistics.median(intervals)
    said = (f"every {measured:.3g} s (median of {len(intervals)}), period_s "
            + (f"{period_s:g}" if period_s is not None else f"absent: {declared:g} s taken"))
    if declared / PERIOD_SLACK <= measured <= declared * PERIOD_SLACK:
        return Finding(True, f"{who}: {what} {said}")
    return Finding(False, f"{who}: {what} {said} — the robot judges staleness by the declared "
                          f"period, so declare the one you send at")


# -- python -m ubf_async.inspector conform ------------------------------------------------------


def add_conform_parser(sub: Any, connection: argparse.ArgumentParser) -> None:
    """``conform``: check one component's traffic against the protocol."""
    conform = sub.add_parser(
        "conform", parents=[connection],
        help="watch a component's traffic and report how it departs from the protocol",
        description="Listen for --seconds to COMPONENT (the name of its liveliness token "
                    "ubf/<robot>/alive/COMPONENT) and check its token, its heartbeats (if it "
                    "sends any) and the samples on its keys — those its heartbeats announce, "
                    "or those given with --key — against docs/protocol.md: key form, schema, "
                    "stamps on the robot clock, seq, declared vs measured period. One line a "
                    "check; exit status 1 if any failed.")
    conform.add_argument("component", metavar="COMPONENT")
    conform.add_argument("--key", action="append", default=[], metavar="KEY",
                         help="a key the component publishes (relative to ubf/<robot>/), for "
                              "a component whose heartbeats announce none; repeatable")
    conform.add_argument("--seconds", type=float, default=DEFAULT_SECONDS, metavar="S",
                         help=f"how long to listen (default: {DEFAULT_SECONDS:g})")


async def cmd_conform(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    if not args.seconds > 0:
        common.say_error(f"--seconds must be > 0, got {args.seconds:g}")
        return 2
    keys = bus.keys
    try:
        check_segment("component", args.component)
        given = tuple(common.resolve_key(keys, key) for key in args.key)
    except (ValueError, ProtocolError) as exc:
        common.say_error(exc)
        return 2
    clock = await follow.follow_robot_clock(bus, mode="auto")
    judge = Conformance(keys, args.component, given_keys=given, simulated=clock.is_simulated)
    token_key, heartbeat_key = keys.alive(args.component), keys.heartbeat(args.component)
    alive: set[str] = set()
    # Only the component's own keys are listened to (a subscription to everything would make
    # the simulator publish its ground truth and world snapshots for this tool alone).
    listened: dict[str, Subscription] = {}

    def on_token(key: str, is_alive: bool) -> None:
        (alive.add if is_alive else alive.discard)(key)
        judge.token(is_alive and key == token_key)

    def on_sample(key: str, payload: bytes, received_ns: int) -> None:
        judge.sample(key, payload, received_ns / 1e9, now_ns=bus.clock.now_ns(),
                     host_monotonic_ns=received_ns)

    def listen(key: str) -> None:
        if key not in listened and len(listened) < topics.MAX_ANNOUNCED:
            with contextlib.suppress(ValueError, ProtocolError):  # its form is judged later
                listened[key] = bus.subscribe(key, on_sample, latest=False)

    def on_heartbeat(key: str, payload: bytes, received_ns: int) -> None:
        judge.heartbeat(payload, received_ns / 1e9, token_alive=token_key in alive)
        for announced in judge.announced:
            listen(announced)

    subscriptions = [bus.watch_liveliness(token_key, on_token),
                     bus.subscribe(heartbeat_key, on_heartbeat, latest=False)]
    for key in given:
        listen(key)
    try:
        await asyncio.sleep(args.seconds)
    finally:
        for subscription in [*subscriptions, *listened.values()]:
            subscription.close()
    findings = judge.findings(args.seconds)
    failed = sum(not f.ok for f in findings)
    print(f"conform {args.component} on robot {keys.robot!r} ({args.seconds:g} s; "
          f"{follow.describe(clock, robot=keys.robot)}):", file=out)
    for finding in findings:
        print(f"  {finding.line()}", file=out)
    print(f"{failed} deviation(s)" if failed else "conforms: no deviation seen", file=out)
    return 1 if failed else 0
