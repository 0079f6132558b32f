"""``python -m ubf_async.evolve SPEC.yaml --out DIR``: behaviour trees evolved by genetic
programming, each individual scored by simulated runs.

The SPEC (docs/evolve.md) says what a tree may hold, the training and held-out scenario sets
and how the runs' figures make a fitness; the flags override its budget. The library is
:mod:`ubf_async.runs.evolve`; this is its command line: the checks first (a bad SPEC is one
line, ``SPEC:LINE: …``, exit status 2, before anything runs), a progress bar on a terminal
(the generation, the best fitness, the time left; a line per generation otherwise), the
outputs at the end.

Ctrl-C or SIGTERM stops it: the runs in flight are lost, every finished run is in
``DIR/journal.jsonl`` and every finished generation in ``DIR/checkpoint.json``; ``--resume``
goes on from there to the result an uninterrupted evolution gives (exit status 130). A second
one exits at once.

Exit status: 0 when the evolution finished, 2 for a mistake in the command or the SPEC, 130
when stopped.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from ubf_async import __version__, extras
from ubf_async.cli.run import EXIT_INTERRUPTED, run_sync
from ubf_async.errors import ConfigurationError
from ubf_async.runs import evolve
from ubf_async.runs.sweep import execution
from ubf_async.runs.sweep.execution import RunRecord
from ubf_async.tools.sweep import (
    ExampleFormatter,
    add_pool_arguments,
    check_pool_arguments,
    pool_description,
    pool_stop_guard,
    pool_words,
    time_spent,
)

__all__ = ["EXAMPLE", "PROG", "BarProgress", "PlainProgress", "build_parser", "describe", "main",
           "report", "resume_command", "run"]

PROG = "python -m ubf_async.evolve"

EXAMPLE = """\
examples:
  python -m ubf_async.evolve examples/evolve/mini-whegs.yaml --out out/evolve
  python -m ubf_async.evolve SPEC.yaml --out DIR --generations 3 --population 8 --seed 2
  python -m ubf_async.evolve SPEC.yaml --out DIR --resume     # after Ctrl-C or a kill
  python -m ubf_async.evolve SPEC.yaml --out DIR --resume --compare out/tune/best.yaml

Out, in DIR: best.yaml (python -m ubf_async.launch DIR/best.yaml runs it), hall-of-fame/
and pareto/ (robot files), log.jsonl (a line per generation), fitness.png (fitness and
tree sizes per generation), trees.png (the seed's tree and the best's), report.md and
heldout.csv (the best and the seed robot on the held-out set), scenarios/ (the generated
scenario files), checkpoint.json and journal.jsonl (what --resume goes on from).
docs/evolve.md says more."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description=("Evolve behaviour trees by genetic programming from a seed robot file,\n"
                     "each individual scored by simulated runs on the training scenarios;\n"
                     "the same SPEC and seed give the same result on any number of workers."),
        epilog=EXAMPLE, formatter_class=ExampleFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("spec", type=Path, metavar="SPEC.yaml", help="the evolution's SPEC")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="the folder of the outputs (required unless --check)")
    parser.add_argument("--resume", action="store_true",
                        help="go on from DIR's checkpoint (the runs of its journal are kept); "
                             "without it, a DIR that holds an evolution is refused")
    parser.add_argument("--check", action="store_true",
                        help="check the SPEC, say what would run, and exit")
    budget = parser.add_argument_group("the SPEC's values, replaced")
    budget.add_argument("--seed", type=int, default=None, metavar="N",
                        help="the seed of the evolution's generator")
    budget.add_argument("--generations", type=int, default=None, metavar="G")
    budget.add_argument("--population", type=int, default=None, metavar="P")
    budget.add_argument("--seed-robot", default=None, metavar="FILE",
                        help="the robot file evolution starts from (in the first population; "
                             "default: the SPEC's seed_robot, else the shipped Mini-WHEGS)")
    parser.add_argument("--compare", action="append", default=[], metavar="FILE",
                        help="a robot file to set beside the evolved one on the held-out set "
                             "(repeat for more)")
    add_pool_arguments(parser)
    return parser


class PlainProgress:
    """A line per generation: its best, its mean, the time spent and left."""

    def __init__(self, generations: int, out: TextIO) -> None:
        self.generations, self.out = generations, out
        self.start = time.monotonic()

    def __enter__(self) -> PlainProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def batch(self, runs: int) -> None:
        pass

    def run(self, record: RunRecord) -> None:
        pass

    def generation(self, entry: dict[str, Any]) -> None:
        done = entry["generation"] + 1
        print(f"  generation {done}/{self.generations}: best {entry['best']['fitness']:g} "
              f"({entry['best']['size']} nodes), mean {entry['fitness']['mean']:g}; "
              f"{time_spent(self.start, done, self.generations)}",
              file=self.out, flush=True)


