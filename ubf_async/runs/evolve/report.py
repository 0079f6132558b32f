"""What an evolution leaves in its folder, besides its log and checkpoint: the best robot file,
the hall of fame and the Pareto front as robot files, the scenario files its sets were made
of, ``fitness.png``, and the held-out report — robot files against each other on scenarios
and seeds evolution never trained on (``heldout.csv``, ``report.md``).
"""

from __future__ import annotations

import shutil
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ubf_async.runs.evolve import genome
from ubf_async.runs.evolve.fitness import Evaluation, Evaluator, Fitness
from ubf_async.runs.evolve.loop import Individual, State
from ubf_async.runs.evolve.spec import EvolvePlan, ScenarioSet
from ubf_async.runs.sweep import table

__all__ = ["BEST", "FITNESS_PNG", "HALL_OF_FAME", "HELD_OUT_CSV", "PARETO", "REPORT", "SCENARIOS",
           "TREES_PNG", "Compared", "draw_trees", "header", "held_out", "layout", "markdown",
           "node_label", "plot_fitness", "rows", "write_report", "write_robot", "write_robots",
           "write_scenarios"]

BEST = "best.yaml"
HALL_OF_FAME = "hall-of-fame"
PARETO = "pareto"
SCENARIOS = "scenarios"
FITNESS_PNG = "fitness.png"
TREES_PNG = "trees.png"
HELD_OUT_CSV = "heldout.csv"
REPORT = "report.md"


def header(lines: Sequence[str]) -> str:
    return "".join(f"# {line}\n" for line in lines)


def write_robot(path: Path, individual: Individual, plan: EvolvePlan, what: str) -> Path:
    assert individual.evaluation is not None
    text = header([f"{what}, evolved by python -m ubf_async.evolve {plan.source.name} "
                   f"(seed {plan.seed}) from {plan.seed_source}:",
                   f"fitness {individual.fitness:g} on the training set "
                   f"({plan.training.describe()}), {individual.size} nodes"]) + individual.text
    return table.write_whole(path, text)


def write_robots(out: Path, plan: EvolvePlan, state: State) -> Path:
    """``best.yaml``, ``hall-of-fame/NN-HASH.yaml`` and ``pareto/size-NN-HASH.yaml``."""
    best = write_robot(out / BEST, state.hall_of_fame[0], plan, "The best robot")
    for folder, members, name in (
            (HALL_OF_FAME, state.hall_of_fame, lambda k, i: f"{k + 1:02d}-{i.hash}.yaml"),
            (PARETO, state.pareto, lambda k, i: f"size-{i.size:02d}-{i.hash}.yaml")):
        shutil.rmtree(out / folder, ignore_errors=True)  # of an earlier end: written anew
        (out / folder).mkdir()
        for k, individual in enumerate(members):
            write_robot(out / folder / name(k, individual), individual, plan,
                        f"{folder} {k + 1}")
    return best


def write_scenarios(out: Path, sets: Sequence[ScenarioSet]) -> None:
    """The generated scenario files of each set, to run or read again."""
    for scenario_set in sets:
        folder = out / SCENARIOS / scenario_set.label
        folder.mkdir(parents=True, exist_ok=True)
        for made in scenario_set.generated:
            table.write_whole(folder / made.file_name, made.text)


def plot_fitness(path: Path, log: Sequence[dict[str, Any]]) -> Path:
    """Best and mean fitness per generation, and the trees' mean and best's size."""
    import matplotlib  # drawn once, at the end: not imported by the loop's workers

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    from matplotlib.ticker import MaxNLocator

    # Numbered from 1, as the console counts them ("generation 2/2").
    generations = [e["generation"] + 1 for e in log]
    figure, (left, right) = plt.subplots(1, 2, figsize=(9, 4), dpi=100,
                                         gridspec_kw={"width_ratios": [3, 2]})
    left.plot(generations, [e["best"]["fitness"] for e in log], "o-", color="tab:red",
              label="best")
    left.plot(generations, [e["fitness"]["mean"] for e in log], "s--", color="tab:orange",
              label="mean")
    left.set_ylabel("fitness (training set)")
    # Sizes on an axis of their own, beside: a twin axis drew them over the fitness.
    right.plot(generations, [e["size"]["mean"] for e in log], "s--", color="tab:blue",
               label="mean")
    right.plot(generations, [e["best"]["size"] for e in log], "^-", color="tab:cyan",
               label="the best's")
    right.set_ylabel("tree size (nodes)")
    for axes in (left, right):
        axes.set_xlabel("generation")
        axes.xaxis.set_major_locator(MaxNLocator(integer=True))  # whole generations only
        axes.grid(alpha=0.3)
        # Outside the data: above the plot.
        axes.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=2, fontsize=8,
                    frameon=False)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
    return path


def node_label(node: genome.Node) -> str:
    """What a drawn node says: an arbiter's kind (a ``Conditional``'s predicate), a
    behaviour's name and the parameters the file gives it."""
    def values(params: dict[str, Any]) -> str:
        shown = [f"{k} {v:g}" if isinstance(v, int | float) and not isinstance(v, bool)
                 else f"{k} {v}" for k, v in params.items() if k != "source"]
        return "\n".join(shown)

    if genome.is_composite(node):
        kind = genome.arbiter_kind(node)
        params = genome.arbiter_params(node) if isinstance(node["arbiter"], dict) else {}
        if kind == genome.CONDITIONAL:
            predicate = params.get("predicate", "?")
            return f"Conditional\nif {predicate}\n" + values(params.get("predicate_params")
                                                              or {})
        return f"{kind}\n{values(params)}".strip()
    return f"{node['behavior']}\n{values(node.get('params') or {})}".strip()


