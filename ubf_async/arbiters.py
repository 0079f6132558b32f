"""Arbiters: each reduces the children's proposals to one action.

An arbiter is an object with one method, :meth:`Arbiter.arbitrate`, which receives the
*candidates* — children that returned an action with a vote above 0, in child order — and
returns a :class:`~ubf_async.behavior.Decision`. Children that returned ``None`` or voted 0
never reach it, so "empty input" and "all abstain" are the same case: the decision is
``Decision(None, ())`` and the composite abstains in turn.

Common rules (where the original UBF code was loose, these are the sane choices):

* *utility* of a candidate = ``vote × weight``; weight defaults to 1 and is never "unset".
* Ties always go to the child that comes first in the composite.
* Field-wise arbiters treat an unset field (``None``) as "no opinion": it is filled from the
  next candidate that did set it, and stays unset if nobody did.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Sequence

from ubf_async.action import FIELDS, NUMERIC_FIELDS, Action, clamp_command
from ubf_async.behavior import Candidate, Child, Decision
from ubf_async.state import State

NO_DECISION = Decision(None, ())


def _decide(action: Action, winners: tuple[int, ...]) -> Decision:
    # Same as Decision(action, winners) without the NamedTuple argument handling: arbiters
    # run on every tick of every composite.
    return tuple.__new__(Decision, (action, winners))


class Arbiter:
    """Base class. Subclasses implement :meth:`arbitrate`; :meth:`select` is optional."""

    name = "Arbiter"

    def select(
        self, children: Sequence[tuple[int, Child]], state: State
    ) -> Sequence[tuple[int, Child]]:
        """Which of the ``(index, child)`` pairs to evaluate this tick (default: all)."""
        return children

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        raise NotImplementedError

    def reset(self) -> None:
        """Forget memory (e.g. a MonteCarlo hold); called when the controller starts."""

    def describe(self) -> str:
        return self.name


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


def _take_first_set(
    values: dict[str, object], ranked: Sequence[Candidate], names: Sequence[str],
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
    values: dict[str, object] = {}
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
        values: dict[str, object] = {}
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
        if not candidates:
            return NO_DECISION
        ranked = _stable_desc(candidates, _priority_then_utility)
        return _fieldwise(ranked, ranked[0].action.vote)


class UtilityFusion(Arbiter):
    """Field by field, each field from the candidate with the largest ``vote × weight`` that
    set it (also known as ActivationFusion). The fused vote is the largest vote."""

    name = "UtilityFusion"

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        if not candidates:
            return NO_DECISION
        ranked = _stable_desc(candidates, _utility)
        return _fieldwise(ranked, ranked[0].action.vote)


def _stable_desc(
    candidates: Sequence[Candidate], key: Callable[[Candidate], float | tuple[float, ...]]
) -> list[Candidate]:
    """Sorted by ``key`` descending; ``sorted`` is stable, so ties keep child order."""
    return sorted(candidates, key=key, reverse=True)


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
        values: dict[str, object] = {}
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
    the held child abstains, in which case a new draw is made at once. Pass ``seed`` or an
    ``rng`` (a :class:`random.Random`) to make runs repeatable.
    """

    name = "MonteCarlo"

    def __init__(
        self, *, hold_ticks: int = 1, seed: int | None = None, rng: random.Random | None = None
    ) -> None:
        if hold_ticks < 1:
            raise ValueError(f"hold_ticks must be ≥ 1, got {hold_ticks}")
        self.hold_ticks = hold_ticks
        self._rng = rng if rng is not None else random.Random(seed)
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

    Only the chosen child is evaluated (the other's :meth:`~ubf_async.behavior.Behavior.act`
    does not run that tick), and its action passes through unchanged.
    """

    name = "Conditional"

    def __init__(self, predicate: Callable[[State], bool], *, label: str | None = None) -> None:
        self.predicate = predicate
        self.label = label or getattr(predicate, "__name__", "predicate")

    def select(
        self, children: Sequence[tuple[int, Child]], state: State
    ) -> Sequence[tuple[int, Child]]:
        if len(children) != 2:
            raise ValueError(
                f"Conditional needs exactly two children (if-true, if-false), got {len(children)}"
            )
        return (children[0] if self.predicate(state) else children[1],)

    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        if not candidates:
            return NO_DECISION
        only = candidates[0]
        return _decide(only.action, (only.index,))

    def describe(self) -> str:
        return f"{self.name}({self.label})"
