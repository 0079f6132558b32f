"""Two cameras and a wide lens on the Mini-WHEGS (issue 49, items 4-5; docs/bodies.md).

* The fusion of several cameras into one wide camera (:mod:`ubf_async.core.fusion`): pure,
  no bus;
* the rodent's and the wide lens's robot files load and check as ``launch --check`` does, and
  run the shipped search, chase and flee classes unchanged;
* a short in-process run of each on ball-behind finds the ball;
* a bad ``controller: fuse`` is refused at its line.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import REPOSITORY
from ubf_async import experiment
from ubf_async.assembly.robotfile import load_robot, load_robot_text
from ubf_async.behaviors.pink_ball import Chase, Flee, Search
from ubf_async.core.behavior import Composite
from ubf_async.core.fusion import CameraFusion, merge_bins
from ubf_async.core.state import Reading, State
from ubf_async.errors import RobotFileError
from ubf_async.tools import launch
from ubf_async.wire.topics import CameraSeekcolor

RODENT = REPOSITORY / "examples" / "robots" / "mini-whegs-rodent.yaml"
WIDE = REPOSITORY / "examples" / "robots" / "mini-whegs-wide.yaml"
BOTH = CameraFusion("camera/both", ("camera/left", "camera/right"))


def camera(bins: tuple[int, ...], *, stamp_ns: int = 0, seq: int = 1,
           stale: bool = False) -> Reading:
    return Reading(value=CameraSeekcolor(bins=bins, total=sum(bins), latency_s=0.11, width=160,
                                         height=128),
                   stamp_ns=stamp_ns, seq=seq, age_s=0.01, stale=stale)


# -- the fusion -----------------------------------------------------------------------------

def test_two_cameras_bins_are_summed_pairwise_left_camera_first() -> None:
    # Left camera (0…+35°) then right (0…−35°): ten 7° bins, five 14° ones.
    assert merge_bins([(1, 2, 3, 4, 5), (6, 7, 8, 9, 10)]) == (3, 7, 11, 15, 19)
    assert merge_bins([(0, 0, 0, 0, 9), (9, 0, 0, 0, 0)]) == (0, 0, 18, 0, 0)  # straight ahead
    assert merge_bins([(1,) * 5, (1,) * 5, (1,) * 5]) == (3, 3, 3, 3, 3)
    with pytest.raises(ValueError, match="must be 5"):
        merge_bins([(1, 2, 3), (1, 2, 3, 4, 5)])
    with pytest.raises(ValueError, match="at least one"):
        merge_bins([])


def test_a_fused_reading_is_as_old_and_as_stale_as_its_worst_camera() -> None:
    fused = BOTH.reading({"camera/left": camera((0, 0, 0, 0, 40), stamp_ns=5, seq=3),
                          "camera/right": camera((60, 0, 0, 0, 0), stamp_ns=2, seq=4)})
    assert fused is not None
    assert fused.value.bins == (0, 0, 100, 0, 0) and fused.value.total == 100
    assert fused.value.width == 320 and fused.value.height == 128
    assert fused.value.bearing_rad is None
    assert (fused.stamp_ns, fused.seq, fused.stale) == (2, 7, False)
    stale = BOTH.reading({"camera/left": camera((0,) * 5),
                          "camera/right": camera((0,) * 5, stale=True)})
    assert stale is not None and stale.stale
    assert BOTH.reading({"camera/left": camera((0,) * 5)}) is None  # one camera not heard yet


def test_the_shipped_behaviours_read_the_fused_source_unchanged() -> None:
    readings = {"camera/left": camera((0, 0, 0, 30, 0)), "camera/right": camera((0,) * 5)}
    BOTH.add_to(readings)
    state = State(readings)
    # Pink at +7…+21° (left camera's fourth bin): chase turns left 30, search abstains.
    action = Chase(source="camera/both").act(state)
    assert action is not None and action.turn == 30.0
    assert Search(source="camera/both").act(state) is None
    assert Flee(source="camera/both").act(state) is None  # 30 pixels: far
    # A camera gone stale: the fused source is stale and all three abstain.
    readings["camera/right"] = camera((0,) * 5, stale=True)
    BOTH.add_to(readings)
    assert Chase(source="camera/both").act(State(readings)) is None


@pytest.mark.parametrize("sources, says", [
    (["camera/left"], "at least two"),
    (["camera/left", "camera/left"], "named twice"),
    (["camera/both", "camera/left"], "itself"),
])
def test_a_fusion_of_fewer_than_two_distinct_cameras_is_refused(sources: list[str],
                                                                says: str) -> None:
    with pytest.raises(ValueError, match=says):
        CameraFusion("camera/both", tuple(sources))


# -- the robot files ------------------------------------------------------------------------

@pytest.mark.parametrize("path", [RODENT, WIDE], ids=["rodent", "wide"])
def test_the_variants_load_and_check_as_launch_check_does(path: Path) -> None:
    plan = launch.plan_launch(launch.parse_args([str(path), "--check",
                                                 "--scenario", "ball-behind"]))
    root = plan.robot.root
    assert isinstance(root, Composite)
    kinds = [type(child.behavior) for child in root.children]
    assert kinds == [Search, Chase, Flee]  # the shipped classes, as the Mini-WHEGS's
    cameras = [d.name for d in plan.robot.devices if d.kind == "camera"]
    if path == RODENT:
        assert cameras == ["left", "right"]
        assert plan.robot.spec.controller.fusions() == (BOTH,)
        assert {getattr(child.behavior, "source", None) for child in root.children} == {
            "camera/both"}
    else:
        assert cameras == ["front"]
        assert next(d for d in plan.robot.devices if d.kind == "camera").params["hfov_deg"] == 90


@pytest.mark.parametrize("path", [RODENT, WIDE], ids=["rodent", "wide"])
def test_each_variant_finds_a_ball_behind_it(path: Path) -> None:
    result = experiment.run(load_robot(path), "ball-behind", seed=7, duration_s=9.0)
    view = result.summary["ball_view"]
    # The ball came in front of it (within the thesis lens's ±17.5°) and it chased it.
    assert view["first_in_view_s"] is not None and view["first_in_view_s"] < 8.0, view
    assert result.summary["ticks"]["winner_share"].get("chase", 0) > 0.1
    assert result.summary["ball_distance_m"] < 0.8


FUSE_TEXT = RODENT.read_text()


@pytest.mark.parametrize("old, new, line_of, says", [
    ("camera/both: [camera/left, camera/right]", "camera/left: [camera/left, camera/right]",
     "camera/left: [", "a device's own"),
    ("camera/both: [camera/left, camera/right]", "range/both: [camera/left, camera/right]",
     "range/both:", "not a camera/NAME"),
    ("camera/both: [camera/left, camera/right]", "camera/both: [camera/left, range/front]",
     "camera/both:", "'range/front' is not a camera"),
    ("camera/both: [camera/left, camera/right]", "camera/both: [camera/left]",
     "camera/both:", "at least two"),
    ("sync_source: camera/left", "sync_source: camera/both", "sync_source:", "no sample of it"),
], ids=["a device's name", "not a camera", "a range finder fused", "one camera", "sync on it"])
def test_a_bad_fusion_is_refused_at_its_line(old: str, new: str, line_of: str,
                                             says: str) -> None:
    text = FUSE_TEXT.replace(old, new)
    line = next(i for i, row in enumerate(text.splitlines(), 1) if line_of in row)
    with pytest.raises(RobotFileError) as refused:
        load_robot_text(text, source="bad.yaml")
    assert str(refused.value).startswith(f"bad.yaml:{line}: "), str(refused.value)
    assert says in str(refused.value)
