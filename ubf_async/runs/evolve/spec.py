"""An evolution's SPEC file (docs/evolve.md), checked whole before anything runs.

:func:`load_evolve` decodes the SPEC (its form: unknown keys, types, ranges) and checks what
decoding cannot: every behaviour, arbiter and predicate named is registered; every parameter's
range or value is one its schema accepts (the robot-file loader's own check, at both ends of
a range); every scenario — named or generated — is one the simulator loads and runs with the
seed robot; every fitness figure is a field of a run's summary (a run of a tenth of a
simulated second says which fields there are); the ``tune`` section's paths lead into the
robot file and its ranges load. A mistake is refused as ``SPEC:LINE: message`` (a
:class:`~ubf_async.errors.RobotFileError`, as a sweep spec's are).
"""

from __future__ import annotations

import hashlib
import json
import random
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

import msgspec
import msgspec.inspect
import yaml
from msgspec import Meta

from ubf_async.assembly.registry import (
    ARBITERS,
    BEHAVIORS,
    PREDICATES,
    checked_params,
    parameters_of,
)
from ubf_async.assembly.robotfile import (
    INJECTED_TREE,
    MAX_DEPTH,
    YAML_LOADER,
    Path_,
    Robot,
    Spec,
    format_path,
    load_robot_text,
    read_robot_file,
)
from ubf_async.errors import EvolveSpecError, ParameterError, PluginError, RobotFileError, UbfError
from ubf_async.runs import inprocess, overrides
from ubf_async.runs.evolve import genome, scenarios
from ubf_async.runs.evolve.fitness import Fitness, Term, task
from ubf_async.runs.evolve.scenarios import Generated
from ubf_async.runs.sweep import execution
from ubf_async.runs.sweep.spec import (
    FIGURE,
    Checker,
    RunTask,
    decode_spec,
    figure_problem,
    probe_summary,
    read_scenario,
)

DEFAULT_SEED_ROBOT = "mini-whegs"
DEFAULT_DURATION_S = 20.0
"""A generated scenario's simulated seconds when its set gives none."""

Figure = Annotated[str, Meta(pattern=FIGURE, max_length=200)]
Seed = Annotated[int, Meta(ge=0, le=2**63 - 1)]
Name = Annotated[str, Meta(min_length=1, max_length=500)]
Span = tuple[float, float]
Weight = Annotated[float, Meta(ge=0.0, le=1e6)]


class GeneratorSpec(Spec):
    """``{generate: random, count: 3, distance_m: [0.5, 1.2]}``."""

    what: ClassVar[str] = "a scenario generator"

    generate: Literal["random", "behind", "fov_edge", "moving"]
    count: Annotated[int, Meta(ge=1, le=1000)] = 1
    distance_m: Span | None = None
    bearing_deg: Span | None = None
    speed_m_s: Span | None = None
    at_s: Span | None = None


class ScenarioSetSpec(Spec):
    """A set of scenarios × seeds: named scenarios and generators."""

    what: ClassVar[str] = "a scenario set"
    lists: ClassVar[Mapping[str, str]] = {"scenarios": "scenarios", "seeds": "seeds"}

    scenarios: Annotated[list[Name | GeneratorSpec], Meta(min_length=1)]
    seeds: Annotated[list[Seed], Meta(min_length=1)]
    seed: Seed = 0
    """Of the generators: the same seed, the same scenario files."""
    duration_s: Annotated[float, Meta(gt=0.0, le=1e5)] | None = None
    """Simulated seconds of each run (default: a named scenario's own, a generated one's
    20)."""


class TermSpec(Spec):
    what: ClassVar[str] = "a fitness term"

    figure: Figure
    weight: Annotated[float, Meta(ge=-1e6, le=1e6)]
    target: float | None = None
    missing: float = 0.0


class FitnessSpec(Spec):
    what: ClassVar[str] = "`fitness`"

    terms: Annotated[list[TermSpec], Meta(min_length=1)]
    mean: Weight = 1.0
    worst: Weight = 0.0