def layout(tree: genome.Node) -> dict[genome.Path_, tuple[float, float]]:
    """Each node's place in a drawing: leaves one apart left to right, a composite above the
    middle of its children, a level a row down."""
    places: dict[genome.Path_, tuple[float, float]] = {}
    leaves = 0
    for at, node in genome.walk(tree):
        if not node.get("children"):
            places[at] = (float(leaves), -float(len(at)))
            leaves += 1
    for at, node in sorted(genome.walk(tree), key=lambda pair: -len(pair[0])):
        children = node.get("children") or []
        if children:
            places[at] = (statistics.fmean(places[(*at, i)][0] for i in range(len(children))),
                          -float(len(at)))
    return places


def draw_trees(path: Path, trees: Sequence[tuple[str, genome.Node]]) -> Path:
    """The trees side by side, each node a box (composites blue, behaviours green), each
    edge marked with the child's priority."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    widths = [max(1, sum(1 for _, n in genome.walk(tree) if not genome.is_composite(n)))
              for _, tree in trees]
    depth = max(genome.depth(tree) for _, tree in trees)
    figure, axes = plt.subplots(1, len(trees), figsize=(1.25 * sum(widths) + 0.5, 1.5 * depth),
                                dpi=100, gridspec_kw={"width_ratios": widths}, squeeze=False)
    for ax, (title, tree) in zip(axes[0], trees, strict=True):
        places = layout(tree)
        for at, node in genome.walk(tree):
            x, y = places[at]
            for i, child in enumerate(node.get("children") or []):
                cx, cy = places[(*at, i)]
                ax.plot([x, cx], [y, cy], color="0.6", zorder=1)
                ax.text((x + cx) / 2, (y + cy) / 2, f"p{child.get('priority', 0)}",
                        fontsize=7, color="0.3", ha="center", va="center",
                        bbox={"boxstyle": "round", "fc": "white", "ec": "none"}, zorder=2)
            ax.text(x, y, node_label(node), ha="center", va="center", fontsize=8, zorder=3,
                    bbox={"boxstyle": "round", "ec": "0.4",
                          "fc": "#cfe2ff" if genome.is_composite(node) else "#d8f5d0"})
        xs = [x for x, _ in places.values()]
        ax.set_xlim(min(xs) - 0.6, max(xs) + 0.6)
        ax.set_ylim(-depth + 0.4, 0.6)
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
    return path


@dataclass(frozen=True, slots=True)
class Compared:
    """A robot file on the held-out set."""

    label: str
    source: str
    text: str
    evaluation: Evaluation | None = None


def held_out(evaluator: Evaluator, scenario_set: ScenarioSet,
             robots: Sequence[Compared]) -> list[Compared]:
    """Each robot file evaluated on ``scenario_set``."""
    runs = [scenario_set.tasks(r.text, r.source) for r in robots]
    return [Compared(r.label, r.source, r.text, e)
            for r, e in zip(robots, evaluator.evaluate(runs), strict=True)]


def rows(fitness: Fitness, compared: Sequence[Compared]) -> tuple[list[str], list[dict[str, Any]]]:
    """The held-out table: per robot its fitness, mean and worst score, and per term the mean
    of its figure and its worst (the lowest for a term that counts for, the highest for one
    that counts against)."""
    columns = ["robot", "source", "fitness", "mean_score", "worst_score", "failed"]
    for term in fitness.terms:
        columns += [f"{term.label} mean", f"{term.label} worst"]
    out = []
    for robot in compared:
        e = robot.evaluation
        assert e is not None
        row: dict[str, Any] = {"robot": robot.label, "source": robot.source,
                               "fitness": e.fitness if not e.failed else None,
                               "mean_score": e.mean, "worst_score": e.worst, "failed": e.failed}
        for k, term in enumerate(fitness.terms):
            values = [v[k] for v in e.values]
            if values:
                row[f"{term.label} mean"] = table.significant(statistics.fmean(values))
                row[f"{term.label} worst"] = table.significant(
                    min(values) if term.weight >= 0 else max(values))
        out.append(row)
    return columns, out


def markdown(columns: Sequence[str], body: Sequence[dict[str, Any]]) -> str:
    shown = [c for c in columns if c != "source"]
    lines = ["| " + " | ".join(c.replace("|", "\\|") for c in shown) + " |",
             "|" + "|".join("---" if c == "robot" else "---:" for c in shown) + "|"]
    lines += ["| " + " | ".join(table.text(row.get(c)).replace("|", "\\|") for c in shown)
              + " |" for row in body]
    return "\n".join(lines) + "\n"


def write_report(out: Path, plan: EvolvePlan, compared: Sequence[Compared]) -> Path:
    columns, body = rows(plan.fitness, compared)
    table.write_whole(out / HELD_OUT_CSV, table.csv_text(columns, body))
    terms = "; ".join(f"{t.weight:g} × {t.label}" + (f" (missing: {t.missing:g})"
                                                     if t.missing else "")
                      for t in plan.fitness.terms)
    text = (f"# Held-out report: {plan.source.name}\n\n"
            f"Each robot file on the held-out set ({plan.held_out.describe()}; scenarios: "
            f"{', '.join(name for name, _ in plan.held_out.scenarios)}), which evolution "
            f"never trained on. A run's score: {terms}. Fitness: {plan.fitness.mean:g} × "
            f"mean + {plan.fitness.worst:g} × worst.\n\n"
            + markdown(columns, body)
            + "\n" + "".join(f"* {r.label}: {r.source}\n" for r in compared))
    return table.write_whole(out / REPORT, text)
