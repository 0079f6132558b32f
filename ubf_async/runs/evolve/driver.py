"""An evolution from its plan to its outputs: :func:`run_evolution`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ubf_async.assembly.robotfile import load_robot_text, read_robot_file
from ubf_async.errors import ConfigurationError
from ubf_async.runs.evolve import report
from ubf_async.runs.evolve.fitness import Evaluator
from ubf_async.runs.evolve.loop import CHECKPOINT, LOG, Evolution, Individual
from ubf_async.runs.evolve.spec import EvolvePlan
from ubf_async.runs.sweep import execution
from ubf_async.runs.sweep.execution import RunRecord
from ubf_async.runs.sweep.journal import JOURNAL

__all__ = ["EvolveOutputs", "check_folder", "compared_robots", "run_evolution"]


@dataclass(frozen=True, slots=True)
class EvolveOutputs:
    """What a finished evolution wrote, and how its best did."""

    out_dir: Path
    best: Path
    generations: int
    best_fitness: float
    seed_fitness: float
    held_out: list[report.Compared]
    ran: int
    """Runs run by this call (the others were in the journal, or met before)."""
    best_is_seed: bool = False
    """Whether the best tree found is the seed robot's own: nothing evolved beat it."""

    @property
    def files(self) -> list[str]:
        return [report.BEST, report.HALL_OF_FAME, report.PARETO, LOG, report.FITNESS_PNG,
                report.TREES_PNG, report.HELD_OUT_CSV, report.REPORT, CHECKPOINT, JOURNAL,
                report.SCENARIOS]


def compared_robots(paths: Sequence[str | Path]) -> list[report.Compared]:
    """Robot files to set beside the evolved one on the held-out set, each loaded first.
    Raises :class:`~ubf_async.errors.RobotFileError`."""
    out = []
    for path in paths:
        text, source = read_robot_file(path)
        load_robot_text(text, source=source)
        out.append(report.Compared(str(path), source, text))
    return out


def check_folder(plan: EvolvePlan, out_dir: str | Path, *, resume: bool) -> Path:
    """``out_dir``, refused when it holds an evolution and ``resume`` is false (a checkpoint
    of another evolution is refused when resuming, by :func:`loop.load_checkpoint`)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigurationError(f"{out}: exists and is not a folder")
    if not resume and ((out / CHECKPOINT).exists() or (out / JOURNAL).exists()):
        raise ConfigurationError(f"{out} holds an evolution already: resume it (--resume), or "
                                 f"choose another folder")
    return out


def run_evolution(plan: EvolvePlan, out_dir: str | Path, *, workers: int | None = None,
                  executor: str = "local", address: str | None = None,
                  runtime_env: dict[str, Any] | None = None, resume: bool = False,
                  compare: Sequence[str | Path] = (),
                  on_run: Callable[[RunRecord], None] | None = None,
                  on_batch: Callable[[int], None] | None = None,
                  on_generation: Callable[[dict[str, Any]], None] | None = None) -> EvolveOutputs:
    """Evolve ``plan`` into ``out_dir`` (resume: from its checkpoint; an evolution already
    finished there writes its outputs again, with ``compare``'s robot files on the held-out
    set beside the evolved one and the seed robot). ``on_batch`` is told how many runs each
    evaluation is about to run (a generation's, the held-out report's), ``on_run`` of each
    run as it ends, ``on_generation`` of each generation's line of the log. Raises
    :class:`~ubf_async.errors.ConfigurationError` before anything runs."""
    out = check_folder(plan, out_dir, resume=resume)
    others = compared_robots(compare)
    out.mkdir(parents=True, exist_ok=True)
    report.write_scenarios(out, (plan.training, plan.held_out))
    workers = execution.pool_workers(executor, workers, plan.population * plan.training.runs)
    with execution.open_pool(executor, workers=workers, address=address,
                             runtime_env=runtime_env) as pool:
        evaluator = Evaluator(plan.fitness, pool, out / JOURNAL, on_run=on_run,
                              on_batch=on_batch)
        try:
            evolution = Evolution(plan, out, evaluator, on_generation=on_generation)
            if resume and (out / CHECKPOINT).exists():
                evolution.resume()
            else:
                evolution.start()
            while not evolution.done:
                evolution.step()
            state = evolution.state
            assert state is not None
            best = report.write_robots(out, plan, state)
            report.plot_fitness(out / report.FITNESS_PNG, state.log)
            seed = Individual.of(plan, plan.seed_tree)
            evolution.evaluate([seed])
            report.draw_trees(out / report.TREES_PNG, [
                (f"the seed robot ({plan.seed_source}): fitness {seed.fitness:g}", seed.tree),
                (f"evolved ({report.BEST}): fitness {state.hall_of_fame[0].fitness:g}",
                 state.hall_of_fame[0].tree)])
            robots = [report.Compared("shipped" if plan.seed_source == "mini-whegs.yaml"
                                      else "seed", plan.seed_source, seed.text),
                      report.Compared("evolved", report.BEST, state.hall_of_fame[0].text),
                      *others]
            compared = report.held_out(evaluator, plan.held_out, robots)
            report.write_report(out, plan, compared)
        finally:
            evaluator.close()
    return EvolveOutputs(out_dir=out, best=best, generations=state.generation + 1,
                         best_fitness=state.hall_of_fame[0].fitness,
                         seed_fitness=seed.fitness, held_out=compared, ran=evaluator.ran,
                         best_is_seed=state.hall_of_fame[0].hash == seed.hash)
