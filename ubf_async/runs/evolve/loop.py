"""The evolution: a generational GP loop on the standard library, reproducible and resumable.

One :class:`random.Random`, seeded by the SPEC's ``seed``, is the only source of chance, and
only this process draws from it: the first population, every selection, every operator.
Evaluations are pure (a run is a function of its robot file, scenario and seed), and come back
keyed by their run, so which worker ran what — one, several, a Ray cluster — changes nothing:
the same SPEC and seed give the same log and the same best robot, byte for byte.

Each generation ends with a checkpoint, ``DIR/checkpoint.json``, written whole: the
population's trees, the hall of fame, the Pareto front, the log so far and the generator's
state. ``resume`` starts from it — the population's fitness read back from the journal, the
runs of a generation cut short by a kill found there too — and goes on exactly as the
uninterrupted evolution would have.

Per generation: the elites (the best, distinct) are kept as they are; every other child is
made by an operator drawn by the SPEC's weights from parents chosen by tournament, on fitness
less ``parsimony`` × its size (bloat control beside ``max_depth`` and ``max_nodes``). A child
that is not a robot file the loader takes, that breaks the bounds, or that is already in the
new population is drawn again (at most :data:`TRIES` times, then its parent is copied).
"""

from __future__ import annotations

import json
import random
import statistics
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ubf_async.assembly.robotfile import load_robot_text
from ubf_async.errors import ConfigurationError, RobotFileError
from ubf_async.runs.evolve import genome
from ubf_async.runs.evolve.fitness import Evaluation, Evaluator
from ubf_async.runs.evolve.spec import EvolvePlan
from ubf_async.runs.sweep import table

__all__ = ["CHECKPOINT", "FORMAT", "MUTATIONS", "TRIES", "Evolution", "Individual", "State",
           "load_checkpoint", "log_entry", "pareto_front", "save_checkpoint", "write_log"]

CHECKPOINT = "checkpoint.json"
LOG = "log.jsonl"
FORMAT = 1
TRIES = 20
MUTATIONS = ("parameter", "arbiter", "predicate", "insert", "delete", "shrink")
"""The operators that make a first population's mutants of the seed robot."""


@dataclass(slots=True)
class Individual:
    """A tree, its robot file and, once evaluated, its fitness."""

    tree: genome.Node
    text: str
    hash: str
    size: int
    evaluation: Evaluation | None = None

    @classmethod
    def of(cls, plan: EvolvePlan, tree: genome.Node) -> Individual:
        """``tree`` as an individual of ``plan``: canonical, its root named as the seed's."""
        tree = genome.normalize({**tree, "name": plan.seed_tree["name"]})
        text = plan.text_of(tree)
        return cls(tree, text, genome.identity(text), genome.size(tree))

    @property
    def fitness(self) -> float:
        assert self.evaluation is not None, "evaluated first"
        return self.evaluation.fitness

    def rank(self) -> tuple[float, int, str]:
        """Best first: fitness, then the smaller, then by hash (one order, always)."""
        return (-self.fitness, self.size, self.hash)

    def entry(self) -> dict[str, Any]:
        assert self.evaluation is not None
        return {"hash": self.hash, "size": self.size, **self.evaluation.as_json()}


@dataclass(slots=True)
class State:
    """An evolution after a generation was evaluated: what a checkpoint holds."""

    generation: int
    population: list[Individual]
    rng: random.Random
    hall_of_fame: list[Individual] = field(default_factory=list)
    pareto: list[Individual] = field(default_factory=list)
    log: list[dict[str, Any]] = field(default_factory=list)


# -- checkpoints ------------------------------------------------------------------------------

def _rng_state(rng: random.Random) -> list[Any]:
    version, internal, gauss = rng.getstate()
    return [version, list(internal), gauss]


def _rng_from(state: list[Any]) -> random.Random:
    rng = random.Random()
    rng.setstate((state[0], tuple(state[1]), state[2]))
    return rng


