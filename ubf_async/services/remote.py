"""Remote behaviours: a behaviour in another process joins the robot's behaviour tree.

The wire side (documented in ``docs/protocol.md``, section *Remote behaviours*):

* a remote process holds the liveliness token ``ubf/<robot>/alive/<behaviour>`` and publishes
  its votes on ``ubf/<robot>/vote/<composite>/<behaviour>``, schema ``"vote"``: the action's
  fields (``speed``, ``turn``, ``seek_color``, ``message``, ``leds``), its ``vote`` (0 =
  abstain) and optionally ``ttl_s`` (how long the vote holds), ``priority`` and ``weight``;
* the robot's :class:`RemoteBehaviors` component attaches a :class:`RemoteBehavior` as a
  child of the composite named in the key, on the first valid vote of a behaviour whose token
  is alive, with the priority/weight configured on the robot (``config``) or else requested
  in the vote. The child's action is the newest vote while that vote is younger than its
  TTL on the robot clock and the token lives; otherwise it abstains. When the token goes
  the child is detached (and attached again when the process comes back and votes).

The remote side: :class:`RemoteBehaviorHost` runs any plain :class:`~ubf_async.core.behavior.
Behavior` in this process — it builds the state with its own state aggregator (the same
sensor samples the robot sees), ticks the behaviour and publishes its votes;
:mod:`ubf_async.tools.remote_host` makes a command-line program of it
(``examples/teleop_override.py``, ``examples/avoid_obstacles.py``).

Everything runs on the event loop; zenoh's threads only hand samples over (see ``bus``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import logging
import math
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Concatenate, ParamSpec, TypeVar

from ubf_async import throttle
from ubf_async.clocks import clockdomain
from ubf_async.core.action import Action
from ubf_async.core.behavior import Behavior, Composite
from ubf_async.core.state import State
from ubf_async.errors import ConfigurationError, ProtocolError
from ubf_async.runtime import refusals
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus, Publisher
from ubf_async.runtime.component import Component
from ubf_async.runtime.ordering import SampleOrder, ahead_of_clock
from ubf_async.wire.keys import Keys, check_segment
from ubf_async.wire.protocol import Message, count_malformed, decode, encode_data
from ubf_async.wire.topics import (
    DRIVE,
    REMOTES_STATUS,
    VOTE,
    Drive,
    SeekColor,
)
from ubf_async.wire.topics import (
    MAX_TTL_S as MAX_TTL_S,
)
from ubf_async.wire.topics import (
    MAX_WEIGHT as MAX_WEIGHT,
)
from ubf_async.wire.topics import (
    PRIORITY_LIMIT as PRIORITY_LIMIT,
)
from ubf_async.wire.topics import Vote as VoteData

__all__ = ["DEFAULT_MAX_FUTURE_S", "DEFAULT_TTL_S", "MAX_NAME_LEN", "RESERVED_NAMES",
           "STATUS_SCHEMA", "VOTE_SCHEMA", "PriorityWeight", "ReceivedVote", "RemoteBehavior",
           "RemoteBehaviorHost", "RemoteBehaviors", "RemoteInfo", "action_of_vote", "all_votes",
           "parse_remote_spec", "parse_vote_key", "remote_spec", "vote_data", "vote_key"]

log = logging.getLogger(__name__)

VOTE_SCHEMA = VOTE.schema
STATUS_SCHEMA = REMOTES_STATUS.schema
DEFAULT_TTL_S = 0.5
"""How long a vote holds when neither the vote nor the robot says otherwise."""
MAX_NAME_LEN = 128
"""Longest remote behaviour name accepted: the drive command lists winners as text of at most
128 characters, so a longer name would make every tick's command invalid."""
RESERVED_NAMES = frozenset({"controller", "aggregator", "remotes", "tree"})
"""Names no remote behaviour may take (the robot's own components); launch adds the rest."""
DEFAULT_MAX_FUTURE_S = 0.1
"""How far ahead of the robot clock a vote may be stamped (clock skew between followers of
the same simulation time, delivery order) before it is refused."""


# ---------------------------------------------------------------------------------------------
# Keys and the "vote" schema


def vote_key(keys: Keys, composite: str, behavior: str) -> str:
    """``ubf/<robot>/vote/<composite>/<behaviour>``: where ``behavior`` votes in ``composite``."""
    check_segment("composite name", composite)
    check_segment("behaviour name", behavior)
    return VOTE.key(keys, composite=composite, behavior=behavior)


def all_votes(keys: Keys) -> str:
    """Every vote of the robot (``**`` so that malformed keys are seen, and rejected)."""
    return f"{keys.prefix}/vote/**"


