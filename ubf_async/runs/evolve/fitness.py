"""Fitness: figures of the runs' summaries combined as the SPEC says, and the evaluation of
candidates on a sweep's pool, each run journaled and scored once.

A run's **score** is the sum of the SPEC's terms, each ``weight × value``: the value the
figure at a dotted path of the run's summary (``ball_view.facing_share``), ``|figure −
target|`` when a target is given (``ball_distance_m`` against 0.45 m), and ``missing`` in
place of a figure the run's summary leaves empty (the ball never in view). A candidate's
**fitness** over its runs — the set's scenarios × seeds — is ``mean × (mean score) + worst ×
(lowest score)``: higher is better. A candidate one of whose runs failed (it raised) gets
:data:`FAILED_FITNESS`.

The runs are the sweep's (:class:`~ubf_async.runs.sweep.RunTask`, run by
:func:`~ubf_async.runs.sweep.execution.run_task` on :func:`~ubf_async.runs.sweep.open_pool`'s
pool, each appended to the sweep's journal as it finishes). A run is known by a digest of its
robot file's text, the scenario file's, the seed and the duration, so a robot file met again
— an elite, a child identical to another — costs nothing, and a resumed evolution or study
runs only what its journal does not hold. Fitness is a pure function of the runs, so it is
the same whichever worker ran what, in whatever order.
"""

from __future__ import annotations

import json
import statistics
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ubf_async.runs.sweep import execution, table
from ubf_async.runs.sweep.execution import RunRecord
from ubf_async.runs.sweep.journal import Journal, read_journal
from ubf_async.runs.sweep.spec import RunTask, digest

__all__ = ["FAILED_FITNESS", "Evaluation", "Evaluator", "Fitness", "RunScore", "Term", "task"]

FAILED_FITNESS = -1e9
"""The fitness of a candidate one of whose runs raised: below any other."""


@dataclass(frozen=True, slots=True)
class Term:
    """One figure of a run's summary, weighed."""

    figure: str
    weight: float
    target: float | None = None
    missing: float = 0.0

    def value(self, summary: Mapping[str, Any]) -> float:
        found = table.number(table.figure(summary, self.figure))
        value = self.missing if found is None else found
        return abs(value - self.target) if self.target is not None else value

    @property
    def label(self) -> str:
        return f"|{self.figure} − {self.target:g}|" if self.target is not None else self.figure


@dataclass(frozen=True, slots=True)
class RunScore:
    """What a run counts for: its terms' values and its score (``None``: it failed)."""

    values: tuple[float, ...] | None
    score: float | None
    error: str | None = None


@dataclass(frozen=True, slots=True)
class Evaluation:
    """A candidate over its runs."""

    fitness: float
    mean: float | None
    worst: float | None
    failed: int
    values: tuple[tuple[float, ...], ...]
    """Each run's terms' values, in the runs' order."""
    error: str | None = None
    """A failed run's error (the first)."""

    def as_json(self) -> dict[str, Any]:
        return {"fitness": self.fitness, "mean": self.mean, "worst": self.worst,
                "failed": self.failed}


@dataclass(frozen=True, slots=True)
class Fitness:
    """The SPEC's terms and how a candidate's runs combine."""

    terms: tuple[Term, ...]
    mean: float = 1.0
    worst: float = 0.0

    def run_score(self, record: RunRecord) -> RunScore:
        if record.status != "ok" or record.summary is None:
            return RunScore(None, None, record.error or "failed")
        values = tuple(term.value(record.summary) for term in self.terms)
        return RunScore(values, sum(t.weight * v for t, v in zip(self.terms, values,
                                                                  strict=True)))

    def evaluation(self, scores: Sequence[RunScore]) -> Evaluation:
        failed = [s for s in scores if s.score is None]
        ok = [s.score for s in scores if s.score is not None]
        values = tuple(s.values for s in scores if s.values is not None)
        if failed or not ok:
            return Evaluation(FAILED_FITNESS, None, None, len(failed), values,
                              failed[0].error if failed else None)
        mean, worst = statistics.fmean(ok), min(ok)
        return Evaluation(table.significant(self.mean * mean + self.worst * worst),
                          table.significant(mean), table.significant(worst), 0, values)


def task(*, robot_text: str, robot_source: str, scenario: str, scenario_text: str | None,
         seed: int, duration_s: float | None, order: tuple[int, ...] = (),
         overrides: tuple[tuple[str, Any], ...] = ()) -> RunTask:
    """One run of a candidate, known by a digest of everything that makes it."""
    identity = json.dumps([digest(robot_text), [list(o) for o in overrides], scenario,
                           None if scenario_text is None else digest(scenario_text), seed,
                           duration_s], sort_keys=True, separators=(",", ":"))
    return RunTask(run_id=digest(identity), order=order, robot=robot_source,
                   robot_source=robot_source, robot_text=robot_text, overrides=overrides,
                   scenario=scenario, scenario_text=scenario_text, seed=seed,
                   duration_s=duration_s)


class Evaluator:
    """Candidates' runs on ``pool``, each journaled in ``journal_path`` as it finishes and
    scored once (the journal's runs are known at the start: a resumed evolution or study runs
    only the others). ``on_batch`` is told how many runs an evaluation is about to run,
    ``on_run`` of each run as it finishes."""

    def __init__(self, fitness: Fitness, pool: execution.Pool, journal_path: Path, *,
                 on_run: Callable[[RunRecord], None] | None = None,
                 on_batch: Callable[[int], None] | None = None) -> None:
        self.fitness = fitness
        self.pool = pool
        self.scores: dict[str, RunScore] = {
            run_id: fitness.run_score(record)
            for run_id, record in read_journal(journal_path).items() if record.status == "ok"}
        self.journal = Journal(journal_path)
        self.on_run = on_run
        self.on_batch = on_batch
        self.ran = 0

    def pending(self, candidates: Iterable[Sequence[RunTask]]) -> list[RunTask]:
        """The runs of ``candidates`` not scored yet, each once, in their order."""
        seen: set[str] = set()
        out = []
        for runs in candidates:
            for run in runs:
                if run.run_id not in self.scores and run.run_id not in seen:
                    seen.add(run.run_id)
                    out.append(run)
        return out

    def evaluate(self, candidates: Sequence[Sequence[RunTask]]) -> list[Evaluation]:
        """Each candidate's evaluation over its runs (run those not scored yet)."""
        pending = self.pending(candidates)
        if self.on_batch is not None:
            self.on_batch(len(pending))
        for record in self.pool.imap_unordered(execution.run_task, pending, chunksize=1):
            self.journal.append(record)
            self.scores[record.id] = self.fitness.run_score(record)
            self.ran += 1
            if self.on_run is not None:
                self.on_run(record)
        return [self.fitness.evaluation([self.scores[run.run_id] for run in runs])
                for runs in candidates]

    def close(self) -> None:
        self.journal.close()
