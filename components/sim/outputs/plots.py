"""The run's trajectory plot (``trajectory.png`` of ``--record``), drawn with matplotlib.

Top-down, axes in metres: walls, obstacles and distractors; the robot's path coloured by the
behaviour that won each stretch (legend), with time marks every few seconds; the ball's path,
and where the ball was when each step of its script began; start and end poses. It draws on a
:class:`~matplotlib.figure.Figure` of its own (the Agg canvas, no pyplot state), so it may run
in any thread — the simulator runs it in a worker thread, never on the event loop.

Labels never sit on one another: time marks the robot passed while standing still are one
label (``60–70s``), script steps at one place are one label, and each label goes at the first
of a ring of places around its point that overlaps no label, marker or the legend (with a
leader line when it had to move away).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from pathlib import Path

from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon
from matplotlib.text import Annotation, Text
from matplotlib.transforms import Bbox

from components.sim.outputs.trajectory import TrajectorySample, ball_on_stage
from components.sim.world.snapshot import WorldSnapshot

__all__ = ["BALL_COLOUR", "NEAR_PX", "WINNER_COLOURS", "plot_run", "save_run_plot",
           "time_mark_step_s"]

WINNER_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple",
                  "tab:brown", "tab:olive", "tab:cyan")
BALL_COLOUR = "#ff3ca0"


def time_mark_step_s(duration_s: float) -> float:
    """A round step giving five to ten time marks over the run."""
    for step in (0.5, 1, 2, 5, 10, 20, 30, 60, 120, 300, 600):
        if duration_s / step <= 10:
            return step
    return 600.0 * math.ceil(duration_s / 6000)


def plot_run(samples: Sequence[TrajectorySample], world: WorldSnapshot, *, title: str,
             events: Sequence[tuple[float, str]] = ()) -> Figure:
    """The figure of one run; ``events`` are ``(time_s, label)`` marked on the ball's path,
    those after the last sample left out (a script's later steps never happened in a run
    shorter than the scenario)."""
    figure = Figure(figsize=(8, 8), dpi=100)
    FigureCanvasAgg(figure)
    ax = figure.add_subplot()
    ax.set_title(title, fontsize=11)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.grid(True, color="#e0e0e0", linewidth=0.6)
    for wall in world.walls:
        ax.plot([wall.x1_m, wall.x2_m], [wall.y1_m, wall.y2_m], color="#3c3c3c", linewidth=3)
    for box in world.boxes:
        ax.add_patch(Polygon(box.corners(), closed=True, color="#787878"))
    for d in world.distractors:
        ax.add_patch(Circle((d.x_m, d.y_m), max(d.radius_m, 0.02),
                            color=tuple(c / 255 for c in d.color)))
    # The robot's path, one colour per winning behaviour.
    segments: dict[str, list[list[tuple[float, float]]]] = {}
    for a, b in itertools.pairwise(samples):
        segments.setdefault(b.winners or "(none: a stop)", []).append(
            [(a.robot_x_m, a.robot_y_m), (b.robot_x_m, b.robot_y_m)])
    for i, (who, lines) in enumerate(segments.items()):
        ax.add_collection(LineCollection(lines, colors=WINNER_COLOURS[i % len(WINNER_COLOURS)],
                                         linewidths=2.2, capstyle="round", label=who))
    marks: list[tuple[TrajectorySample, str]] = []
    if samples:
        step = time_mark_step_s(samples[-1].t_s - samples[0].t_s)
        next_mark = samples[0].t_s
        for s in samples:
            if s.t_s + 1e-9 >= next_mark:
                ax.plot(s.robot_x_m, s.robot_y_m, marker="o", markersize=4, color="black")
                marks.append((s, f"{s.t_s:g}"))
                next_mark += step
        first, last = samples[0], samples[-1]
        for pose, colour, label in ((first, "#a0a0a0", "start"), (last, "black", "end")):
            ax.annotate("", xy=_arrow_tip(pose), xytext=(pose.robot_x_m, pose.robot_y_m),
                        arrowprops={"arrowstyle": "-|>", "color": colour, "linewidth": 2})
            ax.plot([], [], color=colour, marker=r"$\rightarrow$", linestyle="",
                    label=f"robot at {label}")
    ball = [s for s in samples if ball_on_stage(s)]
    steps: list[tuple[tuple[float, float], str]] = []
    if ball:
        # The ball's path, broken where a script lifted it out of the world.
        hops = [[(a.ball_x_m or 0.0, a.ball_y_m or 0.0), (b.ball_x_m or 0.0, b.ball_y_m or 0.0)]
                for a, b in itertools.pairwise(samples)
                if ball_on_stage(a) and ball_on_stage(b)]
        ax.add_collection(LineCollection(hops, colors=BALL_COLOUR, linewidths=1,
                                         linestyles="--", label="ball"))
        ax.add_patch(Circle((ball[-1].ball_x_m or 0.0, ball[-1].ball_y_m or 0.0), 0.0325,
                            color=BALL_COLOUR))
        for t_s, label in events:
            if t_s > samples[-1].t_s + 1e-9:
                continue
            at = min(ball, key=lambda s: abs(s.t_s - t_s))
            where = (at.ball_x_m or 0.0, at.ball_y_m or 0.0)
            ax.plot(*where, marker="D", markersize=6, color=BALL_COLOUR, markeredgecolor="black")
            steps.append((where, f"{label} at {t_s:g}s"))
    _frame(ax, samples, ball)
    ax.legend(loc="upper left", fontsize=8, title="robot's path: who won", title_fontsize=8)
    figure.tight_layout()  # before the labels: they are placed in the final layout's pixels
    labels = _Labels(ax)
    for xy in [xy for xy, _ in steps] + [_xy(s) for s, _ in marks]:
        labels.reserve(xy)  # every marked point, before any label can cover one
    for pose in (samples[0], samples[-1]) if samples else ():
        labels.reserve(_xy(pose), _arrow_tip(pose))  # and the start and end arrows
    for xy, text in _merge_steps(ax, steps):
        labels.add(xy, text, color="#b0006a")
    for xy, text in _merge_marks(ax, marks):
        labels.add(xy, text)
    return figure


NEAR_PX = 10.0
"""Points closer than this on the figure (pixels) share one label."""


def _merge_marks(ax: Axes, marks: Sequence[tuple[TrajectorySample, str]]
                 ) -> list[tuple[tuple[float, float], str]]:
    """Time marks (``(sample, "12")``) as labels: consecutive marks the robot passed without
    moving away (a stop, a turn on the spot) are one label, ``60–70s``."""
    groups: list[list[tuple[TrajectorySample, str]]] = []
    for mark in marks:
        if groups and _px(ax, _xy(groups[-1][0][0]), _xy(mark[0])) < NEAR_PX:
            groups[-1].append(mark)
        else:
            groups.append([mark])
    return [(_xy(group[0][0]),
             f"{group[0][1]}s" if len(group) == 1 else f"{group[0][1]}–{group[-1][1]}s")
            for group in groups]


def _merge_steps(ax: Axes, steps: Sequence[tuple[tuple[float, float], str]]
                 ) -> list[tuple[tuple[float, float], str]]:
    """The ball script's steps as labels: steps where the ball was at one place (a hide and
    the next step's placing, taken at the last place it was seen) are one label."""
    merged: list[tuple[tuple[float, float], list[str]]] = []
    for xy, text in steps:
        near = next((m for m in merged if _px(ax, m[0], xy) < NEAR_PX), None)
        if near is None:
            merged.append((xy, [text]))
        else:
            near[1].append(text.removeprefix("ball: "))
    return [(xy, ", ".join(texts)) for xy, texts in merged]