class GenomeSpec(Spec):
    what: ClassVar[str] = "`genome`"

    behaviors: Annotated[dict[str, dict[str, Any]], Meta(min_length=1)]
    arbiters: Annotated[dict[str, dict[str, Any]], Meta(min_length=1)]
    predicates: dict[str, dict[str, Any]] = msgspec.field(default_factory=dict)
    priorities: tuple[int, int] = (0, 0)
    weights: Span | None = None
    max_depth: Annotated[int, Meta(ge=2, le=MAX_DEPTH)] = 4
    max_nodes: Annotated[int, Meta(ge=2, le=500)] = 15


class OperatorsSpec(Spec):
    """Each operator's weight: how often it makes a child."""

    what: ClassVar[str] = "`operators`"

    crossover: Weight = 4.0
    parameter: Weight = 4.0
    arbiter: Weight = 1.0
    predicate: Weight = 1.0
    insert: Weight = 1.0
    delete: Weight = 1.0
    shrink: Weight = 1.0


class TuneSpec(Spec):
    what: ClassVar[str] = "`tune`"

    parameters: Annotated[dict[str, tuple[int | float, int | float]], Meta(min_length=1)]
    """A path into the robot file → the range to tune it in (ints at both ends, for a
    parameter that is not a float in the file: an int)."""
    robot: Name | None = None
    """The robot file tuned (default: ``seed_robot``)."""
    trials: Annotated[int, Meta(ge=1, le=100_000)] = 30
    sampler: Literal["tpe", "cmaes"] = "tpe"


class EvolveFile(Spec):
    """An evolution SPEC as written."""

    what: ClassVar[str] = "an evolution spec"

    genome: GenomeSpec
    training: ScenarioSetSpec
    held_out: ScenarioSetSpec
    fitness: FitnessSpec
    seed_robot: Name = DEFAULT_SEED_ROBOT
    seed: Seed = 0
    population: Annotated[int, Meta(ge=2, le=100_000)] = 20
    generations: Annotated[int, Meta(ge=1, le=100_000)] = 10
    elites: Annotated[int, Meta(ge=0)] = 2
    tournament: Annotated[int, Meta(ge=1)] = 3
    parsimony: Annotated[float, Meta(ge=0.0, le=1e6)] = 0.0
    """Fitness taken off per node of a tree when selecting (not in the reported fitness)."""
    hall_of_fame: Annotated[int, Meta(ge=1, le=1000)] = 5
    operators: OperatorsSpec = msgspec.field(default_factory=OperatorsSpec)
    tune: TuneSpec | None = None


# -- the checked plan -------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class ScenarioSet:
    """A checked set: its scenarios (``(name, file text or None for a built-in)``), the files
    its generators made, its seeds and duration."""

    label: str
    scenarios: tuple[tuple[str, str | None], ...]
    generated: tuple[Generated, ...]
    seeds: tuple[int, ...]
    duration_s: float | None

    def tasks(self, robot_text: str, robot_source: str,
              overrides: tuple[tuple[str, Any], ...] = ()) -> list[RunTask]:
        """A robot file's runs of this set, scenario by scenario, seed by seed."""
        return [task(robot_text=robot_text, robot_source=robot_source, scenario=name,
                     scenario_text=text, seed=seed, duration_s=self.duration_s,
                     order=(s, k), overrides=overrides)
                for s, (name, text) in enumerate(self.scenarios)
                for k, seed in enumerate(self.seeds)]

    @property
    def runs(self) -> int:
        return len(self.scenarios) * len(self.seeds)

    def describe(self) -> str:
        return (f"{len(self.scenarios)} scenarios × {len(self.seeds)} seeds"
                + (f", {self.duration_s:g} s each" if self.duration_s else ""))


