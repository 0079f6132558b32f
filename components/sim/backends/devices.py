"""Device backends on top of a simulated :class:`~components.sim.world.physics.World`.

Each class implements one of the device backend protocols (``components/<device>/backend.py``)
so a device component can run against the simulator exactly as it would against hardware. They
read the world's latest immutable snapshot, so they are safe to call from worker threads while
the world steps in another. Nothing here touches the message bus or asyncio.

The factories at the end (``camera_backend`` …) are what the ``ubf_async.backends`` entry
points ``<kind>.sim`` name: ``(*, context, **params) -> backend``. Each says it requires the
``mini-whegs`` simulator (its ``requires_simulator`` attribute), whose world it finds in
``context.simulation``: a :class:`~components.sim.world.physics.World` in the simulator's process, a
:class:`~components.sim.mirror.remote_world.RemoteWorld` in a device's own process.
"""

from __future__ import annotations

import math
import os
import threading
import time
import zlib
from collections.abc import Callable
from typing import Annotated, Any, Protocol, TypeVar

import msgspec
import numpy as np

from components.camera.backend import DEFAULT_MOUNT, CameraBackend, CameraMount
from components.camera.seekcolor import SUBSAMPLE_STEP
from components.encoders.backend import EncoderBackend
from components.leds.backend import LedBackend
from components.motors.backend import MotorBackend
from components.radio.backend import RadioBackend
from components.range.backend import MountPose, RangeBackend
from components.sim.render.camera import DEFAULT_CAMERA, CameraParams, render_camera, warm_up
from components.sim.render.process import (
    RenderProcess,
    render_process_wanted,
    shared_render_process,
)
from components.sim.world.air import RadioAir
from components.sim.world.config import WorldConfig
from components.sim.world.ranging import beam_distance_m
from components.sim.world.snapshot import WorldSnapshot
from ubf_async.assembly.context import DeviceContext
from ubf_async.errors import ConfigurationError

__all__ = ["CAMERA_RNG_STREAM", "ENCODER_RNG_STREAM", "QUADRATURE_SEQUENCE", "RENDER_DELAY_ENV",
           "SIMULATOR", "SimAirRadioBackend", "SimCameraBackend", "SimEncoderBackend",
           "SimLedBackend", "SimMotorBackend", "SimRadioBackend", "SimRangeBackend", "WorldView",
           "camera_backend", "camera_stream", "edge_index", "encoders_backend", "insert_glitches",
           "leds_backend", "motors_backend", "quadrature_states", "radio_air_backend",
           "radio_backend", "range_backend", "render_delay_s"]


class WorldView(Protocol):
    """What the backends use of a world: a :class:`~components.sim.world.physics.World` in this
    process, or a :class:`~components.sim.mirror.remote_world.RemoteWorld` fed over the bus."""

    @property
    def config(self) -> WorldConfig: ...

    def snapshot(self) -> WorldSnapshot: ...

    def set_motor_pulses(self, left_ms: float, right_ms: float) -> None: ...

    def make_rng(self, stream: int) -> np.random.Generator: ...

    @property
    def air(self) -> RadioAir | None:
        """The air between the world's radios; None for a world seen over the bus."""
        ...

    @property
    def index(self) -> int:
        """Which robot of the world the backends sense and drive (0: the first)."""
        ...


CAMERA_RNG_STREAM = 1
ENCODER_RNG_STREAM = 2


def camera_stream(name: str) -> int:
    """The random stream of the camera device ``name`` other than ``front``: stable across
    runs and processes (not Python's salted ``hash``), clear of the fixed streams."""
    return 1000 + zlib.crc32(name.encode())

QUADRATURE_SEQUENCE = np.array([0, 1, 3, 2], dtype=np.uint8)
"""2-bit states ``(A << 1) | B`` in the order a forward-turning wheel steps through them."""


