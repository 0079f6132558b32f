"""The run's trajectory plot (``trajectory.png`` of ``--record``), drawn with matplotlib.

Top-down, axes in metres: walls, obstacles and distractors; the robot's path coloured by the
behaviour that won each stretch (legend), with time marks every few seconds; the ball's path,
and where the ball was when each step of its script began; start and end poses. It draws on a
:class:`~matplotlib.figure.Figure` of its own (the Agg canvas, no pyplot state), so it may run
in any thread — the simulator runs it in a worker thread, never on the event loop.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon

from components.sim.record import TrajectorySample, ball_on_stage
from components.sim.world import WorldSnapshot

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
    """The figure of one run; ``events`` are ``(time_s, label)`` marked on the ball's path."""
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
    if samples:
        step = time_mark_step_s(samples[-1].t_s - samples[0].t_s)
        next_mark = samples[0].t_s
        for s in samples:
            if s.t_s + 1e-9 >= next_mark:
                ax.plot(s.robot_x_m, s.robot_y_m, marker="o", markersize=4, color="black")
                ax.annotate(f"{s.t_s:g}s", (s.robot_x_m, s.robot_y_m), fontsize=7,
                            xytext=(4, 4), textcoords="offset points")
                next_mark += step
        first, last = samples[0], samples[-1]
        for pose, colour, label in ((first, "#a0a0a0", "start"), (last, "black", "end")):
            ax.annotate("", xy=(pose.robot_x_m + 0.08 * math.cos(pose.robot_heading_rad),
                                pose.robot_y_m + 0.08 * math.sin(pose.robot_heading_rad)),
                        xytext=(pose.robot_x_m, pose.robot_y_m),
                        arrowprops={"arrowstyle": "-|>", "color": colour, "linewidth": 2})
            ax.plot([], [], color=colour, marker=r"$\rightarrow$", linestyle="",
                    label=f"robot at {label}")
    ball = [s for s in samples if ball_on_stage(s)]
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
            at = min(ball, key=lambda s: abs(s.t_s - t_s))
            ax.plot(at.ball_x_m, at.ball_y_m, marker="D", markersize=6, color=BALL_COLOUR,
                    markeredgecolor="black")
            ax.annotate(f"{label} at {t_s:g}s", (at.ball_x_m or 0.0, at.ball_y_m or 0.0),
                        fontsize=7, xytext=(5, -10), textcoords="offset points")
    _frame(ax, samples, ball)
    ax.legend(loc="upper left", fontsize=8, title="robot's path: who won", title_fontsize=8)
    figure.tight_layout()
    return figure


def _frame(ax: object, samples: Sequence[TrajectorySample],
           ball: Sequence[TrajectorySample]) -> None:
    """Show what happened (robot and ball, with a margin), whatever the walls."""
    xs = [s.robot_x_m for s in samples] + [s.ball_x_m or 0.0 for s in ball]
    ys = [s.robot_y_m for s in samples] + [s.ball_y_m or 0.0 for s in ball]
    xs, ys = xs or [0.0], ys or [0.0]
    span = max(max(xs) - min(xs), max(ys) - min(ys), 0.6) + 0.6
    cx, cy = (max(xs) + min(xs)) / 2, (max(ys) + min(ys)) / 2
    ax.set_xlim(cx - span / 2, cx + span / 2)  # type: ignore[attr-defined]
    ax.set_ylim(cy - span / 2, cy + span / 2)  # type: ignore[attr-defined]


def save_run_plot(path: Path, samples: Sequence[TrajectorySample], world: WorldSnapshot, *,
                  title: str, events: Sequence[tuple[float, str]] = ()) -> Figure:
    """Draw :func:`plot_run` and write it as a PNG to ``path``; return the figure."""
    figure = plot_run(samples, world, title=title, events=events)
    figure.savefig(path)
    return figure
