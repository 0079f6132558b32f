"""Behaviours, arbiters, composites and the per-tick explanation (trace).

Everything a behaviour tree is made of lives here — :class:`Behavior` (leaves),
:class:`Composite` (a behaviour made of children), :class:`Arbiter` (how a composite reduces
its children's actions to one) and the values passed between them (:class:`Child`,
:class:`Candidate`, :class:`Decision`, :class:`Trace`). The concrete arbiters are in
:mod:`ubf_async.core.arbiters`, which imports this module; this module imports no other part of
the tree.

Lifecycle — when each hook runs
-------------------------------

A tree is driven by a :class:`~ubf_async.runtime.controller.Controller`. Each time the controller
component runs (its start, and again after each restart that follows a failure):

1. ``root.setup()`` — once, before the first tick. A composite sets up its children in child
   order, depth first. A behaviour acquires resources and checks its configuration there and
   may raise :class:`~ubf_async.errors.ConfigurationError`: the exception fails the
   controller's run (the component logs it and restarts with backoff), no tick runs, and step
   4 still happens so that whatever a partial setup acquired is released.
2. ``root.reset()`` — once, after setup. A composite resets its children, then its arbiter.
3. Every tick, ``root.evaluate(state)``: it calls ``root.run(state)``. A composite's ``run``
   asks its arbiter's :meth:`Arbiter.select` which children to run this tick (all of them
   unless the arbiter narrows the set, as :class:`~ubf_async.core.arbiters.Conditional` does),
   calls each selected child's ``run`` — for a leaf that is just its :meth:`Behavior.act` —
   and hands the non-abstaining proposals to :meth:`Arbiter.arbitrate`. ``act`` receives the
   tick's :class:`~ubf_async.core.state.State` and returns an
   :class:`~ubf_async.core.action.Action` or ``None`` to abstain. It must not block: it runs on the
   event loop.
   A child whose ``run`` raises (its ``act``, or a composite's arbiter) is **cut off for
   that tick**: logged, counted, treated as abstaining, and its siblings and the arbiter go
   on (trio's faulty-observer rule). A child that fails on
   :attr:`Composite.quarantine_after` consecutive ticks is **quarantined**: skipped (shown
   abstaining, marked ``QUARANTINED`` in the trace) until the composite's next ``reset()``
   — the controller's next run or a restart, a reload of the tree — or until it leaves the
   composite and joins again. Only a failure of the root itself reaches the controller,
   which then commands a stop.
4. ``root.shutdown()`` — when the controller's run ends, however it ends (stopped, cancelled,
   or failed, including a failed setup). A composite shuts its children down in *reverse*
   child order; one that raises is logged and the others are still shut down.

Changing the tree between ticks (:meth:`Composite.add`, :meth:`~Composite.remove`,
:meth:`~Composite.replace_children`, :meth:`~Composite.set_child`, assigning
:attr:`Composite.arbiter`):

* the arbiter's :meth:`Arbiter.validate` sees the resulting set of children first — also when
  the arbiter itself is swapped, never on a tick. If it refuses (or a child name is taken)
  :class:`~ubf_async.errors.ConfigurationError` is raised, naming the composite, and the
  composite is left exactly as it was;
* a behaviour that joins is ``reset()``; if the composite is *live* (set up and not yet shut
  down) it is ``setup()`` before it joins — a behaviour never ticks without its setup — and a
  behaviour that leaves a live composite is ``shutdown()`` after it has left;
* an arbiter that takes over is ``reset()``.

Hooks — what to override
------------------------

* :class:`Behavior`: :meth:`~Behavior.act` (required), and as needed
  :meth:`~Behavior.reset` (forget memory), :meth:`~Behavior.setup` (acquire, validate) and
  :meth:`~Behavior.shutdown` (release; must be harmless when called twice or without setup).
* :class:`Arbiter`: :meth:`~Arbiter.arbitrate` (required), and as needed
  :meth:`~Arbiter.select`, :meth:`~Arbiter.validate` and :meth:`~Arbiter.reset`.

:meth:`Behavior.run` and :meth:`Behavior.evaluate` are the framework's internal tick, not
hooks: :class:`Composite` is the one class that overrides ``run``, and a subclass defined
anywhere else that overrides either is refused with :class:`TypeError` when it is defined.
"""