class SimMotorBackend(MotorBackend):
    """Hands the pulse widths to the simulated motors."""

    hold_s = 0.0  # the simulated motors see a pulse at once

    def __init__(self, world: WorldView) -> None:
        self._world = world

    def apply_pulses(self, *, left_ms: float, right_ms: float) -> None:
        self._world.set_motor_pulses(left_ms, right_ms)


def edge_index(angle_rad: float, edges_per_rev: int) -> int:
    """Number of quadrature edges a wheel has passed at ``angle_rad`` (floor, signed)."""
    return math.floor(angle_rad / (2.0 * math.pi / edges_per_rev))


def quadrature_states(previous_edge: int, edge: int) -> np.ndarray:
    """The states a line steps through going from edge index ``previous_edge`` to ``edge``.

    At edge index ``k`` the line is in state ``QUADRATURE_SEQUENCE[k % 4]`` (state 0 at angle
    0). Forward motion yields the states of ``previous_edge + 1 … edge``; backward motion those
    of ``previous_edge - 1 … edge``; no motion an empty array.
    """
    if edge > previous_edge:
        idx = np.arange(previous_edge + 1, edge + 1, dtype=np.int64)
    elif edge < previous_edge:
        idx = np.arange(previous_edge - 1, edge - 1, -1, dtype=np.int64)
    else:
        return np.empty(0, dtype=np.uint8)
    return QUADRATURE_SEQUENCE[idx % 4]


def insert_glitches(
    states: np.ndarray, probability: float, rng: np.random.Generator
) -> np.ndarray:
    """After each state, with ``probability``, insert a false edge: a jump to one of its two
    neighbouring states and straight back (so the true count is unchanged)."""
    n = len(states)
    if n == 0 or probability <= 0.0:
        return states
    glitch = rng.random(n) < probability
    if not glitch.any():
        return states
    repeats = np.where(glitch, 3, 1)
    out = np.repeat(states, repeats)
    starts = np.cumsum(repeats) - repeats
    # Position of each glitched state in the Gray cycle, then a random neighbour.
    position = np.argsort(QUADRATURE_SEQUENCE)[states[glitch]]
    offset = np.where(rng.random(int(glitch.sum())) < 0.5, 1, -1)
    out[starts[glitch] + 1] = QUADRATURE_SEQUENCE[(position + offset) % 4]
    return out