def parse_vote_key(keys: Keys, key: str) -> tuple[str, str]:
    """``ubf/<robot>/vote/<composite>/<behaviour>`` → ``(composite, behaviour)``."""
    head = f"{keys.prefix}/vote/"
    parts = key[len(head):].split("/") if key.startswith(head) else []
    if len(parts) != 2 or not all(parts):
        raise ProtocolError(
            f"{key!r} is not a vote key: expected {head}<composite>/<behaviour>"
        )
    return parts[0], parts[1]


def action_of_vote(data: VoteData) -> Action:
    """The :class:`Action` a validated vote describes (raises :class:`ProtocolError`)."""
    seek = data.seek_color
    try:
        return Action(
            speed=data.speed,
            turn=data.turn,
            vote=data.vote,
            seek_color=None if seek is None else (seek.lo, seek.hi),
            message=data.message,
            leds=data.leds,
        )
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f"data: not a valid action: {exc}") from None


def vote_data(
    action: Action | None,
    *,
    ttl_s: float | None = None,
    priority: int | None = None,
    weight: float | None = None,
) -> VoteData:
    """The ``"vote"`` data for ``action`` (``None`` → a vote of 0: abstain)."""
    if action is None:
        return VoteData(vote=0.0, ttl_s=ttl_s, priority=priority, weight=weight)
    seek = action.seek_color
    return VoteData(
        vote=float(action.vote), speed=action.speed, turn=action.turn, message=action.message,
        leds=action.leds,
        seek_color=None if seek is None else SeekColor(lo=tuple(seek.lo), hi=tuple(seek.hi)),
        ttl_s=None if ttl_s is None else float(ttl_s), priority=priority,
        weight=None if weight is None else float(weight))


@dataclass(frozen=True, slots=True, kw_only=True)
class ReceivedVote:
    """One decoded, validated vote."""

    composite: str
    behavior: str
    action: Action
    stamp_ns: int
    seq: int
    ttl_s: float | None = None
    priority: int | None = None
    weight: float | None = None
    pub: int | None = None
    """The voting publisher's identity (envelope ``pub``), if it sent one."""

    @classmethod
    def decode(cls, keys: Keys, key: str, payload: bytes) -> ReceivedVote:
        """Parse key and payload (raises :class:`ProtocolError`, nothing else)."""
        composite, behavior = parse_vote_key(keys, key)
        message = decode(payload, topic=VOTE)
        return cls.of_message(composite, behavior, message)

    @classmethod
    def of_message(cls, composite: str, behavior: str, message: Message[VoteData]) -> ReceivedVote:
        data = message.data
        return cls(
            composite=composite, behavior=behavior, action=action_of_vote(data),
            stamp_ns=message.stamp_ns, seq=message.seq, ttl_s=data.ttl_s,
            priority=data.priority, weight=data.weight, pub=message.pub,
        )


# ---------------------------------------------------------------------------------------------
# Robot side


class RemoteBehavior(Behavior):
    """A child of a composite whose action comes from another process's votes.

    :meth:`act` (each tick, on the event loop) returns the newest vote's action while the
    vote's age on the robot clock, ``state.now_ns − stamp_ns``, is within ``ttl_s`` (a vote
    stamped more than ``ttl_s`` in the *future* means the two clocks disagree and is dropped
    too) and the process's liveliness token is alive; otherwise ``None`` (abstain).
    :meth:`reset` keeps the vote: it is the remote process's opinion, not this object's memory.
    """

    def __init__(self, *, name: str, composite: str, ttl_s: float = DEFAULT_TTL_S) -> None:
        super().__init__(name=name)
        self.composite = composite
        self.ttl_s = ttl_s
        self.alive = False
        """The process's liveliness token is present (kept by :class:`RemoteBehaviors`)."""
        self.action: Action | None = None
        self.stamp_ns = 0
        self.seq = 0
        self.votes = 0
        """Accepted votes."""

    @property
    def ttl_s(self) -> float:
        return self._ttl_ns / 1e9

    @ttl_s.setter
    def ttl_s(self, value: float) -> None:
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"ttl_s must be finite and > 0, got {value!r}")
        self._ttl_ns = int(value * 1e9)

    def update(self, action: Action, *, stamp_ns: int, seq: int = 0) -> bool:
        """Take a new vote (the robot's :class:`RemoteBehaviors` has already ordered it per
        publisher, see :class:`~ubf_async.runtime.ordering.SampleOrder`). Returns ``True``."""
        self.action = action
        self.stamp_ns = stamp_ns
        self.seq = seq
        self.votes += 1
        return True

    def forget(self) -> None:
        """Drop the current vote (the process went away)."""
        self.action = None

    def valid(self, now_ns: int) -> bool:
        """Whether the current vote counts at robot time ``now_ns``."""
        if not self.alive or self.action is None:
            return False
        age = now_ns - self.stamp_ns
        return -self._ttl_ns <= age <= self._ttl_ns

    def act(self, state: State) -> Action | None:
        action = self.action
        if action is None or action.vote == 0 or not self.valid(state.now_ns):
            return None  # a vote of 0 abstains: shown as such in the explanation
        return action

    def describe(self, indent: int = 0) -> str:
        return "  " * indent + f"{self.name} (remote, ttl {self.ttl_s:g}s)"


