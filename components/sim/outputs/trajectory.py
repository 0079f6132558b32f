"""Recording a simulated run: trajectory samples, a top-down plot, annotated camera frames.

No bus here (NumPy/OpenCV): the runner calls the drawing and file functions from worker
threads. A run's memory stays bounded however long it lasts: :class:`TrajectoryBuffer` keeps
a decimated history of the whole run plus the recent samples at full rate, and
:class:`TrajectoryCsvWriter` streams every sample to ``trajectory.csv`` as the run goes.
"""

from __future__ import annotations

import csv
import itertools
import math
import threading
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TextIO

import cv2
import numpy as np

from components.camera.seekcolor import SeekResult
from components.camera.view import draw_view
from components.sim.render.camera import CameraParams
from components.sim.scenarios.scenario import CAMERA_OFFSET_M
from components.sim.world.snapshot import WorldSnapshot
from ubf_async.wire.topics import LedState

__all__ = ["CAMERA_HALF_FOV_DEG", "CLOSE_M", "FACING_DEG", "HISTORY_CAPACITY", "LED_DARK_BGR",
           "LED_LIT_BGR", "RECENT_SAMPLES", "BallView", "TrajectoryBuffer", "TrajectoryCsvWriter",
           "TrajectorySample", "annotate_frame", "ball_on_stage", "camera_to_ball", "motion_over",
           "read_trajectory_csv", "trajectory_sample"]


@dataclass(frozen=True, slots=True)
class TrajectorySample:
    t_s: float
    robot_x_m: float
    robot_y_m: float
    robot_heading_rad: float
    ball_x_m: float | None
    ball_y_m: float | None
    speed_cmd: float | None
    turn_cmd: float | None
    winners: str


def trajectory_sample(snap: WorldSnapshot, *, speed_cmd: float | None = None,
                      turn_cmd: float | None = None, winners: str = "") -> TrajectorySample:
    """The sample of ``snap``: robot pose and ball position, with the command then in force."""
    return TrajectorySample(
        t_s=snap.time_s, robot_x_m=snap.robot.x_m, robot_y_m=snap.robot.y_m,
        robot_heading_rad=snap.robot.heading_rad,
        ball_x_m=snap.ball.x_m if snap.ball else None,
        ball_y_m=snap.ball.y_m if snap.ball else None,
        speed_cmd=speed_cmd, turn_cmd=turn_cmd, winners=winners,
    )


def camera_to_ball(
    x_m: float, y_m: float, heading_rad: float, ball_x_m: float, ball_y_m: float, *,
    camera_x_m: float = CAMERA_OFFSET_M,
) -> tuple[float, float]:
    """Distance (m) and bearing (deg, + left) from the robot's camera, ``camera_x_m`` ahead
    of its centre, to the ball centre."""
    cam_x = x_m + camera_x_m * math.cos(heading_rad)
    cam_y = y_m + camera_x_m * math.sin(heading_rad)
    dx, dy = ball_x_m - cam_x, ball_y_m - cam_y
    bearing = math.atan2(dy, dx) - heading_rad
    bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
    return math.hypot(dx, dy), math.degrees(bearing)


def motion_over(samples: Sequence[TrajectorySample], seconds: float) -> dict[str, float]:
    """How much the robot moved over the last ``seconds``: path length, the farthest it was
    from where it ended (small when it only dithers in place), and total heading change."""
    if not samples:
        return {"distance_m": 0.0, "max_offset_m": 0.0, "heading_change_deg": 0.0,
                "window_s": 0.0}
    start = samples[-1].t_s - seconds
    window = [s for s in samples if s.t_s >= start - 1e-9]
    distance = sum(math.hypot(b.robot_x_m - a.robot_x_m, b.robot_y_m - a.robot_y_m)
                   for a, b in itertools.pairwise(window))
    turn = sum(abs((b.robot_heading_rad - a.robot_heading_rad + math.pi) % (2 * math.pi) - math.pi)
               for a, b in itertools.pairwise(window))
    end = window[-1]
    offset = max(math.hypot(p.robot_x_m - end.robot_x_m, p.robot_y_m - end.robot_y_m)
                 for p in window)
    return {"distance_m": distance, "max_offset_m": offset,
            "heading_change_deg": math.degrees(turn), "window_s": end.t_s - window[0].t_s}


CAMERA_HALF_FOV_DEG = CameraParams().hfov_deg / 2
"""Half the simulated camera's horizontal field of view."""
FACING_DEG = 10.0
"""Facing the ball: its bearing within this (the scenarios' ``|ball_bearing_deg|`` bound)."""
CLOSE_M = 0.35
"""Too close: nearer than the comfortable distance's lower bound (the scenarios' 0.35 m)."""