class SimEncoderBackend(EncoderBackend):
    """Quadrature A/B phases from the simulated wheel angles.

    Each wheel has the body's ``edges_per_rev`` edges per revolution (the Mini-WHEGS's:
    4096); ``read_phases`` turns the change in wheel angle since the previous call into the
    states the A/B lines stepped through, optionally with seeded false edges
    (``glitch_probability`` per real edge). The lines are in state 0 at wheel angle 0.
    """

    def __init__(
        self,
        world: WorldView,
        *,
        glitch_probability: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        if not 0.0 <= glitch_probability <= 1.0:
            raise ValueError(f"glitch_probability must be in [0, 1], got {glitch_probability}")
        self._world = world
        self._edges_per_rev = world.config.robot.geometry.edges_per_rev
        self._glitch_probability = glitch_probability
        self._rng = rng if rng is not None else world.make_rng(ENCODER_RNG_STREAM)
        self._lock = threading.Lock()
        r = world.snapshot().robot
        self._last = (
            edge_index(r.left_wheel_angle_rad, self._edges_per_rev),
            edge_index(r.right_wheel_angle_rad, self._edges_per_rev),
        )

    def current_states(self) -> tuple[int, int]:
        """The (left, right) line states as of the previous read (the decoder's start state)."""
        with self._lock:
            return (
                int(QUADRATURE_SEQUENCE[self._last[0] % 4]),
                int(QUADRATURE_SEQUENCE[self._last[1] % 4]),
            )

    def read_phases(self) -> tuple[np.ndarray, np.ndarray]:
        r = self._world.snapshot().robot
        now = (
            edge_index(r.left_wheel_angle_rad, self._edges_per_rev),
            edge_index(r.right_wheel_angle_rad, self._edges_per_rev),
        )
        with self._lock:
            left = quadrature_states(self._last[0], now[0])
            right = quadrature_states(self._last[1], now[1])
            self._last = now
            if self._glitch_probability > 0.0:
                left = insert_glitches(left, self._glitch_probability, self._rng)
                right = insert_glitches(right, self._glitch_probability, self._rng)
        return left, right


RENDER_DELAY_ENV = "UBF_TEST_RENDER_DELAY_S"
"""A test hook: seconds of wall time each simulated camera frame takes at least (its
render thread waits them out), to show that a slow render costs no simulated time."""


def render_delay_s() -> float:
    """The extra wall time per frame :data:`RENDER_DELAY_ENV` asks for (0 when unset)."""
    text = os.environ.get(RENDER_DELAY_ENV, "").strip()
    try:
        delay = float(text) if text else 0.0
    except ValueError:
        raise ValueError(f"{RENDER_DELAY_ENV}={text!r}: expected seconds") from None
    if not (math.isfinite(delay) and delay >= 0):
        raise ValueError(f"{RENDER_DELAY_ENV}={text!r}: expected seconds >= 0")
    return delay


class SimCameraBackend(CameraBackend):
    """Renders the world's latest snapshot (call ``capture`` from a worker thread).

    ``capture`` renders without holding any world lock: the snapshot it reads is immutable.

    ``grid`` = 1 (the default) renders every pixel: full frames, for recordings and anything
    that looks at the picture. ``grid`` = ``SUBSAMPLE_STEP`` (what the ``camera.sim`` device
    backend uses) renders only the pixels seekcolor's subsampler reads, ``(8·i, 8·j)``, and
    returns them in a frame of the full size whose other pixels are black (a *sparse* frame:
    the camera component and its published width/height are unchanged, and its seekcolor
    counts are those of the full frame, see :func:`~components.sim.render.camera.render_camera`),
    several times faster.

    ``renderer``: a :class:`~components.sim.render.process.RenderProcess` to render in (the
    ``camera.sim`` device backend gives it the process's shared one), so the rendering holds
    another process's GIL, not this one's: :meth:`capture` only waits on it. Without one, or
    whenever it has no worker running, the frame is rendered in the calling thread — the same
    pixels, from the same per-frame seed.
    """

    renders_in_python = True
    """Captures are CPU work under the GIL (in-thread), or wait on the render process: the
    camera component runs them on the process's one render thread
    (:data:`components.camera.component._RENDERS`), one at a time, as the render process
    renders one at a time."""

    def __init__(
        self,
        world: WorldView,
        params: CameraParams = DEFAULT_CAMERA,
        *,
        rng: np.random.Generator | None = None,
        grid: int = 1,
        renderer: RenderProcess | None = None,
    ) -> None:
        if grid < 1:
            raise ValueError(f"grid must be >= 1, got {grid}")
        self._world = world
        self._params = params
        self._grid = grid
        self._renderer = renderer
        self._rng = rng if rng is not None else world.make_rng(CAMERA_RNG_STREAM)
        self._lock = threading.Lock()
        self._closed = False
        self._exposed: WorldSnapshot | None = None
        self._delay_s = render_delay_s()

    @property
    def params(self) -> CameraParams:
        return self._params

    def mount(self, mount: CameraMount) -> None:
        """Render from the device's mount, through its lens, at its frame size. A camera
        other than ``front`` draws its noise and bob from a stream of its own (so two
        cameras of one robot do not share them); ``front`` keeps the stream it always had."""
        with self._lock:
            self._params = self._params.mounted(mount)
            if mount.name != DEFAULT_MOUNT.name:
                self._rng = self._world.make_rng(camera_stream(mount.name))

    @property
    def renderer(self) -> RenderProcess | None:
        return self._renderer

    def prepare(self) -> None:
        """Start the render process if this camera has one and it is not running yet (≈1 s,
        once per process), with its caches built for this camera; otherwise (no render
        process, or it cannot start) build this process's cached background and noise field
        (a few hundred ms). Either way the first frame costs no more than the others."""
        if self._renderer is not None and self._renderer.prepare(self._params, grid=self._grid):
            # This process builds its own caches only if it ever renders a frame itself.
            return
        warm_up(self._params, grid=self._grid)

    def expose(self) -> None:
        """Latch the world's current snapshot for the next :meth:`capture`."""
        snapshot = self._world.snapshot()
        with self._lock:
            self._exposed = snapshot

    def capture(self) -> np.ndarray:
        """Render the snapshot latched by :meth:`expose` (or, without one, the current one)."""
        with self._lock:
            if self._closed:
                raise RuntimeError("camera backend is closed")
            # One seed per frame keeps concurrent captures independent, and is all a render
            # process needs to draw the same noise and bob as this thread would.
            seed = int(self._rng.integers(0, 2**63))
            snapshot, self._exposed = self._exposed, None
        if snapshot is None:
            snapshot = self._world.snapshot()
        if self._delay_s:
            time.sleep(self._delay_s)  # the test hook (RENDER_DELAY_ENV); a worker thread
        small = None
        if self._renderer is not None:
            small = self._renderer.render(snapshot, self._params, seed=seed, grid=self._grid)
        if small is None:
            small = render_camera(snapshot, self._params, np.random.default_rng(seed),
                                  grid=self._grid)
        if self._grid == 1:
            return small
        # np.zeros maps fresh zero pages: only the pages the grid rows touch cost anything.
        frame = np.zeros((self._params.height_px, self._params.width_px, 3), dtype=np.uint8)
        frame[::self._grid, ::self._grid] = small
        return frame

    def close(self) -> None:
        with self._lock:
            self._closed = True


class SimRangeBackend(RangeBackend):
    """True beam distance from :func:`components.sim.world.ranging.beam_distance_m`."""

    def __init__(self, world: WorldView) -> None:
        self._world = world

    def distance_m(self, mount: MountPose, *, max_range_m: float) -> float | None:
        return beam_distance_m(self._world.snapshot(), mount, max_range_m)


class SimRadioBackend(RadioBackend):
    """An in-memory text link: ``send`` appends to ``outbox``; ``inject`` makes a message arrive.

    Thread-safe.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._outbox: list[str] = []
        self._inbox: list[str] = []

    def send(self, text: str) -> None:
        if not isinstance(text, str):
            raise TypeError(f"radio messages are text, got {type(text).__name__}")
        with self._lock:
            self._outbox.append(text)

    def receive(self) -> list[str]:
        with self._lock:
            arrived, self._inbox = self._inbox, []
        return arrived

    def inject(self, text: str) -> None:
        """Make ``text`` arrive (it is returned by the next ``receive``)."""
        if not isinstance(text, str):
            raise TypeError(f"radio messages are text, got {type(text).__name__}")
        with self._lock:
            self._inbox.append(text)

    @property
    def outbox(self) -> list[str]:
        """Every message sent so far, oldest first (a copy)."""
        with self._lock:
            return list(self._outbox)

    def clear_outbox(self) -> list[str]:
        """Return and forget the messages sent so far."""
        with self._lock:
            sent, self._outbox = self._outbox, []
        return sent


# -- backend factories (entry points ``ubf_async.backends``: ``<kind>.sim``) -------------------

SIMULATOR = "mini-whegs"
"""The simulator plug-in (``ubf_async.simulators``) whose world these backends need."""

Factory = TypeVar("Factory", bound=Callable[..., Any])


def _on_simulator(factory: Factory) -> Factory:
    factory.requires_simulator = SIMULATOR  # type: ignore[attr-defined]
    return factory


def _world(context: DeviceContext, backend: str) -> WorldView:
    world = context.simulation
    if world is None:
        raise ConfigurationError(
            f"backend {backend!r} needs the {SIMULATOR!r} simulator's world, and none was given"
        )
    return world


@_on_simulator
def camera_backend(*, context: DeviceContext, full_frames: bool = False,
                   render_process: bool = True) -> SimCameraBackend:
    """``camera.sim``: renders the simulated OV9655's view of the world. By default only the
    pixels seekcolor reads (sparse frames, see :class:`SimCameraBackend`); ``full_frames``
    renders every pixel (slower, the same counts). ``render_process``: render in the
    process's render process (:mod:`components.sim.render.process`, shared by its simulated
    cameras), so rendering does not hold this process's GIL; ``false``, or
    ``UBF_RENDER_PROCESS=0`` in the environment, or a run that starts no helper processes
    (:attr:`~ubf_async.assembly.context.DeviceContext.helper_processes`), renders in the
    camera's thread (the same frames)."""
    grid = 1 if full_frames else SUBSAMPLE_STEP
    wanted = render_process and context.helper_processes and render_process_wanted()
    renderer = shared_render_process() if wanted else None
    return SimCameraBackend(_world(context, "camera.sim"), grid=grid, renderer=renderer)


