"""The run summary: how the run was started and with which version, the scenario's expected
outcome with a verdict per criterion, a warning when the run could not keep the speed asked
for, and numbers rounded to sensible precision."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

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
    assert summary["warnings"] == [
        f"the run reached {rtf:.2f}x real time, short of the 500x asked for (--speed): the "
        f"machine could not keep up"]
    assert "warning: the run reached" in out