@dataclass(frozen=True, slots=True)
class TunePlan:
    robot_text: str
    robot_source: str
    parameters: tuple[tuple[str, float, float, bool], ...]
    """``(path, low, high, integer)``."""
    start: dict[str, float]
    """The robot file's own values of the parameters, where in range (the first trial)."""
    trials: int
    sampler: str
    names: dict[str, str]
    """Each parameter's path → the name it is shown by (``search.period_s``:
    :func:`~ubf_async.runs.overrides.readable_name`)."""


@dataclass(frozen=True, slots=True)
class EvolvePlan:
    """A checked SPEC: everything an evolution or a study needs."""

    source: Path
    spec: EvolveFile
    seed_source: str
    base: dict[str, Any]
    """The seed robot's file as data, without its tree: every individual's devices,
    controller and the rest."""
    seed_tree: genome.Node
    space: genome.Space
    training: ScenarioSet
    held_out: ScenarioSet
    fitness: Fitness
    tune: TunePlan | None
    identity: str
    """A digest of what makes an evolution: the seed robot's text, the training set's
    scenarios and everything of the SPEC but the held-out set, the ``tune`` section and the
    generations (a resumed evolution may go on further)."""

    @property
    def seed(self) -> int:
        return self.spec.seed

    @property
    def population(self) -> int:
        return self.spec.population

    @property
    def generations(self) -> int:
        return self.spec.generations

    def text_of(self, tree: genome.Node) -> str:
        return genome.robot_text(self.base, tree)

    def seed_text(self) -> str:
        return self.text_of(self.seed_tree)


# -- loading ----------------------------------------------------------------------------------

def load_evolve(path: str | Path, *, seed: int | None = None, population: int | None = None,
                generations: int | None = None, seed_robot: str | None = None,
                probe: bool = True) -> EvolvePlan:
    """Read and check an evolution SPEC; the arguments given replace its own values (the
    command line's flags). ``probe=False`` skips the run that checks the fitness figures.
    Raises :class:`EvolveSpecError` (``SPEC:LINE: …``) or
    :class:`~ubf_async.errors.ConfigurationError`."""
    source = Path(path)
    spec, locator = decode_spec(source, EvolveFile, EvolveSpecError, what="evolution spec")
    changes = {k: v for k, v in (("seed", seed), ("population", population),
                                 ("generations", generations), ("seed_robot", seed_robot))
               if v is not None}
    check = Checker(locator, EvolveSpecError)
    if changes:
        try:
            spec = msgspec.convert(msgspec.to_builtins(msgspec.structs.replace(spec, **changes)),
                                   EvolveFile)
        except msgspec.ValidationError as exc:
            raise EvolveSpecError(f"{', '.join(changes)}: {exc}", path=str(source)) from None
    _check_budget(spec, check)
    seed_source, seed_text = _seed_robot(spec, source.parent, check, "seed_robot" in changes)
    data = yaml.load(seed_text, Loader=YAML_LOADER)
    # No other process joins an individual's simulated run: neither the remote slots nor the
    # ROS 2 bridge (whose slot is one of them) are part of a genome.
    base = {k: v for k, v in data.items() if k not in ("tree", "ros2")}
    seed_tree = genome.normalize(genome.without_remotes(data["tree"]))
    space = _space(spec.genome, check)
    plan_check = _PlanCheck(check, base, source.parent)
    first = plan_check.individual(seed_tree, ("seed_robot",), "the seed robot")
    plan_check.leaves(space, spec.genome)
    training = plan_check.scenario_set(spec.training, "training", first)
    held_out = plan_check.scenario_set(spec.held_out, "held-out", first)
    fitness = Fitness(tuple(Term(t.figure, t.weight, t.target, t.missing)
                            for t in spec.fitness.terms), spec.fitness.mean, spec.fitness.worst)
    if probe:
        plan_check.figures(spec.fitness, first, training)
    tune = _tune(spec, seed_source, seed_text, source.parent, check)
    # What makes the evolution (not the held-out set, the tune section, the generations):
    # changing it makes a checkpoint another evolution's; the generated scenarios' texts stand
    # for the generators' code.
    made = {k: v for k, v in msgspec.to_builtins(spec).items()
            if k not in ("held_out", "tune", "generations", "seed_robot")}
    identity = hashlib.sha256(json.dumps(
        [made, seed_text, training.scenarios], sort_keys=True).encode()).hexdigest()[:16]
    return EvolvePlan(source=source, spec=spec, seed_source=seed_source, base=base,
                      seed_tree=seed_tree, space=space, training=training, held_out=held_out,
                      fitness=fitness, tune=tune, identity=identity)


