"""Genomes: behaviour trees as robot-file data, and the operators that vary them.

A genome is the ``tree:`` node of a robot file as plain data (the dicts and lists YAML gives):
a composite ``{name, arbiter, priority, children}``, a leaf ``{behavior, params, priority}``.
An individual is the seed robot's file with its tree replaced, so every individual is a robot
file; :func:`normalize` gives each tree one canonical form (key order, sibling names made
unique, numbers rounded), whose YAML text is the individual's identity (its hash keys the
cache of its runs).

What may vary is a :class:`Space`, made from the SPEC's ``genome`` section: the behaviours,
arbiters and predicates allowed and, for each parameter, a :class:`Gene` — a fixed value, a
range or a set of choices — that draws and mutates it within the range the SPEC gives (which
the SPEC's check holds within the parameter's schema).

The operators (:data:`OPERATORS`) take the parent's one generator: subtree crossover; the
mutation of a parameter (a behaviour's, an arbiter's, a predicate's, a child's priority or
weight), of an arbiter's kind, of a ``Conditional``'s predicate; the insertion of a node, its
deletion and the shrinking of a composite to one of its children. An operator that does not
apply to a tree (no ``Conditional`` to change, nothing to delete) returns ``None``, and one
whose child breaks ``max_depth`` or ``max_nodes`` is refused by :meth:`Space.fits`: the
caller tries again.
"""

from __future__ import annotations

import copy
import hashlib
import random
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import yaml

__all__ = ["CONDITIONAL", "DECIMALS", "GROUP", "NODE_KEYS", "OPERATORS", "RESAMPLE", "STEP",
           "Choice", "Fixed", "Gene", "Genes", "Node", "Operator", "Path_", "Range", "Space",
           "arbiter_kind", "arbiter_params", "at", "crossover", "delete", "depth", "identity",
           "insert", "is_composite", "mutate_arbiter", "mutate_parameter", "mutate_predicate",
           "named", "normalize", "replaced", "robot_text", "rounded", "shrink", "size", "walk",
           "without_remotes"]

Node = dict[str, Any]
Path_ = tuple[int, ...]
"""A node's place: the child indices from the root."""

CONDITIONAL = "Conditional"
GROUP = "group"
"""The name a new composite gets (made unique among its siblings)."""
NODE_KEYS = ("name", "behavior", "arbiter", "priority", "weight", "params", "children")
"""A node's keys in the canonical order."""
DECIMALS = 3
"""A drawn or mutated float's decimals: a genome's text stays short, and canonical."""
RESAMPLE = 0.2
"""A mutated range's chance of a fresh draw rather than a step."""
STEP = 1 / 6
"""A mutation's step: a normal deviate of this share of the range."""


class Gene(Protocol):
    """How one parameter is drawn and mutated."""

    @property
    def mutable(self) -> bool: ...

    def draw(self, rng: random.Random) -> Any: ...

    def mutate(self, value: Any, rng: random.Random) -> Any: ...


@dataclass(frozen=True, slots=True)
class Fixed:
    """A value the SPEC fixes (``source: camera/front``)."""

    value: Any
    mutable = False

    def draw(self, rng: random.Random) -> Any:
        return copy.deepcopy(self.value)

    def mutate(self, value: Any, rng: random.Random) -> Any:
        return copy.deepcopy(self.value)


@dataclass(frozen=True, slots=True)
class Range:
    """A number between ``low`` and ``high`` (both included): an int when ``integer``."""

    low: float
    high: float
    integer: bool
    mutable = True

    def _clip(self, value: float) -> float | int:
        if self.integer:
            return int(min(self.high, max(self.low, round(value))))
        return min(self.high, max(self.low, round(value, DECIMALS)))

    def draw(self, rng: random.Random) -> float | int:
        if self.integer:
            return rng.randint(int(self.low), int(self.high))
        return self._clip(rng.uniform(self.low, self.high))

    def mutate(self, value: Any, rng: random.Random) -> float | int:
        if rng.random() < RESAMPLE or not isinstance(value, int | float):
            return self.draw(rng)
        stepped = self._clip(value + rng.gauss(0.0, (self.high - self.low) * STEP))
        if self.integer and stepped == value and self.high > self.low:  # a step of at least 1
            stepped = self._clip(value + rng.choice((-1, 1)))
        return stepped