@_on_simulator
def motors_backend(*, context: DeviceContext) -> SimMotorBackend:
    """``motors.sim``: drives the simulated wheels."""
    return SimMotorBackend(_world(context, "motors.sim"))


@_on_simulator
def encoders_backend(
    *,
    context: DeviceContext,
    glitch_probability: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.0,
) -> SimEncoderBackend:
    """``encoders.sim``: quadrature phases from the simulated wheel angles, with a false edge
    after a real one with ``glitch_probability`` (seeded by the world's seed)."""
    return SimEncoderBackend(_world(context, "encoders.sim"),
                             glitch_probability=glitch_probability)


@_on_simulator
def range_backend(*, context: DeviceContext) -> SimRangeBackend:
    """``range.sim``: true beam distances in the simulated world."""
    return SimRangeBackend(_world(context, "range.sim"))


def radio_backend(*, context: DeviceContext) -> SimRadioBackend:
    """``radio.sim``: an in-memory text link (``inject`` a message, read ``outbox``). It
    needs nothing of the world, so it does not require the simulator."""
    return SimRadioBackend()


radio_backend.requires_simulator = None  # type: ignore[attr-defined]


class SimAirRadioBackend(RadioBackend):
    """A radio on the air of a simulated world (:class:`~components.sim.world.air.RadioAir`):
    what it sends, every other robot of the world receives."""

    def __init__(self, air: RadioAir, robot: int) -> None:
        self.air = air
        self.robot = robot

    def send(self, text: str) -> None:
        if not isinstance(text, str):
            raise TypeError(f"radio messages are text, got {type(text).__name__}")
        self.air.broadcast(self.robot, text)

    def receive(self) -> list[str]:
        return self.air.take(self.robot)


