"""``python -m ubf_async.sweep SPEC.yaml --out DIR``: many simulated runs, one table.

The SPEC (docs/experiments.md, Sweeps) names robot files or overrides of their values,
scenarios and seeds; their product runs on ``--workers`` processes of this machine (each runs
many runs, :func:`ubf_async.runs.inprocess.run`) or on a Ray cluster (``--executor ray``), into
``DIR/runs.csv``, ``DIR/cells.csv``, a plot and, when pyarrow is installed, ``DIR/runs.parquet``.
The library is :mod:`ubf_async.runs.sweep`; this is its command line: the checks first (a bad
spec is one line, ``SPEC:LINE: …``, exit status 2, before anything runs), a progress bar on a
terminal (plain lines otherwise), the tables at the end.

Ctrl-C or SIGTERM stops the sweep: the runs in flight are lost, every finished run is in
``DIR/journal.jsonl``, and ``--resume`` continues from there (exit status 130). A second one
exits at once. There is no event loop here to cancel, so :class:`~ubf_async.cli.run.StopGuard`
stands alone: its first signal raises ``KeyboardInterrupt`` in the main thread, wherever it is
waiting for a run.

Exit status: 0 when every run ran (whatever their outcomes), 1 when some run failed (its error
is in the table and ``DIR/runs.log``), 2 for a mistake in the command or the spec, a Ray
cluster that cannot be joined (one line: the cause and the fix) or runs lost with a node that
died (``--resume`` runs them again), 130 when stopped.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from ubf_async import __version__, extras
from ubf_async.cli.args import HelpFormatter
from ubf_async.cli.run import EXIT_ERROR, EXIT_INTERRUPTED, STOP_BOUND_S, StopGuard, run_sync
from ubf_async.errors import ConfigurationError, RunsLostError
from ubf_async.runs import sweep
from ubf_async.runs.sweep import execution, table
from ubf_async.runs.sweep.execution import EXECUTORS, RunRecord

__all__ = [
    "CELLS_SHOWN",
    "EXAMPLE",
    "EXIT_RUNS_FAILED",
    "PLAIN_STEPS",
    "PROG",
    "RAY_STOP_BOUND_S",
    "BarProgress",
    "ExampleFormatter",
    "PlainProgress",
    "add_pool_arguments",
    "build_parser",
    "cells_table",
    "check_arguments",
    "check_pool_arguments",
    "clock_text",
    "execute",
    "json_object",
    "main",
    "pool_description",
    "pool_stop_guard",
    "pool_words",
    "print_plan",
    "report",
    "resume_command",
    "run",
    "time_spent",
]

PROG = "python -m ubf_async.sweep"
EXIT_RUNS_FAILED = 1
RAY_STOP_BOUND_S = 30.0
"""Ray's actors and local cluster take longer to end than this machine's processes."""
PLAIN_STEPS = 10
"""Without a terminal: a line per tenth of the runs."""

EXAMPLE = """\
a SPEC (YAML; paths relative to it):

  robots: [mini-whegs]                  # robot files, or shipped robots' names
  overrides:                            # optional: a path into each robot file → values to try
    tree.arbiter: [PriorityMerge, UtilityFusion]
    tree.children[0].params.period_s: [2, 4, 6]
  scenarios: [ball-in-sight, ball-behind]   # built-in names or scenario files
  seeds: {first: 1, last: 10}           # or a list: [1, 2, 3]
  duration_s: 20                        # optional: simulated seconds (default: the scenario's)
  figures: [ball_distance_m, contacts.time_s]   # summary fields to tabulate
  plot: ball_distance_m                 # optional: plotted against each swept parameter

The runs are the product (here 1 × 2 × 3 × 2 × 10 = 120). Out come DIR/runs.csv (every run:
its key, figures, verdicts, ok/failed and error; the same bytes whatever ran it), DIR/cells.csv
(per cell, everything but the seed: mean, min, max, pass rate, worst seed), DIR/FIGURE.png,
DIR/runs.parquet with pyarrow, and DIR/journal.jsonl (each run as it finished).

