"""Plug-ins registered exactly as docs/robot-file.md says, used by name from a robot file; and
the groups nothing reads, pointed out instead of silently left out (issue 39).

The third-party distribution is written into a folder as ``pip install --target`` leaves one
(the package and its dist-info with ``entry_points.txt``), its entry points converted from the
docs' own ``pyproject.toml`` example: what a plug-in author copies is what is tested.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tests.cli_inprocess import launch_main
from ubf_async import experiment
from ubf_async.assembly import registry

ROOT = Path(__file__).resolve().parent.parent
ROBOT_FILE_MD = ROOT / "docs" / "robot-file.md"

PACKAGE = {
    "__init__.py": '"""A third party\'s plug-ins: a behaviour, an arbiter, a predicate."""\n',
    "behaviors.py": '''\
from ubf_async import Action, Behavior


class Wander(Behavior):
    def __init__(self, *, name: str = "wander", speed: float = 30.0) -> None:
        super().__init__(name=name)
        self.speed = speed

    def act(self, state):
        return Action(speed=self.speed)
''',
    "arbiters.py": '''\
from ubf_async import Arbiter, Decision


class LastWins(Arbiter):
    """The last child that votes wins outright."""

    name = "LastWins"

    def arbitrate(self, candidates, state):
        if not candidates:
            return Decision(None)
        return Decision(candidates[-1].action, (candidates[-1].index,))
''',
    "predicates.py": '''\
def battery_low(*, source: str = "battery/main", below_v: float = 6.5):
    """True while ``source``'s fresh reading says less than ``below_v`` volts."""
    def predicate(state) -> bool:
        volts = state.value(source, "volts")
        return volts is not None and volts < below_v
    return predicate
''',
}

ROBOT = """\
name: third
devices:
  - {kind: motors, name: main, backend: sim}
  - {kind: encoders, name: wheels, backend: sim}
tree:
  name: root
  arbiter: LastWins                 # the plug-in's arbiter
  children:
    - behavior: stop
    - name: pick
      arbiter: {type: Conditional, params: {predicate: battery_low,
                                            predicate_params: {below_v: 6.5}}}
      children:
        - behavior: stop
          name: rest
        - behavior: wander          # the plug-in's behaviour
          params: {speed: 30}
"""


def docs_entry_points() -> dict[str, dict[str, str]]:
    """The ``[project.entry-points.…]`` example of docs/robot-file.md's Plug-ins section."""
    text = ROBOT_FILE_MD.read_text("utf-8").partition("## Plug-ins")[2]
    block = re.search(r"```toml\n(.*?)```", text, re.S)
    assert block is not None
    return tomllib.loads(block.group(1))["project"]["entry-points"]


def install(site: Path, entry_points: dict[str, dict[str, str]]) -> Path:
    """The package ``my_robot`` and its distribution's metadata in ``site``."""
    (site / "my_robot").mkdir(parents=True)
    for name, source in PACKAGE.items():
        (site / "my_robot" / name).write_text(source, "utf-8")
    dist_info = site / "my_robot-0.1.0.dist-info"
    dist_info.mkdir()
    (dist_info / "METADATA").write_text("Metadata-Version: 2.4\nName: my-robot\nVersion: 0.1.0\n")
    (dist_info / "entry_points.txt").write_text("".join(
        f"[{group}]\n" + "".join(f"{name} = {value}\n" for name, value in points.items()) + "\n"
        for group, points in entry_points.items()))
    (dist_info / "top_level.txt").write_text("my_robot\n")
    return site


def test_the_docs_example_registers_under_groups_read() -> None:
    # docs/robot-file.md's table against the registry and pyproject.toml: tests/test_docs.py
    assert set(docs_entry_points()) <= set(registry.READ)


def _run(site: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    return subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=60)


@pytest.mark.slow
def test_a_plugin_registered_as_documented_is_used_by_name(
        tmp_path: Path, capfd: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    site = install(tmp_path / "site", docs_entry_points())
    robot = tmp_path / "third.yaml"
    robot.write_text(ROBOT)
    listed = _run(site, "-m", "ubf_async.robotfile", "plugins")
    assert listed.returncode == 0, listed.stderr
    for line in ("  LastWins             my_robot.arbiters:LastWins",
                 "  battery_low          my_robot.predicates:battery_low",
                 "  wander               my_robot.behaviors:Wander"):
        assert line in listed.stdout.splitlines()
    assert "read by nothing" not in listed.stdout
    # Checked as launch checks it, in a process of its own…
    checked = _run(site, "-m", "ubf_async.launch", str(robot), "--check")
    assert checked.returncode == 0, checked.stderr
    assert "root <LastWins>" in checked.stdout
    assert "pick <Conditional(battery_low(below_v=6.5))>" in checked.stdout
    assert "wander (Wander) [p=0 w=1]" in checked.stdout
    # …and run in this one: the plug-in's entry points read again with its folder on the path.
    monkeypatch.syspath_prepend(str(site))
    for reg in (registry.BEHAVIORS, registry.ARBITERS, registry.PREDICATES):
        monkeypatch.setattr(reg, "_entry_points", None)
        monkeypatch.setattr(reg, "_loaded", dict(reg._loaded))  # forgotten after
    assert launch_main([str(robot), "--check"], capfd, monkeypatch).returncode == 0
    data = experiment.run(robot, "ball-behind", duration_s=1.0).summary
    # LastWins takes the Conditional; no battery reading, so not low: wander drives.
    assert data["ticks"]["winner_share"] == {"wander": 1.0}
    assert math.hypot(data["robot"]["x_m"], data["robot"]["y_m"]) > 0.05


def test_a_group_nothing_reads_is_pointed_out(tmp_path: Path) -> None:
    # The mistake issue 39 found: the module's path taken for the group's name.
    wrong = {f"ubf_async.core.{group.rpartition('.')[2]}" if "arbiters" in group else group:
             points for group, points in docs_entry_points().items()}
    site = install(tmp_path / "site", wrong)
    robot = tmp_path / "third.yaml"
    robot.write_text(ROBOT)
    listed = _run(site, "-m", "ubf_async.robotfile", "plugins")
    assert listed.returncode == 0, listed.stderr
    lines = listed.stdout.splitlines()
    heading = next(i for i, line in enumerate(lines) if line.startswith("ubf_async.core."))
    assert lines[heading].startswith(
        "ubf_async.core.arbiters: read by nothing, so left out (did you mean group "
        "ubf_async.arbiters?); the groups read: ubf_async.behaviors, ubf_async.arbiters, ")
    assert lines[heading + 1:] == ["  LastWins             my_robot.arbiters:LastWins"]
    checked = _run(site, "-m", "ubf_async.launch", str(robot), "--check")
    assert checked.returncode == 2
    assert checked.stderr.strip().endswith(
        "(or a 'module:factory' reference); 'LastWins' is registered under "
        "ubf_async.core.arbiters, which nothing reads: did you mean group ubf_async.arbiters?")
    assert f"{robot}:7: unknown arbiter 'LastWins'" in checked.stderr
