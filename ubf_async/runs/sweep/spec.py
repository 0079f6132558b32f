"""A sweep's SPEC file, and the runs it asks for.

A SPEC (YAML, ``docs/experiments.md``) names robot files, overrides of their values (each a
list of values to try), scenarios and seeds; the runs are their product. :func:`load_sweep`
checks the whole of it before anything runs — every robot variant is loaded, every scenario
planned — and refuses a mistake as ``SPEC:LINE: message``.

Each run is a :class:`RunTask` that carries what its worker needs: the robot file's text and the
scenario file's (a worker on another machine needs neither file), the overrides, the seed. Its
``run_id`` is a digest of all of it, so a journal's record (:mod:`.journal`) stands for the same
run only while the robot file, the scenario file and the values are the same.
"""

from __future__ import annotations

import difflib
import hashlib
import itertools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar, TypeVar

import msgspec
import yaml
from msgspec import Meta

from ubf_async.assembly.robotfile import (
    YAML_LOADER,
    Locator,
    Path_,
    Robot,
    Spec,
    read_robot_file,
)
from ubf_async.errors import (
    ConfigurationError,
    RobotFileError,
    ScenarioError,
    SweepSpecError,
    UbfError,
)
from ubf_async.runs import inprocess, overrides

__all__ = ["DEFAULT_FIGURES", "FIGURE", "MAX_RUNS", "OPEN_MAPS", "PROBE_S", "RESULT_COLUMNS",
           "Checker", "Figure", "Name", "RunTask", "Seed", "SeedRange", "SweepFile", "SweepPlan",
           "decode_spec", "digest", "figure_problem", "format_place", "load_sweep",
           "number_fields", "probe_summary", "read_scenario"]

MAX_RUNS = 1_000_000
DEFAULT_FIGURES = ("ball_distance_m", "ball_bearing_deg")
FIGURE = r"^[A-Za-z0-9_-]+(\.[A-Za-z0-9_-]+)*$"
"""A summary field, dotted: ``motion_last_2s.max_offset_m``, ``ticks.winner_share.chase``."""
RESULT_COLUMNS = ("robot", "scenario", "seed", "status", "pass", "error")
"""Columns of the table a figure or an override may not be named as."""

Figure = Annotated[str, Meta(pattern=FIGURE, max_length=200)]
Seed = Annotated[int, Meta(ge=0, le=2**63 - 1)]  # numpy's generators refuse negative seeds
Name = Annotated[str, Meta(min_length=1, max_length=500)]
S = TypeVar("S", bound=Spec)


class SeedRange(Spec):
    """``seeds: {first: 1, last: 10}``: every seed from ``first`` to ``last``, both included."""

    what: ClassVar[str] = "`seeds` (a range)"

    first: Seed
    last: Seed


class SweepFile(Spec):
    """A sweep spec as written."""

    what: ClassVar[str] = "a sweep spec"
    lists: ClassVar[Mapping[str, str]] = {
        "robots": "robot files", "scenarios": "scenarios", "seeds": "seeds",
        "overrides": "values to try", "figures": "summary fields"}

    robots: Annotated[list[Name], Meta(min_length=1)]
    """Robot files (relative to the spec) or shipped robots' names."""
    scenarios: Annotated[list[Name], Meta(min_length=1)]
    """Built-in scenarios' names or scenario files (relative to the spec)."""
    seeds: Annotated[list[Seed], Meta(min_length=1)] | SeedRange
    overrides: dict[str, Annotated[list[Any], Meta(min_length=1)]] = msgspec.field(
        default_factory=dict)
    """Path into each robot file → the values to try (:mod:`ubf_async.runs.overrides`)."""
    duration_s: Annotated[float, Meta(gt=0.0, le=1e6)] | None = None
    """Simulated seconds of each run (default: each scenario's)."""
    figures: Annotated[list[Figure], Meta(min_length=1)] = msgspec.field(
        default_factory=lambda: list(DEFAULT_FIGURES))
    """Summary fields to tabulate (dotted paths into the run's summary)."""
    plot: Figure | None = None
    """The figure plotted against each swept parameter (default: the first figure)."""