examples:
  python -m ubf_async.sweep examples/sweeps/arbiters.yaml --out out/arbiters
  python -m ubf_async.sweep SPEC.yaml --out DIR --resume     # after Ctrl-C or a kill
  python -m ubf_async.sweep SPEC.yaml --out DIR --executor ray --address auto

docs/experiments.md says more."""


class ExampleFormatter(HelpFormatter, argparse.RawDescriptionHelpFormatter):
    """The tools' formatter, the spec's example kept as written."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description=("Run the product of robot files (or overrides of their values), scenarios\n"
                     "and seeds — each run simulated in-process, flat out, the same whatever\n"
                     "the machine — on every core or on a Ray cluster, into one table."),
        epilog=EXAMPLE, formatter_class=ExampleFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("spec", type=Path, metavar="SPEC.yaml", help="the sweep's spec")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="the folder of the tables (required unless --check)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the sweep in DIR: runs of this spec finished there are "
                             "kept, the others run (a failed run runs again); without it, a "
                             "DIR that holds a sweep is refused")
    parser.add_argument("--check", action="store_true",
                        help="check the spec (every robot variant, every scenario), say what "
                             "would run, and exit")
    add_pool_arguments(parser)
    return parser


def add_pool_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers``, ``--executor``, ``--address``, ``--runtime-env``: where the runs run
    (:func:`ubf_async.runs.sweep.open_pool`); :func:`check_pool_arguments` checks them."""
    run = parser.add_argument_group("where the runs run")
    run.add_argument("--workers", type=int, default=None, metavar="N",
                     help="worker processes, each running many runs (default: every core "
                          "of this machine; with Ray: every CPU of the cluster)")
    run.add_argument("--executor", choices=EXECUTORS, default="local",
                     help="local: processes of this machine; ray: a Ray cluster's "
                          "(pip install 'ubf-async[cluster]')")
    run.add_argument("--address", default=None, metavar="auto|ray://HOST:10001",
                     help="with --executor ray: the cluster to join (auto: the one this "
                          "machine belongs to; default: a new one on this machine)")
    run.add_argument("--runtime-env", type=json_object, default=None, metavar="JSON",
                     help="with --executor ray: Ray's runtime_env for the workers (default: "
                          "this process's ubf_async and components packages as py_modules; "
                          "'{}' when every node has ubf-async installed)")


def check_pool_arguments(args: argparse.Namespace) -> None:
    if args.executor != "ray" and (args.address is not None or args.runtime_env is not None):
        raise ConfigurationError("--address and --runtime-env are for --executor ray")
    if args.workers is not None and args.workers < 1:
        raise ConfigurationError(f"--workers must be at least 1, got {args.workers}")


def pool_words(args: argparse.Namespace) -> list[str]:
    """The pool's arguments as given, to repeat in a command (the resume command)."""
    words = []
    if args.workers is not None:
        words += ["--workers", str(args.workers)]
    if args.executor != "local":
        words += ["--executor", args.executor]
    if args.address is not None:
        words += ["--address", args.address]
    if args.runtime_env is not None:
        words += ["--runtime-env", json.dumps(args.runtime_env)]
    return words


def pool_stop_guard(prog: str, args: argparse.Namespace) -> StopGuard:
    """The tool's :class:`StopGuard`, given as long to stop as the pool needs."""
    return StopGuard(prog=prog, stop_bound_s=RAY_STOP_BOUND_S if args.executor == "ray"
                     else STOP_BOUND_S)


def pool_description(args: argparse.Namespace, workers: int | None) -> str:
    """``2 local worker processes``, ``Ray (auto): a worker per CPU``."""
    if args.executor == "local":
        return f"{workers} local worker process{'es' if workers != 1 else ''}"
    return (f"Ray ({args.address or 'a new cluster of this machine'}): "
            + (f"{workers} worker processes" if workers else "a worker per CPU"))


