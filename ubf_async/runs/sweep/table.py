"""A sweep's tables: every run (``runs.csv``, and ``runs.parquet`` when pyarrow is there) and
every cell — the runs that differ only by their seed — aggregated (``cells.csv``).

``runs.csv`` holds nothing that depends on how the runs were run (no wall time, no worker, no
order): the rows in the spec's order of robots, override values, scenarios and seeds, the
columns fixed by the spec and the scenarios' criteria, each value written one way (a float as
Python's shortest repr, ``true``/``false``, empty for none) — so it is the same byte for byte
whatever ran it: one worker or many, a cluster, a resumed sweep.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import statistics
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ubf_async.runs.sweep.execution import RunRecord
from ubf_async.runs.sweep.spec import SweepPlan

__all__ = ["CELLS_CSV", "CRITERION_PREFIX", "RUNS_CSV", "RUNS_PARQUET", "Row", "aggregate",
           "cell_rows", "csv_text", "expected_ranges", "figure", "number", "run_rows",
           "significant", "text", "write_parquet", "write_whole"]

RUNS_CSV = "runs.csv"
RUNS_PARQUET = "runs.parquet"
CELLS_CSV = "cells.csv"
CRITERION_PREFIX = "pass:"

Row = dict[str, Any]


def text(value: Any) -> str:
    """A value as the tables write it: one way only."""
    if value is None:
        return ""
    if value is True or value is False:
        return "true" if value else "false"
    if isinstance(value, int | float | str):
        return repr(value) if isinstance(value, float) else str(value)
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False)


def number(value: Any) -> float | None:
    """``value`` as a number to aggregate or plot (``None``: not a finite number, or a bool)."""
    if value is True or value is False or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def figure(summary: Mapping[str, Any], path: str) -> Any:
    """The summary's field at a dotted ``path`` (``None`` where there is none)."""
    value: Any = summary
    for part in path.split("."):
        value = value.get(part) if isinstance(value, Mapping) else None
    return value


def run_rows(plan: SweepPlan, records: Mapping[str, RunRecord]) -> tuple[list[str], list[Row]]:
    """``(columns, rows)`` of ``runs.csv``: each run of ``plan`` with a record, in the plan's
    order. Columns: the key (robot, each override, scenario, seed), ``status``, the figures,
    ``pass`` (the scenario's expected outcome) and ``pass:CRITERION`` for each criterion of
    any scenario, ``error``."""
    rows: list[Row] = []
    criteria: dict[str, None] = {}  # in the order first met: the same for the same runs
    for task in plan.tasks:
        record = records.get(task.run_id)
        if record is None:
            continue
        summary = record.summary or {}
        expected = summary.get("expected") or {}
        row: Row = {**task.key, "status": record.status}
        row.update({name: figure(summary, name) for name in plan.figures})
        row["pass"] = expected.get("pass")
        for verdict in expected.get("criteria") or ():
            name = CRITERION_PREFIX + str(verdict.get("criterion"))
            criteria.setdefault(name)
            row[name] = verdict.get("pass")
        row["error"] = record.error
        rows.append(row)
    columns = [*plan.key_columns, "status", *plan.figures, "pass", *criteria, "error"]
    return columns, rows


def expected_ranges(plan: SweepPlan, records: Mapping[str, RunRecord],
                    name: str) -> dict[str, tuple[float, float, bool]]:
    """Per scenario, the range its expected outcome gives figure ``name`` (a criterion on it,
    or on its magnitude): ``(low, high, absolute)``, from the runs' summaries (``expected``'s
    criteria); scenarios without one are left out."""
    found: dict[str, tuple[float, float, bool]] = {}
    for task in plan.tasks:
        record = records.get(task.run_id)
        if task.scenario in found or record is None or record.summary is None:
            continue
        for verdict in (record.summary.get("expected") or {}).get("criteria") or ():
            criterion, bounds = verdict.get("criterion"), verdict.get("range")
            if criterion in (name, f"|{name}|") and isinstance(bounds, list) \
                    and len(bounds) == 2:
                found[task.scenario] = (float(bounds[0]), float(bounds[1]),
                                        criterion != name)
    return found


