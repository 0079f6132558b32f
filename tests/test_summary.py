"""The run summary: how the run was started and with which version, the scenario's expected
outcome with a verdict per criterion, a warning when the run could not keep the speed asked
for, and numbers rounded to sensible precision."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

from matplotlib.text import Text

ROOT = Path(__file__).resolve().parent.parent


def launch(tmp_path: Path, *args: str) -> tuple[dict[str, Any], str]:
    summary = tmp_path / "summary.json"
    result = subprocess.run(
        [sys.executable, "-m", "ubf_async.launch", "--scenario", "ball-in-sight", "--quiet",
         "--listen", "tcp/127.0.0.1:0", "--summary", str(summary), *args],
        cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    return json.loads(summary.read_text()), result.stdout


def floats(value: Any) -> list[float]:
    if isinstance(value, float):
        return [value]
    if isinstance(value, dict):
        return [f for v in value.values() for f in floats(v)]
    if isinstance(value, list):
        return [f for v in value for f in floats(v)]
    return []


def test_a_run_too_short_to_settle_fails_its_expected_outcome(tmp_path: Path) -> None:
    summary, out = launch(tmp_path, "--speed", "5", "--duration", "1")
    expected = summary["expected"]
    assert expected["outcome"].startswith("turns to the ball")
    verdicts = {c["criterion"]: c for c in expected["criteria"]}
    moving = verdicts["motion_last_2s.max_offset_m"]  # still driving at the ball after 1 s
    assert moving["pass"] is False and moving["value"] > 0.02
    assert expected["pass"] is False
    assert "expected: turns to the ball" in out and "NOT met (" in out
    assert "motion_last_2s.max_offset_m" in out
    assert summary["command_line"][:3] == ["python", "-m", "ubf_async.launch"]
    assert "--duration" in summary["command_line"]
    assert summary["version"] == "0.1.0"
    # Six significant digits at most, not seventeen.
    assert all(len(f"{abs(f):.15g}".replace(".", "").lstrip("0").rstrip("0")) <= 6
               for f in floats(summary))


def test_a_run_that_settles_meets_it_and_a_run_too_slow_is_warned_about(
        tmp_path: Path) -> None:
    summary, out = launch(tmp_path, "--speed", "500", "--duration", "25")
    assert summary["expected"]["pass"] is True, summary["expected"]
    assert "— met" in out
    rtf = summary["real_time_factor"]
    assert rtf < 500
    [warning] = summary["warnings"]
    said = re.fullmatch(r"the run reached ([0-9.]+)x real time, short of the 500x asked for "
                        r"\(--speed\): the machine could not keep up", warning)
    assert said is not None, warning
    assert abs(float(said[1]) - rtf) <= 0.01  # two decimals of the unrounded factor
    assert "warning: the run reached" in out


def test_the_trajectory_plot_is_in_metres_with_time_marks_events_and_winners(
        tmp_path: Path) -> None:
    from components.sim.plots import save_run_plot
    from components.sim.record import read_trajectory_csv
    from components.sim.scenarios import load_scenario
    from components.sim.world import World

    result = subprocess.run(
        [sys.executable, "-m", "ubf_async.launch", "--scenario", "keep-away", "--speed", "20",
         "--duration", "25", "--quiet", "--listen", "tcp/127.0.0.1:0", "--record",
         str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
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
