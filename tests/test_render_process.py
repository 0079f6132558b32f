"""Simulated cameras rendering in a worker process (components/sim/render/process.py): the same
frames as in-thread, a worker replaced when it dies or hangs, in-thread rendering when it
cannot start or is not wanted, and no process left behind however the launch ends."""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from components.camera.seekcolor import SUBSAMPLE_STEP
from components.sim.backends.devices import SimCameraBackend, WorldView, camera_backend
from components.sim.render import process as render_process
from components.sim.render.calibrate import ball_ahead_world
from components.sim.render.camera import DEFAULT_CAMERA
from components.sim.render.process import ENV_VAR, RenderProcess, shared_render_process
from components.sim.world.config import Arena, BallConfig, WorldConfig, WorldPose
from components.sim.world.physics import RobotView, World
from tests.test_sim_camera import busy_arena
from ubf_async.assembly.context import DeviceContext

ROOT = Path(__file__).resolve().parent.parent


def _fleet_robot() -> WorldView:
    fleet = World(WorldConfig(arena=Arena(), ball=BallConfig(x_m=0.8, y_m=0.0),
                              more_robots=(WorldPose(x_m=0.4, y_m=0.1), WorldPose(x_m=-0.5)),
                              seed=9))
    return RobotView(fleet, 2)


SCENES: dict[str, Callable[[], WorldView]] = {
    # The ball near (coarse sphere shading in full frames), mid-way off-centre, and far.
    "ball 0.12 m": lambda: ball_ahead_world(0.12),
    "ball 0.45 m left": lambda: ball_ahead_world(0.45, lateral_m=0.06),
    "ball 3.6 m": lambda: ball_ahead_world(3.6),
    "busy dim arena": lambda: busy_arena(seed=5),
    "fleet robot 2": _fleet_robot,  # the other robots are boxes in its view
}


def _camera_and_twin(world: WorldView, seed: int, renderer: RenderProcess, *,
                     grid: int = SUBSAMPLE_STEP) -> tuple[SimCameraBackend, SimCameraBackend]:
    """A camera rendering in ``renderer`` and its twin rendering in-thread, from the same
    frame seeds: whatever renders them, their frames must be the same."""
    return (SimCameraBackend(world, rng=np.random.default_rng(seed), grid=grid,
                             renderer=renderer),
            SimCameraBackend(world, rng=np.random.default_rng(seed), grid=grid))


@pytest.fixture(scope="module")
def renderer() -> Iterator[RenderProcess]:
    rp = RenderProcess()
    yield rp
    rp.close()


@pytest.mark.parametrize("grid", [1, SUBSAMPLE_STEP])
@pytest.mark.parametrize("name", SCENES)
def test_frames_from_the_worker_are_the_frames_rendered_in_thread(
    renderer: RenderProcess, name: str, grid: int
) -> None:
    world = SCENES[name]()
    there, here = _camera_and_twin(world, 21, renderer, grid=grid)
    there.prepare()
    assert renderer.running
    before = renderer.rendered
    for _ in range(3):
        a, b = here.capture(), there.capture()
        assert a.shape == b.shape == (1024, 1280, 3) and b.dtype == np.uint8
        assert np.array_equal(a, b), name
    assert renderer.rendered == before + 3  # the worker rendered them, not a fallback


def _gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (exited and reaped, or a zombie nobody reaped yet)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] in ("Z", "X")


def _wait(predicate: Any, *, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s}s waiting for {what}")
        time.sleep(0.01)


