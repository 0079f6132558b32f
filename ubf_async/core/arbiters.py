"""Arbiters: each reduces the children's proposals to one action.

An arbiter (:class:`~ubf_async.core.behavior.Arbiter`, defined with the rest of the tree in
:mod:`ubf_async.core.behavior` and re-exported here) has one required method,
:meth:`~ubf_async.core.behavior.Arbiter.arbitrate`, which receives the *candidates* — children that
returned an action with a vote above 0, in child order — and returns a
:class:`~ubf_async.core.behavior.Decision`. Children that returned ``None`` or voted 0 never reach
it, so "empty input" and "all abstain" are the same case: the decision is
``Decision(None, ())`` and the composite abstains in turn. Optional hooks: ``select`` (which
children run this tick), ``validate`` (refuse a set of children, when the tree changes — never
on a tick) and ``reset``; the lifecycle is in :mod:`ubf_async.core.behavior`.

Common rules (where the original UBF code was loose, these are the sane choices):

* *utility* of a candidate = ``vote × weight``; weight defaults to 1 and is never "unset".
* Ties always go to the child that comes first in the composite.
* Field-wise arbiters treat an unset field (``None``) as "no opinion": it is filled from the
  next candidate that did set it, and stays unset if nobody did.

Every arbiter is built from keywords with plain-data values, so a robot file can name it
(entry-point group ``ubf_async.arbiters``): the six deterministic ones take none,
``MonteCarlo(hold_ticks=…, seed=…)``, and ``Conditional`` through
:func:`ubf_async.assembly.plugins.conditional` (a predicate by registered name or
``module:factory`` reference, resolved and checked when the arbiter is built). ``rng`` is
injected by the robot-file loader.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Sequence
from typing import Annotated, Any

import msgspec

from ubf_async.core.action import FIELDS, NUMERIC_FIELDS, Action, clamp_command
from ubf_async.core.behavior import Arbiter, Candidate, Child, Decision
from ubf_async.core.state import State
from ubf_async.errors import ConfigurationError

__all__ = [
    "NO_DECISION",
    "Arbiter",
    "CommandFusion",
    "Conditional",
    "HighestActivation",
    "HighestPriority",
    "MonteCarlo",
    "Predicate",
    "PriorityFusion",
    "PriorityMerge",
    "UtilityFusion",
]

Predicate = Callable[[State], bool]
"""What :class:`Conditional` asks each tick: true selects the first child, false the second."""

NO_DECISION = Decision(None, ())


def _decide(action: Action, winners: tuple[int, ...]) -> Decision:
    # Same as Decision(action, winners) without the NamedTuple argument handling: arbiters
    # run on every tick of every composite.
    return tuple.__new__(Decision, (action, winners))


def _priority_then_utility(c: Candidate) -> tuple[int, float]:
    return (c.priority, c.action.vote * c.weight)


def _utility(c: Candidate) -> float:
    return c.action.vote * c.weight


class HighestActivation(Arbiter):
    """The single action with the largest ``vote × weight`` wins, unchanged."""

    name = "HighestActivation"

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        if not candidates:
            return NO_DECISION
        best = candidates[0]
        best_utility = best.action.vote * best.weight
        for c in candidates:
            utility = c.action.vote * c.weight
            if utility > best_utility:
                best, best_utility = c, utility
        return _decide(best.action, (best.index,))


class HighestPriority(Arbiter):
    """The candidate with the highest priority wins outright.

    Equal priorities are broken by ``vote × weight``, then by child order.
    """

    name = "HighestPriority"

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        if not candidates:
            return NO_DECISION
        best = max(candidates, key=_priority_then_utility)  # max keeps the first of ties
        return _decide(best.action, (best.index,))


NON_NUMERIC_FIELDS = tuple(f for f in FIELDS if f not in NUMERIC_FIELDS)


# ``values`` are Action keyword arguments copied field by field (via getattr): typed Any.
def _take_first_set(
    values: dict[str, Any], ranked: Sequence[Candidate], names: Sequence[str],
    winners: set[int],
) -> None:
    """For each field in ``names``, the value of the first candidate in ``ranked`` that set
    it (fields nobody set stay out of ``values``); contributors are added to ``winners``."""
    for name in names:
        for c in ranked:
            value = getattr(c.action, name)
            if value is not None:
                values[name] = value
                winners.add(c.index)
                break


def _fieldwise(ranked: Sequence[Candidate], vote: float) -> Decision:
    """Each field from the first candidate in ``ranked`` that set it."""
    values: dict[str, Any] = {}
    winners: set[int] = set()
    _take_first_set(values, ranked, FIELDS, winners)
    return _decide(Action(vote=vote, **values), tuple(sorted(winners)))


class PriorityMerge(Arbiter):
    """The thesis's arbiter (§3.4.3): the highest priority wins; equal priorities are summed.

    Among the candidates of the highest priority, speed and turn are **summed** (unset values
    do not contribute; if none of them set a field it stays unset) and the sum is clamped to
    ±100. Non-numeric fields (seek colour, message, LEDs) cannot be summed: they come from the
    first candidate of that priority that set them. The merged vote is the largest vote in
    the group. Weights are ignored here — use :class:`CommandFusion` for weighted blending.
    """

    name = "PriorityMerge"

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        if not candidates:
            return NO_DECISION
        top = max(c.priority for c in candidates)
        group = [c for c in candidates if c.priority == top]
        if len(group) == 1:
            only = group[0]
            return _decide(only.action, (only.index,))
        values: dict[str, Any] = {}
        for name in NUMERIC_FIELDS:
            parts = [v for c in group if (v := getattr(c.action, name)) is not None]
            if parts:
                values[name] = clamp_command(sum(parts))
        _take_first_set(values, group, NON_NUMERIC_FIELDS, set())
        vote = max(c.action.vote for c in group)
        return _decide(Action(vote=vote, **values), tuple(c.index for c in group))


class PriorityFusion(Arbiter):
    """Field by field, each field from the highest-priority candidate that set it.

    Within one priority the larger ``vote × weight`` ranks first, then child order. The fused
    vote is the vote of the top-ranked candidate.
    """

    name = "PriorityFusion"

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        return _fused(candidates, _priority_then_utility)


class UtilityFusion(Arbiter):
    """Field by field, each field from the candidate with the largest ``vote × weight`` that
    set it (also known as ActivationFusion). The fused vote is the largest vote."""

    name = "UtilityFusion"

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        return _fused(candidates, _utility)


def _stable_desc(
    candidates: Sequence[Candidate], key: Callable[[Candidate], float | tuple[float, ...]]
) -> list[Candidate]:
    """Sorted by ``key`` descending; ``sorted`` is stable, so ties keep child order."""
    return sorted(candidates, key=key, reverse=True)


def _fused(
    candidates: Sequence[Candidate], key: Callable[[Candidate], float | tuple[float, ...]]
) -> Decision:
    """Field by field (:func:`_fieldwise`) over the candidates ranked by ``key``
    (:func:`_stable_desc`), with the vote of the top-ranked one."""
    if not candidates:
        return NO_DECISION
    ranked = _stable_desc(candidates, key)
    return _fieldwise(ranked, ranked[0].action.vote)


class CommandFusion(Arbiter):
    """Motor-schema blending: each numeric field is the mean weighted by ``vote × weight``.

    ``f = Σ fᵢ·uᵢ / Σ uᵢ`` over the candidates that set the field (unset values do not pull
    the mean toward zero). Candidates with zero weight do not count. Non-numeric fields come
    from the highest-utility candidate that set them. The fused vote is the largest vote.
    """

    name = "CommandFusion"

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        counted = [c for c in candidates if c.weight > 0]
        if not counted:
            return NO_DECISION
        values: dict[str, Any] = {}
        winners: set[int] = set()
        for name in NUMERIC_FIELDS:
            total = 0.0
            utility = 0.0
            for c in counted:
                value = getattr(c.action, name)
                if value is not None:
                    u = c.action.vote * c.weight
                    total += value * u
                    utility += u
                    winners.add(c.index)
            if utility > 0:
                values[name] = clamp_command(total / utility)
        _take_first_set(values, _stable_desc(counted, _utility), NON_NUMERIC_FIELDS, winners)
        vote = max(c.action.vote for c in counted)
        return _decide(Action(vote=vote, **values), tuple(sorted(winners)))


class MonteCarlo(Arbiter):
    """Random choice with probability ∝ ``vote × weight``, optionally held for N ticks.

    ``hold_ticks`` is how many consecutive ticks one draw lasts (1 = draw every tick). The
    hold counts down every tick (the original code's counter never did) and ends early when
    the held child abstains, in which case a new draw is made at once.

    Repeatable runs: ``seed`` gives the arbiter a generator of its own; otherwise ``rng`` (a
    :class:`random.Random`; the robot-file loader injects one derived from the robot's seed)
    is used; with neither, the draws are unseeded. An explicit ``seed`` wins over ``rng``.
    """

    name = "MonteCarlo"

    def __init__(
        self,
        *,
        hold_ticks: Annotated[int, msgspec.Meta(ge=1)] = 1,
        seed: int | None = None,
        rng: random.Random | None = None,
    ) -> None:
        if isinstance(hold_ticks, bool) or not isinstance(hold_ticks, int) or hold_ticks < 1:
            raise ConfigurationError(f"MonteCarlo: hold_ticks must be an int ≥ 1, got "
                                     f"{hold_ticks!r}")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise ConfigurationError(f"MonteCarlo: seed must be an int, got {seed!r}")
        self.hold_ticks = hold_ticks
        if seed is not None:
            self._rng = random.Random(seed)
        else:
            self._rng = rng if rng is not None else random.Random()
        self._held: int | None = None
        self._remaining = 0

    def reset(self) -> None:
        self._held = None
        self._remaining = 0

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        counted = [c for c in candidates if c.action.vote * c.weight > 0]
        if not counted:
            self.reset()
            return NO_DECISION
        if self._remaining > 0:
            for c in counted:
                if c.index == self._held:
                    self._remaining -= 1
                    return _decide(c.action, (c.index,))
        chosen = self._rng.choices(counted, weights=[_utility(c) for c in counted])[0]
        self._held = chosen.index
        self._remaining = self.hold_ticks - 1
        return _decide(chosen.action, (chosen.index,))

    def describe(self) -> str:
        return f"{self.name}(hold_ticks={self.hold_ticks})"


class Conditional(Arbiter):
    """A predicate on the state picks one of exactly two children.

    The first child runs when the predicate is true, the second when it is false. Only the
    chosen child is run (the other's :meth:`~ubf_async.core.behavior.Behavior.act` does not run
    that tick), and its action passes through unchanged. A composite with any other number
    of children is refused when the children or the arbiter are set
    (:meth:`validate`), not on a tick.

    ``predicate`` is a callable ``State -> bool``. A predicate by name (a registered factory such
    as ``"sees_color"``, or a ``module:factory`` reference, with its parameters) is what a
    robot file gives: :func:`ubf_async.assembly.plugins.conditional` resolves it, checks it and
    builds this arbiter, so an unknown name or a bad parameter fails then, never at a tick::

        Conditional(lambda state: state.value("range/front", "range_mm", 9999) < 200)
    """

    name = "Conditional"

    def __init__(self, predicate: Predicate, *, label: str | None = None) -> None:
        if isinstance(predicate, str) or not callable(predicate):
            # The core knows no plug-in registry: names are resolved in the assembly.
            raise ConfigurationError(
                f"Conditional: predicate must be a callable State -> bool, got "
                f"{type(predicate).__name__} (a predicate by name: "
                f"ubf_async.assembly.plugins.conditional)")
        self.predicate: Predicate = predicate
        self.label = label or getattr(predicate, "__name__", "predicate")

    def validate(self, children: Sequence[Child]) -> None:
        if len(children) != 2:
            raise ConfigurationError(
                f"Conditional needs exactly two children (if-true, if-false), got "
                f"{len(children)}")

    def select(
        self, children: Sequence[tuple[int, Child]], state: State
    ) -> Sequence[tuple[int, Child]]:
        return (children[0] if self.predicate(state) else children[1],)

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        if not candidates:
            return NO_DECISION
        only = candidates[0]
        return _decide(only.action, (only.index,))

    def describe(self) -> str:
        return f"{self.name}({self.label})"
