"""Device backends on the simulator: encoders, motors, camera, range, radio."""

from __future__ import annotations

import math
import subprocess
import sys
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from components.motors.pwm import LEFT_MOTOR, RIGHT_MOTOR, wheel_speed_rad_s
from components.sim.backends.devices import (
    SimCameraBackend,
    SimEncoderBackend,
    SimMotorBackend,
    SimRadioBackend,
    insert_glitches,
    quadrature_states,
)
from components.sim.world.config import BallConfig, WorldConfig
from components.sim.world.physics import World

EDGES_PER_REV = 4096
FORWARD_NEXT = {0: 1, 1: 3, 3: 2, 2: 0}


def decode(states: np.ndarray, start: int = 0) -> int:
    """Tiny reference decoder: +1 per forward Gray step, -1 per backward step."""
    count = 0
    prev = start
    for s in (int(v) for v in states):
        if s == FORWARD_NEXT[prev]:
            count += 1
        elif prev == FORWARD_NEXT[s]:
            count -= 1
        else:
            raise AssertionError(f"illegal transition {prev} -> {s}")
        prev = s
    return count


class FakeWorld:
    """Just enough of a World for the encoder backend, with wheel angles set by the test."""

    def __init__(self) -> None:
        self.left = 0.0
        self.right = 0.0
        self.config = SimpleNamespace(
            robot=SimpleNamespace(geometry=SimpleNamespace(edges_per_rev=EDGES_PER_REV))
        )

    def snapshot(self) -> SimpleNamespace:
        return SimpleNamespace(
            robot=SimpleNamespace(left_wheel_angle_rad=self.left, right_wheel_angle_rad=self.right)
        )

    def make_rng(self, stream: int) -> np.random.Generator:
        return np.random.default_rng(stream)


def test_quadrature_sequence() -> None:
    assert quadrature_states(0, 8).tolist() == [1, 3, 2, 0, 1, 3, 2, 0]
    assert quadrature_states(0, -3).tolist() == [2, 3, 1]
    assert quadrature_states(5, 5).tolist() == []
    assert quadrature_states(5, 5).dtype == np.uint8


def test_encoder_phases_for_known_rotation() -> None:
    world = FakeWorld()
    enc = SimEncoderBackend(world)  # type: ignore[arg-type]
    world.left = 2 * math.pi + 0.001  # one revolution and a bit forward
    world.right = -math.pi  # half a revolution backward
    left, right = enc.read_phases()
    assert left.dtype == np.uint8 and right.dtype == np.uint8
    expected_left = math.floor(world.left / (2 * math.pi / EDGES_PER_REV))
    assert expected_left == EDGES_PER_REV  # 0.001 rad is less than one edge (1.53 mrad)
    assert len(left) == expected_left
    assert decode(left) == EDGES_PER_REV
    assert len(right) == EDGES_PER_REV // 2
    assert decode(right) == -EDGES_PER_REV // 2
    # The next read continues from where the line was; no motion gives no states.
    start = enc.current_states()
    assert start == (int(left[-1]), int(right[-1]))
    assert [len(a) for a in enc.read_phases()] == [0, 0]
    world.left -= 10 * (2 * math.pi / EDGES_PER_REV)
    left, right = enc.read_phases()
    assert decode(left, start[0]) == -10
    assert len(right) == 0


def test_encoder_follows_simulated_wheels() -> None:
    world = World()
    enc = SimEncoderBackend(world)
    world.set_motor_pulses(1.9, 1.2)
    total = [0, 0]
    state = list(enc.current_states())
    for _ in range(20):
        world.step(0.01)
        for i, phases in enumerate(enc.read_phases()):
            total[i] += decode(phases, state[i])
            if len(phases):
                state[i] = int(phases[-1])
    r = world.snapshot().robot
    step = 2 * math.pi / EDGES_PER_REV
    assert total[0] == math.floor(r.left_wheel_angle_rad / step) > 0
    assert total[1] == math.floor(r.right_wheel_angle_rad / step) < 0
    assert wheel_speed_rad_s(LEFT_MOTOR, 1.9) > 0 > wheel_speed_rad_s(RIGHT_MOTOR, 1.2)


def test_glitches_are_false_edges_that_cancel() -> None:
    world = FakeWorld()
    enc = SimEncoderBackend(  # type: ignore[arg-type]
        world, glitch_probability=0.2, rng=np.random.default_rng(7)
    )
    world.left = 500 * (2 * math.pi / EDGES_PER_REV) + 1e-6
    world.right = -300 * (2 * math.pi / EDGES_PER_REV) - 1e-6
    left, right = enc.read_phases()
    assert len(left) > 500 and len(right) > 301
    assert decode(left) == 500
    assert decode(right) == -301  # floor of a slightly negative angle
    # Deterministic with the seed.
    again = insert_glitches(quadrature_states(0, 500), 0.2, np.random.default_rng(7))
    assert len(again) > 500


def test_motor_backend_sets_pulses() -> None:
    world = World()
    SimMotorBackend(world).apply_pulses(left_ms=1.7, right_ms=1.3)
    assert world.motor_pulses == (1.7, 1.3)
    world.step(0.01)
    assert world.snapshot().robot.left_pulse_ms == 1.7


def test_camera_backend_captures_while_the_world_steps() -> None:
    world = World(WorldConfig(ball=BallConfig(x_m=0.5, y_m=0.0), seed=3))
    camera = SimCameraBackend(world)
    frames: list[np.ndarray] = []
    worker = threading.Thread(target=lambda: frames.extend(camera.capture() for _ in range(3)))
    worker.start()
    for _ in range(50):
        world.step(0.01)
    worker.join()
    assert len(frames) == 3
    assert all(f.shape == (1024, 1280, 3) and f.dtype == np.uint8 for f in frames)
    # Same seed, same first frame.
    twin = SimCameraBackend(World(WorldConfig(ball=BallConfig(x_m=0.5, y_m=0.0), seed=3)))
    assert np.array_equal(twin.capture(), SimCameraBackend(
        World(WorldConfig(ball=BallConfig(x_m=0.5, y_m=0.0), seed=3))).capture())
    camera.close()
    with pytest.raises(RuntimeError):
        camera.capture()


def test_radio_backend_is_an_in_memory_link() -> None:
    radio = SimRadioBackend()
    assert radio.receive() == []
    radio.send("hello")
    radio.send("world")
    assert radio.outbox == ["hello", "world"]
    radio.inject("go")
    radio.inject("stop")
    assert radio.receive() == ["go", "stop"]
    assert radio.receive() == []
    assert radio.clear_outbox() == ["hello", "world"]
    assert radio.outbox == []
    with pytest.raises(TypeError):
        radio.send(b"bytes")  # type: ignore[arg-type]


def test_sim_imports_no_bus_or_asyncio() -> None:
    code = (
        "import sys, components.sim.backends.devices, components.sim.render.calibrate;"
        "print(sorted(m for m in ('zenoh', 'asyncio') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "[]"