@dataclass(frozen=True, slots=True)
class Choice:
    """One of ``values``."""

    values: tuple[Any, ...]

    @property
    def mutable(self) -> bool:
        return len(self.values) > 1

    def draw(self, rng: random.Random) -> Any:
        return copy.deepcopy(rng.choice(self.values))

    def mutate(self, value: Any, rng: random.Random) -> Any:
        others = [v for v in self.values if v != value]
        return copy.deepcopy(rng.choice(others)) if others else self.draw(rng)


Genes = Mapping[str, Gene]


@dataclass(frozen=True)
class Space:
    """What a genome may hold, and its bounds."""

    behaviors: Mapping[str, Genes]
    arbiters: Mapping[str, Genes]
    predicates: Mapping[str, Genes] = field(default_factory=dict)
    priority: Gene = Fixed(0)
    weight: Gene | None = None
    """``None``: children keep the weight they have (1 when new)."""
    max_depth: int = 4
    max_nodes: int = 15

    # -- drawing --------------------------------------------------------------------------

    def params(self, genes: Genes, rng: random.Random) -> dict[str, Any]:
        return {name: gene.draw(rng) for name, gene in genes.items()}

    def leaf(self, rng: random.Random) -> Node:
        """A behaviour drawn from the allowed ones, with its parameters drawn."""
        kind = rng.choice(sorted(self.behaviors))
        node: Node = {"behavior": kind, "priority": self.priority.draw(rng)}
        if self.weight is not None:
            node["weight"] = self.weight.draw(rng)
        params = self.params(self.behaviors[kind], rng)
        if params:
            node["params"] = params
        return node

    def arbiter(self, rng: random.Random, *, other_than: str | None = None) -> Any:
        """An arbiter drawn (a kind other than ``other_than`` when there is one), its
        parameters drawn: a ``Conditional`` with a predicate drawn."""
        kinds = [k for k in sorted(self.arbiters) if k != other_than] or sorted(self.arbiters)
        kind = rng.choice(kinds)
        if kind == CONDITIONAL:
            return {"type": CONDITIONAL, "params": self.predicate(rng)}
        params = self.params(self.arbiters[kind], rng)
        return {"type": kind, "params": params} if params else kind

    def predicate(self, rng: random.Random, *, other_than: str | None = None) -> dict[str, Any]:
        """``Conditional``'s parameters: a predicate drawn, and its parameters."""
        names = [p for p in sorted(self.predicates) if p != other_than] or sorted(self.predicates)
        name = rng.choice(names)
        params = self.params(self.predicates[name], rng)
        return {"predicate": name, **({"predicate_params": params} if params else {})}

    def composite(self, rng: random.Random, children: list[Node]) -> Node:
        """A new composite over ``children`` (two of them for a ``Conditional``: the first two,
        or a leaf added to one)."""
        node: Node = {"name": GROUP, "arbiter": self.arbiter(rng),
                      "priority": self.priority.draw(rng), "children": children}
        if self.weight is not None:
            node["weight"] = self.weight.draw(rng)
        self.fit_arity(node, rng)
        return node

    def tree(self, rng: random.Random, depth: int) -> Node:
        """A random composite at most ``depth`` deep (grow: each child a leaf or, while depth
        allows, a composite)."""
        count = rng.randint(2, 4)
        children = [self.tree(rng, depth - 1) if depth > 2 and rng.random() < 0.3
                    else self.leaf(rng) for _ in range(count)]
        return self.composite(rng, children)

    def fit_arity(self, node: Node, rng: random.Random) -> None:
        """A ``Conditional`` keeps exactly two children: the first two, or one drawn added."""
        if arbiter_kind(node) == CONDITIONAL:
            children = node["children"]
            del children[2:]
            while len(children) < 2:
                children.append(self.leaf(rng))

    # -- bounds ---------------------------------------------------------------------------

    def fits(self, tree: Node) -> bool:
        return depth(tree) <= self.max_depth and size(tree) <= self.max_nodes

    # -- the genes of a tree --------------------------------------------------------------

    def genes_of(self, tree: Node) -> list[tuple[Path_, str, str]]:
        """Every value of ``tree`` a mutation may change: ``(path, where, name)``, ``where``
        being ``params``, ``arbiter``, ``predicate`` or ``place`` (``priority``/``weight``)."""
        found: list[tuple[Path_, str, str]] = []
        for path, node in walk(tree):
            if path:
                if self.priority.mutable:
                    found.append((path, "place", "priority"))
                if self.weight is not None and self.weight.mutable:
                    found.append((path, "place", "weight"))
            if "behavior" in node:
                genes = self.behaviors.get(node["behavior"], {})
                found += [(path, "params", n) for n, g in genes.items() if g.mutable]
            elif "arbiter" in node:
                kind = arbiter_kind(node)
                if kind == CONDITIONAL:
                    predicate = arbiter_params(node).get("predicate")
                    genes = self.predicates.get(predicate, {}) if isinstance(predicate,
                                                                              str) else {}
                    found += [(path, "predicate", n) for n, g in genes.items() if g.mutable]
                else:
                    genes = self.arbiters.get(kind, {})
                    found += [(path, "arbiter", n) for n, g in genes.items() if g.mutable]
        return found

    def gene(self, node: Node, where: str, name: str) -> Gene:
        if where == "place":
            assert name == "weight" or name == "priority"
            return self.priority if name == "priority" else self.weight or Fixed(1.0)
        if where == "params":
            return self.behaviors[node["behavior"]][name]
        if where == "predicate":
            return self.predicates[arbiter_params(node)["predicate"]][name]
        return self.arbiters[arbiter_kind(node)][name]