class BallView:
    """How the ball stood to the robot over a whole run, tallied sample by sample (so a run
    of any length keeps four numbers): when it first came into the camera's field of view,
    the share of samples it was in view, the robot faced it, it was too close, and of those
    too close the share the robot was backing away (the summary's ``ball_view``)."""

    def __init__(self, *, camera_x_m: float = CAMERA_OFFSET_M) -> None:
        self.camera_x_m = camera_x_m
        """Where the camera sits ahead of the robot's centre (the robot's body)."""
        self.samples = self.in_view = self.facing = self.close = self.backing = 0
        self.first_in_view_s: float | None = None

    def add(self, sample: TrajectorySample) -> None:
        self.samples += 1
        if sample.ball_x_m is None or sample.ball_y_m is None:  # hidden: out of view
            return
        distance, bearing = camera_to_ball(sample.robot_x_m, sample.robot_y_m,
                                           sample.robot_heading_rad, sample.ball_x_m,
                                           sample.ball_y_m, camera_x_m=self.camera_x_m)
        if abs(bearing) <= CAMERA_HALF_FOV_DEG:
            self.in_view += 1
            if self.first_in_view_s is None:
                self.first_in_view_s = sample.t_s
        self.facing += abs(bearing) <= FACING_DEG
        if distance < CLOSE_M:
            self.close += 1
            self.backing += sample.speed_cmd is not None and sample.speed_cmd < 0

    def summary(self) -> dict[str, float | None]:
        def share(count: int, of: int) -> float | None:
            return count / of if of else None
        return {"first_in_view_s": self.first_in_view_s,
                "in_view_share": share(self.in_view, self.samples),
                "facing_share": share(self.facing, self.samples),
                "close_share": share(self.close, self.samples),
                "backing_when_close_share": share(self.backing, self.close)}


HISTORY_CAPACITY = 4096
"""Most samples :class:`TrajectoryBuffer` keeps of the run's history (before the recent ones)."""
RECENT_SAMPLES = 1200
"""Samples :class:`TrajectoryBuffer` keeps at full rate at the end: 60 s at the runner's 50 ms."""


