"""A script of sensor samples over robot time: what a behaviour author feeds a tree."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ubf_async.errors import ConfigurationError
from ubf_async.wire.keys import check_segment

__all__ = ["Sample", "Script", "at", "bins", "every", "mm", "source_of"]


@dataclass(frozen=True, slots=True)
class Sample:
    """One sample of the script: at ``t_s`` of robot time, ``data`` on ``source``
    (``"<kind>/<name>"``), declaring ``period_s`` (``None``: an event, never stale)."""

    t_s: float
    source: str
    data: Mapping[str, Any]
    period_s: float | None = None


def source_of(keyword: str) -> str:
    """``camera_front`` → ``camera/front`` (the kind is the part before the first ``_``);
    a ``kind/name`` stays as it is."""
    kind, sep, name = keyword.replace("/", "_", 1).partition("_")
    if not sep or not kind or not name:
        raise ConfigurationError(f"a source is kind_name (camera_front) or kind/name, got "
                                 f"{keyword!r}")
    check_segment("kind", kind)
    check_segment("name", name)
    return f"{kind}/{name}"


def _check_time(what: str, value: float) -> float:
    if not (math.isfinite(value) and value >= 0):
        raise ConfigurationError(f"{what} must be a finite time ≥ 0 s, got {value!r}")
    return float(value)


def at(t_s: float, *, period_s: float | None = None, **sources: Mapping[str, Any]
       ) -> list[Sample]:
    """One sample per source at ``t_s``: ``at(0.5, camera_front=bins(0, 0, 300, 0, 0))``.
    Without ``period_s`` a sample is an event (it stays fresh until the next)."""
    _check_time("at()'s time", t_s)
    return [Sample(float(t_s), source_of(k), dict(v), period_s) for k, v in sources.items()]


def every(period_s: float, *, from_s: float = 0.0, until_s: float,
          **sources: Mapping[str, Any]) -> list[Sample]:
    """The same sample of each source every ``period_s`` from ``from_s`` until before
    ``until_s``, each declaring ``period_s`` (a sensor publishing at its rate)."""
    if not (math.isfinite(period_s) and period_s > 0):
        raise ConfigurationError(f"every()'s period must be > 0 s, got {period_s!r}")
    start, end = _check_time("from_s", from_s), _check_time("until_s", until_s)
    count = max(0, math.ceil((end - start) / period_s - 1e-9))
    return [sample for i in range(count)
            for sample in at(start + i * period_s, period_s=period_s, **sources)]


def bins(*counts: int) -> dict[str, Any]:
    """A camera's seekcolor sample: pink pixels in its 5 bins, image left to right."""
    if len(counts) != 5:
        raise ConfigurationError(f"bins() takes the 5 bins' counts, got {len(counts)}")
    return {"bins": list(counts), "total": sum(counts)}


def mm(range_mm: int | None, *, status: str = "ok") -> dict[str, Any]:
    """A range finder's sample: ``mm(180)``; out of range ``mm(None, status="too_far")``."""
    return {"range_mm": range_mm, "status": status}


class Script:
    """Samples in time order (the order given among samples of one instant)."""

    def __init__(self, *parts: Sample | Iterable[Sample]) -> None:
        samples: list[Sample] = []
        for part in parts:
            samples.extend([part] if isinstance(part, Sample) else part)
        self.samples = sorted(samples, key=lambda s: s.t_s)

    @classmethod
    def from_csv(cls, source: str | Path) -> Script:
        """From a CSV file (or its text) with the columns ``t_s``, ``source``, ``period_s``
        (empty: an event) and ``data`` (the sample's fields as JSON)::

            t_s,source,period_s,data
            0.5,camera/front,0.11,"{""bins"": [0, 0, 300, 0, 0], ""total"": 300}"
        """
        text = source.read_text("utf-8") if isinstance(source, Path) else source
        rows = csv.DictReader(io.StringIO(text))
        missing = {"t_s", "source", "data"} - set(rows.fieldnames or ())
        if missing:
            raise ConfigurationError(f"a script's CSV needs the columns t_s, source, data "
                                     f"(and period_s); missing {sorted(missing)}")
        samples = []
        for line, row in enumerate(rows, start=2):
            try:
                period = row.get("period_s") or ""
                data = json.loads(row["data"])
                if not isinstance(data, dict):
                    raise ValueError("data is not a JSON object")
                samples.append(Sample(_check_time("t_s", float(row["t_s"])),
                                      source_of(row["source"]), data,
                                      float(period) if period.strip() else None))
            except (ValueError, ConfigurationError) as exc:
                raise ConfigurationError(f"script CSV line {line}: {exc}") from None
        return cls(samples)

    def __len__(self) -> int:
        return len(self.samples)

    def __repr__(self) -> str:
        sources = sorted({s.source for s in self.samples})
        span = f"{self.samples[0].t_s:g}–{self.samples[-1].t_s:g} s" if self.samples else "empty"
        return f"<Script {len(self.samples)} samples of {', '.join(sources) or 'nothing'}, {span}>"