from __future__ import annotations

import abc
import logging
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple, final

from ubf_async import throttle
from ubf_async.core.action import Action
from ubf_async.core.state import State
from ubf_async.errors import ConfigurationError

__all__ = ["Arbiter", "Behavior", "Candidate", "Child", "Composite", "Decision", "FunctionBehavior",
           "Trace", "behavior"]

log = logging.getLogger(__name__)

_INTERNAL_METHODS = ("run", "evaluate")


class Behavior(abc.ABC):
    """Base class of every behaviour: ``state -> Action | None``.

    Subclasses implement :meth:`act` and may override :meth:`reset`, :meth:`setup` and
    :meth:`shutdown` (see the module's lifecycle section for when each runs).
    """

    def __init__(self, *, name: str | None = None) -> None:
        self.name = name or type(self).__name__

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__module__ == __name__:
            return  # Composite: the one internal override of run()
        overridden = [m for m in _INTERNAL_METHODS if m in cls.__dict__]
        if overridden:
            raise TypeError(
                f"{cls.__qualname__} overrides {' and '.join(overridden)}(), the framework's "
                f"internal tick; override act() (and reset/setup/shutdown) instead"
            )

    # -- hooks -------------------------------------------------------------------------------
    @abc.abstractmethod
    def act(self, state: State) -> Action | None:
        """Return the desired action for this tick, or ``None`` to abstain."""

    def reset(self) -> None:
        """Forget any memory; called when the controller starts and when (re)attached."""
        return None

    def setup(self) -> None:
        """Acquire resources and check the configuration, once before the first tick.

        Raise :class:`~ubf_async.errors.ConfigurationError` for a configuration that cannot
        work. The default does nothing.
        """
        return None

    def shutdown(self) -> None:
        """Release what :meth:`setup` acquired, when the controller stops.

        Must be harmless when called twice, or without :meth:`setup` (or after a setup that
        raised halfway). The default does nothing.
        """
        return None

    # -- internal: not to be overridden ------------------------------------------------------
    def run(self, state: State) -> tuple[Action | None, Trace | None]:
        """What a composite calls each tick: the action and, for composites, their trace.

        Internal; override :meth:`act` instead. Leaves return no trace (their parent records
        their action), which keeps the per-child cost of a tick down to the ``act`` call.
        """
        return self.act(state), None

    @final
    def evaluate(self, state: State) -> Trace:
        """One tick of this behaviour with its explanation: what the controller calls on the
        root. Internal; override :meth:`act` instead."""
        action, trace = self.run(state)
        return trace if trace is not None else Trace(self.name, action)

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
        if not isinstance(self.behavior, Behavior):
            raise ConfigurationError(
                f"a child must be a Behavior, got {type(self.behavior).__name__}")
        if isinstance(self.priority, bool) or not isinstance(self.priority, int):
            raise ConfigurationError(f"priority must be an int, got {self.priority!r}")
        if (isinstance(self.weight, bool) or not isinstance(self.weight, int | float)
                or not (math.isfinite(self.weight) and self.weight >= 0)):
            raise ConfigurationError(f"weight must be finite and ≥ 0, got {self.weight!r}")


class Candidate(NamedTuple):
    """One child's non-abstaining proposal, as an arbiter sees it."""

    # A NamedTuple field named ``index`` shadows ``tuple.index``; it is public API (arbiters
    # and plug-ins read ``c.index``), and candidates are never searched with ``.index()``.
    index: int  # type: ignore[assignment]
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