def _check_budget(spec: EvolveFile, check: Checker) -> None:
    if spec.elites >= spec.population:
        raise check.error(f"elites: {spec.elites} elites leave no room for a child in a "
                          f"population of {spec.population}", ("elites",))
    if spec.tournament > spec.population:
        raise check.error(f"tournament: {spec.tournament} is more than the population "
                          f"({spec.population})", ("tournament",))
    weights = msgspec.structs.asdict(spec.operators)
    if not any(weights.values()):
        raise check.error("operators: every weight is 0: no child could be made",
                          ("operators",))
    if spec.genome.priorities[0] > spec.genome.priorities[1]:
        raise check.error("priorities: the low end is above the high end",
                          ("genome", "priorities"))
    if spec.genome.weights is not None and not 0 <= spec.genome.weights[0] \
            <= spec.genome.weights[1]:
        raise check.error("weights: expected 0 ≤ low ≤ high", ("genome", "weights"))


def _seed_robot(spec: EvolveFile, spec_dir: Path, check: Checker,
                given: bool) -> tuple[str, str]:
    """``(source, text)`` of the seed robot: a file relative to the SPEC (or to here, when
    given on the command line), or a shipped robot's name; refused unless it loads."""
    name = spec.seed_robot
    beside = spec_dir / name
    target: str | Path = beside if not given and beside.is_file() else name
    try:
        text, source = read_robot_file(target)
        load_robot_text(text, source=source)
    except RobotFileError as exc:
        if given:
            raise
        raise check.error(f"seed_robot {name!r}: {exc}", ("seed_robot",)) from None
    return source, text


# -- the genome's space -----------------------------------------------------------------------

def _numeric(factory: Any, name: str, injected: frozenset[str]) -> str | None:
    """``"int"`` or ``"float"``: the type the schema of ``factory`` gives parameter ``name``
    (``None``: not a number, or no such parameter)."""
    struct = parameters_of(factory, injected=injected)
    info = msgspec.inspect.type_info(struct)
    assert isinstance(info, msgspec.inspect.StructType)
    for field_ in info.fields:
        if field_.name != name:
            continue
        kinds = set()
        stack: list[msgspec.inspect.Type] = [field_.type]
        while stack:
            t = stack.pop()
            if isinstance(t, msgspec.inspect.Metadata):
                stack.append(t.type)
            elif isinstance(t, msgspec.inspect.UnionType):
                stack += t.types
            elif isinstance(t, msgspec.inspect.IntType):
                kinds.add("int")
            elif isinstance(t, msgspec.inspect.FloatType):
                kinds.add("float")
        return "float" if "float" in kinds else "int" if "int" in kinds else None
    return None