class TrajectoryBuffer:
    """The samples of a run in bounded memory, keeping the whole run's shape.

    Two parts, together at most ``capacity + recent`` samples whatever the run's length:

    * the *history*: every ``stride``-th sample since the start. When it holds ``capacity``
      samples, every other one is dropped and the stride doubles, so the kept samples always
      cover the whole run evenly (the first sample stays; a 1 h run at 20 samples/s keeps one
      in 32, every 1.6 s) — enough for the trajectory plot;
    * the *recent* samples, the last ``recent`` at full rate — for figures over the run's
      end (:func:`motion_over` over the last 2 s) and the final pose.

    :meth:`samples` joins both in time order. ``append`` is O(1) amortised; call it from one
    thread (the runner's event loop).
    """

    def __init__(self, *, capacity: int = HISTORY_CAPACITY, recent: int = RECENT_SAMPLES) -> None:
        if capacity < 2 or capacity % 2:
            raise ValueError(f"capacity must be an even number >= 2, got {capacity}")
        if recent < 1:
            raise ValueError(f"recent must be >= 1, got {recent}")
        self._capacity = capacity
        self._history: list[TrajectorySample] = []
        self._recent: deque[TrajectorySample] = deque(maxlen=recent)
        self._stride = 1
        self._count = 0

    @property
    def count(self) -> int:
        """Samples appended since the start (kept or not)."""
        return self._count

    @property
    def stride(self) -> int:
        """The history keeps the samples whose index is a multiple of this."""
        return self._stride

    @property
    def max_kept(self) -> int:
        """The most samples the buffer ever holds."""
        return self._capacity + (self._recent.maxlen or 0)

    @property
    def last(self) -> TrajectorySample | None:
        return self._recent[-1] if self._recent else None

    def __len__(self) -> int:
        """Samples held now (``<= max_kept``)."""
        return len(self._history) + len(self._recent)

    def append(self, sample: TrajectorySample) -> None:
        if self._count % self._stride == 0:
            self._history.append(sample)
            if len(self._history) >= self._capacity:
                # Indices were multiples of stride; now multiples of 2·stride. The next index
                # kept (capacity·stride) is one of them, as capacity is even.
                self._history = self._history[::2]
                self._stride *= 2
        self._recent.append(sample)
        self._count += 1

    def samples(self) -> list[TrajectorySample]:
        """The kept samples in time order: the history before the recent ones, then those."""
        first_recent = self._count - len(self._recent)
        older = -(-first_recent // self._stride)  # history entries with index < first_recent
        return self._history[:older] + list(self._recent)


_CSV_FIELDS = list(TrajectorySample.__dataclass_fields__)


class TrajectoryCsvWriter:
    """Streams samples to a ``trajectory.csv`` as the run goes, so none is held for the end.

    The event loop hands samples over with :meth:`add` (cheap, no I/O) and takes them back in
    batches with :meth:`take`; :meth:`write` (a worker thread's job) appends a batch to the
    file. Writes are serialised by a lock, so batches land in the order ``write`` was called.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fh: TextIO | None = path.open("w", newline="", encoding="utf-8")
        self._writer = csv.DictWriter(self._fh, fieldnames=_CSV_FIELDS)
        self._writer.writeheader()
        self._pending: list[TrajectorySample] = []
        self._lock = threading.Lock()
        self.written = 0

    @property
    def pending(self) -> int:
        return len(self._pending)

    def add(self, sample: TrajectorySample) -> None:
        self._pending.append(sample)

    def take(self) -> list[TrajectorySample]:
        batch, self._pending = self._pending, []
        return batch

    def write(self, samples: Iterable[TrajectorySample]) -> None:
        """Append ``samples`` to the file and flush it (blocking I/O: not on the loop)."""
        with self._lock:
            if self._fh is None:
                raise ValueError(f"{self.path} is closed")
            for s in samples:
                self._writer.writerow(asdict(s))
                self.written += 1
            self._fh.flush()

    def close(self) -> None:
        """Close the file (blocking I/O: not on the loop). Samples still pending are not
        written: :meth:`take` and :meth:`write` them first."""
        with self._lock:
            if self._fh is not None:
                self._fh.close()
                self._fh = None


def read_trajectory_csv(path: Path) -> list[TrajectorySample]:
    def num(v: str) -> float | None:
        return None if v == "" else float(v)

    with path.open(encoding="utf-8") as fh:
        return [
            TrajectorySample(
                t_s=float(r["t_s"]), robot_x_m=float(r["robot_x_m"]),
                robot_y_m=float(r["robot_y_m"]), robot_heading_rad=float(r["robot_heading_rad"]),
                ball_x_m=num(r["ball_x_m"]), ball_y_m=num(r["ball_y_m"]),
                speed_cmd=num(r["speed_cmd"]), turn_cmd=num(r["turn_cmd"]), winners=r["winners"],
            )
            for r in csv.DictReader(fh)
        ]


# ---------------------------------------------------------------------------------------------
# Pictures (BGR for OpenCV)



LED_LIT_BGR = (40, 40, 255)
LED_DARK_BGR = (60, 60, 60)


def annotate_frame(frame_rgb: np.ndarray, result: SeekResult, *, t_s: float,
                   scale: int = 4, leds: Mapping[str, LedState] | None = None) -> np.ndarray:
    """The camera's view (:func:`components.camera.view.draw_view`: the 160×128 subsample the
    robot sees, enlarged, with the five seekcolor bins and their counts), with the time and the
    pink count below and the robot's LEDs (``leds``: each LED device's state by name) as a row
    of dots, lit red."""
    image = draw_view(frame_rgb, result, scale=scale, mark_matches=False)
    h = image.shape[0] // scale
    label = f"t = {t_s:.1f} s   pink = {result.total}"
    cv2.rectangle(image, (0, h * scale - 34), (330, h * scale), (0, 0, 0), -1)
    cv2.putText(image, label, (10, h * scale - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.7,
                (255, 255, 255), 1, cv2.LINE_AA)
    _draw_leds(image, leds or {})
    return image


def _draw_leds(image: np.ndarray, leds: Mapping[str, LedState]) -> None:
    """Each LED device's LEDs as dots at the bottom right, lit ones filled red."""
    h, w = image.shape[:2]
    x = w - 14
    for name in sorted(leds, reverse=True):
        state = leds[name]
        for i in reversed(range(state.count)):
            lit = bool(state.mask >> i & 1)
            cv2.circle(image, (x, h - 17), 9, (0, 0, 0), -1)
            cv2.circle(image, (x, h - 17), 7, LED_LIT_BGR if lit else LED_DARK_BGR,
                       -1 if lit else 2)
            x -= 24
        x -= 12


def ball_on_stage(s: TrajectorySample) -> bool:
    """The ball is in the world (not lifted out of it by a scenario's ``hide``)."""
    return s.ball_x_m is not None and s.ball_y_m is not None and abs(s.ball_x_m) < 20 \
        and abs(s.ball_y_m) < 20