class Arbiter(abc.ABC):
    """Base class of every arbiter: reduces a composite's proposals to one :class:`Decision`.

    Subclasses implement :meth:`arbitrate` and may override :meth:`select`, :meth:`validate`
    and :meth:`reset`. :attr:`name` (shown in traces) defaults to the class name.
    """

    name: ClassVar[str] = "Arbiter"

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "name" not in cls.__dict__:
            cls.name = cls.__name__

    @abc.abstractmethod
    def arbitrate(self, candidates: Sequence[Candidate], state: State) -> Decision:
        """The decision of one tick.

        ``candidates`` are the selected children that returned an action with a vote above 0,
        in child order; children that abstained or voted 0 never reach it, so an empty
        sequence means "nobody voted" (return ``Decision(None, ())``).
        """

    def select(
        self, children: Sequence[tuple[int, Child]], state: State
    ) -> Sequence[tuple[int, Child]]:
        """Which of the ``(index, child)`` pairs to run this tick (default: all)."""
        return children

    def validate(self, children: Sequence[Child]) -> None:
        """Refuse a set of children this arbiter cannot work with.

        Called with the complete set whenever children are attached, replaced, moved or
        removed, and when this arbiter is about to take over a composite — never on a tick.
        Raise :class:`~ubf_async.errors.ConfigurationError` saying what is wrong; the
        composite adds its own name. The default accepts any set.
        """
        return None

    def reset(self) -> None:
        """Forget memory (e.g. a MonteCarlo hold); called when the controller starts and
        when this arbiter takes over a composite."""
        return None

    def describe(self) -> str:
        return self.name

