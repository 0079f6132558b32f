"""The end-of-run verdict says what ran (issue 28, item 6): a scenario's expectation is
judged only on a robot that runs the behaviours it describes ("not applicable" otherwise), and
a quarantined behaviour or a live change of the tree appears in the verdict and in the exit
status (3); a run stopped before its duration is not judged. The verdicts in the summary are
checked on runs in this process (the same summary as launch's, tests/test_experiment.py); what
launch prints and exits with, on launches in a subprocess: one for a robot that is not judged
and not run as its file says, the suite's launch of ball-in-sight (tests/shared_runs.py) for
one that is, and one changed live."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import REPOSITORY, free_port, repository_env
from tests.shared_runs import launched, launched_once
from ubf_async import experiment
from ubf_async.runs.wiring import EXIT_DEGRADED

DEFAULT_ROBOT = REPOSITORY / "ubf_async" / "robots" / "mini-whegs.yaml"
SEARCH = """    - behavior: search
      priority: 2
      params: {source: camera/front, period_s: 4.0, leds: 0}
"""


RAISING = """    - behavior: tests.plugin_behaviors:Raising
      name: raising
      priority: 5
"""


def robot_text(*, replace_search_with: str) -> str:
    text = DEFAULT_ROBOT.read_text()
    assert SEARCH in text
    return text.replace(SEARCH, replace_search_with)


def robot_file(tmp_path: Path, *, replace_search_with: str) -> Path:
    path = tmp_path / "robot.yaml"
    path.write_text(robot_text(replace_search_with=replace_search_with))
    return path


def launch(tmp_path: Path, *args: str) -> tuple[subprocess.Popen[str], Path]:
    summary = tmp_path / "summary.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ubf_async.launch", *args, "--summary", str(summary),
         "--quiet"], cwd=REPOSITORY, env=repository_env(), stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)
    return proc, summary


def finished(proc: subprocess.Popen[str], summary: Path) -> tuple[str, dict[str, Any]]:
    output, _ = proc.communicate(timeout=240)
    return output, json.loads(summary.read_text())


def test_an_expectation_about_a_behaviour_the_robot_has_not_is_not_applicable(
        tmp_path: Path) -> None:
    """ball-behind's outcome is search's: on a robot without search it is not judged."""
    no_search = robot_file(tmp_path, replace_search_with="")
    result = experiment.run(no_search, "ball-behind", duration_s=3.0)
    expected = result.expected
    assert expected is not None
    assert expected["applicable"] is False and expected["pass"] is None, expected
    assert "the robot has no search" in expected["why"]
    assert result.passed is None and result.summary["quarantined"] == []


def test_the_same_scenario_on_the_robot_it_describes_is_judged(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    result = experiment.run("mini-whegs", "ball-in-sight", duration_s=3.0)
    assert result.summary["expected"]["applicable"] is True
    assert result.summary["quarantined"] == [] and result.summary["tree_changes"] == []
    # The launch of the scenario the suite makes (tests/shared_runs.py): exit status 0, and
    # nothing said of a run other than the robot file's.
    launch = launched(tmp_path_factory, "ball-in-sight")
    assert launch.returncode == 0, launch.output
    assert launch.summary()["expected"]["applicable"] is True
    assert launch.summary()["quarantined"] == [] and launch.summary()["tree_changes"] == []
    assert "ubf_async: stopped\n" in launch.output
    assert "not as the robot file describes" not in launch.output


def test_a_quarantined_behaviour_is_in_the_verdict(tmp_path: Path) -> None:
    raising = robot_file(tmp_path, replace_search_with=RAISING + SEARCH)
    summary = experiment.run(raising, "ball-in-sight", duration_s=3.0).summary
    assert summary["quarantined"] == ["seek_pink_ball/raising"], summary["quarantined"]
    assert any("quarantined" in w and "seek_pink_ball/raising" in w
               for w in summary["warnings"]), summary["warnings"]
    assert summary["expected"]["applicable"] is True


def test_launch_says_what_was_not_judged_and_what_did_not_run_with_exit_status_3(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    """One launch for what launch prints and exits with: a robot whose search is replaced by
    a behaviour that always fails, on ball-behind (search's scenario): the verdict is not
    applicable, the failing behaviour is quarantined, and the exit status is 3."""

    def arguments(folder: Path) -> list[str]:
        robot = folder / "robot.yaml"
        robot.write_text(robot_text(replace_search_with=RAISING))
        return [str(robot), "--scenario", "ball-behind", "--speed", "max", "--duration", "3",
                "--quiet", "--listen", f"tcp/127.0.0.1:{free_port()}"]

    launch = launched_once(tmp_path_factory, "verdict-no-search-and-raising", arguments)
    output, summary = launch.output, launch.summary()
    assert launch.returncode == EXIT_DEGRADED, output
    assert summary["expected"]["applicable"] is False
    assert "— not applicable (the robot has no search" in output, output
    assert "— met" not in output and "NOT met" not in output
    assert summary["quarantined"] == ["seek_pink_ball/raising"], summary["quarantined"]
    assert "warning: quarantined" in output
    assert "stopped, but not as the robot file describes (quarantined: seek_pink_ball/raising)" \
        in output, output


def test_a_live_tree_change_is_in_the_verdict_and_the_exit_status(tmp_path: Path) -> None:
    """A change applied while the robot runs (inspector tree set-child), then SIGTERM: the
    summary lists the change, the verdict warns, the exit status is 3."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc, summary_path = launch(tmp_path, "--scenario", "ball-in-sight", "--listen", endpoint,
                                "--duration", "600")
    assert proc.stdout is not None
    for line in proc.stdout:
        if line.startswith("  controller:"):
            break
    change = subprocess.run(
        [sys.executable, "-m", "ubf_async.inspector", "tree", "set-child", "seek_pink_ball",
         "chase", "--priority", "3", "--connect", endpoint],
        cwd=REPOSITORY, env=repository_env(), capture_output=True, text=True, timeout=120)
    assert change.returncode == 0, change.stdout + change.stderr
    proc.send_signal(signal.SIGTERM)
    output, summary = finished(proc, summary_path)
    assert proc.returncode == EXIT_DEGRADED, output
    [applied] = summary["tree_changes"]
    assert "chase" in applied["what"] and "priority 3" in applied["what"], applied
    assert any("the tree was changed during the run" in w for w in summary["warnings"])
    assert "not as the robot file describes (the tree was changed live 1 time(s))" in output
    # Stopped long before its 600 s (issue 35): not judged, and the summary says so. The
    # saving is said after the stop (the output is stdout and stderr in one pipe).
    assert summary["interrupted"]["of_s"] == 600, summary["interrupted"]
    assert summary["expected"]["judged"] is False and summary["expected"]["pass"] is None
    assert "— not judged (interrupted at " in output and "— met" not in output, output
    assert (output.index("stopping (press Ctrl-C again to quit at once)")
            < output.index("saving the run's results ...")), output