# -- trees as data ----------------------------------------------------------------------------

def walk(tree: Node, path: Path_ = ()) -> Iterator[tuple[Path_, Node]]:
    """Every node of ``tree`` with its path, in preorder."""
    yield path, tree
    for i, child in enumerate(tree.get("children") or ()):
        yield from walk(child, (*path, i))


def size(tree: Node) -> int:
    """Nodes in ``tree``: composites and leaves."""
    return 1 + sum(size(c) for c in tree.get("children") or ())


def depth(tree: Node) -> int:
    """Levels of ``tree``: 1 for a leaf."""
    return 1 + max((depth(c) for c in tree.get("children") or ()), default=0)


def at(tree: Node, path: Path_) -> Node:
    node = tree
    for i in path:
        node = node["children"][i]
    return node


def replaced(tree: Node, path: Path_, new: Node) -> Node:
    """A copy of ``tree`` with the node at ``path`` replaced by a copy of ``new``."""
    if not path:
        return copy.deepcopy(new)
    out = copy.deepcopy(tree)
    at(out, path[:-1])["children"][path[-1]] = copy.deepcopy(new)
    return out


def arbiter_kind(node: Node) -> str:
    arbiter = node["arbiter"]
    return str(arbiter["type"] if isinstance(arbiter, dict) else arbiter)


def arbiter_params(node: Node) -> dict[str, Any]:
    arbiter = node["arbiter"]
    return arbiter.setdefault("params", {}) if isinstance(arbiter, dict) else {}


def is_composite(node: Node) -> bool:
    return "arbiter" in node


def without_remotes(tree: Node) -> Node:
    """``tree`` without its ``remote:`` slots: no other process attaches to a simulated run of
    an individual, so they are no part of a genome."""
    out = {k: v for k, v in tree.items() if k != "children"}
    if "children" in tree:
        out["children"] = [without_remotes(c) for c in tree["children"] if "remote" not in c]
    return out