def _gene(factory: Any, name: str, value: Any, *, injected: frozenset[str], what: str,
          check: Checker, at: Path_) -> genome.Gene:
    """The gene the SPEC gives parameter ``name`` of ``factory``: ``[low, high]`` a range,
    ``{choices: [...]}`` a choice, anything else a fixed value — each value it can take
    checked against the parameter's schema."""
    def accepted(v: Any, told: str, written: Any = None) -> None:
        try:
            checked_params(factory, {name: v}, injected=injected, what=what)
        except ParameterError as refusal:
            shown = v if written is None else written
            raise check.error(f"{what}: {told} {shown!r}: {refusal.problem}"
                              + (f"; it takes: {', '.join(refusal.takes)}"
                                 if refusal.takes else ""), at) from None
        except PluginError as exc:
            raise check.error(f"{what}: {exc}", at) from None

    if isinstance(value, list) and len(value) == 2 and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in value):
        kind = _numeric(factory, name, injected)
        if kind is None:
            accepted(value, "value")  # not a number: the schema says what it takes
            raise check.error(f"{what}: {name} is not a number: give one value, or "
                              f"{{choices: [...]}}", at)
        low, high = value
        if low > high:
            raise check.error(f"{what}: {name}: the range's low end {low!r} is above its "
                              f"high end {high!r}", at)
        if kind == "int" and not all(float(v).is_integer() for v in value):
            raise check.error(f"{what}: {name} is an int: give its range as ints", at)
        for end, told in ((low, "the range's low end"), (high, "the range's high end")):
            accepted(int(end) if kind == "int" else float(end), told, end)
        return genome.Range(low, high, integer=kind == "int")
    if isinstance(value, dict) and set(value) == {"choices"}:
        choices = value["choices"]
        if not isinstance(choices, list) or not choices:
            raise check.error(f"{what}: {name}: choices must be a list of values", at)
        for choice in choices:
            accepted(choice, "choice")
        return genome.Choice(tuple(choices))
    accepted(value, "value")
    return genome.Fixed(value)


def _genes(registry_get: Any, section: str, name: str, params: dict[str, Any],
           injected: frozenset[str], check: Checker) -> dict[str, genome.Gene]:
    try:
        factory = registry_get(name)
    except PluginError as exc:
        raise check.error(str(exc), ("genome", section), key=name) from None
    what = f"{section[:-1]} {name!r}" if section != "behaviors" else f"behaviour {name!r}"
    return {param: _gene(factory, param, value, injected=injected, what=what, check=check,
                         at=("genome", section, name, param))
            for param, value in params.items()}


def _space(spec: GenomeSpec, check: Checker) -> genome.Space:
    behaviors = {name: _genes(BEHAVIORS.get, "behaviors", name, params, INJECTED_TREE, check)
                 for name, params in spec.behaviors.items()}
    arbiters: dict[str, dict[str, genome.Gene]] = {}
    for name, params in spec.arbiters.items():
        if name == genome.CONDITIONAL:
            if params:
                raise check.error("Conditional: its parameters are its predicate's: give "
                                  "those under genome.predicates", ("genome", "arbiters"),
                                  key=name)
            if not spec.predicates:
                raise check.error("Conditional needs a predicate to choose by: give "
                                  "genome.predicates", ("genome", "arbiters"), key=name)
            ARBITERS.get(name)
            arbiters[name] = {}
            continue
        arbiters[name] = _genes(ARBITERS.get, "arbiters", name, params, INJECTED_TREE, check)
    predicates = {name: _genes(PREDICATES.get, "predicates", name, params, frozenset(), check)
                  for name, params in spec.predicates.items()}
    low, high = spec.priorities
    return genome.Space(
        behaviors=behaviors, arbiters=arbiters, predicates=predicates,
        priority=genome.Range(low, high, integer=True) if high > low else genome.Fixed(low),
        weight=None if spec.weights is None else genome.Range(*spec.weights, integer=False),
        max_depth=spec.max_depth, max_nodes=spec.max_nodes)


# -- what needs the robot file loader and the simulator ---------------------------------------