@dataclass(frozen=True, slots=True)
class RemoteInfo:
    composite: str
    behavior: str
    attached: bool
    alive: bool
    priority: int | None
    weight: float | None
    ttl_s: float
    age_s: float | None
    votes: int
    action: str


PriorityWeight = tuple[int, float]


def parse_remote_spec(spec: str) -> tuple[str, PriorityWeight]:
    """``"NAME=PRIORITY[:WEIGHT]"`` → ``(NAME, (priority, weight))`` for ``config``.

    ``NAME`` is ``composite/behaviour`` or just ``behaviour`` (any composite). Raises
    :class:`ValueError` with a readable message.
    """
    name, sep, value = spec.partition("=")
    name = name.strip()
    if not sep or not name or not value:
        raise ValueError(f"{spec!r}: expected NAME=PRIORITY[:WEIGHT], e.g. teleop=10")
    segments = name.split("/")
    if len(segments) > 2 or not all(segments) or any(c in name for c in "*$?#"):
        raise ValueError(f"{spec!r}: NAME must be 'behaviour' or 'composite/behaviour'")
    priority_text, _, weight_text = value.partition(":")
    try:
        priority = int(priority_text)
        weight = float(weight_text) if weight_text else 1.0
    except ValueError:
        raise ValueError(f"{spec!r}: PRIORITY must be an int and WEIGHT a number") from None
    if not (math.isfinite(weight) and weight >= 0):
        raise ValueError(f"{spec!r}: WEIGHT must be finite and ≥ 0")
    return name, (priority, weight)


