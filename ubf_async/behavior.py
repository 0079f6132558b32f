"""Behaviours, composites and the per-tick explanation (trace).

Lifecycle — when each hook runs:

* :meth:`Behavior.act` runs once per controller tick *if the behaviour's composite selects it*
  (every child is selected unless the arbiter narrows the set, as :class:`~ubf_async.arbiters.
  Conditional` does). It receives the tick's :class:`~ubf_async.state.State` and returns an
  :class:`~ubf_async.action.Action` or ``None`` to abstain. It must not block: it runs on the
  event loop.
* :meth:`Behavior.reset` runs when the controller starts and whenever a behaviour is (re)attached
  to a composite; stateful behaviours clear their memory there.
* :meth:`Behavior.evaluate` is what a composite calls; it wraps ``act`` into a :class:`Trace`.
  Composites override it to evaluate their children and arbitrate.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from ubf_async.action import Action
from ubf_async.state import State

if TYPE_CHECKING:
    from ubf_async.arbiters import Arbiter


class Behavior:
    """Base class: ``state -> Action | None``. Subclasses override :meth:`act`."""

    def __init__(self, *, name: str | None = None) -> None:
        self.name = name or type(self).__name__

    def act(self, state: State) -> Action | None:
        """Return the desired action for this tick, or ``None`` to abstain."""
        raise NotImplementedError(f"{type(self).__name__}.act")

    def reset(self) -> None:
        """Forget any memory; called on controller start and when (re)attached."""

    def evaluate(self, state: State) -> Trace:
        """Run :meth:`act` and record the result."""
        return Trace(self.name, self.act(state))

    def run(self, state: State) -> tuple[Action | None, Trace | None]:
        """What a composite calls each tick: the action and, for composites, their trace.

        Leaves return no trace (their parent records their action), which keeps the
        per-child cost of a tick down to the ``act`` call itself.
        """
        return self.act(state), None

    def describe(self, indent: int = 0) -> str:
        """This behaviour as one line of an indented tree."""
        return "  " * indent + f"{self.name} ({type(self).__name__})"

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"


class FunctionBehavior(Behavior):
    """A plain function ``state -> Action | None`` as a behaviour."""

    def __init__(self, fn: Callable[[State], Action | None], *, name: str | None = None) -> None:
        super().__init__(name=name or getattr(fn, "__name__", "function"))
        self._fn = fn

    def act(self, state: State) -> Action | None:
        return self._fn(state)


def behavior(fn: Callable[[State], Action | None]) -> FunctionBehavior:
    """Decorator: turn ``def avoid(state): ...`` into a behaviour named ``avoid``."""
    return FunctionBehavior(fn)


@dataclass(frozen=True, slots=True)
class Child:
    """A behaviour's place in a composite: its priority (higher wins) and weight (≥ 0)."""

    behavior: Behavior
    priority: int = 0
    weight: float = 1.0

    def __post_init__(self) -> None:
        if isinstance(self.priority, bool) or not isinstance(self.priority, int):
            raise ValueError(f"priority must be an int, got {self.priority!r}")
        if not (math.isfinite(self.weight) and self.weight >= 0):
            raise ValueError(f"weight must be finite and ≥ 0, got {self.weight!r}")


class Candidate(NamedTuple):
    """One child's non-abstaining proposal, as an arbiter sees it."""

    index: int
    """Position of the child in the composite (ties go to the lower index)."""
    priority: int
    weight: float
    action: Action

    @property
    def utility(self) -> float:
        return self.action.vote * self.weight


class Decision(NamedTuple):
    """An arbiter's result: the action (``None`` if nobody voted) and which candidates won."""

    action: Action | None
    winners: tuple[int, ...] = ()
    """Child indexes whose actions make up ``action``."""


class Trace:
    """What happened in one behaviour on one tick.

    For a composite, :attr:`children` lists a trace per evaluated child, each with ``won``
    set when that child's action contributed to the composite's result. Child traces are
    built on first access, so a tick that nobody inspects pays nothing for them.
    :meth:`render` prints the whole tick as a tree.
    """

    __slots__ = ("_children", "_results", "_selected", "_winners", "action", "arbiter",
                 "name", "priority", "weight", "won")

    def __init__(
        self,
        name: str,
        action: Action | None,
        children: list[Trace] | None = None,
        *,
        arbiter: str | None = None,
        won: bool = False,
        priority: int | None = None,
        weight: float | None = None,
    ) -> None:
        self.name = name
        self.action = action
        self.arbiter = arbiter
        self.won = won
        self.priority = priority
        self.weight = weight
        self._children = children
        self._selected: Sequence[tuple[int, Child]] = ()
        self._results: list[tuple[Action | None, Trace | None]] = []
        self._winners: tuple[int, ...] = ()

    @classmethod
    def _of_composite(
        cls,
        name: str,
        action: Action | None,
        arbiter: str,
        selected: Sequence[tuple[int, Child]],
        results: list[tuple[Action | None, Trace | None]],
        winners: tuple[int, ...],
    ) -> Trace:
        trace = cls.__new__(cls)
        trace.name = name
        trace.action = action
        trace.arbiter = arbiter
        trace.won = False
        trace.priority = None
        trace.weight = None
        trace._children = None
        trace._selected = selected
        trace._results = results
        trace._winners = winners
        return trace

    @property
    def children(self) -> list[Trace]:
        if self._children is None:
            built = []
            for (index, child), (action, sub) in zip(self._selected, self._results, strict=True):
                node = sub if sub is not None else Trace(child.behavior.name, action)
                node.priority = child.priority
                node.weight = child.weight
                node.won = index in self._winners
                built.append(node)
            self._children = built
        return self._children

    def render(self, indent: int = 0) -> str:
        mark = "*" if self.won else " "
        what = self.action.describe() if self.action is not None else "abstain"
        place = ""
        if self.priority is not None:
            place = f" [p={self.priority} w={self.weight:g}]"
        head = f"{'  ' * indent}{mark} {self.name}{place}"
        if self.arbiter:
            head += f" <{self.arbiter}>"
        lines = [f"{head}: {what}"]
        lines.extend(child.render(indent + 1) for child in self.children)
        return "\n".join(lines)

    def winning_leaves(self) -> list[str]:
        """Names of the leaf behaviours whose actions reached this node's result."""
        children = self.children
        if not children:
            return [self.name] if self.action is not None else []
        out: list[str] = []
        for child in children:
            if child.won:
                out.extend(child.winning_leaves())
        return out

    def walk(self) -> Iterator[Trace]:
        yield self
        for child in self.children:
            yield from child.walk()

    def __repr__(self) -> str:
        return f"<Trace {self.name!r} {self.action!r}>"