class _PlanCheck:
    def __init__(self, check: Checker, base: dict[str, Any], spec_dir: Path) -> None:
        self.check = check
        self.base = base
        self.spec_dir = spec_dir

    def individual(self, tree: genome.Node, at: Path_, what: str) -> Robot:
        text = genome.robot_text(self.base, tree)
        try:
            return load_robot_text(text, source=what)
        except RobotFileError as exc:
            raise self.check.error(f"{what} does not load as a robot file: {exc.message}",
                                   at) from None

    def leaves(self, space: genome.Space, spec: GenomeSpec) -> None:
        """One tree per behaviour, arbiter and predicate allowed, drawn and loaded: what a
        parameter's schema alone cannot say (a parameter the factory requires, values that
        only together are refused) is said here, at the SPEC's line."""
        rng = random.Random(0)
        for name, genes in space.behaviors.items():
            leaf: genome.Node = {"behavior": name, "params": space.params(genes, rng)}
            self.individual({"name": "root", "arbiter": "PriorityMerge", "children": [leaf]},
                            ("genome", "behaviors", name), f"behaviour {name!r}")
        any_leaf = {"behavior": next(iter(space.behaviors)),
                    "params": space.params(next(iter(space.behaviors.values())), rng)}
        for name, genes in space.arbiters.items():
            if name == genome.CONDITIONAL:
                continue
            params = space.params(genes, rng)
            arbiter = {"type": name, "params": params} if params else name
            self.individual({"name": "root", "arbiter": arbiter, "children": [any_leaf]},
                            ("genome", "arbiters", name), f"arbiter {name!r}")
        for name, genes in space.predicates.items():
            params = space.params(genes, rng)
            arbiter = {"type": genome.CONDITIONAL, "params": {
                "predicate": name, **({"predicate_params": params} if params else {})}}
            twin = {**any_leaf, "name": "other"}
            self.individual({"name": "root", "arbiter": arbiter, "children": [any_leaf, twin]},
                            ("genome", "predicates", name), f"predicate {name!r}")

    def scenario_set(self, spec: ScenarioSetSpec, label: str, robot: Robot) -> ScenarioSet:
        section = "training" if label == "training" else "held_out"
        rng = random.Random(spec.seed)
        named: list[tuple[str, str | None]] = []
        generated: list[Generated] = []
        counts: dict[str, int] = {}
        for i, item in enumerate(spec.scenarios):
            at: Path_ = (section, "scenarios", i)
            if isinstance(item, str):
                named.append(read_scenario(item, self.spec_dir, self.check, at))
                continue
            ranges: dict[str, tuple[float, float]] = {}
            for key in ("distance_m", "bearing_deg", "speed_m_s", "at_s"):
                span = getattr(item, key)
                if span is None:
                    continue
                if key not in scenarios.DEFAULTS[item.generate]:
                    raise self.check.error(f"generator {item.generate!r} takes no {key}", at,
                                           key=key)
                if span[0] > span[1]:
                    raise self.check.error(f"{key}: the low end is above the high end", at,
                                           key=key)
                ranges[key] = span
            made = scenarios.generate(item.generate, item.count, rng=rng, prefix=label,
                                      duration_s=spec.duration_s or DEFAULT_DURATION_S,
                                      ranges=ranges, start=counts.get(item.generate, 0))
            counts[item.generate] = counts.get(item.generate, 0) + item.count
            generated += made
            named += [(g.file_name, g.text) for g in made]
        seen: dict[str, int] = {}
        for i, (name, _) in enumerate(named):
            if name in seen:
                raise self.check.error(f"scenario {name!r} twice in the set",
                                       (section, "scenarios"))
            seen[name] = i
        if len(set(spec.seeds)) != len(spec.seeds):
            raise self.check.error("a seed twice in the set", (section, "seeds"))
        made_set = ScenarioSet(label, tuple(named), tuple(generated), tuple(spec.seeds),
                               spec.duration_s)
        for i, (name, text) in enumerate(named):
            try:
                inprocess.plan_run(robot, execution.scenario_path(name, text),
                                   seed=spec.seeds[0], duration_s=spec.duration_s)
            except UbfError as exc:
                at = (section, "scenarios", _item_of(spec, i))
                raise self.check.error(f"scenario {name!r}: {exc}", at) from None
        return made_set

    def figures(self, spec: FitnessSpec, robot: Robot, training: ScenarioSet) -> None:
        """Each term's figure is a number field of a run's summary: a run of
        :data:`~ubf_async.runs.sweep.spec.PROBE_S` simulated seconds says which fields there
        are."""
        name, text = training.scenarios[0]
        summary = probe_summary(robot, execution.scenario_path(name, text), training.seeds[0])
        problems = [self.check.error(f"figure {term.figure!r}: {problem}",
                                     ("fitness", "terms", i), key="figure")
                    for i, term in enumerate(spec.terms)
                    if (problem := figure_problem(summary, term.figure)) is not None]
        if problems:
            raise EvolveSpecError.all_of(problems)


