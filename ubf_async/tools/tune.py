"""``python -m ubf_async.tune SPEC.yaml --out DIR``: a robot file's parameters tuned with
Optuna on an evolution SPEC's training runs (its ``tune`` section; docs/evolve.md).

The library is :mod:`ubf_async.runs.tune`. A bad SPEC is one line, ``SPEC:LINE: …``, exit
status 2, before anything runs. ``--storage sqlite:///FILE`` keeps the study: the same
command resumes it after Ctrl-C or a kill (the trial in flight is lost; its finished runs are
in ``DIR/journal.jsonl``), and several machines given the same storage share the study.

Exit status: 0 when the study holds its trials, 2 for a mistake in the command or the SPEC,
130 when stopped.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from ubf_async import __version__
from ubf_async.cli.run import EXIT_INTERRUPTED, run_sync
from ubf_async.errors import ConfigurationError
from ubf_async.runs import tune
from ubf_async.runs.evolve.spec import EvolvePlan, load_evolve
from ubf_async.tools.sweep import (
    ExampleFormatter,
    add_pool_arguments,
    check_pool_arguments,
    pool_stop_guard,
    pool_words,
    time_spent,
)

__all__ = ["EXAMPLE", "PROG", "build_parser", "main", "print_plan", "run"]

PROG = "python -m ubf_async.tune"

EXAMPLE = """\
examples:
  python -m ubf_async.tune examples/evolve/mini-whegs.yaml --out out/tune
  python -m ubf_async.tune SPEC.yaml --out DIR --storage sqlite:///study.db   # resumable
  python -m ubf_async.tune SPEC.yaml --out DIR --sampler cmaes --trials 60
  python -m ubf_async.tune SPEC.yaml --check     # what it would tune and run

Out, in DIR: best.yaml (the robot file with the best values), trials.csv, history.png and
importance.png (Optuna's plots), report.md and heldout.csv (the tuned robot against the file
it started from, on the held-out set). docs/evolve.md says more."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description=("Tune a robot file's parameters with Optuna (a seeded TPE or CMA-ES\n"
                     "sampler), each trial scored by simulated runs on an evolution SPEC's\n"
                     "training scenarios; the SPEC's `tune` section says what to tune."),
        epilog=EXAMPLE, formatter_class=ExampleFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("spec", type=Path, metavar="SPEC.yaml", help="the SPEC (its `tune`)")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="the folder of the outputs (required unless --check)")
    parser.add_argument("--storage", default=None, metavar="URL",
                        help="Optuna's storage (sqlite:///FILE): the study is kept there, "
                             "resumed by the same command, shared by machines given the same "
                             "URL (default: in memory, for this run only)")
    parser.add_argument("--study", default=None, metavar="NAME",
                        help="the study's name in the storage (default: SPEC's name-tune)")
    parser.add_argument("--trials", type=int, default=None, metavar="N",
                        help="complete trials the study should hold (default: the SPEC's)")
    parser.add_argument("--sampler", choices=tune.SAMPLERS, default=None,
                        help="default: the SPEC's (tpe)")
    parser.add_argument("--seed", type=int, default=None, metavar="N",
                        help="the sampler's seed (default: the SPEC's)")
    parser.add_argument("--check", action="store_true",
                        help="check the SPEC, say what the study would tune and run, and exit "
                             "(--out is then not needed)")
    add_pool_arguments(parser)
    return parser


def print_plan(plan: EvolvePlan, args: argparse.Namespace, out: TextIO) -> None:
    """What ``--check`` says: the parameters by name (with their paths and ranges), the
    training runs of a trial, the trials and the sampler."""
    assert plan.tune is not None
    tune_plan = plan.tune
    wanted = args.trials if args.trials is not None else tune_plan.trials
    print(f"{plan.source}: {len(tune_plan.parameters)} parameters of "
          f"{tune_plan.robot_source}, {wanted} trials ({args.sampler or tune_plan.sampler}, "
          f"seed {plan.seed}) — OK", file=out)
    for path, low, high, integer in tune_plan.parameters:
        kind = "int" if integer else "float"
        start = tune_plan.start.get(path)
        print(f"  {tune_plan.names[path]}: {kind} in [{low:g}, {high:g}]"
              + (f", from {start:g}" if start is not None else "") + f"  ({path})", file=out)
    print(f"  training: {plan.training.describe()} = {plan.training.runs} runs per trial",
          file=out)
    print(f"  held out: {plan.held_out.describe()}", file=out)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_sync(lambda: run(args, sys.stdout), prog=PROG)


def run(args: argparse.Namespace, out: TextIO) -> int:
    check_pool_arguments(args)
    if args.trials is not None and args.trials < 1:
        raise ConfigurationError(f"--trials must be at least 1, got {args.trials}")
    plan = load_evolve(args.spec, seed=args.seed)
    if plan.tune is None:
        raise ConfigurationError(f"{args.spec}: no `tune` section: nothing to tune")
    if args.check:
        print_plan(plan, args, out)
        return 0
    if args.out is None:
        raise ConfigurationError("--out DIR is required (unless --check)")
    names = plan.tune.names
    try:  # a line per trial is said below, not Optuna's own
        import optuna
        optuna.logging.set_verbosity(optuna.logging.WARNING)
    except ImportError:  # said by run_study
        pass
    print(f"{args.spec}: {len(plan.tune.parameters)} parameters of {plan.tune.robot_source}; "
          f"training: {plan.training.describe()} = {plan.training.runs} runs per trial",
          file=out, flush=True)

    started: list[tuple[float, int]] = []  # (when, complete trials then): this process's pace

    def said(number: int, value: float, best: float, complete: int, wanted: int) -> None:
        if not started:
            started.append((time.monotonic() - 1e-9, complete - 1))
        since, before = started[0]
        print(f"  trial {number} ({complete}/{wanted}): {value:g} (best {best:g}); "
              f"{time_spent(since, complete - before, wanted - before)}", file=out, flush=True)

    guard = pool_stop_guard(PROG, args)
    try:
        with guard.installed():
            outputs = tune.run_study(
                plan, args.out, storage=args.storage, study_name=args.study,
                trials=args.trials, sampler=args.sampler, workers=args.workers,
                executor=args.executor, address=args.address, runtime_env=args.runtime_env,
                on_trial=said)
    except KeyboardInterrupt:
        again = shlex.join([*PROG.split(), str(args.spec), "--out", str(args.out),
                            *(["--storage", args.storage] if args.storage else []),
                            *pool_words(args)])
        print(f"{PROG}: stopped" + (f"; the study is kept in {args.storage}. Resume with:\n"
                                    f"  {again}" if args.storage else
                                    " (no --storage: the study is lost)"),
              file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED
    print(f"study {outputs.study!r}: {outputs.trials} trials; best {outputs.best_value:g}: "
          + ", ".join(f"{names[k]} = {v:g}" for k, v in outputs.best_params.items()), file=out)
    print("held out:", file=out)
    for robot in outputs.held_out:
        e = robot.evaluation
        assert e is not None
        print(f"  {robot.label}: fitness {e.fitness:g} (mean {e.mean}, worst {e.worst})",
              file=out)
    print(f"written in {outputs.out_dir}: best.yaml, {tune.TRIALS_CSV}, "
          + ", ".join(p.name for p in outputs.plots) + ", report.md, heldout.csv", file=out)
    if outputs.trials < tune.IMPORTANCE_TRIALS:
        print(f"  caution: {tune.IMPORTANCE_PNG}'s ranking is from {outputs.trials} trials, "
              f"noise below {tune.IMPORTANCE_TRIALS} (--trials N)", file=out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