PROBE_S = 0.1
"""Simulated seconds of the run that tells which fields a run's summary has."""
OPEN_MAPS = ("ticks.winner_share", "distractors")
"""Summary maps whose keys depend on the run (a behaviour that never won has no share)."""


def probe_summary(robot: Robot, scenario: str, seed: int) -> dict[str, Any]:
    """The summary of a :data:`PROBE_S`-second run of ``robot`` through ``scenario`` (a
    built-in's name or a scenario file): which fields a run's summary has."""
    return inprocess.run(robot, scenario, seed=seed, duration_s=PROBE_S).summary


def figure_problem(summary: Mapping[str, Any], path: str) -> str | None:
    """What is wrong with naming the dotted ``path`` as a figure of runs whose summary is like
    ``summary`` (``None``: it is a number field, or a key of one of :data:`OPEN_MAPS`)."""
    value: Any = summary
    parts = path.split(".")
    for i, part in enumerate(parts):
        here = ".".join(parts[:i])
        if not isinstance(value, Mapping):
            return f"{here} is not a map of fields"
        if part not in value:
            if here in OPEN_MAPS:
                return None  # a key of a map the run fills
            near = difflib.get_close_matches(path, number_fields(summary), n=3, cutoff=0.6)
            return ("a run's summary has no such field ("
                    + (f"the nearest: {', '.join(near)}" if near else
                       f"at {here or 'the top'}: {', '.join(sorted(value))}")
                    + "; docs/scenarios.md, Outputs)")
        value = value[part]
    if isinstance(value, Mapping | list | str | bool):
        return f"not a number (a {type(value).__name__}): name one of its fields"
    return None


def number_fields(summary: Mapping[str, Any], prefix: str = "") -> list[str]:
    """The dotted paths of every number in ``summary``."""
    found = []
    for key, value in summary.items():
        if isinstance(value, Mapping):
            found += number_fields(value, f"{prefix}{key}.")
        elif isinstance(value, int | float) and not isinstance(value, bool):
            found.append(f"{prefix}{key}")
    return found


def digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True, slots=True)
class RunTask:
    """One run of a sweep: everything its worker needs, in a picklable value."""

    run_id: str
    order: tuple[int, ...]
    """Its place in the table: robot, each override's value, scenario and seed by their place
    in the spec."""
    robot: str
    """The robot file as the spec names it."""
    robot_source: str
    robot_text: str
    overrides: tuple[tuple[str, Any], ...]
    scenario: str
    """The scenario as the spec names it."""
    scenario_text: str | None
    """A scenario file's text (``None``: a built-in scenario)."""
    seed: int
    duration_s: float | None

    @property
    def key(self) -> dict[str, Any]:
        """The run's key columns: robot, each override, scenario, seed."""
        return {"robot": self.robot, **dict(self.overrides), "scenario": self.scenario,
                "seed": self.seed}


@dataclass(frozen=True, slots=True)
class SweepPlan:
    """A checked sweep spec and its runs in table order."""

    source: Path
    spec: SweepFile
    robots: tuple[str, ...]
    paths: tuple[str, ...]
    """The override paths, in the spec's order."""
    values: tuple[tuple[Any, ...], ...]
    """Each override's values, in the spec's order."""
    scenarios: tuple[str, ...]
    seeds: tuple[int, ...]
    tasks: tuple[RunTask, ...]

    @property
    def figures(self) -> tuple[str, ...]:
        return tuple(self.spec.figures)

    @property
    def plot(self) -> str:
        return self.spec.plot or self.spec.figures[0]

    @property
    def key_columns(self) -> tuple[str, ...]:
        return ("robot", *self.paths, "scenario", "seed")

    def dimensions(self) -> list[tuple[str, tuple[Any, ...]]]:
        """Key columns with their values in the spec's order (the seed's last)."""
        return [("robot", self.robots), *zip(self.paths, self.values, strict=True),
                ("scenario", self.scenarios), ("seed", self.seeds)]

    def describe(self) -> str:
        """``40 runs: 2 values of tree.arbiter × 2 scenarios × 10 seeds``."""
        parts = [f"{len(self.robots)} robot files"] if len(self.robots) > 1 else []
        parts += [f"{len(v)} values of {p}" for p, v in zip(self.paths, self.values, strict=True)
                  if len(v) > 1]
        parts += [f"{len(self.scenarios)} scenario" + ("s" if len(self.scenarios) > 1 else ""),
                  f"{len(self.seeds)} seed" + ("s" if len(self.seeds) > 1 else "")]
        return f"{len(self.tasks)} runs: {' × '.join(parts)}"


