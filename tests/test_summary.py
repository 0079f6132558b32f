"""The run summary: how the run was started and with which version, the scenario's expected
outcome with a verdict per criterion, a warning when the run could not keep the speed asked
for, and numbers rounded to sensible precision.

What a summary says of the run is checked on runs in this process
(:func:`ubf_async.experiment.run`, the same summary as launch's, tests/test_experiment.py);
what launch writes and prints, on one launch shared by those tests (and, for a run that
settles, the suite's launch of ``ball-in-sight``, tests/shared_runs.py)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from matplotlib.text import Text

from tests.shared_runs import Launch, launched, launched_once
from ubf_async import experiment

ONE_SECOND_TOO_FAST = ["--scenario", "ball-in-sight", "--speed", "500", "--duration", "1",
                       "--quiet", "--listen", "tcp/127.0.0.1:0"]
"""One simulated second of ball-in-sight (too short to settle) asked for at 500x real time
(more than any machine reaches)."""


def one_second_too_fast(factory: pytest.TempPathFactory) -> Launch:
    launch = launched_once(factory, "summary-one-second-at-500x",
                           lambda folder: list(ONE_SECOND_TOO_FAST))
    assert launch.returncode == 0, launch.output
    return launch


def floats(value: Any) -> list[float]:
    if isinstance(value, float):
        return [value]
    if isinstance(value, dict):
        return [f for v in value.values() for f in floats(v)]
    if isinstance(value, list):
        return [f for v in value for f in floats(v)]
    return []


def six_significant_digits_at_most(summary: dict[str, Any]) -> bool:
    return all(len(f"{abs(f):.15g}".replace(".", "").lstrip("0").rstrip("0")) <= 6
               for f in floats(summary))


def test_a_run_too_short_to_settle_fails_its_expected_outcome() -> None:
    summary = experiment.run("mini-whegs", "ball-in-sight", duration_s=1.0).summary
    expected = summary["expected"]
    assert expected["outcome"].startswith("turns to the ball")
    verdicts = {c["criterion"]: c for c in expected["criteria"]}
    moving = verdicts["motion_last_2s.max_offset_m"]  # still driving at the ball after 1 s
    assert moving["pass"] is False and moving["value"] > 0.02
    assert expected["pass"] is False
    assert summary["version"] == "0.1.0"
    # Six significant digits at most, not seventeen.
    assert floats(summary) and six_significant_digits_at_most(summary)


def test_launch_prints_the_verdict_and_writes_how_it_was_started(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    launch = one_second_too_fast(tmp_path_factory)
    summary = launch.summary()
    assert summary["expected"]["pass"] is False
    assert "expected: turns to the ball" in launch.output and "NOT met (" in launch.output
    assert "motion_last_2s.max_offset_m" in launch.output
    assert summary["command_line"][:3] == ["python", "-m", "ubf_async.launch"]
    assert "--duration" in summary["command_line"]
    assert summary["version"] == "0.1.0"
    assert six_significant_digits_at_most(summary)


def test_a_run_that_settles_meets_it_and_a_run_too_slow_is_warned_about(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    settles = launched(tmp_path_factory, "ball-in-sight")  # 25 s, flat out
    assert settles.returncode == 0, settles.output
    assert settles.summary()["expected"]["pass"] is True, settles.summary()["expected"]
    assert "— met" in settles.output
    assert settles.summary()["warnings"] == []  # flat out is never too slow
    launch = one_second_too_fast(tmp_path_factory)
    summary = launch.summary()
    rtf = summary["real_time_factor"]
    assert rtf < 500
    [warning] = summary["warnings"]
    said = re.fullmatch(r"the run reached ([0-9.]+)x real time, short of the 500x asked for "
                        r"\(--speed\): the machine could not keep up", warning)
    assert said is not None, warning
    assert abs(float(said[1]) - rtf) <= 0.01  # two decimals of the unrounded factor
    assert "warning: the run reached" in launch.output


def test_the_trajectory_plot_is_in_metres_with_time_marks_events_and_winners(
        tmp_path: Path) -> None:
    """The plot a recorded run draws (launch's --record, run()'s pictures: the same runner)."""
    from components.sim.outputs.plots import save_run_plot
    from components.sim.outputs.trajectory import read_trajectory_csv
    from components.sim.scenarios.scenario import load_scenario
    from components.sim.world.physics import World

    experiment.run("mini-whegs", "keep-away", duration_s=25.0, out_dir=tmp_path, pictures=True)
    assert (tmp_path / "trajectory.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    scenario = load_scenario("keep-away")
    samples = read_trajectory_csv(tmp_path / "trajectory.csv")
    events = [(step.at_s, f"ball: {step.kind}") for step in scenario.ball_script
              if step.at_s <= 25]
    figure = save_run_plot(tmp_path / "again.png", samples, World(scenario.world).snapshot(),
                           title="keep-away", events=events)
    ax = figure.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (m)", "y (m)")
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert {"search", "chase"} <= set(legend) and "ball" in legend
    labels = [t for t in ax.texts if t.get_text()]  # (the start and end arrows have none)
    notes = [t.get_text() for t in labels]
    # Time marks along the path, every 5 s of the 25: those the robot passed standing still
    # share a label ("10–15s").
    marked: set[float] = set()
    for note in notes:
        if (span := re.fullmatch(r"([\d.]+)(?:–([\d.]+))?s", note)) is not None:
            first, last = float(span[1]), float(span[2] or span[1])
            marked.update(t for t in (0, 5, 10, 15, 20, 25) if first <= t <= last)
    assert marked >= {0, 5, 10, 15, 20}, notes
    # Every step of the ball's script, once (steps at one place share a label).
    assert sum(n.count(" at ") for n in notes if n.startswith("ball: ")) == len(events) >= 1
    # No label covers another, the legend, or leaves the plot.
    renderer = figure.canvas.get_renderer()  # type: ignore[attr-defined]
    boxes = []
    for label in labels:
        label.update_positions(renderer)
        boxes.append(Text.get_window_extent(label, renderer))
    area = ax.get_window_extent(renderer)
    legend_box = ax.get_legend().get_window_extent(renderer)
    for i, box in enumerate(boxes):
        assert area.contains(box.x0, box.y0) and area.contains(box.x1, box.y1), notes[i]
        assert not box.overlaps(legend_box), notes[i]
        for j in range(i):
            assert not box.overlaps(boxes[j]), (notes[i], notes[j])
    # Framed on what happened: the ball lifted out of the world is not in view.
    assert ax.get_xlim()[1] < 5 and ax.get_ylim()[1] < 5
