"""A sweep from its plan to its tables: :func:`open_sweep` (the output folder, what its journal
already holds), :func:`execute` (the remaining runs through a pool, each journaled as it
finishes), :func:`finish` (the tables, the plot, the log). :func:`run_sweep` does all three.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ubf_async.errors import ConfigurationError
from ubf_async.runs.sweep import execution, plot, table
from ubf_async.runs.sweep.execution import RunRecord
from ubf_async.runs.sweep.journal import JOURNAL, Journal, read_journal
from ubf_async.runs.sweep.spec import RunTask, SweepPlan, load_sweep

__all__ = ["RUNS_LOG", "Sweep", "SweepOutputs", "execute", "finish", "open_sweep", "run_sweep"]

RUNS_LOG = "runs.log"


@dataclass(slots=True)
class Sweep:
    """A sweep under way: its plan, its folder, the runs done and those left."""

    plan: SweepPlan
    out_dir: Path
    records: dict[str, RunRecord]
    """The plan's runs done, by id (from the journal, then as they finish)."""
    pending: list[RunTask]
    others: int = 0
    """Runs of the journal that are not this plan's (kept there, not tabulated)."""

    @property
    def journal(self) -> Path:
        return self.out_dir / JOURNAL


@dataclass(frozen=True, slots=True)
class SweepOutputs:
    """What a finished sweep wrote, and how its runs went."""

    runs_csv: Path
    cells_csv: Path
    parquet: Path | None
    plot: Path | None
    log: Path | None
    runs: int
    failed: int
    passed: int
    failures: list[str] = field(default_factory=list)
    """``KEY: error`` of each failed run (the first ten)."""
    cells: list[dict[str, Any]] = field(default_factory=list)
    """``cells.csv``'s rows: per cell (the key but the seed), its runs, passes and figures."""


def open_sweep(plan: SweepPlan, out_dir: str | Path, *, resume: bool = False) -> Sweep:
    """The sweep of ``plan`` into ``out_dir``: refused (:class:`ConfigurationError`) when the
    folder holds a sweep's journal and ``resume`` is false, or when resuming a journal none of
    whose runs is one of ``plan``'s (another spec's sweep, or its files changed since).
    Resuming keeps the runs that ended ``ok`` and runs the others again."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigurationError(f"{out}: exists and is not a folder")
    found = read_journal(out / JOURNAL)
    if found and not resume:
        raise ConfigurationError(
            f"{out} holds a sweep already ({len(found)} runs in {out / JOURNAL}): resume it "
            f"(--resume: the runs of this spec done there are kept), or choose another folder")
    ids = {task.run_id for task in plan.tasks}
    mine = {run_id: record for run_id, record in found.items() if run_id in ids}
    if found and not mine:
        raise ConfigurationError(
            f"none of the {len(found)} runs in {out / JOURNAL} is a run of {plan.source}: "
            f"another spec's sweep, or its robot files or scenario files have changed since; "
            f"choose another folder")
    done = {run_id: record for run_id, record in mine.items() if record.status == "ok"}
    out.mkdir(parents=True, exist_ok=True)
    return Sweep(plan=plan, out_dir=out, records=done,
                 pending=[task for task in plan.tasks if task.run_id not in done],
                 others=len(found) - len(mine))


def execute(sweep: Sweep, pool: execution.Pool,
            on_record: Callable[[RunRecord], None] | None = None) -> None:
    """Run ``sweep``'s pending runs on ``pool``, journaling each as it finishes (then
    ``on_record``). Interrupted, the journal keeps every run finished so far."""
    with Journal(sweep.journal) as journal:
        for record in pool.imap_unordered(execution.run_task, sweep.pending, chunksize=1):
            journal.append(record)
            sweep.records[record.id] = record
            if on_record is not None:
                on_record(record)
    sweep.pending = [task for task in sweep.pending if task.run_id not in sweep.records]


def finish(sweep: Sweep) -> SweepOutputs:
    """Write the tables (``runs.csv``, ``cells.csv``, ``runs.parquet`` when pyarrow is there),
    the plot of the plan's plotted figure and ``runs.log`` (each run's error and the warnings
    it logged, if any did), from the runs done."""
    plan, out = sweep.plan, sweep.out_dir
    columns, rows = table.run_rows(plan, sweep.records)
    runs_csv = table.write_whole(out / table.RUNS_CSV, table.csv_text(columns, rows))
    cell_columns, cells = table.cell_rows(plan, rows)
    cells_csv = table.write_whole(out / table.CELLS_CSV, table.csv_text(cell_columns, cells))
    parquet = table.write_parquet(out / table.RUNS_PARQUET, columns, rows)
    drawn = plot.plot_figure(plan, rows, plan.plot, out / f"{plan.plot}.png",
                             bands=table.expected_ranges(plan, sweep.records, plan.plot))
    log = _write_log(sweep)
    failed = [row for row in rows if row["status"] == "failed"]
    return SweepOutputs(
        runs_csv=runs_csv, cells_csv=cells_csv, parquet=parquet, plot=drawn, log=log,
        runs=len(rows), failed=len(failed), passed=sum(1 for row in rows if row["pass"] is True),
        failures=[f"{_key_text(row, plan)}: {row['error']}" for row in failed[:10]],
        cells=cells)


def _key_text(key: dict[str, object], plan: SweepPlan) -> str:
    return " ".join(f"{name}={table.text(key[name])}" for name in plan.key_columns)


def _write_log(sweep: Sweep) -> Path | None:
    path = sweep.out_dir / RUNS_LOG
    parts = []
    for task in sweep.plan.tasks:
        record = sweep.records.get(task.run_id)
        if record is None or (record.status == "ok" and not record.log):
            continue
        lines = [record.traceback or record.error or ""] if record.status == "failed" else []
        lines += record.log
        body = "\n".join("  " + line for chunk in lines for line in chunk.splitlines())
        parts.append(f"{_key_text(task.key, sweep.plan)}: {record.status}\n{body}\n")
    if not parts:
        path.unlink(missing_ok=True)  # a resumed sweep's old log would describe other runs
        return None
    return table.write_whole(path, "\n".join(parts))


def run_sweep(spec: str | Path | SweepPlan, out_dir: str | Path, *, workers: int | None = None,
              executor: str = "local", address: str | None = None,
              runtime_env: dict[str, object] | None = None, resume: bool = False,
              on_record: Callable[[RunRecord], None] | None = None) -> SweepOutputs:
    """Run the sweep ``spec`` (a SPEC file or a plan from
    :func:`~ubf_async.runs.sweep.spec.load_sweep`) into ``out_dir``: every run not done yet on
    a pool (:func:`~ubf_async.runs.sweep.execution.open_pool`), then the tables. Raises
    :class:`~ubf_async.errors.ConfigurationError` before anything runs."""
    plan = spec if isinstance(spec, SweepPlan) else load_sweep(spec)
    sweep = open_sweep(plan, out_dir, resume=resume)
    if sweep.pending:
        workers = execution.pool_workers(executor, workers, len(sweep.pending))
        with execution.open_pool(executor, workers=workers, address=address,
                                 runtime_env=runtime_env) as pool:
            execute(sweep, pool, on_record)
    return finish(sweep)