def normalize(tree: Node) -> Node:
    """``tree`` in its canonical form: each node's keys in :data:`NODE_KEYS` order, default
    values left out (priority 0, weight 1, no params), each child's name unique among its
    siblings (``chase``, ``chase_2``: a leaf is named only when its behaviour's name is taken),
    floats of :data:`DECIMALS` decimals. The root keeps its name."""
    def clean(node: Node) -> Node:
        out: Node = {}
        for key in NODE_KEYS:
            if key not in node:
                continue
            value = node[key]
            if (key == "priority" and value == 0) or (key == "weight" and value == 1.0) \
                    or (key == "params" and not value):
                continue
            if key == "children":
                value = named([clean(c) for c in value])
            elif key == "arbiter" and isinstance(value, dict):
                params = rounded(value.get("params") or {})
                value = {"type": value["type"], **({"params": params} if params else {})}
                if not params:
                    value = value["type"]
            elif key in ("params", "weight"):
                value = rounded(value)
            out[key] = value
        return out

    root = clean(tree)
    root.pop("priority", None)  # the root has no parent to be placed in
    root.pop("weight", None)
    return root


def named(children: list[Node]) -> list[Node]:
    """``children`` named from what they are, each name unique among them: a behaviour by its
    own name (``chase``; ``chase_2`` for a second one), a composite ``group``, ``group_2``…
    A behaviour that keeps its own name is not named in the file (the factory's default)."""
    taken: set[str] = set()
    out = []
    for child in children:
        behavior = child.get("behavior")
        base = GROUP if behavior is None else re.sub(r"[^A-Za-z0-9_.-]", "_",
                                                     behavior.rpartition(":")[2])
        name, n = base, 1
        while name in taken:
            n += 1
            name = f"{base}_{n}"
        taken.add(name)
        rest = {k: v for k, v in child.items() if k != "name"}
        plain = behavior is not None and name == behavior  # a registered name, not taken
        out.append(rest if plain else {"name": name, **rest})
    return out


def rounded(value: Any) -> Any:
    if isinstance(value, float):
        return round(value, DECIMALS)
    if isinstance(value, dict):
        return {k: rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [rounded(v) for v in value]
    return value


# -- individuals as robot files ---------------------------------------------------------------

def robot_text(base: Mapping[str, Any], tree: Node) -> str:
    """The robot file of ``tree``: ``base`` (the seed robot's data) with its tree replaced,
    as YAML in one way only (the order of ``base``'s keys, the tree canonical)."""
    data = {k: v for k, v in base.items()}
    data["tree"] = tree
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=100,
                          default_flow_style=False)


def identity(text: str) -> str:
    """An individual's hash: of its robot file's canonical text."""
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# -- operators --------------------------------------------------------------------------------

def _non_root(tree: Node) -> list[Path_]:
    return [p for p, _ in walk(tree) if p]


def crossover(space: Space, rng: random.Random, a: Node, b: Node) -> Node | None:
    """A node of ``a`` (not its root) replaced by a subtree of ``b``."""
    targets = _non_root(a)
    if not targets:
        return None
    target = rng.choice(targets)
    donor = at(b, rng.choice([p for p, _ in walk(b)]))
    return replaced(a, target, donor)


def mutate_parameter(space: Space, rng: random.Random, a: Node, b: Node) -> Node | None:
    """One value changed within its gene: a behaviour's, an arbiter's or a predicate's
    parameter, or a child's priority or weight."""
    genes = space.genes_of(a)
    if not genes:
        return None
    path, where, name = rng.choice(genes)
    out = copy.deepcopy(a)
    node = at(out, path)
    gene = space.gene(node, where, name)
    if where == "place":
        node[name] = gene.mutate(node.get(name, 0 if name == "priority" else 1.0), rng)
    elif where == "params":
        params = node.setdefault("params", {})
        params[name] = gene.mutate(params.get(name), rng)
    elif where == "predicate":
        params = arbiter_params(node).setdefault("predicate_params", {})
        params[name] = gene.mutate(params.get(name), rng)
    else:
        params = arbiter_params(node)
        params[name] = gene.mutate(params.get(name), rng)
    return out