class BarProgress:
    """rich's bar over the generations, moving with each run: the generation, the best
    fitness, the time spent and left."""

    def __init__(self, generations: int, out: TextIO) -> None:
        extras.require("sim", "rich", who="python -m ubf_async.evolve")
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.generations = generations
        self.bar = Progress(TextColumn("generation {task.fields[generation]}"), BarColumn(),
                            TextColumn("best {task.fields[best]}"), TimeElapsedColumn(),
                            TextColumn("left"), TimeRemainingColumn(),
                            console=Console(file=out))
        self.task = self.bar.add_task("evolve", total=generations, generation=f"1/{generations}",
                                      best="–")
        self.share = 0.0
        self.done = 0

    def __enter__(self) -> BarProgress:
        self.bar.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.bar.stop()

    def batch(self, runs: int) -> None:
        self.share = 1.0 / runs if runs else 0.0

    def run(self, record: RunRecord) -> None:
        self.bar.advance(self.task, self.share * 0.95)  # the last of it when it closes

    def generation(self, entry: dict[str, Any]) -> None:
        self.done = entry["generation"] + 1
        self.bar.update(self.task, completed=min(self.done, self.generations),
                        generation=f"{min(self.done + 1, self.generations)}/{self.generations}",
                        best=f"{entry['best']['fitness']:g}")


def resume_command(args: argparse.Namespace) -> str:
    words = [*PROG.split(), str(args.spec), "--out", str(args.out), "--resume"]
    for flag in ("seed", "generations", "population", "seed_robot"):
        value = getattr(args, flag)
        if value is not None:
            words += [f"--{flag.replace('_', '-')}", str(value)]
    return shlex.join(words + pool_words(args))


def describe(plan: evolve.EvolvePlan) -> list[str]:
    spec = plan.spec
    return [f"{plan.source}: population {plan.population} × {plan.generations} generations from "
            f"{plan.seed_source} (seed {plan.seed})",
            f"  training: {plan.training.describe()} = {plan.training.runs} runs per "
            f"individual; held out: {plan.held_out.describe()}",
            f"  genome: {len(plan.space.behaviors)} behaviours, {len(plan.space.arbiters)} "
            f"arbiters, {len(plan.space.predicates)} predicates; max_depth "
            f"{spec.genome.max_depth}, max_nodes {spec.genome.max_nodes}"]


def report(outputs: evolve.EvolveOutputs, out: TextIO) -> None:
    print(f"{outputs.generations} generations: best fitness {outputs.best_fitness:g} on the "
          f"training set (the seed robot: {outputs.seed_fitness:g}); {outputs.ran} runs run",
          file=out)
    if outputs.best_is_seed:
        print("  the best tree is the seed robot's own: no tree evolved beat it on the "
              "training set (more generations, a larger population or other operators may)",
              file=out)
    print("held out" + (" (the evolved robot is the seed's tree: the same figures)"
                        if outputs.best_is_seed else "") + ":", file=out)
    for robot in outputs.held_out:
        e = robot.evaluation
        assert e is not None
        said = (f"fitness {e.fitness:g} (mean {e.mean:g}, worst {e.worst:g})" if not e.failed
                else f"{e.failed} run(s) failed: {e.error}")
        print(f"  {robot.label}: {said}", file=out)
    print(f"written in {outputs.out_dir}: {', '.join(outputs.files)}", file=out)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_sync(lambda: run(args, sys.stdout), prog=PROG)


def run(args: argparse.Namespace, out: TextIO) -> int:
    if args.out is None and not args.check:
        raise ConfigurationError("--out DIR is required (the folder of the outputs)")
    check_pool_arguments(args)
    plan = evolve.load_evolve(args.spec, seed=args.seed, population=args.population,
                              generations=args.generations, seed_robot=args.seed_robot)
    if args.check:
        print("\n".join(describe(plan)) + "\n  — OK", file=out)
        return 0
    evolve.check_folder(plan, args.out, resume=args.resume)
    evolve.compared_robots(args.compare)
    print("\n".join(describe(plan)), file=out)
    workers = execution.pool_workers(args.executor, args.workers,
                                     plan.population * plan.training.runs)
    print(f"running on {pool_description(args, workers)}", file=out, flush=True)
    progress = (BarProgress if out.isatty() else PlainProgress)(plan.generations, out)
    guard = pool_stop_guard(PROG, args)
    try:
        with guard.installed(), progress:
            outputs = evolve.run_evolution(
                plan, args.out, workers=workers, executor=args.executor, address=args.address,
                runtime_env=args.runtime_env, resume=args.resume, compare=args.compare,
                on_run=progress.run, on_batch=progress.batch,
                on_generation=progress.generation)
    except KeyboardInterrupt:
        print(f"{PROG}: stopped: every finished generation is in "
              f"{args.out / 'checkpoint.json'}, every finished run in "
              f"{args.out / 'journal.jsonl'}; the runs in flight were lost. Resume with:\n"
              f"  {resume_command(args)}", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED
    report(outputs, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
