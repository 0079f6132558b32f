from __future__ import annotations

import math

import pytest

from ubf_async import Action, ColorBox, Reading, State, clamp_command


def test_unset_is_distinguishable_from_zero() -> None:
    a = Action(speed=0)
    assert a.is_set("speed") and not a.is_set("turn")
    assert a.turn is None and a.speed == 0


@pytest.mark.parametrize(
    "kwargs",
    [
        {"speed": 101},
        {"turn": -100.5},
        {"speed": math.nan},
        {"turn": math.inf},
        {"speed": True},
        {"vote": -1},
        {"vote": math.nan},
        {"leds": 256},
        {"message": "x" * 257},
        {"seek_color": ((0, 0, 0), (255, 255, 256))},
        {"seek_color": ((10, 0, 0), (5, 255, 255))},
    ],
)
def test_invalid_actions_are_refused(kwargs) -> None:
    with pytest.raises(ValueError):
        Action(**kwargs)


def test_seek_color_normalised_and_describe() -> None:
    a = Action(speed=40, turn=-30, seek_color=((90, 20, 40), (255, 120, 160)))
    assert isinstance(a.seek_color, ColorBox)
    assert a.describe() == "speed=+40 turn=-30 seek_color=[90, 20, 40]..[255, 120, 160] vote=1"


def test_clamp_command() -> None:
    assert clamp_command(140) == 100
    assert clamp_command(-1e9) == -100
    with pytest.raises(ValueError):
        clamp_command(math.nan)


def test_state_fresh_and_stale() -> None:
    state = State(
        {
            "camera/front": Reading(value={"bins": [1, 2, 3, 4, 5], "total": 15}, stamp_ns=5,
                                    age_s=0.1),
            "range/left": Reading(value={"range_mm": 300, "status": "ok"}, stamp_ns=1,
                                  age_s=9.0, stale=True),
        },
        now_ns=10,
    )
    assert state.value("camera/front", "bins") == [1, 2, 3, 4, 5]
    assert state.value("range/left", "range_mm", "gone") == "gone"
    assert state.fresh("range/left") is None
    assert state["range/left"].value["range_mm"] == 300
    assert set(state) == {"camera/front", "range/left"}
    assert "STALE" in repr(state)
