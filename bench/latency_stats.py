"""Small statistics helpers for the latency benchmark: percentiles and printable figures.

Every figure is computed from durations in nanoseconds that one timer observed (two
``time.monotonic_ns()`` readings, or stamps carried in messages and compared on the same
host); nothing here invents or interpolates an event that was not observed.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any


def percentile(sorted_values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile (0…100) of already sorted values, nearest-rank method
    (always a value that was actually observed)."""
    if not sorted_values:
        raise ValueError("no values")
    rank = max(1, math.ceil(q / 100.0 * len(sorted_values)))
    return sorted_values[min(rank, len(sorted_values)) - 1]


def summarize(values_ns: Iterable[float]) -> dict[str, Any]:
    """``{n, median_us, p90_us, p99_us, max_us, min_us, mean_us}`` of durations in ns.

    The median is the nearest-rank 50th percentile, so every figure is an observed sample.
    """
    values = sorted(values_ns)
    if not values:
        return {"n": 0}
    us = [v / 1e3 for v in values]
    return {
        "n": len(us),
        "min_us": us[0],
        "median_us": percentile(us, 50),
        "p90_us": percentile(us, 90),
        "p99_us": percentile(us, 99),
        "max_us": us[-1],
        "mean_us": sum(us) / len(us),
    }


def fmt_us(value_us: float | None) -> str:
    """A duration given in µs as a short string: µs below 10 ms, ms above."""
    if value_us is None:
        return "—"
    if abs(value_us) >= 10_000:
        return f"{value_us / 1e3:.1f} ms"
    if abs(value_us) >= 1000:
        return f"{value_us / 1e3:.2f} ms"
    return f"{value_us:.0f} µs"


def ratio(
    a: dict[str, Any] | None, b: dict[str, Any] | None, key: str = "median_us"
) -> float | None:
    """``a[key] / b[key]`` when both exist and ``b[key] > 0``."""
    if not a or not b or a.get(key) is None or not b.get(key):
        return None
    return a[key] / b[key]


def row(label: str, summary: dict[str, Any] | None, note: str = "") -> str:
    """One table line: label, n, median, p90, p99, max, note."""
    if not summary or not summary.get("n"):
        return f"  {label:<46} {'n=0':>6}  {'':>9} {'':>9} {'':>9} {'':>9}  {note}"
    s = summary
    return (f"  {label:<46} {s['n']:>6}  {fmt_us(s['median_us']):>9} {fmt_us(s['p90_us']):>9} "
            f"{fmt_us(s['p99_us']):>9} {fmt_us(s['max_us']):>9}  {note}").rstrip()


def header() -> str:
    return (f"  {'':<46} {'n':>6}  {'median':>9} {'p90':>9} {'p99':>9} {'max':>9}")