def _item_of(spec: ScenarioSetSpec, index: int) -> int:
    """The SPEC's item that made the set's ``index``-th scenario."""
    count = 0
    for i, item in enumerate(spec.scenarios):
        count += 1 if isinstance(item, str) else item.count
        if index < count:
            return i
    return len(spec.scenarios) - 1


# -- tune -------------------------------------------------------------------------------------

def _tune(spec: EvolveFile, seed_source: str, seed_text: str, spec_dir: Path,
          check: Checker) -> TunePlan | None:
    if spec.tune is None:
        return None
    tune = spec.tune
    if tune.robot is not None:
        source, text = _seed_robot(msgspec.structs.replace(spec, seed_robot=tune.robot),
                                   spec_dir, check, False)
    else:
        source, text = seed_source, seed_text
    data = yaml.load(text, Loader=YAML_LOADER)
    parameters = []
    start: dict[str, float] = {}
    for path, (low, high) in tune.parameters.items():
        at: Path_ = ("tune", "parameters")
        if low > high:
            raise check.error(f"{path}: the range's low end is above its high end", at,
                              key=path)
        integer = all(isinstance(v, int) for v in (low, high)) and _is_int_place(data, path)
        for end in (low, high):
            value = int(end) if integer else float(end)
            try:
                overrides.load_robot_text_with(text, {path: value}, source=source)
            except overrides.OverridePathError as exc:
                raise check.error(f"tune: {exc}", at, key=path) from None
            except RobotFileError as exc:
                raise check.error(f"tune: {exc}", (*at, path)) from None
        parameters.append((path, float(low), float(high), integer))
        current = _value_at(data, path)
        if current is None:
            current = _default_at(data, path)
        if isinstance(current, int | float) and not isinstance(current, bool) \
                and low <= current <= high:
            start[path] = current
    names = overrides.readable_names(data, [path for path, *_ in parameters])
    return TunePlan(robot_text=text, robot_source=source, parameters=tuple(parameters),
                    names=names,
                    start=start, trials=tune.trials, sampler=tune.sampler)


def _value_at(data: Any, path: str) -> Any:
    node = data
    for part in overrides.parse_path(path):
        if isinstance(part, int):
            node = node[part] if isinstance(node, list) and 0 <= part < len(node) else None
        else:
            node = node.get(part) if isinstance(node, dict) else None
        if node is None:
            return None
    return node


def _default_at(data: Any, path: str) -> Any:
    """The default of a behaviour's parameter at ``path`` (``….params.NAME``) that the robot
    file does not give: its factory's (``None`` for anything else)."""
    parts = overrides.parse_path(path)
    if len(parts) < 3 or parts[-2] != "params" or not isinstance(parts[-1], str):
        return None
    node = _value_at(data, format_path(parts[:-2]))
    if not isinstance(node, dict) or not isinstance(node.get("behavior"), str):
        return None
    try:
        struct = parameters_of(BEHAVIORS.get(node["behavior"]), injected=INJECTED_TREE)
    except (PluginError, TypeError, ValueError):
        return None
    info = msgspec.inspect.type_info(struct)
    assert isinstance(info, msgspec.inspect.StructType)
    found = next((f for f in info.fields if f.name == parts[-1]), None)
    return None if found is None or found.required else found.default


def _is_int_place(data: Any, path: str) -> bool:
    """Whether the robot file's value at ``path`` is an int, or there is none (then the
    range's ends say)."""
    current = _value_at(data, path)
    return current is None or (isinstance(current, int) and not isinstance(current, bool))


__all__ = ["EvolveFile", "EvolvePlan", "EvolveSpecError", "ScenarioSet", "TunePlan",
           "load_evolve"]