def cell_rows(plan: SweepPlan, rows: Sequence[Row]) -> tuple[list[str], list[Row]]:
    """``(columns, rows)`` of ``cells.csv``: per cell (everything of the key but the seed), the
    number of runs, failed runs and passes, the pass rate (passes over runs: a failed run or
    one not passing counts against), the worst seed (the first that failed or did not pass)
    and per figure its mean, min and max over the seeds, with the seed of each."""
    keys = [c for c in plan.key_columns if c != "seed"]
    cells: dict[tuple[str, ...], list[Row]] = {}
    for row in rows:
        cells.setdefault(tuple(text(row[k]) for k in keys), []).append(row)
    columns = [*keys, "runs", "failed", "passed", "pass_rate", "worst_seed"]
    for name in plan.figures:
        columns += [f"{name}.{what}" for what in ("mean", "min", "min_seed", "max", "max_seed")]
    out: list[Row] = []
    for runs in cells.values():
        passed = sum(1 for r in runs if r["pass"] is True)
        judged = [r for r in runs if r["status"] == "failed" or r["pass"] is not None]
        worst = next((r["seed"] for r in runs if r["status"] == "failed" or r["pass"] is False),
                     None)
        cell: Row = {k: runs[0][k] for k in keys}
        cell.update(runs=len(runs), failed=sum(1 for r in runs if r["status"] == "failed"),
                    passed=passed, worst_seed=worst,
                    pass_rate=significant(passed / len(judged)) if judged else None)
        for name in plan.figures:
            cell.update(aggregate(name, [(r["seed"], number(r[name])) for r in runs]))
        out.append(cell)
    return columns, out


def aggregate(name: str, values: Iterable[tuple[int, float | None]]) -> Row:
    """Mean, min and max of the numbers among ``values`` (seed, number), and their seeds (the
    first seed reaching each)."""
    found = [(seed, value) for seed, value in values if value is not None]
    if not found:
        return {}
    low = min(found, key=lambda pair: pair[1])
    high = max(found, key=lambda pair: pair[1])
    return {f"{name}.mean": significant(statistics.fmean(v for _, v in found)),
            f"{name}.min": low[1], f"{name}.min_seed": low[0],
            f"{name}.max": high[1], f"{name}.max_seed": high[0]}


def significant(value: float) -> float:
    """Six significant digits, as the runs' summaries keep them."""
    return float(f"{value:.6g}")


def csv_text(columns: Sequence[str], rows: Iterable[Row]) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([text(row.get(c)) for c in columns])
    return out.getvalue()


def write_whole(path: Path, data: str | bytes) -> Path:
    """Write ``path`` whole or not at all (a kill while writing leaves the old file)."""
    part = path.with_name(f".{path.name}.part")
    if isinstance(data, str):
        part.write_text(data, encoding="utf-8")
    else:
        part.write_bytes(data)
    os.replace(part, path)
    return path


def write_parquet(path: Path, columns: Sequence[str], rows: Sequence[Row]) -> Path | None:
    """``runs.csv``'s table as Parquet, typed, if pyarrow is installed (``None`` if not). A
    column whose values are not of one type (an override of a number or a name) is text."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    arrays = []
    for column in columns:
        values = [row.get(column) for row in rows]
        try:
            arrays.append(pa.array(values))
        except (pa.ArrowInvalid, pa.ArrowTypeError):
            arrays.append(pa.array([text(v) if v is not None else None for v in values]))
    table = pa.Table.from_arrays(arrays, names=list(columns))
    part = path.with_name(f".{path.name}.part")
    pq.write_table(table, part)
    os.replace(part, path)
    return path
