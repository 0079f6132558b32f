"""Tuning a robot file's parameters with Optuna (``python -m ubf_async.tune``, docs/evolve.md):
the same SPEC, scenario sets, runs and fitness as an evolution, the tree kept as it is.

The SPEC's ``tune`` section names paths into the robot file (``tree.children[0].params.
period_s``, as a sweep's overrides do) and the range of each. A trial is a set of values; its
value is the fitness of the robot file with them on the training set — its runs on the sweep's
pool, journaled and cached as an evolution's are. The sampler is seeded: Optuna's TPE by
default, CMA-ES (``sampler: cmaes``) for the ranges it fits (every parameter here is a number).
The trials are asked and told one at a time in this process, each trial's runs spread over
the workers, so a study of one process is the same study whatever the workers.

A new study's first trial is the robot file's own values (where they are in range), so the
best found is never worse than the file on the training set. ``storage`` (an Optuna storage
URL, ``sqlite:///study.db``) keeps the study: the same command resumes it, and several
machines given the same storage work on one study, Optuna's own way — each runs trials until
the study holds ``trials`` complete ones.

Out, in the folder: ``best.yaml`` (the robot file with the best values), ``trials.csv``,
``importance.png`` and ``history.png`` (Optuna's plots), and the held-out report
(``report.md``, ``heldout.csv``: the tuned robot against the file it started from).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ubf_async import extras
from ubf_async.errors import ConfigurationError
from ubf_async.runs import overrides
from ubf_async.runs.evolve import report
from ubf_async.runs.evolve.fitness import Evaluator
from ubf_async.runs.evolve.spec import EvolvePlan, TunePlan
from ubf_async.runs.sweep import execution, table
from ubf_async.runs.sweep.execution import RunRecord
from ubf_async.runs.sweep.journal import JOURNAL

__all__ = ["HISTORY_PNG", "IMPORTANCE_PNG", "IMPORTANCE_TRIALS", "SAMPLERS", "TRIALS_CSV",
           "TuneOutputs",
           "distributions", "draw", "run_study", "tuned_text", "write_trials"]

TRIALS_CSV = "trials.csv"
IMPORTANCE_PNG = "importance.png"
HISTORY_PNG = "history.png"
SAMPLERS = ("tpe", "cmaes")
IMPORTANCE_TRIALS = 20
"""Complete trials below which a ranking of the parameters' importance is noise: the plot
and the console say so (fANOVA fits a forest to the trials; a handful fit anything)."""


@dataclass(frozen=True, slots=True)
class TuneOutputs:
    out_dir: Path
    best: Path
    study: str
    trials: int
    """Complete trials in the study."""
    best_value: float
    best_params: dict[str, Any]
    held_out: list[report.Compared]
    plots: list[Path]
    ran: int


def _optuna() -> Any:
    return extras.require("tune", "optuna", who="tuning")


def _sampler(optuna: Any, name: str, seed: int) -> Any:
    if name == "cmaes":
        return optuna.samplers.CmaEsSampler(seed=seed, warn_independent_sampling=False)
    return optuna.samplers.TPESampler(seed=seed)


def distributions(optuna: Any, tune: TunePlan) -> dict[str, Any]:
    return {path: (optuna.distributions.IntDistribution(int(low), int(high)) if integer
                   else optuna.distributions.FloatDistribution(low, high))
            for path, low, high, integer in tune.parameters}


def tuned_text(tune: TunePlan, params: dict[str, Any], header_lines: list[str]) -> str:
    """The tuned robot file: its data with ``params`` at their paths, as YAML (the comments
    of the file are not kept), after ``header_lines``."""
    data, _ = overrides.robot_data_with(tune.robot_text, params, source=tune.robot_source)
    return report.header(header_lines) + yaml.safe_dump(data, sort_keys=False,
                                                        allow_unicode=True, width=100)


def run_study(plan: EvolvePlan, out_dir: str | Path, *, storage: str | None = None,
              study_name: str | None = None, trials: int | None = None,
              sampler: str | None = None, workers: int | None = None, executor: str = "local",
              address: str | None = None, runtime_env: dict[str, Any] | None = None,
              on_trial: Callable[[int, float, float, int, int], None] | None = None,
              on_run: Callable[[RunRecord], None] | None = None,
              on_batch: Callable[[int], None] | None = None) -> TuneOutputs:
    """Tune ``plan``'s ``tune`` parameters into ``out_dir`` until the study holds ``trials``
    complete trials (default: the SPEC's), then write the outputs. ``on_trial(number, value,
    best, complete, wanted)`` is told of each trial told (``complete``: the study's complete
    trials, that one included; ``wanted``: how many it is to hold). Raises
    :class:`ConfigurationError` before anything runs (no ``tune`` section, no Optuna, a
    storage that cannot be opened)."""
    tune = plan.tune
    if tune is None:
        raise ConfigurationError(f"{plan.source}: no `tune` section: nothing to tune")
    optuna = _optuna()
    wanted = trials if trials is not None else tune.trials
    name = study_name or f"{plan.source.stem}-tune"
    chosen = sampler or tune.sampler
    if chosen not in SAMPLERS:
        raise ConfigurationError(f"sampler {chosen!r}: expected one of {', '.join(SAMPLERS)}")
    try:
        study = optuna.create_study(study_name=name, storage=storage, direction="maximize",
                                    sampler=_sampler(optuna, chosen, plan.seed),
                                    load_if_exists=True)
    except Exception as exc:  # Optuna's and the database's errors alike: refused, said why
        raise ConfigurationError(f"cannot open the study {name!r} in {storage}: "
                                 f"{type(exc).__name__}: {exc}") from None
    if not study.trials and tune.start:
        study.enqueue_trial(tune.start)  # the robot file as written: the first trial
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    report.write_scenarios(out, (plan.training, plan.held_out))
    space = distributions(optuna, tune)
    workers = execution.pool_workers(executor, workers, plan.training.runs)
    complete = optuna.trial.TrialState.COMPLETE
    with execution.open_pool(executor, workers=workers, address=address,
                             runtime_env=runtime_env) as pool:
        evaluator = Evaluator(plan.fitness, pool, out / JOURNAL, on_run=on_run,
                              on_batch=on_batch)
        try:
            while (held := len(study.get_trials(deepcopy=False, states=(complete,)))) < wanted:
                trial = study.ask(space)
                values = tuple(trial.params.items())
                runs = plan.training.tasks(tune.robot_text, tune.robot_source, values)
                value = evaluator.evaluate([runs])[0].fitness
                study.tell(trial, value)
                if on_trial is not None:
                    on_trial(trial.number, value, study.best_value, held + 1, wanted)
            best = study.best_trial
            header_lines = [f"Tuned by python -m ubf_async.tune {plan.source.name} "
                            f"(study {name!r}, {chosen}, seed {plan.seed}) from "
                            f"{tune.robot_source}:",
                            f"fitness {best.value:g} on the training set "
                            f"({plan.training.describe()}), trial {best.number}"]
            text = tuned_text(tune, best.params, header_lines)
            best_path = table.write_whole(out / report.BEST, text)
            compared = report.held_out(evaluator, plan.held_out, [
                report.Compared("shipped" if tune.robot_source == "mini-whegs.yaml"
                                else "untuned", tune.robot_source, tune.robot_text),
                report.Compared("tuned", report.BEST, text)])
            report.write_report(out, plan, compared)
        finally:
            evaluator.close()
    done = study.get_trials(deepcopy=False, states=(complete,))
    write_trials(out / TRIALS_CSV, study, tune.names)
    plots = draw(optuna, study, out, tune.names)
    return TuneOutputs(out_dir=out, best=best_path, study=name, trials=len(done),
                       best_value=best.value, best_params=dict(best.params),
                       held_out=compared, plots=plots, ran=evaluator.ran)


def write_trials(path: Path, study: Any, names: dict[str, str]) -> Path:
    """Every trial: its number, state, value and each parameter, under the name it is shown by
    (``names``: path → name, :attr:`TunePlan.names`)."""
    columns = ["trial", "state", "value", *names.values()]
    rows = [{"trial": t.number, "state": t.state.name, "value": t.value,
             **{name: t.params.get(path) for path, name in names.items()}}
            for t in study.get_trials(deepcopy=False)]
    return table.write_whole(path, table.csv_text(columns, rows))


def draw(optuna: Any, study: Any, out: Path, names: dict[str, str]) -> list[Path]:
    """Optuna's history and importance plots (matplotlib), the parameters under their
    ``names``: the importance needs two complete trials of different values, and is left out
    without them; with fewer than :data:`IMPORTANCE_TRIALS` its title says it is noise."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    drawn = []
    plots = ((HISTORY_PNG, optuna.visualization.matplotlib.plot_optimization_history),
             (IMPORTANCE_PNG, optuna.visualization.matplotlib.plot_param_importances))
    for name, plot in plots:
        with warnings.catch_warnings():
            # Optuna marks its matplotlib plots experimental; the plots are what is wanted.
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            try:
                axes = plot(study)
            except (ValueError, RuntimeError):  # too few distinct trials to say anything
                continue
        if name == IMPORTANCE_PNG:
            axes.set_yticks(axes.get_yticks(), [names.get(label.get_text(), label.get_text())
                                                for label in axes.get_yticklabels()])
            trials = len(study.get_trials(deepcopy=False,
                                          states=(optuna.trial.TrialState.COMPLETE,)))
            if trials < IMPORTANCE_TRIALS:
                axes.set_title(f"Importances from {trials} trials: noise below "
                               f"{IMPORTANCE_TRIALS}", loc="left", color="firebrick")
        figure = axes.figure
        figure.set_size_inches(7, 4)
        figure.tight_layout()
        figure.savefig(out / name, dpi=100)
        plt.close(figure)
        drawn.append(out / name)
    return drawn
