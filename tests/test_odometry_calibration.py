"""python -m components.encoders.calibrate: the effective track fitted on the simulated robot."""

from __future__ import annotations

import pytest

from components.encoders.calibrate import (
    DEFAULT_TURNS,
    Turn,
    fit_effective_track,
    main,
    measure_turns,
    simulated_rig,
)
from components.encoders.odometry import EFFECTIVE_TRACK_M
from ubf_async.errors import ConfigurationError


def test_fit_on_the_simulated_robot_matches_the_default() -> None:
    turns = measure_turns(simulated_rig(), DEFAULT_TURNS, settle_s=0.5, measure_s=1.0)
    fit = fit_effective_track(turns)
    assert fit.effective_track_m == pytest.approx(EFFECTIVE_TRACK_M, rel=0.02)
    # With the fit every turn's heading is within 2 % (the physical track reads ≈7×).
    assert max(fit.relative_errors()) < 0.02
    spin = turns[-1]
    naive = 0.02 * (spin.d_right_rad - spin.d_left_rad) / 0.06
    assert 5.0 < naive / spin.true_yaw_rad < 9.0


def test_fit_is_least_squares_of_the_yaw() -> None:
    # Two turns made with tracks 0.4 and 0.5 m: the fit lies between them.
    turns = [Turn(speed=0, turn=100, d_left_rad=-10.0, d_right_rad=10.0,
                  true_yaw_rad=0.02 * 20.0 / 0.4),
             Turn(speed=0, turn=-100, d_left_rad=10.0, d_right_rad=-10.0,
                  true_yaw_rad=-0.02 * 20.0 / 0.5)]
    assert 0.4 < fit_effective_track(turns).effective_track_m < 0.5


def test_no_turning_is_refused() -> None:
    straight = [Turn(speed=40, turn=0, d_left_rad=5.0, d_right_rad=5.0, true_yaw_rad=0.0)]
    with pytest.raises(ConfigurationError, match="no usable yaw"):
        fit_effective_track(straight)


def test_command_prints_the_fit(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--settle-s", "0.3", "--measure-s", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "effective track: 0.4" in out and "effective_track_m: 0.4" in out
    assert main(["--simulator", "no-such-simulator"]) == 2