def save_checkpoint(path: Path, plan: EvolvePlan, state: State) -> None:
    data = {"format": FORMAT, "evolution": plan.identity, "generation": state.generation,
            "rng": _rng_state(state.rng),
            "population": [i.tree for i in state.population],
            "hall_of_fame": [i.tree for i in state.hall_of_fame],
            "pareto": [i.tree for i in state.pareto], "log": state.log}
    table.write_whole(path, json.dumps(data, separators=(",", ":"), ensure_ascii=False))


def load_checkpoint(path: Path, plan: EvolvePlan) -> State:
    """The state a checkpoint holds, its individuals not evaluated yet. Raises
    :class:`ConfigurationError` for a checkpoint of another evolution."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigurationError(f"{path}: cannot read the checkpoint: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ConfigurationError(f"{path}: not an evolution's checkpoint")
    if data.get("evolution") != plan.identity:
        raise ConfigurationError(
            f"{path}: the checkpoint of another evolution (its SPEC, seed robot, seed or "
            f"population differ from {plan.source}'s); choose another folder")

    def individuals(trees: Iterable[genome.Node]) -> list[Individual]:
        return [Individual.of(plan, tree) for tree in trees]

    return State(generation=data["generation"], population=individuals(data["population"]),
                 rng=_rng_from(data["rng"]), hall_of_fame=individuals(data["hall_of_fame"]),
                 pareto=individuals(data["pareto"]), log=data["log"])


# -- the loop ---------------------------------------------------------------------------------

class Evolution:
    """One evolution into ``out_dir`` on an evaluator: :meth:`start` or :meth:`resume`, then
    :meth:`step` until :attr:`done`."""

    def __init__(self, plan: EvolvePlan, out_dir: Path, evaluator: Evaluator, *,
                 on_generation: Callable[[dict[str, Any]], None] | None = None) -> None:
        self.plan = plan
        self.out = out_dir
        self.evaluator = evaluator
        self.on_generation = on_generation
        self.state: State | None = None

    @property
    def checkpoint(self) -> Path:
        return self.out / CHECKPOINT

    @property
    def done(self) -> bool:
        return self.state is not None and self.state.generation + 1 >= self.plan.generations

    def evaluate(self, individuals: Sequence[Individual]) -> None:
        runs = [self.plan.training.tasks(i.text, f"{i.hash}.yaml") for i in individuals]
        for individual, evaluation in zip(individuals, self.evaluator.evaluate(runs),
                                          strict=True):
            individual.evaluation = evaluation

    def start(self) -> None:
        rng = random.Random(self.plan.seed)
        population = self.first_population(rng)
        self.evaluate(population)
        self.state = State(0, population, rng)
        self._close_generation(Counter({"seed": 1, "first": len(population) - 1}))

    def resume(self) -> None:
        state = load_checkpoint(self.checkpoint, self.plan)
        self.evaluate([*state.population, *state.hall_of_fame, *state.pareto])
        self.state = state
        write_log(self.out / LOG, state.log)  # without a generation past the checkpoint

    def step(self) -> None:
        """Breed, evaluate and checkpoint the next generation."""
        state = self.state
        assert state is not None and not self.done
        children, made = self.breed(state.population, state.rng)
        self.evaluate(children)
        state.population = children
        state.generation += 1
        self._close_generation(made)

    def _close_generation(self, made: Counter[str]) -> None:
        state = self.state
        assert state is not None
        everyone = _distinct([*state.hall_of_fame, *state.population])
        state.hall_of_fame = sorted(everyone, key=Individual.rank)[:self.plan.spec.hall_of_fame]
        state.pareto = pareto_front([*state.pareto, *state.population])
        entry = log_entry(state, made)
        state.log.append(entry)
        write_log(self.out / LOG, state.log)
        save_checkpoint(self.checkpoint, self.plan, state)
        if self.on_generation is not None:
            self.on_generation(entry)

    # -- making individuals -------------------------------------------------------------------

    def valid(self, tree: genome.Node | None, taken: set[str]) -> Individual | None:
        """``tree`` as an individual if it is one: a composite root within the bounds, new
        to ``taken``, and a robot file the loader takes."""
        if tree is None or not genome.is_composite(tree) or not self.plan.space.fits(tree):
            return None
        individual = Individual.of(self.plan, tree)
        if individual.hash in taken:
            return None
        try:
            load_robot_text(individual.text, source=f"{individual.hash}.yaml")
        except RobotFileError:
            return None
        return individual

    def first_population(self, rng: random.Random) -> list[Individual]:
        """The seed robot, then mutants of it and random trees, one of each in turn."""
        seed = Individual.of(self.plan, self.plan.seed_tree)
        population, taken = [seed], {seed.hash}
        space = self.plan.space
        while len(population) < self.plan.population:
            made = None
            for _ in range(TRIES):
                if len(population) % 2:
                    tree = self.plan.seed_tree
                    for _ in range(rng.randint(1, 3)):
                        step = genome.OPERATORS[rng.choice(MUTATIONS)](space, rng, tree, tree)
                        tree = step if step is not None else tree
                else:
                    tree = space.tree(rng, min(space.max_depth, 3))
                made = self.valid(tree, taken)
                if made is not None:
                    break
            if made is None:  # the bounds leave little room: a copy
                made = Individual.of(self.plan, self.plan.seed_tree)
            population.append(made)
            taken.add(made.hash)
        return population

    def select(self, population: Sequence[Individual], rng: random.Random) -> Individual:
        """A tournament on fitness less the parsimony term."""
        parsimony = self.plan.spec.parsimony
        picks = [population[rng.randrange(len(population))]
                 for _ in range(self.plan.spec.tournament)]
        return min(picks, key=lambda i: (-(i.fitness - parsimony * i.size), i.size, i.hash))

    def breed(self, population: Sequence[Individual],
              rng: random.Random) -> tuple[list[Individual], Counter[str]]:
        spec = self.plan.spec
        children = _distinct(sorted(population, key=Individual.rank))[:spec.elites]
        made: Counter[str] = Counter({"elite": len(children)})
        taken = {c.hash for c in children}
        weights = {name: w for name, w in
                   ((n, getattr(spec.operators, n)) for n in genome.OPERATORS) if w > 0}
        names, values = list(weights), list(weights.values())
        while len(children) < self.plan.population:
            child = None
            for _ in range(TRIES):
                operator = rng.choices(names, values)[0]
                a = self.select(population, rng)
                b = self.select(population, rng) if operator == "crossover" else a
                child = self.valid(genome.OPERATORS[operator](self.plan.space, rng, a.tree,
                                                              b.tree), taken)
                if child is not None:
                    made[operator] += 1
                    break
            if child is None:
                child = Individual.of(self.plan, a.tree)
                made["copy"] += 1
            children.append(child)
            taken.add(child.hash)
        return children, made


def _distinct(individuals: Iterable[Individual]) -> list[Individual]:
    seen: set[str] = set()
    out = []
    for individual in individuals:
        if individual.hash not in seen:
            seen.add(individual.hash)
            out.append(individual)
    return out


def pareto_front(individuals: Iterable[Individual]) -> list[Individual]:
    """The individuals no other beats on both fitness and size (smallest first)."""
    front: list[Individual] = []
    for individual in sorted(_distinct(individuals), key=lambda i: (i.size, -i.fitness, i.hash)):
        if not front or individual.fitness > front[-1].fitness:
            front.append(individual)
    return front


def log_entry(state: State, made: Counter[str]) -> dict[str, Any]:
    """A generation's line of the log: nothing of how or where it ran."""
    population = state.population
    best = min(population, key=Individual.rank)
    fitnesses = [i.fitness for i in population]
    sizes = [i.size for i in population]
    return {"generation": state.generation, "best": best.entry(),
            "fitness": {"mean": table.significant(statistics.fmean(fitnesses)),
                        "median": table.significant(statistics.median(fitnesses))},
            "size": {"mean": table.significant(statistics.fmean(sizes)), "min": min(sizes),
                     "max": max(sizes)},
            "failed": sum(1 for i in population if i.evaluation and i.evaluation.failed),
            "distinct": len({i.hash for i in population}),
            "children": dict(sorted(made.items())),
            "hall_of_fame": state.hall_of_fame[0].entry()}


def write_log(path: Path, entries: Sequence[dict[str, Any]]) -> None:
    table.write_whole(path, "".join(json.dumps(e, ensure_ascii=False, separators=(",", ":"))
                                    + "\n" for e in entries))