@_on_simulator
def radio_air_backend(*, context: DeviceContext) -> SimAirRadioBackend:
    """``radio.air``: a radio the other robots of the same simulated world hear (a fleet,
    ``python -m ubf_async.fleet``); alone in its world it hears nothing."""
    world = _world(context, "radio.air")
    air = world.air
    if air is None:
        raise ConfigurationError("backend 'radio.air' needs the simulated world in its own "
                                 "process (launch, or a fleet's world), not one seen over "
                                 "the bus")
    return SimAirRadioBackend(air, world.index)


class SimLedBackend(LedBackend):
    """LEDs in memory: ``mask`` is what is lit. The simulator draws them on its recorded
    camera frames from the LED device's ``sensor/leds/<name>`` samples, so a ``leds.sim``
    device in another process shows there too. Thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._mask = 0
        self.changes = 0

    def set_leds(self, mask: int) -> None:
        with self._lock:
            if mask != self._mask:
                self.changes += 1
            self._mask = mask

    @property
    def mask(self) -> int:
        with self._lock:
            return self._mask


def leds_backend(*, context: DeviceContext) -> SimLedBackend:
    """``leds.sim``: LEDs in memory (drawn on the simulator's recorded frames). It needs
    nothing of the world, so it does not require the simulator."""
    return SimLedBackend()


leds_backend.requires_simulator = None  # type: ignore[attr-defined]