def mutate_arbiter(space: Space, rng: random.Random, a: Node, b: Node) -> Node | None:
    """A composite's arbiter changed to another kind (its parameters drawn; a
    ``Conditional`` keeps two children)."""
    composites = [p for p, n in walk(a) if is_composite(n)]
    path = rng.choice(composites)
    out = copy.deepcopy(a)
    node = at(out, path)
    node["arbiter"] = space.arbiter(rng, other_than=arbiter_kind(node))
    space.fit_arity(node, rng)
    return out


def mutate_predicate(space: Space, rng: random.Random, a: Node, b: Node) -> Node | None:
    """A ``Conditional``'s predicate changed to another (or, with one allowed, its parameters
    drawn anew)."""
    conditionals = [p for p, n in walk(a) if is_composite(n) and arbiter_kind(n) == CONDITIONAL]
    if not conditionals or not space.predicates:
        return None
    out = copy.deepcopy(a)
    node = at(out, rng.choice(conditionals))
    current = arbiter_params(node).get("predicate")
    node["arbiter"] = {"type": CONDITIONAL,
                       "params": space.predicate(rng, other_than=current
                                                 if isinstance(current, str) else None)}
    return out


def insert(space: Space, rng: random.Random, a: Node, b: Node) -> Node | None:
    """A node added: a leaf drawn as a new child of a composite (not a ``Conditional``), or a
    node wrapped in a new composite beside a leaf drawn."""
    out = copy.deepcopy(a)
    open_ = [p for p, n in walk(out) if is_composite(n) and arbiter_kind(n) != CONDITIONAL]
    wrappable = _non_root(out)
    if open_ and (not wrappable or rng.random() < 0.5):
        node = at(out, rng.choice(open_))
        children = node["children"]
        children.insert(rng.randint(0, len(children)), space.leaf(rng))
        return out
    if not wrappable:
        return None
    path = rng.choice(wrappable)
    inner = at(out, path)
    place: dict[str, Any] = {k: inner.pop(k) for k in ("priority", "weight") if k in inner}
    pair = [inner, space.leaf(rng)]
    rng.shuffle(pair)
    wrapper = space.composite(rng, pair)
    wrapper.update(place)  # the wrapper takes the wrapped node's place in its parent
    return replaced(out, path, wrapper)


def delete(space: Space, rng: random.Random, a: Node, b: Node) -> Node | None:
    """A node removed from a composite that keeps at least one child (not from a
    ``Conditional``, which needs its two)."""
    candidates = [p for p in _non_root(a)
                  if arbiter_kind(parent := at(a, p[:-1])) != CONDITIONAL
                  and len(parent["children"]) > 1]
    if not candidates:
        return None
    path = rng.choice(candidates)
    out = copy.deepcopy(a)
    del at(out, path[:-1])["children"][path[-1]]
    return out


def shrink(space: Space, rng: random.Random, a: Node, b: Node) -> Node | None:
    """A composite replaced by one of its children (the root only by a composite child: a
    tree's root is a composite)."""
    candidates = [(p, i) for p, n in walk(a) if is_composite(n)
                  for i, c in enumerate(n["children"]) if p or is_composite(c)]
    if not candidates:
        return None
    path, index = rng.choice(candidates)
    node = at(a, path)
    child = copy.deepcopy(node["children"][index])
    if not path:
        child["name"] = node["name"]  # the root keeps its name
        child.pop("priority", None)
        child.pop("weight", None)
    else:
        for key in ("priority", "weight"):  # the child takes the composite's place
            child.pop(key, None)
            if key in node:
                child[key] = node[key]
    return replaced(a, path, child)


Operator = Callable[[Space, random.Random, Node, Node], Node | None]

OPERATORS: dict[str, Operator] = {
    "crossover": crossover,
    "parameter": mutate_parameter,
    "arbiter": mutate_arbiter,
    "predicate": mutate_predicate,
    "insert": insert,
    "delete": delete,
    "shrink": shrink,
}
"""Each operator by the name the SPEC's ``operators`` weighs it by. ``b`` is the second parent
(crossover's donor; the others ignore it)."""