def json_object(text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return value


class PlainProgress:
    """Progress as plain lines: one per tenth of the runs, with the count and what is left."""

    def __init__(self, total: int, out: TextIO) -> None:
        self.total, self.out = total, out
        self.done = self.failed = 0
        self.every = max(1, -(-total // PLAIN_STEPS))
        self.start = time.monotonic()

    def __enter__(self) -> PlainProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def advance(self, record: RunRecord) -> None:
        self.done += 1
        self.failed += record.status == "failed"
        if self.done % self.every and self.done != self.total:
            return
        print(f"  {self.done}/{self.total} runs ({100 * self.done // self.total} %), "
              f"{self.failed} failed, {time_spent(self.start, self.done, self.total)}",
              file=self.out, flush=True)


class BarProgress:
    """Progress as rich's bar, with the count, failures, elapsed time and time left."""

    def __init__(self, total: int, out: TextIO) -> None:
        extras.require("sim", "rich", who="python -m ubf_async.sweep")
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.done = self.failed = 0
        self.bar = Progress(TextColumn("runs"), BarColumn(), MofNCompleteColumn(),
                            TextColumn("{task.fields[failed]} failed"), TimeElapsedColumn(),
                            TextColumn("left"), TimeRemainingColumn(),
                            console=Console(file=out))
        self.task = self.bar.add_task("runs", total=total, failed=0)

    def __enter__(self) -> BarProgress:
        self.bar.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.bar.stop()

    def advance(self, record: RunRecord) -> None:
        self.done += 1
        self.failed += record.status == "failed"
        self.bar.update(self.task, advance=1, failed=self.failed)


def time_spent(start: float, done: int, total: int) -> str:
    """``0:12 elapsed, about 1:30 left``: since ``start`` (``time.monotonic``), ``done`` of
    ``total`` steps taken here, the rest guessed at the same pace (nothing left: elapsed
    alone)."""
    elapsed = time.monotonic() - start
    left = elapsed / done * (total - done) if 0 < done < total else 0.0
    return f"{clock_text(elapsed)} elapsed" + (f", about {clock_text(left)} left"
                                               if done < total else "")


def clock_text(seconds: float) -> str:
    minutes, secs = divmod(int(seconds + 0.5), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{secs:02d}" if minutes >= 60 \
        else f"{minutes}:{secs:02d}"


def print_plan(plan: sweep.SweepPlan, out: TextIO) -> None:
    print(f"{plan.source}: {plan.describe()} — OK", file=out)
    for name, values in plan.dimensions():
        shown = ", ".join(table.text(v) for v in values[:12])
        print(f"  {name}: {shown}" + (f", … ({len(values)})" if len(values) > 12 else ""),
              file=out)
    print(f"  figures: {', '.join(plan.figures)}; plot: {plan.plot}", file=out)


def resume_command(args: argparse.Namespace) -> str:
    return shlex.join([*PROG.split(), str(args.spec), "--out", str(args.out), "--resume",
                       *pool_words(args)])


def check_arguments(args: argparse.Namespace) -> None:
    if args.out is None and not args.check:
        raise ConfigurationError("--out DIR is required (the folder of the tables)")
    check_pool_arguments(args)


def execute(args: argparse.Namespace, state: sweep.Sweep, out: TextIO) -> int | None:
    """Run the pending runs with progress; the exit status if stopped, else ``None``."""
    total = len(state.pending)
    workers = execution.pool_workers(args.executor, args.workers, total)
    print(f"running {total} runs on {pool_description(args, workers)}", file=out, flush=True)
    progress = (BarProgress if out.isatty() else PlainProgress)(total, out)
    guard = pool_stop_guard(PROG, args)
    before = len(state.records)
    try:
        with guard.installed(), progress, sweep.open_pool(
                args.executor, workers=workers, address=args.address,
                runtime_env=args.runtime_env) as pool:
            sweep.execute(state, pool, progress.advance)
    except KeyboardInterrupt:
        done = len(state.records) - before
        print(f"{PROG}: stopped: {done} of {total} runs done, kept in {state.journal}; the "
              f"runs in flight were lost. Resume with:\n"
              f"  {resume_command(args)}", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED
    except RunsLostError as exc:
        done = len(state.records) - before
        print(f"{PROG}: error: {exc}: {done} of {total} runs done, kept in {state.journal}. "
              f"Resume with (once `ray status` no longer counts the lost node as active):\n"
              f"  {resume_command(args)}", file=sys.stderr, flush=True)
        return EXIT_ERROR
    return None


CELLS_SHOWN = 20
"""Cells the console's table shows at most (all of them are in ``cells.csv``)."""


def cells_table(plan: sweep.SweepPlan, cells: Sequence[dict[str, Any]]) -> list[str]:
    """The console's table of the cells (each key but the seed): its runs, the share that met
    the scenario's expected outcome, and the plotted figure's mean, min and max over the
    seeds — aligned, at most :data:`CELLS_SHOWN` lines of cells."""
    keys = [c for c in plan.key_columns if c != "seed"]
    name = plan.plot
    head = [*keys, "runs", "passed", f"{name} mean", "min", "max"]

    def cell_text(value: Any) -> str:
        return "" if value is None else table.text(value)

    lines = [[cell_text(cell.get(k)) for k in keys]
             + [str(cell["runs"]), "" if cell.get("pass_rate") is None
                else f"{cell['pass_rate']:.0%}",
                *(cell_text(cell.get(f"{name}.{what}")) for what in ("mean", "min", "max"))]
             for cell in cells[:CELLS_SHOWN]]
    widths = [max(len(row[i]) for row in [head, *lines]) for i in range(len(head))]
    shown = ["  " + "  ".join(text.ljust(w) if i < len(keys) else text.rjust(w)
                              for i, (text, w) in enumerate(zip(row, widths, strict=True)))
             .rstrip() for row in [head, *lines]]
    if len(cells) > CELLS_SHOWN:
        shown.append(f"  … and {len(cells) - CELLS_SHOWN} more cells ({table.CELLS_CSV})")
    return shown


def report(outputs: sweep.SweepOutputs, out_dir: Path, out: TextIO,
           plan: sweep.SweepPlan | None = None) -> None:
    ok = outputs.runs - outputs.failed
    print(f"{outputs.runs} runs: {ok} ok, {outputs.failed} failed; {outputs.passed} met their "
          f"scenario's expected outcome", file=out)
    if plan is not None and outputs.cells:
        print("\n".join(cells_table(plan, outputs.cells)), file=out)
    written = [outputs.runs_csv, outputs.cells_csv, outputs.parquet, outputs.plot, outputs.log]
    print(f"written in {out_dir}: {', '.join(p.name for p in written if p is not None)}",
          file=out)
    for failure in outputs.failures:
        print(f"  failed: {failure}", file=out)
    if outputs.failed > len(outputs.failures):
        print(f"  … and {outputs.failed - len(outputs.failures)} more "
              f"({outputs.log.name if outputs.log else 'runs.csv'})", file=out)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_sync(lambda: run(args, sys.stdout), prog=PROG)


def run(args: argparse.Namespace, out: TextIO) -> int:
    check_arguments(args)
    plan = sweep.load_sweep(args.spec)
    if args.check:
        print_plan(plan, out)
        return 0
    state = sweep.open_sweep(plan, args.out, resume=args.resume)
    print(f"{plan.source}: {plan.describe()}", file=out)
    if args.resume:
        print(f"resuming {args.out}: {len(state.records)} runs done already"
              + (f" ({state.others} other runs of the journal are not this spec's: kept, "
                 f"not tabulated)" if state.others else ""), file=out)
    if state.pending:
        stopped = execute(args, state, out)
        if stopped is not None:
            return stopped
    outputs = sweep.finish(state)
    report(outputs, args.out, out, plan)
    return EXIT_RUNS_FAILED if outputs.failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