def test_cameras_in_several_threads_share_one_worker(renderer: RenderProcess) -> None:
    world = busy_arena(seed=5)
    seeds = range(4)
    cameras = [SimCameraBackend(world, rng=np.random.default_rng(s), grid=SUBSAMPLE_STEP,
                                renderer=renderer) for s in seeds]
    for camera in cameras:
        camera.prepare()
    pid, before = renderer.pid, renderer.rendered
    frames: dict[int, list[np.ndarray]] = {s: [] for s in seeds}

    def capture(seed: int, camera: SimCameraBackend) -> None:
        frames[seed].extend(camera.capture() for _ in range(5))

    threads = [threading.Thread(target=capture, args=(s, c))
               for s, c in zip(seeds, cameras, strict=True)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for s in seeds:
        twin = SimCameraBackend(world, rng=np.random.default_rng(s), grid=SUBSAMPLE_STEP)
        assert all(np.array_equal(f, twin.capture()) for f in frames[s])
    assert renderer.rendered == before + 20 and renderer.pid == pid


def test_a_frame_that_fails_in_the_worker_is_left_to_the_thread(
    renderer: RenderProcess, caplog: pytest.LogCaptureFixture
) -> None:
    pid, failures = renderer.pid, renderer.failures
    with caplog.at_level(logging.WARNING, logger=render_process.__name__):
        # Not a snapshot: rendering it fails there (and would fail here).
        assert renderer.render(object(), DEFAULT_CAMERA, seed=1,  # type: ignore[arg-type]
                               grid=SUBSAMPLE_STEP) is None
    assert any("AttributeError" in r.getMessage() for r in caplog.records)
    assert renderer.pid == pid and renderer.failures == failures  # the worker carries on
    assert renderer.render(ball_ahead_world(1.0).snapshot(), DEFAULT_CAMERA, seed=1,
                           grid=SUBSAMPLE_STEP) is not None


def test_the_caches_are_built_in_the_worker_not_here() -> None:
    from components.sim.render.camera import _background, _noise_planes

    def misses() -> tuple[int, int]:
        return _background.cache_info().misses, _noise_planes.cache_info().misses

    world = ball_ahead_world(0.45)
    rp = RenderProcess()
    try:
        # Parameters no other test uses: a cache built for them here would be a miss.
        camera = SimCameraBackend(world, replace(DEFAULT_CAMERA, noise_sigma=1.25),
                                  grid=SUBSAMPLE_STEP, renderer=rp)
        before = misses()
        camera.prepare()
        camera.capture()
        assert rp.rendered == 1 and misses() == before
    finally:
        rp.close()
    alone = SimCameraBackend(world, replace(DEFAULT_CAMERA, noise_sigma=1.5),
                             grid=SUBSAMPLE_STEP)
    alone.prepare()  # renders in-thread: builds them here
    assert all(after > was for after, was in zip(misses(), before, strict=True))


def test_a_killed_worker_is_replaced_and_frames_keep_coming(
    caplog: pytest.LogCaptureFixture
) -> None:
    world = ball_ahead_world(0.45)
    rp = RenderProcess()
    try:
        camera, twin = _camera_and_twin(world, 3, rp)
        camera.prepare()
        first = rp.pid
        assert first is not None
        assert np.array_equal(camera.capture(), twin.capture())
        os.kill(first, signal.SIGKILL)
        with caplog.at_level(logging.ERROR, logger=render_process.__name__):
            # The frame being asked for when the worker is found dead is rendered here.
            assert np.array_equal(camera.capture(), twin.capture())
        assert rp.failures == 1
        assert any(f"render process {first} lost" in r.getMessage() for r in caplog.records)
        assert _gone(first)  # killed and reaped
        assert rp.wait_running(60)
        assert rp.pid not in (None, first)
        assert rp.started == 2
        rendered = rp.rendered
        for _ in range(3):
            assert np.array_equal(camera.capture(), twin.capture())
        assert rp.rendered == rendered + 3  # by the replacement
    finally:
        rp.close()


def test_a_hung_worker_is_killed_and_replaced() -> None:
    world = ball_ahead_world(0.8)
    rp = RenderProcess(reply_timeout_s=0.5)
    try:
        camera, twin = _camera_and_twin(world, 4, rp)
        camera.prepare()
        hung = rp.pid
        assert hung is not None
        os.kill(hung, signal.SIGSTOP)
        assert np.array_equal(camera.capture(), twin.capture())  # in-thread after 0.5 s
        assert rp.failures == 1 and _gone(hung)
        assert rp.wait_running(60) and rp.pid != hung
        assert np.array_equal(camera.capture(), twin.capture())
        assert rp.rendered == 1
    finally:
        rp.close()


def test_a_worker_that_cannot_start_leaves_the_camera_rendering_in_thread(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(render_process.sys, "executable", "/nonexistent/python")
    world = ball_ahead_world(0.45)
    rp = RenderProcess()
    camera, twin = _camera_and_twin(world, 5, rp)
    with caplog.at_level(logging.WARNING, logger=render_process.__name__):
        camera.prepare()
    assert not rp.running
    assert any("render in this process" in r.getMessage() for r in caplog.records)
    assert np.array_equal(camera.capture(), twin.capture())
    monkeypatch.undo()
    assert rp.prepare(camera.params, grid=SUBSAMPLE_STEP) is False  # not tried again
    assert rp.started == 0 and rp.rendered == 0
    rp.close()


def test_the_device_backend_renders_in_the_shared_process_unless_told_not_to(
    monkeypatch: pytest.MonkeyPatch
) -> None:
    context = DeviceContext(bus=None, clock=None, simulation=World())  # type: ignore[arg-type]
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert camera_backend(context=context).renderer is shared_render_process()
    assert camera_backend(context=context, render_process=False).renderer is None
    for off in ("0", "off", "False"):
        monkeypatch.setenv(ENV_VAR, off)
        assert camera_backend(context=context).renderer is None
    monkeypatch.setenv(ENV_VAR, "1")
    assert camera_backend(context=context).renderer is shared_render_process()


# ---------------------------------------------------------------------------------------------
# A launch leaves no process behind, however it ends


def _children(pid: int) -> set[int]:
    out: set[int] = set()
    with contextlib.suppress(FileNotFoundError):
        for task in Path(f"/proc/{pid}/task").iterdir():
            with contextlib.suppress(FileNotFoundError):
                out.update(int(c) for c in (task / "children").read_text().split())
    return out


def _worker_of(pid: int) -> int | None:
    for child in _children(pid):
        with contextlib.suppress(FileNotFoundError):
            if b"render.process import worker_main" in Path(f"/proc/{child}/cmdline").read_bytes():
                return child
    return None


class _Launch:
    """``python -m ubf_async.launch ARGS`` in a process group of its own (as a shell runs a
    command: a Ctrl-C at the terminal goes to the whole group), its output collected."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "ubf_async.launch", *args], cwd=ROOT,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, process_group=0,
            env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        with self.proc.stdout:
            self.lines.extend(line.rstrip("\n") for line in self.proc.stdout)

    def output(self) -> str:
        self._reader.join(timeout=5)
        return "\n".join(self.lines)

    def kill(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(timeout=10)


PR_SET_CHILD_SUBREAPER = 36


@contextlib.contextmanager
def _adopting_orphans() -> Iterator[None]:
    """Make this process the subreaper of its descendants meanwhile: a process orphaned by
    the death of its parent becomes this process's child (instead of init's), so a test can
    tell a worker its launch ended and reaped from one it left behind."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        pytest.skip("cannot become a child subreaper here")
    try:
        yield
    finally:
        libc.prctl(PR_SET_CHILD_SUBREAPER, 0, 0, 0, 0)


def _reap(pid: int, *, timeout_s: float) -> bool:
    """Wait for our (adopted) child ``pid`` to exit and reap it; whether it did in time."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        done, _ = os.waitpid(pid, os.WNOHANG)
        if done == pid:
            return True
        time.sleep(0.01)
    return False


@pytest.mark.slow
@pytest.mark.parametrize("end", ["duration", "Ctrl-C", "SIGTERM", "SIGKILL"])
def test_a_launch_leaves_no_process_behind(endpoint: str, end: str) -> None:
    duration = ("--duration", "3") if end == "duration" else ()
    with _adopting_orphans():
        launch = _Launch("--listen", endpoint, "--status-period-s", "0.2", *duration)
        try:
            _wait(lambda: _worker_of(launch.proc.pid) is not None, timeout_s=60,
                  what="the launch's render process")
            worker = _worker_of(launch.proc.pid)
            assert worker is not None
            # The worker, and no other process (multiprocessing would add its resource
            # tracker).
            assert _children(launch.proc.pid) == {worker}
            _wait(lambda: any("| sim 1." in line for line in launch.lines), timeout_s=60,
                  what="a simulated second of frames")
            if end == "Ctrl-C":
                os.killpg(launch.proc.pid, signal.SIGINT)  # the worker gets it too: ignored
            elif end != "duration":
                launch.proc.send_signal(getattr(signal, end))
            code = launch.proc.wait(timeout=60)
            if end == "SIGKILL":
                # Orphaned, with its end of the pipe closed by the kernel: it reads EOF and
                # exits (and, adopted by this process, is reaped here).
                assert worker in _children(os.getpid()) or _gone(worker)
                assert _reap(worker, timeout_s=10), "the orphaned worker did not exit"
            else:
                assert code == 0, launch.output()
                # Ended and reaped by the launch before it exited: never orphaned.
                assert worker not in _children(os.getpid()), launch.output()
                assert _gone(worker)
                assert "render process" not in launch.output()  # it neither died nor failed
            assert "Traceback" not in launch.output()
        finally:
            launch.kill()


_PROGRAM = """
import os, sys
from components.sim.render.camera import DEFAULT_CAMERA
from components.sim.render.process import shared_render_process
renderer = shared_render_process()
assert renderer.prepare(DEFAULT_CAMERA, grid=8)
print(renderer.pid, flush=True)
if sys.argv[1] == "exception":
    raise RuntimeError("the program fails")
os._exit(3)  # no atexit handlers, as when a second Ctrl-C exits at once
"""


@pytest.mark.parametrize("end", ["exception", "os._exit"])
def test_a_program_that_fails_or_exits_at_once_leaves_no_process_behind(end: str) -> None:
    with _adopting_orphans():
        proc = subprocess.run([sys.executable, "-c", _PROGRAM, end], cwd=ROOT, text=True,
                              capture_output=True, timeout=120)
        worker = int(proc.stdout.split()[0])
        if end == "exception":
            assert proc.returncode == 1 and "the program fails" in proc.stderr
            assert worker not in _children(os.getpid()) and _gone(worker)  # reaped at exit
        else:
            assert proc.returncode == 3
            assert _reap(worker, timeout_s=10), "the orphaned worker did not exit"


def test_close_ends_the_worker_and_starts_no_other() -> None:
    rp = RenderProcess()
    assert rp.prepare(DEFAULT_CAMERA, grid=SUBSAMPLE_STEP)
    pid = rp.pid
    assert pid is not None and not _gone(pid)
    rp.close()
    assert _gone(pid) and not rp.running
    snapshot = ball_ahead_world(1.0).snapshot()
    assert rp.render(snapshot, DEFAULT_CAMERA, seed=1, grid=SUBSAMPLE_STEP) is None
    assert rp.prepare(DEFAULT_CAMERA, grid=SUBSAMPLE_STEP) is False
