"""Issue 51, item 1: the behaviour authors' testing kit (ubf_async.testing) — its scripts,
its questions and their failure messages, its stand-ins, its hypothesis strategies, and its doc
page run as a third party's project would run it: in a temporary folder, through the pytest
plugin, importing nothing of this repository's tests."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings

from ubf_async import testing
from ubf_async.core.action import Action
from ubf_async.errors import ConfigurationError, UbfError
from ubf_async.testing import strategies
from ubf_async.wire import topics
from ubf_async.wire.protocol import decode, encode

ROOT = Path(__file__).resolve().parent.parent
FAR = testing.bins(0, 0, 40, 0, 0)
TOO_CLOSE = testing.bins(0, 60, 180, 60, 0)


def test_the_page_runs_as_a_third_partys_tests(tmp_path: Path) -> None:
    """docs/testing.md's test module, written into a project of its own and run by pytest
    there: the fixtures come from the installed plugin, not from this repository."""
    page = (ROOT / "docs" / "testing.md").read_text("utf-8")
    (module,) = re.findall(r"```python\n(# test_flee\.py\n.*?)```", page, re.S)
    project = tmp_path / "my-robot"
    (project / "tests").mkdir(parents=True)
    (project / "tests" / "test_flee.py").write_text(module, "utf-8")
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:randomly",
         "tests"], cwd=project, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "4 passed" in result.stdout, result.stdout
    assert "tests/" not in module.replace("tests/test_flee.py", "")  # (nothing of ours)


def test_a_script_is_the_same_run_every_time_and_answers_in_robot_time() -> None:
    script = testing.Script(
        testing.every(0.11, until_s=1.0, camera_front=FAR),
        testing.every(0.11, from_s=1.0, until_s=2.0, camera_front=TOO_CLOSE))
    first = testing.run_script("mini-whegs", script, until_s=2.0)
    again = testing.run_script("mini-whegs", script, until_s=2.0)
    assert first.commands == again.commands  # simulated time: no wall time in it
    ticks = [c for c in first.commands if not c.hold]
    assert [round(c.t_s, 3) for c in ticks[:3]] == [0.0, 0.02, 0.04]  # 50 Hz, as the file says
    assert first.drive_at(0.999).winners == ("chase",)
    assert first.drive_at(1.05).winners == ("chase", "flee")
    assert first.held_for("chase") == pytest.approx(2.0 - first.became_active("chase"))
    assert first.held_for("flee", from_s=1.5, to_s=1.7) == pytest.approx(0.2)
    assert "* flee [p=1 w=1]: speed=-80" in repr(first.drive_at(1.5))


def test_a_source_stops_and_goes_stale_as_on_the_robot() -> None:
    """A camera at its rate until 1 s, then silent: 1.5 periods later its last frame is
    stale, and chase, which needs a fresh one, stops winning."""
    run = testing.run_script("mini-whegs", testing.Script(
        testing.every(0.11, until_s=1.0, camera_front=FAR)), until_s=2.0)
    assert run.winners_at(1.0) == ("chase",)
    assert "chase" not in run.winners_at(1.3)  # the last frame (0.99 s) is 0.31 s old


def test_answers_that_fail_say_what_happened() -> None:
    run = testing.run_script("mini-whegs", testing.Script(
        testing.every(0.11, until_s=0.5, camera_front=FAR)), until_s=0.5)
    with pytest.raises(AssertionError) as never:
        run.became_active("flee")
    said = str(never.value)
    assert "'flee' never won a command from 0 s to 0.5 s; the winners were ['chase']" in said
    assert "* chase [p=1 w=1]: speed=+40" in said  # the last ticks' traces
    with pytest.raises(AssertionError, match="no drive command at or before"):
        testing.run_script("mini-whegs", testing.Script(), until_s=0.1).drive_at(-1.0)


def test_stand_ins_replace_a_behaviour_by_name_keeping_its_place() -> None:
    script = testing.Script(testing.every(0.11, until_s=1.0, camera_front=TOO_CLOSE))
    timeline = testing.stand_in(timeline=[(0.0, None), (0.5, Action(speed=-10.0, turn=20.0))])
    run = testing.run_script("mini-whegs", script, until_s=1.0, substitute={"flee": timeline})
    assert run.drive_at(0.4).speed == 40  # the stand-in abstains until 0.5 s
    assert (run.drive_at(0.8).speed, run.drive_at(0.8).turn) == (30, 20)  # summed with chase
    assert run.winners_at(0.8) == ("chase", "flee")
    with pytest.raises(ConfigurationError, match=r"no behaviour named 'fle' .*did you mean "
                                                 r"'flee'\?"):
        testing.run_script("mini-whegs", script, until_s=1.0,
                           substitute={"fle": testing.stand_in(lambda s: None)})


@pytest.mark.parametrize(("make", "said"), [
    (lambda: testing.at(0.5, camerafront=FAR), "a source is kind_name"),
    (lambda: testing.at(-1.0, camera_front=FAR), "finite time ≥ 0 s"),
    (lambda: testing.bins(1, 2, 3), "the 5 bins' counts"),
    (lambda: testing.every(0.0, until_s=1.0, camera_front=FAR), "period must be > 0 s"),
    (lambda: testing.Script.from_csv("t_s,source,data\n0.5,camera/front,[1]\n"),
     "script CSV line 2: data is not a JSON object"),
    (lambda: testing.Script.from_csv("t,source,data\n"), "missing ['t_s']"),
])
def test_a_script_mistake_is_refused_with_the_reason(make: object, said: str) -> None:
    with pytest.raises(UbfError) as refused:
        make()  # type: ignore[operator]
    assert said in str(refused.value)


def test_a_script_from_csv_is_the_script_written_in_python() -> None:
    text = ("t_s,source,period_s,data\n"
            '0.5,camera/front,0.11,"{""bins"": [0, 0, 300, 0, 0], ""total"": 300}"\n'
            '0.2,range_front,,"{""range_mm"": 180, ""status"": ""ok""}"\n')
    assert testing.Script.from_csv(text).samples == testing.Script(
        testing.at(0.5, period_s=0.11, camera_front=testing.bins(0, 0, 300, 0, 0)),
        testing.at(0.2, range_front=testing.mm(180))).samples


@pytest.mark.parametrize("topic", [t for t in topics.TOPICS
                                   if t.type is not topics.PlainData
                                   and not t.schema.startswith("tree.")],
                         ids=lambda t: t.schema)
def test_the_strategies_draw_what_the_robot_accepts(topic: topics.Topic[object]) -> None:
    @settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(strategies.messages(topic))
    def encodes_and_decodes(message: object) -> None:
        assert decode(encode(topic, message, stamp_ns=1, seq=1), topic=topic).data == message

    encodes_and_decodes()