class Composite(Behavior):
    """A behaviour made of children and an arbiter that reduces their actions to one.

    Children and the arbiter can be replaced at run time (between ticks — the controller runs
    ticks on the event loop, so any code on the loop may change them). Composites nest to any
    depth: a composite is itself a behaviour.
    """

    def __init__(
        self,
        *,
        name: str,
        arbiter: Arbiter,
        children: Iterable[Child | Behavior] = (),
    ) -> None:
        super().__init__(name=name)
        self.arbiter = arbiter
        self._children: tuple[Child, ...] = ()
        self._indexed: tuple[tuple[int, Child], ...] = ()
        for child in children:
            self._attach(child if isinstance(child, Child) else Child(child))

    @property
    def children(self) -> tuple[Child, ...]:
        return self._children

    def _attach(self, child: Child) -> None:
        if any(c.behavior.name == child.behavior.name for c in self._children):
            raise ValueError(f"{self.name!r} already has a child named {child.behavior.name!r}")
        child.behavior.reset()
        self._set_children((*self._children, child))

    def _set_children(self, children: tuple[Child, ...]) -> None:
        self._children = children
        self._indexed = tuple(enumerate(children))

    def add(self, behavior: Behavior, *, priority: int = 0, weight: float = 1.0) -> Child:
        """Append a child; names must be unique within a composite."""
        child = Child(behavior, priority, weight)
        self._attach(child)
        return child

    def remove(self, name: str) -> Child:
        """Detach the child named ``name`` (KeyError if there is none)."""
        for child in self._children:
            if child.behavior.name == name:
                self._set_children(tuple(c for c in self._children if c is not child))
                return child
        raise KeyError(f"{self.name!r} has no child named {name!r}")

    def replace_children(self, children: Iterable[Child | Behavior]) -> None:
        self._set_children(())
        for child in children:
            self._attach(child if isinstance(child, Child) else Child(child))

    def find(self, name: str) -> Behavior | None:
        """Depth-first search of this subtree for a behaviour called ``name``."""
        if self.name == name:
            return self
        for child in self._children:
            b = child.behavior
            if b.name == name:
                return b
            if isinstance(b, Composite):
                found = b.find(name)
                if found is not None:
                    return found
        return None

    def reset(self) -> None:
        for child in self._children:
            child.behavior.reset()
        self.arbiter.reset()

    def act(self, state: State) -> Action | None:
        return self.run(state)[0]

    def evaluate(self, state: State) -> Trace:
        return self.run(state)[1]  # type: ignore[return-value]

    def run(self, state: State) -> tuple[Action | None, Trace]:
        arbiter = self.arbiter
        selected = arbiter.select(self._indexed, state)
        results: list[tuple[Action | None, Trace | None]] = []
        candidates: list[Candidate] = []
        new = tuple.__new__  # Candidate(...) validates arity; this is the hot path.
        for index, child in selected:
            result = child.behavior.run(state)
            results.append(result)
            action = result[0]
            if action is not None and action.vote > 0:
                candidates.append(new(Candidate, (index, child.priority, child.weight, action)))
        action, winners = arbiter.arbitrate(candidates, state)
        return action, Trace._of_composite(
            self.name, action, arbiter.name, selected, results, winners
        )

    def describe(self, indent: int = 0) -> str:
        lines = ["  " * indent + f"{self.name} <{self.arbiter.describe()}>"]
        for child in self._children:
            sub = child.behavior.describe(indent + 1)
            first, _, rest = sub.partition("\n")
            lines.append(f"{first} [p={child.priority} w={child.weight:g}]")
            if rest:
                lines.append(rest)
        return "\n".join(lines)

    def render_tree(self) -> str:
        """The tree as indented text: composites with their arbiter, children with p/w."""
        return self.describe()