class Checker:
    """Refusals at a spec's lines, as ``error`` (a :class:`RobotFileError` type)."""

    def __init__(self, locator: Locator, error: type[RobotFileError] = SweepSpecError) -> None:
        self.locator = locator
        self._error = error

    def error(self, message: str, path: Path_, *, key: str | None = None) -> RobotFileError:
        found = self.locator.error(message, path, key=key)
        return self._error(found.message, path=found.path, line=found.line)

    def unique(self, values: list[Any], path: Path_, what: str) -> list[RobotFileError]:
        """A refusal of each value given again in ``values`` (at ``path``)."""
        seen: dict[str, int] = {}
        found = []
        for i, value in enumerate(values):
            text = json.dumps(value, sort_keys=True, default=str)
            if text in seen:
                found.append(self.error(
                    f"{what} {text} twice (also {format_place(path, seen[text])})", (*path, i)))
            seen.setdefault(text, i)
        return found


def format_place(path: Path_, index: int) -> str:
    return f"{'.'.join(str(p) for p in path)}[{index}]"


def _beside(spec_dir: Path, name: str) -> Path | None:
    """A file named ``name`` relative to the spec's folder (or absolute), if there is one."""
    path = spec_dir / name
    return path if path.is_file() else None


def decode_spec(source: Path, root: type[S], error: type[RobotFileError], *,
                what: str) -> tuple[S, Locator]:
    """A spec file read and decoded into ``root``, with the :class:`Locator` of its lines.
    Raises ``error`` (``SPEC:LINE: …``: the robot file's messages) or
    :class:`~ubf_async.errors.ConfigurationError` for a file that cannot be read."""
    try:
        text = source.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigurationError(f"{source}: no such {what}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigurationError(f"{source}: cannot read it: {exc}") from None
    try:
        locator = Locator.parse(text, source=str(source))
        try:
            return msgspec.yaml.decode(text, type=root), locator
        except msgspec.ValidationError as exc:
            # Every mistake at once, not msgspec's first alone.
            data = yaml.load(text, Loader=YAML_LOADER)
            raise error.all_of(locator.problems(data, root)
                               or [locator.from_validation(exc, root=root)]) from None
        except msgspec.DecodeError as exc:
            raise RobotFileError(f"not valid YAML: {exc}", path=str(source)) from None
    except RobotFileError as exc:
        raise error.all_of(exc.problems) from None


def load_sweep(path: str | Path) -> SweepPlan:
    """Read and check a sweep spec: its form, every robot file with every combination of its
    overrides, every scenario. Raises :class:`SweepSpecError` (``SPEC:LINE: …``) or
    :class:`~ubf_async.errors.ConfigurationError` for a spec that cannot be read."""
    source = Path(path)
    spec, locator = decode_spec(source, SweepFile, SweepSpecError, what="sweep spec")
    check = Checker(locator)
    seeds: Sequence[int] = (range(spec.seeds.first, spec.seeds.last + 1)  # counted, not made
                            if isinstance(spec.seeds, SeedRange) else spec.seeds)
    if isinstance(spec.seeds, SeedRange) and not seeds:
        raise check.error(f"seeds: first ({spec.seeds.first}) is past last "
                          f"({spec.seeds.last})", ("seeds",))
    robots = [_robot_text(spec, i, source.parent, check) for i in range(len(spec.robots))]
    scenarios = [read_scenario(name, source.parent, check, ("scenarios", i))
                 for i, name in enumerate(spec.scenarios)]
    found = _check_form(spec, check) + _figure_problems(spec, robots[0], scenarios[0][0],
                                                         seeds[0], check)
    if found:  # every mistake of the spec's form and its figures at once
        raise SweepSpecError.all_of(found)
    paths = list(spec.overrides)
    combinations = list(itertools.product(*(range(len(v)) for v in spec.overrides.values())))
    count = len(robots) * len(combinations) * len(spec.scenarios) * len(seeds)
    if count > MAX_RUNS:
        raise check.error(f"{count} runs: more than {MAX_RUNS} in one sweep", ())
    tasks: list[RunTask] = []
    for r, (robot_source, robot_text) in enumerate(robots):
        for combination in combinations:
            chosen = tuple((p, spec.overrides[p][j]) for p, j in zip(paths, combination,
                                                                       strict=True))
            variant = _variant(spec, r, robot_source, robot_text, chosen, combination, check)
            for s, (scenario, scenario_text) in enumerate(scenarios):
                # Every scenario once, every variant once.
                if (r == 0 and combination == combinations[0]) or s == 0:
                    _check_run(spec, variant, scenario, seeds[0], check, r, s, bool(paths))
                for k, seed in enumerate(seeds):
                    tasks.append(_task(spec, (r, *combination, s, k), robot_source, robot_text,
                                       chosen, scenario_text, s, seed))
    return SweepPlan(source=source, spec=spec, robots=tuple(spec.robots), paths=tuple(paths),
                     values=tuple(tuple(v) for v in spec.overrides.values()),
                     scenarios=tuple(spec.scenarios), seeds=tuple(seeds), tasks=tuple(tasks))


def _check_form(spec: SweepFile, check: Checker) -> list[RobotFileError]:
    """What decoding cannot say: names twice, override paths, values JSON cannot carry,
    figures that would clash with the table's own columns — every mistake."""
    found = [*check.unique(spec.robots, ("robots",), "robot"),
             *check.unique(spec.scenarios, ("scenarios",), "scenario")]
    if isinstance(spec.seeds, list):
        found += check.unique(spec.seeds, ("seeds",), "seed")
    for path, values in spec.overrides.items():
        try:
            overrides.parse_path(path)
        except ValueError as exc:
            found.append(check.error(f"overrides: {exc}", ("overrides",), key=path))
        if path == "seed":
            found.append(check.error("overrides: the robot file's `seed` is replaced by each "
                                     "run's seed: give the seeds as `seeds:`", ("overrides",),
                                     key=path))
        for i, value in enumerate(values):
            try:
                json.dumps(value, allow_nan=False)
            except (TypeError, ValueError):
                found.append(check.error(f"overrides: {path}: {value!r} is not a value a robot "
                                         f"file takes", ("overrides", path, i)))
        found += check.unique(values, ("overrides", path), "value")
    found += check.unique(spec.figures, ("figures",), "figure")
    found += [check.error(f"figures: {name!r} is a column of the table already", ("figures", i))
              for i, name in enumerate(spec.figures) if name in RESULT_COLUMNS]
    if spec.plot is not None and spec.plot not in spec.figures:
        found.append(check.error(f"plot: {spec.plot!r} is not one of the figures "
                                 f"({', '.join(spec.figures)})", ("plot",)))
    return found


def _robot_text(spec: SweepFile, index: int, spec_dir: Path,
                check: Checker) -> tuple[str, str]:
    """``(source, text)`` of robot file ``index``."""
    name = spec.robots[index]
    try:
        text, source = read_robot_file(_beside(spec_dir, name) or name)
        return source, text
    except RobotFileError as exc:
        raise check.error(f"robot {name!r}: {exc}", ("robots", index)) from None


def read_scenario(name: str, spec_dir: Path, check: Checker,
                  at: Path_) -> tuple[str, str | None]:
    """``(what to pass to the run, the file's text or None for a built-in name)`` of the
    scenario ``name`` a spec gives at ``at``."""
    path = _beside(spec_dir, name)
    if path is None:
        return name, None  # a built-in scenario (or no such file: planning the run says so)
    try:
        return str(path), path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise check.error(f"scenario {name!r}: cannot read it: {exc}", at) from None


def _variant(spec: SweepFile, robot: int, source: str, text: str,
             chosen: tuple[tuple[str, Any], ...], combination: tuple[int, ...],
             check: Checker) -> Robot:
    """The robot file ``robot`` with the overrides ``chosen``, loaded. A refusal is told where
    its cause is written: at the override's path when the path leads nowhere, at the value's
    line when that value alone is refused, else at ``overrides:`` (the values together)."""
    try:
        return overrides.load_robot_text_with(text, dict(chosen), source=source)
    except RobotFileError as whole:
        name = spec.robots[robot]
        for (path, value), j in zip(chosen, combination, strict=True):
            try:
                overrides.load_robot_text_with(text, {path: value}, source=source)
            except overrides.OverridePathError as nowhere:
                raise check.error(f"robot {name!r}: {nowhere}", ("overrides",),
                                  key=path) from None
            except RobotFileError as alone:
                raise check.error(f"robot {name!r}: {alone}", ("overrides", path, j)) from None
        at: Path_ = ("overrides",) if chosen else ("robots", robot)
        raise check.error(f"robot {name!r}: {whole}", at) from None


def _check_run(spec: SweepFile, robot: Robot, scenario: str, seed: int, check: Checker,
               r: int, s: int, overridden: bool) -> None:
    """Plan a run of ``robot`` through ``scenario`` as the worker will: an unknown or broken
    scenario, a robot no simulator can run."""
    try:
        inprocess.plan_run(robot, scenario, seed=seed, duration_s=spec.duration_s)
    except ScenarioError as exc:
        raise check.error(f"scenario {spec.scenarios[s]!r}: {exc}", ("scenarios", s)) from None
    except UbfError as exc:
        at: Path_ = ("overrides",) if overridden else ("robots", r)
        raise check.error(f"robot {spec.robots[r]!r}: {exc}", at) from None


def _figure_problems(spec: SweepFile, robot: tuple[str, str], scenario: str, seed: int,
                     check: Checker) -> list[RobotFileError]:
    """A refusal of each figure that is no number field of a run's summary, as a short run of
    the first robot file (``(source, text)``, without overrides: they change no field) through
    the first scenario says. None when that run cannot start: planning every run says why."""
    try:
        summary = probe_summary(overrides.load_robot_text_with(robot[1], {}, source=robot[0]),
                                scenario, seed)
    except UbfError:
        return []
    return [check.error(f"figures: {name!r}: {problem}", ("figures", i))
            for i, name in enumerate(spec.figures)
            if (problem := figure_problem(summary, name)) is not None]


def _task(spec: SweepFile, order: tuple[int, ...], robot_source: str, robot_text: str,
          chosen: tuple[tuple[str, Any], ...], scenario_text: str | None, s: int,
          seed: int) -> RunTask:
    robot, scenario = spec.robots[order[0]], spec.scenarios[s]
    identity = json.dumps([robot, digest(robot_text), [list(c) for c in chosen], scenario,
                           None if scenario_text is None else digest(scenario_text), seed,
                           spec.duration_s], sort_keys=True, separators=(",", ":"))
    return RunTask(run_id=digest(identity), order=order, robot=robot, robot_source=robot_source,
                   robot_text=robot_text, overrides=chosen, scenario=scenario,
                   scenario_text=scenario_text, seed=seed, duration_s=spec.duration_s)

