"""A sweep's plot: one figure of its table against each swept parameter (``DIR/FIGURE.png``).

One panel per parameter the sweep varies (the robot file, each override with more than one
value; the scenario when nothing else varies): its values along the x axis in the spec's order,
every run as a dot (one colour per scenario), the mean over the dots at each value as a dash,
the dashes joined by a line where the values are numbers, and the range each scenario's
expected outcome gives the figure as a band of its colour. Drawn with matplotlib's Agg canvas
on a figure of its own (no pyplot, no global state), once the runs are done.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ubf_async.runs.sweep.spec import SweepPlan
from ubf_async.runs.sweep.table import Row, number, text

__all__ = ["LABEL_CHARS", "PANELS_PER_ROW", "PANEL_SIZE", "plot_figure", "swept"]

PANEL_SIZE = (4.2, 3.4)
PANELS_PER_ROW = 3
LABEL_CHARS = 18


def swept(plan: SweepPlan) -> list[tuple[str, tuple[Any, ...]]]:
    """The key columns the sweep varies, but the seed and the scenario (which tell the dots
    apart); the scenario alone when nothing else varies."""
    varied = [(name, values) for name, values in plan.dimensions()
              if len(values) > 1 and name not in ("seed", "scenario")]
    return varied or [("scenario", plan.scenarios)]


def plot_figure(plan: SweepPlan, rows: Sequence[Row], name: str, path: Path,
                bands: Mapping[str, tuple[float, float, bool]] | None = None) -> Path | None:
    """Draw figure ``name`` of the runs ``rows`` against each swept parameter into ``path``;
    ``None`` (nothing written) when no run has a number for it. ``bands``: per scenario, the
    range its expected outcome gives the figure (``(low, high, absolute)``:
    :func:`~ubf_async.runs.sweep.table.expected_ranges`), drawn as a band of its colour."""
    # Imported here: a sweep's workers import this package too, and draw nothing.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ok = [row for row in rows if row["status"] == "ok" and number(row[name]) is not None]
    if not ok:
        return None
    panels = swept(plan)
    columns = min(len(panels), PANELS_PER_ROW)
    lines = -(-len(panels) // columns)
    figure = Figure(figsize=(PANEL_SIZE[0] * columns, PANEL_SIZE[1] * lines), dpi=100,
                    layout="constrained")
    FigureCanvasAgg(figure)
    scenarios = plan.scenarios if panels[0][0] != "scenario" else ("",)
    colours = [f"C{i % 10}" for i in range(len(scenarios))]
    for index, (column, values) in enumerate(panels):
        axes = figure.add_subplot(lines, columns, index + 1)
        for s, scenario in enumerate(scenarios):
            band = (bands or {}).get(scenario or plan.scenarios[0])
            if band is not None:
                low, high, absolute = band
                spans = [(low, high), (-high, -low)] if absolute else [(low, high)]
                for i, (bottom, top) in enumerate(spans):
                    axes.axhspan(bottom, top, color=colours[s], alpha=0.12, linewidth=0,
                                 label="expected" if i == 0 and index == 0 and s == 0
                                 and len(scenarios) == 1 else None)
        spread = 0.5 / len(scenarios)
        scale = all(number(value) is not None for value in values)
        for s, scenario in enumerate(scenarios):
            offset = (s - (len(scenarios) - 1) / 2) * spread
            means: list[tuple[float, float]] = []
            for x, value in enumerate(values):
                ys = [number(row[name]) for row in ok if text(row[column]) == text(value)
                      and (not scenario or row["scenario"] == scenario)]
                found = [y for y in ys if y is not None]
                if not found:
                    continue
                axes.scatter([x + offset] * len(found), found, s=14, alpha=0.55,
                             color=colours[s], linewidths=0)
                means.append((x + offset, sum(found) / len(found)))
            if means:  # joined where the values lie on a scale (numbers), not for names
                axes.plot([m[0] for m in means], [m[1] for m in means], marker="_",
                          markersize=16, color=colours[s], label=scenario or None,
                          linestyle="-" if scale else "none")
        axes.set_xticks(range(len(values)), [_label(v) for v in values])
        axes.set_xlabel(column)
        axes.set_ylabel(name)
        axes.grid(True, axis="y", alpha=0.3)
        if index == 0 and scenarios != ("",):
            axes.legend(fontsize="small", title="scenario (band: expected)",
                        title_fontsize="small")
        elif index == 0 and bands:
            axes.legend(fontsize="small")
    failed = sum(1 for row in rows if row["status"] == "failed")
    figure.suptitle(f"{name}: {len(ok)} runs, mean per value"
                    + (f" ({failed} failed runs left out)" if failed else ""), fontsize="medium")
    part = path.with_name(f".{path.name}.part.png")
    figure.savefig(part)
    os.replace(part, path)  # whole or not at all
    return path


def _label(value: Any) -> str:
    label = text(value)
    return label if len(label) <= LABEL_CHARS else label[:LABEL_CHARS - 1] + "…"