def remote_spec(text: str) -> tuple[str, PriorityWeight]:
    """:func:`parse_remote_spec` as an argparse ``type=``."""
    try:
        return parse_remote_spec(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


class _Entry:
    __slots__ = ("attached_as", "behavior", "order", "requested")

    def __init__(self, behavior: RemoteBehavior) -> None:
        self.behavior = behavior
        self.order = SampleOrder()
        self.requested: tuple[int | None, float | None] = (None, None)
        self.attached_as: tuple[Composite, int, float] | None = None


P = ParamSpec("P")
R = TypeVar("R")


def _holding_lock(method: Callable[Concatenate[RemoteBehaviors, P], R]
                  ) -> Callable[Concatenate[RemoteBehaviors, P], R]:
    """The method runs holding the component's ``lock`` (the tree's: the reflex lane)."""
    @functools.wraps(method)
    def locked(self: RemoteBehaviors, *args: P.args, **kwargs: P.kwargs) -> R:
        with self.lock:
            return method(self, *args, **kwargs)
    return locked


class RemoteBehaviors(Component):
    """Attaches behaviours of other processes to the robot's tree (the robot's side).

    Hooks: :meth:`run` (the component's task) subscribes to ``ubf/<robot>/vote/**``, watches
    the liveliness tokens ``ubf/<robot>/alive/*`` and publishes a status on
    ``ubf/<robot>/status/<name>`` every ``status_period_s``; when it ends, every remote child
    is detached. :meth:`on_vote` and :meth:`on_liveliness` run on the event loop for each
    sample and token change (call them directly to drive this class without a bus).

    * ``root`` — the tree; a vote's composite is found with ``root.find(name)``.
    * ``config`` — ``{"composite/behaviour" or "behaviour": (priority, weight)}``: the place
      the robot gives a remote behaviour, overriding what its votes request. Without an entry
      the vote's ``priority``/``weight`` are used (default 0 and 1); with
      ``only_configured=True`` behaviours without an entry are refused.
    * ``max_stranger_priority`` — the highest priority an *unconfigured* remote behaviour
      (a stranger) gets, whatever it asks for. ``None`` (the default): one below the lowest
      priority of the composite's own (local) children, so a stranger only acts when every
      local child abstains and never outranks or merges with what the robot's tree decides;
      an int is a fixed cap. Configured behaviours get exactly their configured place.
    * ``default_ttl_s`` — a vote's lifetime when it states none; ``max_ttl_s`` caps what a
      vote may ask for.
    * ``reserved_names`` — names no remote behaviour may take, added to
      :data:`RESERVED_NAMES` and this component's own name (launch passes the robot's
      component names). The names of the tree's own behaviours are refused too.
    * ``max_remotes`` — how many remote children may exist at once. Configured behaviours
      always find their place; strangers share what is left, ``max_remotes − len(config)``,
      so strangers cannot exhaust the slots.
    * ``max_future_s`` — a vote stamped more than this ahead of the robot clock is refused
      and counted in ``future`` (a far-future stamp would otherwise win every ordering).
    * ``lock`` — held while the tree is changed or a remote child's vote is taken: the
      controller's (launch passes it), whose reflex lane may tick the tree on another thread
      (:mod:`ubf_async.runtime.controller`); by default one of its own.
    * ``notify_refusals`` — also tell each refused or malformed vote's sender why, on
      ``ubf/<robot>/refused/vote/<composite>/<behaviour>`` (:mod:`ubf_async.runtime.refusals`;
      launch turns it on).

    Votes that are malformed, name an unknown composite (or a leaf), take a reserved or too
    long name, collide with a local child's name, come from the future or find no slot are
    rejected: counted (``malformed`` / ``rejected`` / ``future``, per key), logged (first and
    every 100th) and dropped.
    """

    def __init__(
        self,
        *,
        bus: Bus,
        root: Composite,
        config: Mapping[str, PriorityWeight] | None = None,
        default_ttl_s: float = DEFAULT_TTL_S,
        max_ttl_s: float = 5.0,
        only_configured: bool = False,
        max_remotes: int = 64,
        max_stranger_priority: int | None = None,
        reserved_names: Iterable[str] = (),
        max_future_s: float = DEFAULT_MAX_FUTURE_S,
        status_period_s: float = 0.5,
        notify_refusals: bool = False,
        lock: threading.RLock | None = None,
        name: str = "remotes",
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=name, **component_options)
        if not 0 < default_ttl_s <= max_ttl_s:
            raise ValueError(f"need 0 < default_ttl_s ({default_ttl_s}) ≤ max_ttl_s "
                             f"({max_ttl_s})")
        if not (math.isfinite(max_future_s) and max_future_s >= 0):
            raise ValueError(f"max_future_s must be finite and ≥ 0, got {max_future_s!r}")
        if max_stranger_priority is not None and (
            isinstance(max_stranger_priority, bool) or not isinstance(max_stranger_priority, int)
        ):
            raise ValueError(f"max_stranger_priority must be an int or None, got "
                             f"{max_stranger_priority!r}")
        self.root = root
        self.lock = lock if lock is not None else threading.RLock()
        self.reserved: set[str] = {*RESERVED_NAMES, name}
        """Names no remote behaviour may take (see :meth:`reserve`)."""
        self.config: dict[str, PriorityWeight] = {}
        self.set_config(config or {})
        self.reserve(reserved_names)
        self.max_stranger_priority = max_stranger_priority
        self.max_future_s = max_future_s
        self.default_ttl_s = default_ttl_s
        self.max_ttl_s = max_ttl_s
        self.only_configured = only_configured
        self.max_remotes = max_remotes
        self.status_period_s = status_period_s
        self.alive: set[str] = set()
        """Names whose liveliness token is present."""
        self.malformed: dict[str, int] = {}
        """Votes that failed to decode, per key."""
        self.rejected: dict[str, int] = {}
        """Valid votes refused (unknown composite, name clash, not configured, full), per key."""
        self.future: dict[str, int] = {}
        """Votes refused for a stamp more than ``max_future_s`` ahead of the robot clock."""
        self.clock_domain = clockdomain.watch(bus)
        """Votes stamped on another clock (:mod:`ubf_async.clocks.clockdomain`; shared with the
        robot's aggregator on this bus)."""
        self.notices = refusals.notices_of(bus) if notify_refusals else None
        """Where refusals are told to their senders (``notify_refusals``)."""
        self.changed = asyncio.Event()
        """Set whenever a remote is attached or detached (tests and tools clear and await it)."""
        self._entries: dict[tuple[str, str], _Entry] = {}

    # -- component ---------------------------------------------------------------------------
    async def run(self) -> None:
        keys = self.bus.keys
        self.subscribe_screened(all_votes(keys), _VoteScreen(self))
        watch = self.bus.watch_liveliness(keys.all_alive, self.on_liveliness)
        status = self.publisher(REMOTES_STATUS, self.name,
                                period_s=self.status_period_s)
        try:
            while True:
                await asyncio.sleep(self.status_period_s)
                self.prune()
                status.publish(self.status())
        finally:
            watch.close()
            self.detach_all()
            self.alive.clear()

    # -- ingest (event loop) -----------------------------------------------------------------
    def on_vote(self, key: str, payload: bytes, received_ns: int = 0) -> None:
        """Handle one sample on ``ubf/<robot>/vote/**`` as the subscription does (which
        decodes on the transport's thread first: :class:`_VoteScreen`)."""
        try:
            vote = ReceivedVote.decode(self.bus.keys, key, payload)
        except ProtocolError as exc:
            self._malformed_vote(key, payload, received_ns, exc, 1)
        else:
            self.accept(vote, key=key)

    def _malformed_vote(self, key: str, payload: bytes, received_ns: int, error: ProtocolError,
                        count: int) -> None:
        count_malformed(self.malformed, key, error, count)
        if self.notices is not None:
            self.notices.report(key, "malformed", f"malformed vote: {error}")

    @_holding_lock
    def accept(self, vote: ReceivedVote, *, key: str = "") -> bool:
        """Take a validated vote (arrived on ``key``, by default its own vote key): create or
        attach its remote child as needed."""
        key = key or self._key(vote.composite, vote.behavior)
        ident = (vote.composite, vote.behavior)
        now_ns = self.bus.clock.now_ns()
        ahead_ns = vote.stamp_ns - now_ns
        self.clock_domain.check_on(self.bus, f"vote/{vote.composite}/{vote.behavior}",
                                   vote.stamp_ns, now_ns, pub=vote.pub)  # reported, then judged
        if ahead_of_clock(vote.stamp_ns, now_ns, int(self.max_future_s * 1e9)):
            return self._reject(key, f"stamped {ahead_ns / 1e9:.3g} s ahead of the robot clock "
                                     f"(more than max_future_s {self.max_future_s:g})",
                                counter=self.future)
        configured = self._configured(*ident)
        if self.only_configured and configured is None:
            return self._reject(key, f"{vote.behavior!r} is not configured on this robot "
                                     "(only configured remote behaviours may attach)")
        entry = self._entries.get(ident)
        if entry is None:
            if refusal := self._name_refusal(vote.behavior):
                return self._reject(key, refusal)
            if configured is None and self._strangers() >= self.stranger_slots:
                return self._reject(key, f"no slot left for unconfigured remote behaviours "
                                         f"({self.stranger_slots} of max_remotes "
                                         f"{self.max_remotes} after {len(self.config)} "
                                         "configured)")
            composite = self.root.find(vote.composite)
            if not isinstance(composite, Composite):
                what = "a leaf, not a composite" if composite is not None else "unknown"
                return self._reject(key, f"composite {vote.composite!r} is {what}")
            entry = _Entry(RemoteBehavior(name=vote.behavior, composite=vote.composite))
            self._entries[ident] = entry
            if vote.behavior not in self.alive:
                log.info("vote of %s waits for its liveliness token %s", vote.behavior,
                         self.bus.keys.alive(vote.behavior))
        remote = entry.behavior
        remote.alive = vote.behavior in self.alive
        if not entry.order.accept(pub=vote.pub, seq=vote.seq, stamp_ns=vote.stamp_ns):
            return self._reject(key, f"seq {vote.seq} (pub {vote.pub}) not newer than the "
                                     "vote held (same rule as sensor samples)")
        remote.update(vote.action, stamp_ns=vote.stamp_ns, seq=vote.seq)
        ttl = self.default_ttl_s if vote.ttl_s is None else vote.ttl_s
        remote.ttl_s = min(ttl, self.max_ttl_s)
        entry.requested = (vote.priority, vote.weight)
        if remote.alive:
            return self._attach(entry, key)
        return True

    @_holding_lock
    def on_liveliness(self, key: str, alive: bool) -> None:
        """A token ``ubf/<robot>/alive/<name>`` appeared (``alive``) or vanished."""
        name = self.bus.keys.component_of_alive(key)
        if alive:
            self.alive.add(name)
        else:
            self.alive.discard(name)
        for (composite, behavior), entry in list(self._entries.items()):
            if behavior != name:
                continue
            entry.behavior.alive = alive
            if alive:
                if entry.behavior.action is not None:
                    self._attach(entry, self._key(composite, behavior))
            else:
                self._detach(entry)
                entry.behavior.forget()
                del self._entries[(composite, behavior)]
                log.info("remote behaviour %s left %s (token gone)", behavior, composite)

    # -- tree changes ------------------------------------------------------------------------
    def placement(self, composite: str, behavior: str,
                  requested: tuple[int | None, float | None] = (None, None)) -> PriorityWeight:
        """The (priority, weight) a remote gets: its configured place; else what it requested
        (default 0 and 1) with the priority capped at :meth:`stranger_cap`."""
        configured = self._configured(composite, behavior)
        if configured is not None:
            return configured
        priority, weight = requested
        cap = self.stranger_cap(composite)
        return (min(0 if priority is None else priority, cap),
                1.0 if weight is None else weight)

    def stranger_cap(self, composite: str) -> int:
        """The highest priority an unconfigured remote gets in ``composite``:
        ``max_stranger_priority``, or one below the composite's lowest local child (0 for a
        composite without local children)."""
        if self.max_stranger_priority is not None:
            return self.max_stranger_priority
        node = self.root.find(composite)
        local = [c.priority for c in node.children if not isinstance(c.behavior, RemoteBehavior)
                 ] if isinstance(node, Composite) else []
        return max(min(local) - 1, -PRIORITY_LIMIT) if local else 0

    @property
    def stranger_slots(self) -> int:
        """How many unconfigured remotes may exist at once: ``max_remotes − len(config)``."""
        return max(0, self.max_remotes - len(self.config))

    def set_config(self, config: Mapping[str, PriorityWeight]) -> None:
        """Take ``config`` (see the class) as the configured places; checks each entry."""
        checked: dict[str, PriorityWeight] = {}
        for key, (priority, weight) in config.items():
            if isinstance(priority, bool) or not isinstance(priority, int):
                raise ValueError(f"config[{key!r}]: priority must be an int, got {priority!r}")
            if not (math.isfinite(weight) and weight >= 0):
                raise ValueError(f"config[{key!r}]: weight must be finite and ≥ 0")
            checked[key] = (priority, float(weight))
        self.config = checked
        self._check_config_names()

    def reserve(self, names: Iterable[str]) -> None:
        """Add ``names`` (e.g. the robot's component names) to the reserved names. Raises
        :class:`~ubf_async.errors.ConfigurationError` if the robot configures one of them as a
        remote behaviour."""
        self.reserved.update(names)
        self._check_config_names()

    def _check_config_names(self) -> None:
        for key in self.config:
            name = key.rpartition("/")[2]
            if name in self.reserved:
                raise ConfigurationError(f"remote behaviour {key!r}: {name!r} is reserved for "
                                         "the robot's own components")

    def _name_refusal(self, behavior: str) -> str:
        """Why a new remote may not use ``behavior`` as its name ('' if it may)."""
        if len(behavior) > MAX_NAME_LEN:
            return f"name longer than {MAX_NAME_LEN} characters ({len(behavior)})"
        if behavior in self.reserved:
            return f"{behavior!r} is reserved for the robot's own components"
        local = self.root.find(behavior)
        if local is not None and not isinstance(local, RemoteBehavior):
            return f"{behavior!r} is the name of a behaviour of the robot's own tree"
        return ""

    def _strangers(self) -> int:
        return sum(1 for ident in self._entries if self._configured(*ident) is None)

    def _configured(self, composite: str, behavior: str) -> PriorityWeight | None:
        return self.config.get(f"{composite}/{behavior}", self.config.get(behavior))

    def _attach(self, entry: _Entry, key: str) -> bool:
        remote = entry.behavior
        priority, weight = self.placement(remote.composite, remote.name, entry.requested)
        current = entry.attached_as
        if current is not None:
            attached, p, w = current
            if (p, w) == (priority, weight) and any(
                c.behavior is remote for c in attached.children
            ):
                return True
            self._detach(entry)  # new placement requested: attach again below
        composite = self.root.find(remote.composite)
        if not isinstance(composite, Composite):
            del self._entries[(remote.composite, remote.name)]
            return self._reject(key, f"composite {remote.composite!r} no longer in the tree")
        if any(c.behavior.name == remote.name for c in composite.children):
            del self._entries[(remote.composite, remote.name)]
            return self._reject(key, f"{remote.composite!r} already has a child named "
                                     f"{remote.name!r}")
        try:
            composite.add(remote, priority=priority, weight=weight)
        except ConfigurationError as exc:  # e.g. a Conditional takes exactly two children
            del self._entries[(remote.composite, remote.name)]
            return self._reject(key, str(exc))
        entry.attached_as = (composite, priority, weight)
        log.info("remote behaviour %s attached to %s at priority %d weight %g",
                 remote.name, remote.composite, priority, weight)
        self.changed.set()
        return True

    def _detach(self, entry: _Entry) -> None:
        if entry.attached_as is None:
            return
        composite = entry.attached_as[0]
        entry.attached_as = None
        if any(c.behavior is entry.behavior for c in composite.children):
            composite.remove(entry.behavior.name)
        self.changed.set()

    @_holding_lock
    def prune(self) -> None:
        """Forget votes still waiting for a token after ``max_ttl_s`` (run periodically)."""
        now = self.bus.clock.now_ns()
        limit_ns = int(self.max_ttl_s * 1e9)
        for ident, entry in list(self._entries.items()):
            remote = entry.behavior
            if entry.attached_as is None and not remote.alive and (
                remote.action is None or abs(now - remote.stamp_ns) > limit_ns
            ):
                del self._entries[ident]

    @_holding_lock
    def detach_all(self) -> None:
        """Remove every remote child from the tree and forget every vote."""
        for entry in self._entries.values():
            self._detach(entry)
            entry.behavior.forget()
        self._entries.clear()

    def _reject(self, key: str, reason: str, *, counter: dict[str, int] | None = None) -> bool:
        counter = self.rejected if counter is None else counter
        n = counter.get(key, 0) + 1
        counter[key] = n
        if throttle.first_and_every(n):
            log.warning("rejected vote #%d on %s: %s", n, key, reason)
        if self.notices is not None:
            self.notices.report(key, "future" if counter is self.future else "rejected",
                                reason)
        return False

    def _key(self, composite: str, behavior: str) -> str:
        return f"{self.bus.keys.prefix}/vote/{composite}/{behavior}"

    # -- queries -----------------------------------------------------------------------------
    def get(self, composite: str, behavior: str) -> RemoteBehavior | None:
        entry = self._entries.get((composite, behavior))
        return entry.behavior if entry is not None else None

    @_holding_lock
    def set_root(self, root: Composite, *,
                 config: Mapping[str, PriorityWeight] | None = None) -> list[str]:
        """Move to a new tree (a live ``load``): detach every remote child from the old tree,
        take ``config`` as the new placements if given, and attach each again in the
        composite of the same name in ``root``. Returns the names of those that could not
        follow (no such composite, no slot while ``only_configured``, or refused by the
        arbiter); they are forgotten, and join again with their next vote if the tree allows."""
        moving = [(key, entry) for key, entry in self._entries.items()
                  if entry.attached_as is not None]
        for _, entry in moving:
            self._detach(entry)
        self.root = root
        if config is not None:
            self.set_config(config)
        left: list[str] = []
        for (composite, behavior), entry in moving:
            key = vote_key(self.bus.keys, composite, behavior)
            configured = self.config.get(f"{composite}/{behavior}", self.config.get(behavior))
            if self.only_configured and configured is None:
                self._entries.pop((composite, behavior), None)
                attached = False
            else:
                attached = self._attach(entry, key) and entry.attached_as is not None
            if not attached:
                left.append(f"{composite}/{behavior}")
        return left

    def attached(self) -> list[str]:
        """``"composite/behaviour"`` of every remote child in the tree, sorted."""
        return sorted(f"{c}/{b}" for (c, b), e in self._entries.items()
                      if e.attached_as is not None)

    def remotes(self) -> list[RemoteInfo]:
        now = self.bus.clock.now_ns()
        out = []
        for (composite, behavior), entry in sorted(self._entries.items()):
            remote = entry.behavior
            placed = entry.attached_as
            out.append(RemoteInfo(
                composite=composite, behavior=behavior, attached=placed is not None,
                alive=remote.alive, priority=placed[1] if placed else None,
                weight=placed[2] if placed else None, ttl_s=remote.ttl_s,
                age_s=(now - remote.stamp_ns) / 1e9 if remote.action is not None else None,
                votes=remote.votes,
                action=(remote.action.describe() if remote.valid(now) and remote.action
                        else "abstain (no valid vote)"),
            ))
        return out

    @_holding_lock
    def status(self) -> dict[str, Any]:
        return {
            "remotes": [
                {"composite": r.composite, "behavior": r.behavior, "attached": r.attached,
                 "alive": r.alive, "priority": r.priority, "weight": r.weight,
                 "ttl_s": r.ttl_s, "age_s": r.age_s, "votes": r.votes, "action": r.action}
                for r in self.remotes()
            ],
            "malformed": sum(self.malformed.values()),
            "rejected": sum(self.rejected.values()),
            "future": sum(self.future.values()),
        }


# ---------------------------------------------------------------------------------------------
# Remote side


class RemoteBehaviorHost(Component):
    """Runs a plain behaviour in this process as a child of a composite on the robot.

    The component (named after the behaviour, so its liveliness token is the
    ``ubf/<robot>/alive/<behaviour>`` the robot watches) does, in :meth:`run`:

    * keeps the robot's state with its own :class:`~ubf_async.runtime.aggregator.StateAggregator` on
      this bus (the same ``sensor/*/*`` samples the robot's aggregator sees; it declares no
      token of its own), with the robot's last drive command as ``previous_action``;
    * ticks the behaviour every ``1/rate_hz`` s of the bus clock, or on every new sample of
      ``trigger`` — :meth:`Behavior.act` runs on the event loop, so it must not block;
    * publishes each result as a vote on ``ubf/<robot>/vote/<composite>/<behaviour>`` stamped
      with the state's time. Abstaining (``None``) is published as a vote of 0, so the robot
      shows the behaviour as attached and abstaining. A behaviour that raises is logged,
      counted in ``errors`` and abstains that tick. When the host stops, it votes 0 once.
    """

    def __init__(
        self,
        *,
        bus: Bus,
        behavior: Behavior,
        composite: str,
        rate_hz: float = 20.0,
        trigger: str | None = None,
        ttl_s: float | None = None,
        priority: int | None = None,
        weight: float | None = None,
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=behavior.name, **component_options)
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.behavior = behavior
        self.composite = composite
        self.key = vote_key(bus.keys, composite, behavior.name)  # validates both names
        self.rate_hz = rate_hz
        self.trigger = trigger
        self.ttl_s = ttl_s
        self.priority = priority
        self.weight = weight
        # The vote's own fields are checked now, not at the first publish.
        encode_data(VOTE.schema, vote_data(None, ttl_s=ttl_s, priority=priority, weight=weight))
        self.votes = 0
        self.errors = 0
        self.last_action: Action | None = None
        self.robot_action: Action | None = None
        """The robot's last ``cmd/drive`` (speed/turn), handed to the behaviour as
        ``state.previous_action``."""
        self.robot_winners: list[str] = []
        self.malformed: dict[str, int] = {}
        self.voted = asyncio.Event()
        """Set after every published vote."""
        self.aggregator: StateAggregator | None = None

    async def run(self) -> None:
        keys = self.bus.keys
        aggregator = StateAggregator(bus=self.bus, name=f"{self.name}-state")
        self.aggregator = aggregator
        publisher = self.publisher(self.key, VOTE.schema,
                                   period_s=None if self.trigger else 1.0 / self.rate_hz)
        self.subscribe_topic(DRIVE.key(keys), DRIVE, self._on_drive, self.malformed)
        self.behavior.reset()
        try:
            async with asyncio.TaskGroup() as group:
                # The aggregator's run() only subscribes and waits; running it here instead of
                # start() keeps it from declaring a liveliness token and heartbeat of its own.
                group.create_task(aggregator.run())
                group.create_task(self._tick_loop(aggregator, publisher))
        finally:
            with contextlib.suppress(Exception):
                publisher.publish(vote_data(None, ttl_s=self.ttl_s, priority=self.priority,
                                            weight=self.weight))
            await aggregator.aclose()

    async def _tick_loop(self, aggregator: StateAggregator, publisher: Publisher) -> None:
        if self.trigger:
            version = 0
            while True:
                entry = await aggregator.wait_for_update(self.trigger, after_version=version)
                version = entry.version
                self.tick(aggregator, publisher)
        period_s = 1.0 / self.rate_hz
        while True:
            self.tick(aggregator, publisher)
            await self.bus.clock.sleep(period_s)

    def tick(self, aggregator: StateAggregator, publisher: Publisher) -> Action | None:
        """Snapshot the state, run the behaviour, publish its vote."""
        state = aggregator.snapshot(previous_action=self.robot_action)
        try:
            action = self.behavior.act(state)
        except Exception:
            self.errors += 1
            if throttle.first_and_every(self.errors):
                log.exception("behaviour %s raised (error #%d): abstaining", self.name,
                              self.errors)
            action = None
        publisher.publish(
            vote_data(action, ttl_s=self.ttl_s, priority=self.priority, weight=self.weight),
            stamp_ns=state.now_ns,
        )
        self.votes += 1
        self.last_action = action
        self.voted.set()
        return action

    def _on_drive(self, key: str, message: Message[Drive], received_ns: int) -> None:
        self.robot_action = Action(speed=message.data.speed, turn=message.data.turn)
        self.robot_winners = list(message.data.winners)


class _VoteScreen:
    """:class:`RemoteBehaviors`' :class:`~ubf_async.runtime.bus.Screen`: a vote is decoded and
    checked against its key on the transport's thread, so garbage on a vote key never displaces
    the valid vote waiting there."""

    def __init__(self, remotes: RemoteBehaviors) -> None:
        self._keys = remotes.bus.keys
        self._remotes = remotes
        self.refuse = remotes._malformed_vote

    def check(self, key: str, payload: bytes) -> ReceivedVote:
        return ReceivedVote.decode(self._keys, key, payload)

    def accept(self, key: str, payload: bytes, received_ns: int, vote: ReceivedVote) -> None:
        self._remotes.accept(vote, key=key)