def _xy(sample: TrajectorySample) -> tuple[float, float]:
    return sample.robot_x_m, sample.robot_y_m


def _arrow_tip(pose: TrajectorySample) -> tuple[float, float]:
    """The tip of the arrow showing the robot's heading at ``pose`` (8 cm long)."""
    return (pose.robot_x_m + 0.08 * math.cos(pose.robot_heading_rad),
            pose.robot_y_m + 0.08 * math.sin(pose.robot_heading_rad))


def _px(ax: Axes, a: tuple[float, float], b: tuple[float, float]) -> float:
    """The distance between two points of the plot on the figure, in pixels."""
    (ax_, ay_), (bx_, by_) = ax.transData.transform([a, b])
    return math.hypot(bx_ - ax_, by_ - ay_)


class _Labels:
    """Places text labels next to points so that none overlaps another label, a labelled
    point or the legend, and none leaves the axes: each takes the first free place of rings
    of eight around its point (nearest first), with a leader line beyond the first ring."""

    RINGS_PT = (5, 12, 22, 34, 48)
    DIRECTIONS = ((1, 1), (1, -1), (-1, 1), (-1, -1), (1, 0), (-1, 0), (0, 1), (0, -1))

    def __init__(self, ax: Axes) -> None:
        self.ax = ax
        self.renderer = ax.figure.canvas.get_renderer()  # type: ignore[attr-defined]
        self.area = ax.get_window_extent(self.renderer)
        legend = ax.get_legend()
        self.taken: list[Bbox] = ([legend.get_window_extent(self.renderer)]
                                  if legend is not None else [])

    def reserve(self, *xy: tuple[float, float]) -> None:
        """Keep labels off a marked point (or the box around several: an arrow's ends)."""
        points = self.ax.transData.transform(list(xy))
        self.taken.append(Bbox.from_extents(points[:, 0].min() - 4, points[:, 1].min() - 4,
                                            points[:, 0].max() + 4, points[:, 1].max() + 4))

    def add(self, xy: tuple[float, float], text: str, **style: object) -> None:
        first = None
        for ring, radius in enumerate(self.RINGS_PT):
            for dx, dy in self.DIRECTIONS:
                # A leader line to its point unless in the usual place (above right, close).
                leader = ring > 0 or (dx, dy) != self.DIRECTIONS[0]
                label = self._annotate(xy, text, dx, dy, radius, leader=leader, **style)
                # The text's own box (a leader line may cross points, a label may not), where
                # the offset puts it (update_positions: what drawing would do first).
                label.update_positions(self.renderer)
                box = Text.get_window_extent(label, self.renderer).padded(2)
                if self._fits(box):
                    self.taken.append(box)
                    if first is not None:
                        first.remove()
                    return
                if first is None:
                    first = label  # kept if no place is free: overlapping beats missing
                else:
                    label.remove()

    def _annotate(self, xy: tuple[float, float], text: str, dx: int, dy: int, radius: float,
                  *, leader: bool, **style: object) -> Annotation:
        label = self.ax.annotate(
            text, xy, xytext=(dx * radius, dy * radius), textcoords="offset points",
            fontsize=7, ha={1: "left", 0: "center", -1: "right"}[dx],
            va={1: "bottom", 0: "center", -1: "top"}[dy],
            bbox={"boxstyle": "round,pad=0.15", "facecolor": "white", "alpha": 0.75,
                  "linewidth": 0},
            arrowprops={"arrowstyle": "-", "color": "#808080", "linewidth": 0.6,
                        "shrinkA": 0, "shrinkB": 2} if leader else None,
            **style)  # type: ignore[arg-type]
        label.set_in_layout(False)
        return label

    def _fits(self, box: Bbox) -> bool:
        inside = (box.x0 >= self.area.x0 and box.x1 <= self.area.x1
                  and box.y0 >= self.area.y0 and box.y1 <= self.area.y1)
        return inside and not any(box.overlaps(other) for other in self.taken)


def _frame(ax: Axes, samples: Sequence[TrajectorySample],
           ball: Sequence[TrajectorySample]) -> None:
    """Show what happened (robot and ball, with a margin), whatever the walls."""
    xs = [s.robot_x_m for s in samples] + [s.ball_x_m or 0.0 for s in ball]
    ys = [s.robot_y_m for s in samples] + [s.ball_y_m or 0.0 for s in ball]
    xs, ys = xs or [0.0], ys or [0.0]
    span = max(max(xs) - min(xs), max(ys) - min(ys), 0.6) + 0.6
    cx, cy = (max(xs) + min(xs)) / 2, (max(ys) + min(ys)) / 2
    ax.set_xlim(cx - span / 2, cx + span / 2)
    ax.set_ylim(cy - span / 2, cy + span / 2)


def save_run_plot(path: Path, samples: Sequence[TrajectorySample], world: WorldSnapshot, *,
                  title: str, events: Sequence[tuple[float, str]] = ()) -> Figure:
    """Draw :func:`plot_run` and write it as a PNG to ``path``; return the figure."""
    figure = plot_run(samples, world, title=title, events=events)
    figure.savefig(path)
    return figure
