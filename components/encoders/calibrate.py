"""Fit the skid-steer robot's effective track for odometry: ``python -m
components.encoders.calibrate``.

A skid-steer robot yaws only a fraction of what its wheel speed difference and physical
track imply (its wheel-legs slide sideways), so odometry integrates the heading with an
*effective* track (:data:`~components.encoders.odometry.EFFECTIVE_TRACK_M`, the encoders
device's ``effective_track_m``). This command drives the robot through turns — the thesis's
chase, search and spin commands, both ways — and for each one takes the wheel rotations the
encoders measured and the yaw the robot really made; the least-squares fit of

    true yaw = wheel_radius · (Δθ_right − Δθ_left) / effective_track

over all turns is the effective track. It prints the fit, each turn's residual and the
robot-file line to use.

The robot is driven through a *turn rig* (:class:`TurnRig`): the ``mini-whegs`` simulator
plug-in provides one (``turn_rig()``), found through the registry like any simulator, whose
true yaw is the simulated body's. A real robot needs a rig whose true yaw comes from outside
(a compass, a camera overhead, or a person measuring): not provided yet.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from components.encoders.odometry import EFFECTIVE_TRACK_M
from components.miniwhegs import MINI_WHEGS, MiniWhegsGeometry
from components.motors.pwm import pulse_widths
from ubf_async.errors import ConfigurationError

DEFAULT_TURNS: tuple[tuple[float, float], ...] = (
    (40.0, 30.0), (40.0, -30.0), (40.0, 60.0), (40.0, -60.0), (10.0, 80.0), (10.0, -80.0),
    (0.0, 100.0), (0.0, -100.0),
)
"""speed/turn commands driven: chase ±30 and ±60, search's ±80 at speed 10, spins ±100."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Turn:
    """One turn as measured: the wheels' rotations (what the encoders count) and the yaw the
    body really made, over the same interval."""

    speed: float
    turn: float
    d_left_rad: float
    d_right_rad: float
    true_yaw_rad: float


class TurnRig(Protocol):
    """Drives a robot with fixed motor pulses and reports what happened."""

    def drive(self, *, left_ms: float, right_ms: float, settle_s: float,
              measure_s: float) -> tuple[float, float, float]:
        """Drive with these pulses for ``settle_s`` (not measured), then ``measure_s`` more;
        return ``(Δθ_left, Δθ_right, true yaw)`` in radians over the measured part."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True)
class TrackFit:
    effective_track_m: float
    turns: tuple[Turn, ...]
    geometry: MiniWhegsGeometry

    def predicted_yaw_rad(self, turn: Turn) -> float:
        r = self.geometry.wheel_radius_m
        return r * (turn.d_right_rad - turn.d_left_rad) / self.effective_track_m

    def relative_errors(self) -> list[float]:
        """Per turn: |predicted − true| / |true| (odometry's heading error with the fit)."""
        return [abs(self.predicted_yaw_rad(t) - t.true_yaw_rad) / max(abs(t.true_yaw_rad), 1e-9)
                for t in self.turns]


def fit_effective_track(turns: Sequence[Turn],
                        geometry: MiniWhegsGeometry = MINI_WHEGS) -> TrackFit:
    """Least-squares effective track: minimises Σ (r·Δθ_diff / T − yaw)² over 1/T.

    Raises :class:`~ubf_async.errors.ConfigurationError` when the turns did not turn (no
    wheel speed difference or no yaw) or the fit comes out non-positive."""
    r = geometry.wheel_radius_m
    num = sum((r * (t.d_right_rad - t.d_left_rad)) ** 2 for t in turns)
    den = sum(r * (t.d_right_rad - t.d_left_rad) * t.true_yaw_rad for t in turns)
    if num <= 0.0 or den <= 0.0:
        raise ConfigurationError("the turns measured no usable yaw (the robot did not turn "
                                 "the way its wheels did): cannot fit an effective track")
    return TrackFit(effective_track_m=num / den, turns=tuple(turns), geometry=geometry)


def measure_turns(rig: TurnRig, commands: Sequence[tuple[float, float]] = DEFAULT_TURNS, *,
                  settle_s: float = 1.0, measure_s: float = 3.0) -> list[Turn]:
    """Drive each speed/turn command (through the HAL's pulse calibration) on ``rig``."""
    turns = []
    for speed, turn in commands:
        pulses = pulse_widths(speed, turn)
        d_left, d_right, yaw = rig.drive(left_ms=pulses.left_ms, right_ms=pulses.right_ms,
                                         settle_s=settle_s, measure_s=measure_s)
        turns.append(Turn(speed=speed, turn=turn, d_left_rad=d_left, d_right_rad=d_right,
                          true_yaw_rad=yaw))
    return turns


def simulated_rig(simulator: str = "mini-whegs") -> TurnRig:
    """The turn rig of a simulator plug-in (registry ``ubf_async.simulators``)."""
    from ubf_async.registry import SIMULATORS

    plugin = SIMULATORS.get(simulator)()
    make_rig = getattr(plugin, "turn_rig", None)
    if make_rig is None:
        raise ConfigurationError(f"simulator {simulator!r} offers no turn rig")
    rig: TurnRig = make_rig()
    return rig


def format_fit(fit: TrackFit) -> str:
    lines = [f"{'speed/turn':>10} {'true yaw °':>11} {'physical-track °':>17} "
             f"{'fitted °':>9} {'error':>7}"]
    r, physical = fit.geometry.wheel_radius_m, fit.geometry.track_width_m
    for t, err in zip(fit.turns, fit.relative_errors(), strict=True):
        naive = math.degrees(r * (t.d_right_rad - t.d_left_rad) / physical)
        lines.append(f"{t.speed:+4.0f}/{t.turn:+4.0f} {math.degrees(t.true_yaw_rad):+11.1f} "
                     f"{naive:+17.1f} {math.degrees(fit.predicted_yaw_rad(t)):+9.1f} "
                     f"{100 * err:6.1f}%")
    lines.append(f"effective track: {fit.effective_track_m:.4f} m (physical "
                 f"{physical:.3f} m; built-in default {EFFECTIVE_TRACK_M:.4f} m)")
    lines.append(f"robot file: encoders params {{effective_track_m: "
                 f"{fit.effective_track_m:.3f}}}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m components.encoders.calibrate",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--simulator", default="mini-whegs",
                        help="simulator plug-in whose robot is driven (default mini-whegs)")
    parser.add_argument("--settle-s", type=float, default=1.0,
                        help="seconds driven before each measurement (default 1)")
    parser.add_argument("--measure-s", type=float, default=3.0,
                        help="seconds measured per command (default 3)")
    args = parser.parse_args(argv)
    if not (args.settle_s >= 0 and args.measure_s > 0):
        parser.error("--settle-s must be >= 0 and --measure-s > 0")
    try:
        rig = simulated_rig(args.simulator)
        fit = fit_effective_track(measure_turns(rig, settle_s=args.settle_s,
                                                measure_s=args.measure_s))
    except ConfigurationError as exc:
        print(f"python -m components.encoders.calibrate: error: {exc}", file=sys.stderr)
        return 2
    print(format_fit(fit))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