class Trace:
    """What happened in one behaviour on one tick.

    For a composite, :attr:`children` lists a trace per evaluated child, each with ``won``
    set when that child's action contributed to the composite's result. Child traces are
    built on first access, so a tick that nobody inspects pays nothing for them.
    :meth:`render` prints the whole tick as a tree.
    """

    __slots__ = ("_children", "_results", "_selected", "_winners", "action", "arbiter",
                 "fault", "name", "priority", "weight", "won")

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
        fault: str | None = None,
    ) -> None:
        self.name = name
        self.action = action
        self.fault = fault
        """Why this behaviour did not run properly this tick (it raised, or is
        quarantined); ``None`` when it did."""
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
        trace.fault = None
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
        if self.fault is not None:
            mark = "!"
            what = f"abstain — {self.fault}"
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
        out: list[str] = []
        if self._children is None:
            # Every tick asks this (the drive command carries it): read what the composite
            # kept instead of building its child traces for it.
            if not self._selected:
                return [self.name] if self.action is not None else []
            winners = self._winners
            for (index, spec), (action, sub) in zip(self._selected, self._results,
                                                    strict=True):
                if index in winners:
                    if sub is not None:
                        out.extend(sub.winning_leaves())
                    elif action is not None:
                        out.append(spec.behavior.name)
            return out
        if not self._children:
            return [self.name] if self.action is not None else []
        for child in self._children:
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

    Children and the arbiter can be replaced at run time, between ticks (the controller runs
    ticks on the event loop, so any code on the loop may change them); every change is
    validated first and a refused one leaves the composite untouched (see the module's
    lifecycle section). Composites nest to any depth: a composite is itself a behaviour.

    The constructor attaches all ``children`` and then validates the complete set once, so an
    arbiter that needs a fixed number of children (:class:`~ubf_async.core.arbiters.Conditional`)
    gets them all at once.

    A child that raises is cut off for the tick; one that fails ``quarantine_after``
    consecutive ticks is quarantined until :meth:`reset` (module docstring).
    """

    def __init__(
        self,
        *,
        name: str,
        arbiter: Arbiter,
        children: Iterable[Child | Behavior] = (),
        quarantine_after: int = 10,
    ) -> None:
        super().__init__(name=name)
        if isinstance(quarantine_after, bool) or not (
                isinstance(quarantine_after, int) and quarantine_after >= 1):
            raise ConfigurationError(
                f"composite {name!r}: quarantine_after must be an int ≥ 1, got "
                f"{quarantine_after!r}")
        self.quarantine_after = quarantine_after
        """Consecutive failing ticks after which a child is quarantined."""
        self._streaks: dict[int, int] = {}
        """Consecutive failing ticks per child behaviour (by id), only while failing."""
        self._quarantined: set[int] = set()
        self.failures: dict[str, int] = {}
        """Ticks on which each child (by name) raised, since the composite was made."""
        if not isinstance(arbiter, Arbiter):
            raise ConfigurationError(
                f"composite {name!r}: the arbiter must be an Arbiter, got "
                f"{type(arbiter).__name__}")
        self._arbiter = arbiter
        self._live = False
        built = self._checked(tuple(_as_child(c) for c in children))
        self._validate(arbiter, built)
        for child in built:
            child.behavior.reset()
        self._set_children(built)

    # -- structure ---------------------------------------------------------------------------
    @property
    def children(self) -> tuple[Child, ...]:
        return self._children

    @property
    def arbiter(self) -> Arbiter:
        return self._arbiter

    @arbiter.setter
    def arbiter(self, arbiter: Arbiter) -> None:
        """Swap the arbiter: validated against the current children, then reset."""
        if not isinstance(arbiter, Arbiter):
            raise ConfigurationError(
                f"composite {self.name!r}: the arbiter must be an Arbiter, got "
                f"{type(arbiter).__name__}")
        self._validate(arbiter, self._children)
        arbiter.reset()
        self._arbiter = arbiter

    @property
    def live(self) -> bool:
        """Set up and not yet shut down: behaviours that join are set up first."""
        return self._live

    def add(self, behavior: Behavior, *, priority: int = 0, weight: float = 1.0) -> Child:
        """Append a child; names must be unique within a composite."""
        child = Child(behavior, priority, weight)
        self._change((*self._children, child))
        return child

    def remove(self, name: str) -> Child:
        """Detach the child named ``name`` (KeyError if there is none)."""
        index = self._index_of(name)
        child = self._children[index]
        self._change(self._children[:index] + self._children[index + 1:])
        return child

    def replace_children(self, children: Iterable[Child | Behavior]) -> None:
        """Replace every child at once (validated as one set)."""
        self._change(tuple(_as_child(c) for c in children))

    def set_child(
        self, name: str, *, priority: int | None = None, weight: float | None = None
    ) -> Child:
        """Change the priority and/or weight of the child named ``name`` (KeyError if there
        is none). The behaviour stays where it is and keeps its memory."""
        index = self._index_of(name)
        old = self._children[index]
        new = Child(
            old.behavior,
            old.priority if priority is None else priority,
            old.weight if weight is None else weight,
        )
        children = (*self._children[:index], new, *self._children[index + 1:])
        self._validate(self._arbiter, children)
        self._set_children(children)
        return new

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

    def _index_of(self, name: str) -> int:
        for index, child in enumerate(self._children):
            if child.behavior.name == name:
                return index
        raise KeyError(f"{self.name!r} has no child named {name!r}")

    def _checked(self, children: tuple[Child, ...]) -> tuple[Child, ...]:
        seen: set[str] = set()
        for child in children:
            if child.behavior.name in seen:
                raise ConfigurationError(
                    f"{self.name!r} already has a child named {child.behavior.name!r}")
            seen.add(child.behavior.name)
        return children

    def _validate(self, arbiter: Arbiter, children: tuple[Child, ...]) -> None:
        try:
            arbiter.validate(children)
        except ValueError as exc:  # ConfigurationError is one
            raise ConfigurationError(
                f"composite {self.name!r} ({arbiter.describe()}): {exc}") from exc

    def _change(self, children: tuple[Child, ...]) -> None:
        """Validate ``children`` as the new set, set up and reset the behaviours that join,
        switch, shut down the ones that left. Nothing changes if any step before the switch
        raises."""
        self._validate(self._arbiter, self._checked(children))
        old = {id(c.behavior) for c in self._children}
        joining = [c.behavior for c in children if id(c.behavior) not in old]
        if self._live:
            started: list[Behavior] = []
            try:
                for b in joining:
                    started.append(b)
                    b.setup()
            except BaseException:
                _shutdown_all(reversed(started), self.name)
                raise
        for b in joining:
            b.reset()
        new = {id(c.behavior) for c in children}
        leaving = [c.behavior for c in self._children if id(c.behavior) not in new]
        self._set_children(children)
        if self._live:
            _shutdown_all(reversed(leaving), self.name)

    def _set_children(self, children: tuple[Child, ...]) -> None:
        self._children = children
        self._indexed = tuple(enumerate(children))
        present = {id(c.behavior) for c in children}
        # A behaviour that left (and may join again later) starts afresh.
        self._streaks = {k: v for k, v in self._streaks.items() if k in present}
        self._quarantined &= present

    # -- lifecycle ---------------------------------------------------------------------------
    def setup(self) -> None:
        """Set up every child in order (depth first). Does nothing if already live."""
        if self._live:
            return
        self._live = True  # from here on shutdown() releases whatever was set up
        for child in self._children:
            child.behavior.setup()

    def shutdown(self) -> None:
        """Shut every child down in reverse order; a child that raises is logged and the
        others are still shut down. Does nothing unless live (so calling it twice is
        harmless)."""
        if not self._live:
            return
        self._live = False
        _shutdown_all(reversed([c.behavior for c in self._children]), self.name)

    def reset(self) -> None:
        """Reset the children and the arbiter; lifts every quarantine in this composite."""
        if self._quarantined:
            log.info("composite %r: quarantine of %s lifted on reset", self.name,
                     ", ".join(self.quarantined_children()))
        self._streaks.clear()
        self._quarantined.clear()
        for child in self._children:
            child.behavior.reset()
        self._arbiter.reset()

    def quarantined_children(self) -> list[str]:
        """Names of this composite's children that are quarantined now."""
        return [c.behavior.name for c in self._children if id(c.behavior) in self._quarantined]

    def quarantined(self) -> list[str]:
        """Every quarantined behaviour in this subtree, as ``composite/child`` paths."""
        out = [f"{self.name}/{name}" for name in self.quarantined_children()]
        for child in self._children:
            if isinstance(child.behavior, Composite):
                out.extend(child.behavior.quarantined())
        return out

    # -- the tick ----------------------------------------------------------------------------
    def act(self, state: State) -> Action | None:
        return self.run(state)[0]

    def run(self, state: State) -> tuple[Action | None, Trace]:
        arbiter = self._arbiter
        selected = arbiter.select(self._indexed, state)
        results: list[tuple[Action | None, Trace | None]] = []
        candidates: list[Candidate] = []
        new = tuple.__new__  # Candidate(...) validates arity; this is the hot path.
        quarantined = self._quarantined
        for index, child in selected:
            behavior = child.behavior
            if quarantined and id(behavior) in quarantined:
                results.append((None, Trace(behavior.name, None, fault=(
                    f"QUARANTINED after {self.quarantine_after} failing ticks"))))
                continue
            try:
                result = behavior.run(state)
            except Exception as exc:
                results.append((None, Trace(behavior.name, None, fault=self._failed(
                    behavior, exc))))
                continue
            if self._streaks:
                self._streaks.pop(id(behavior), None)
            results.append(result)
            action = result[0]
            if action is not None and action.vote > 0:
                candidates.append(new(Candidate, (index, child.priority, child.weight, action)))
        action, winners = arbiter.arbitrate(candidates, state)
        return action, Trace._of_composite(
            self.name, action, arbiter.name, selected, results, winners
        )

    def _failed(self, behavior: Behavior, exc: Exception) -> str:
        """Count and log a child that raised on this tick; quarantine it when it keeps
        failing. Returns the fault shown in the trace."""
        name = behavior.name
        n = self.failures[name] = self.failures.get(name, 0) + 1
        streak = self._streaks[id(behavior)] = self._streaks.get(id(behavior), 0) + 1
        if throttle.first_and_every(n):
            log.error("composite %r: child %r raised (failure #%d), abstains this tick",
                      self.name, name, n, exc_info=exc)
        fault = f"FAILED: {type(exc).__name__}: {exc}"[:200]
        if streak >= self.quarantine_after:
            self._quarantined.add(id(behavior))
            log.error("composite %r: child %r failed %d ticks in a row: quarantined until the "
                      "next reset", self.name, name, streak)
            fault += " (now QUARANTINED)"
        return fault

    def describe(self, indent: int = 0) -> str:
        lines = ["  " * indent + f"{self.name} <{self._arbiter.describe()}>"]
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


def _as_child(child: Child | Behavior) -> Child:
    return child if isinstance(child, Child) else Child(child)


def _shutdown_all(behaviors: Iterable[Behavior], composite: str) -> None:
    """Shut each behaviour down; one that raises is logged and the next still runs."""
    for b in behaviors:
        try:
            b.shutdown()
        except Exception:
            log.exception("shutdown of %r in composite %r raised; continuing", b.name, composite)
