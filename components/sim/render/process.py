"""Simulated cameras render in a worker process: :class:`RenderProcess`.

Rendering a frame (:func:`~components.sim.render.camera.render_camera`) is CPU work in
Python and numpy that holds the GIL for a millisecond or more at a time. In a process whose
event loop also steps the physics and publishes the clock (a launch, a fleet's world with a
camera per robot) the loop waits for the GIL behind it, and the clock's ticks jitter
(docs/fleet.md, *How a fleet scales*). So the frames are rendered in another process: one
worker per process that has simulated cameras, shared by all of them
(:func:`shared_render_process`), started by the first camera's
:meth:`~components.sim.backends.devices.SimCameraBackend.prepare` (which runs in a thread, never on
the event loop). For each frame the camera sends the worker the frame's immutable
:class:`~components.sim.world.snapshot.WorldSnapshot` (pickled: ≈1.2 KB for a robot of a fleet
of 8, ≈80 µs), its :class:`~components.sim.render.camera.CameraParams`, the frame's seed and the
grid; the worker renders with ``np.random.default_rng(seed)`` exactly as the camera would
have in its own thread and sends back the pixels (160×128×3 bytes on the camera device's
grid of 8). Meanwhile the camera's thread waits on the pipe with the GIL released. The frames
are bit-identical to rendering in-thread (``tests/test_render_process.py``).

Lifecycle. The worker is spawned: a fresh interpreter (``python -c``, by :mod:`subprocess`),
never a fork of this process, whose zenoh threads may hold locks a fork would copy held. It
is multiprocessing's ``spawn`` by hand, for two reasons: that one also starts
multiprocessing's resource-tracker process (one more child, which outlives its parent for a
moment) and re-imports the parent's main module in the worker (zenoh and all, for a launch).
The worker ignores SIGINT (a Ctrl-C at the terminal reaches the whole process group; the
parent handles it and ends the worker), and builds the renderer's caches
(:func:`~components.sim.render.camera.warm_up`) for the cameras known when it starts, and
for each camera after. It ends when the parent closes its end of the pipe: at exit (an
``atexit`` handler, so a normal end, a handled Ctrl-C or SIGTERM, or an exception; the
parent then reaps it), or when the parent dies however it dies (SIGKILL, ``os._exit``),
since the kernel then closes the parent's end; between frames the worker also checks that
its parent pid has not changed, in case a copy of the parent's end lives on in another
process. A worker that dies, breaks the pipe or does not answer within ``reply_timeout_s`` is
killed and replaced from a background thread (logged), less and less often if replacements
keep failing; the frames meanwhile, and the one being rendered when it failed, are rendered
in the camera's thread — the same pixels. A frame whose rendering raises in the worker is
rendered in the camera's thread too (where it raises again, as it always did); the worker
carries on. A worker that cannot start at all (``prepare`` fails) is not retried: the
cameras render in-thread for the rest of the run (logged).

In-thread rendering as before: ``UBF_RENDER_PROCESS=0`` (or ``off``, ``no``, ``false``) in
the environment, or ``render_process: false`` in a ``camera.sim`` device's
``backend_params``.

Cost: the worker is a Python interpreter with numpy, OpenCV and pymunk imported and the
renderer's caches built: 0.4–0.5 s to start (while the camera's ``prepare`` holds simulated
time) and ≈85 MB resident, ≈52 MB of it private, once per process (docs/fleet.md). A
capture takes the camera's thread ≈0.5 ms of CPU (the exchange and the sparse frame) instead
of ≈1.6 ms, and a full frame (``grid`` 1, 3.9 MB) costs a few ms more than in-thread
to come through the pipe.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import math
import os
import socket
import subprocess
import sys
import threading
import traceback
from multiprocessing import BufferTooShort
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from components.sim.render.camera import CameraParams, render_camera, warm_up
from components.sim.world.snapshot import WorldSnapshot
from ubf_async.errors import DeviceError

__all__ = ["ENV_VAR", "RenderProcess", "RenderProcessError", "frame_shape", "render_process_wanted",
           "shared_render_process", "worker_main"]

log = logging.getLogger(__name__)

ENV_VAR = "UBF_RENDER_PROCESS"
"""``0``, ``off``, ``no`` or ``false``: simulated cameras render in their own thread."""
_OFF = frozenset({"0", "off", "no", "false"})

_ROOT = Path(__file__).resolve().parents[3]
"""Where the ``components`` package this module belongs to lives."""

_PARENT_CHECK_S = 1.0
"""How often an idle worker checks that its parent is still the process that started it."""


def render_process_wanted() -> bool:
    """Whether the environment lets simulated cameras render in a worker process
    (:data:`ENV_VAR`)."""
    return os.environ.get(ENV_VAR, "").strip().lower() not in _OFF


def frame_shape(params: CameraParams, grid: int) -> tuple[int, int, int]:
    """The shape of what :func:`~components.sim.render.camera.render_camera` returns."""
    return (math.ceil(params.height_px / grid), math.ceil(params.width_px / grid), 3)


class RenderProcessError(DeviceError):
    """The worker could not be started, or stopped answering (the simulated camera's
    device failure)."""


# -- the worker --------------------------------------------------------------------------------

_BOOT = ("import signal; signal.signal(signal.SIGINT, signal.SIG_IGN); "
         "import sys; sys.argv[3] in sys.path or sys.path.insert(0, sys.argv[3]); "
         "from components.sim.render.process import worker_main; worker_main()")
"""The worker's command (``python -c``). It ignores SIGINT before anything else: a Ctrl-C at
the terminal reaches the whole process group, and the parent handles it (then ends the
worker); here it would only kill a frame in flight and print a traceback. Then it imports
this very package from where the parent has it (a work tree, say, rather than an installed
copy)."""


def worker_main() -> None:
    """The worker: ``python -c _BOOT FD PARENT_PID ROOT``, its end of the pipe on ``FD``."""
    conn = Connection(int(sys.argv[1]))
    parent_pid = int(sys.argv[2])
    with contextlib.suppress(EOFError, OSError):  # the parent is gone: nothing to tell it
        for params, grid in conn.recv():  # the cameras known when it starts
            warm_up(params, grid=grid)
        conn.send(("ready",))
        while True:
            if not conn.poll(_PARENT_CHECK_S):
                if os.getppid() != parent_pid:
                    return
                continue
            request = conn.recv()
            try:
                if request[0] == "warm":
                    warm_up(request[1], grid=request[2])
                    conn.send(("ok",))
                    continue
                _, snapshot, params, seed, grid = request
                pixels = render_camera(snapshot, params, np.random.default_rng(seed), grid=grid)
            except Exception:
                conn.send(("error", traceback.format_exc()))
                continue
            conn.send(("ok",))
            conn.send_bytes(np.ascontiguousarray(pixels).data.cast("B"))


# -- the parent's side -------------------------------------------------------------------------


class _Lost(Exception):
    """The worker died, broke the pipe or did not answer in time."""


class _Worker:
    """One started worker process and the parent's end of its pipe."""

    def __init__(self, *, process: subprocess.Popen[bytes], conn: Connection,
                 warmed: set[tuple[CameraParams, int]]) -> None:
        self.process = process
        self.conn = conn
        self.warmed = warmed
        """(params, grid) whose caches the worker has built."""

    @property
    def pid(self) -> int:
        return self.process.pid

    def request(self, message: tuple[Any, ...], timeout_s: float) -> tuple[Any, ...]:
        """Send ``message``; the worker's status reply (raises :class:`_Lost`). The worker's
        death reads as EOF: only it holds the other end of the pipe."""
        try:
            self.conn.send(message)
            if self.conn.poll(timeout_s):
                reply: tuple[Any, ...] = self.conn.recv()
                return reply
        except (EOFError, OSError) as exc:
            status = None
            with contextlib.suppress(subprocess.TimeoutExpired):  # to say how it ended
                status = self.process.wait(0.1)
            raise _Lost(f"it exited (status {status})" if status is not None
                        else f"its pipe broke ({exc!r})") from None
        raise _Lost(f"it did not answer within {timeout_s:g} s")

    def warm(self, params: CameraParams, grid: int, timeout_s: float) -> None:
        """Have the worker build its caches for ``params`` and ``grid`` unless it has (raises
        :class:`_Lost`). A warm-up that fails in the worker is logged: the frames then build
        the caches, or fail (and are rendered in the camera's thread)."""
        if (params, grid) in self.warmed:
            return
        reply = self.request(("warm", params, grid), timeout_s)
        if reply[0] != "ok":
            log.warning("render process: warming up failed:\n%s", reply[1])
        self.warmed.add((params, grid))

    def receive_into(self, out: np.ndarray) -> None:
        try:
            size = self.conn.recv_bytes_into(out.reshape(-1))
        except (EOFError, OSError, BufferTooShort) as exc:
            raise _Lost(f"its frame did not arrive ({exc!r})") from None
        if size != out.nbytes:
            raise _Lost(f"it sent {size} bytes for a {out.shape} frame")

    def stop(self, *, timeout_s: float) -> None:
        """End the worker: EOF on its pipe, then SIGTERM, then SIGKILL; reap it."""
        with contextlib.suppress(OSError):
            self.conn.close()
        for end in (None, self.process.terminate, self.process.kill):
            if end is not None:
                end()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(timeout_s)
                return
        self.process.wait()

    def kill(self) -> None:
        """End a worker that failed: at once (it may be hung)."""
        with contextlib.suppress(OSError):
            self.process.kill()
        self.process.wait()
        with contextlib.suppress(OSError):
            self.conn.close()


class RenderProcess:
    """A worker process rendering frames for the simulated cameras of this process (see the
    module docstring). Thread-safe; one frame at a time.

    :meth:`prepare` starts the worker (blocking: call it from a thread, not the event loop);
    :meth:`render` renders one frame in it, or returns None when there is no worker (it could
    not start, it is being replaced, or it has just failed): the caller then renders in its
    own thread. :meth:`close` ends the worker; :func:`shared_render_process`'s is closed at
    exit.
    """

    def __init__(self, *, reply_timeout_s: float = 10.0, start_timeout_s: float = 60.0,
                 max_restart_delay_s: float = 30.0) -> None:
        self.reply_timeout_s = reply_timeout_s
        self.start_timeout_s = start_timeout_s
        self.max_restart_delay_s = max_restart_delay_s
        self.rendered = 0
        """Frames rendered by a worker."""
        self.failures = 0
        """Workers that died, failed or hung (each was replaced, or is being replaced)."""
        self.started = 0
        """Workers started (the first and its replacements)."""
        self._lock = threading.Lock()  # the state below; held briefly
        self._changed = threading.Condition(self._lock)
        self._pipe = threading.Lock()  # one exchange with the worker at a time
        self._starting = threading.Lock()  # one start at a time
        self._worker: _Worker | None = None
        self._warm: list[tuple[CameraParams, int]] = []
        self._given_up = False
        self._closed = False
        self._failing = 0  # failures since the last frame a worker rendered
        self._restarter: threading.Thread | None = None
        self._stop = threading.Event()

    @property
    def pid(self) -> int | None:
        """The worker's process id (None while there is none)."""
        with self._lock:
            return self._worker.pid if self._worker is not None else None

    @property
    def running(self) -> bool:
        with self._lock:
            return self._worker is not None

    def prepare(self, params: CameraParams, *, grid: int) -> bool:
        """Have a worker running with its caches built for ``params`` and ``grid``: start it
        if none runs yet (blocks for as long as that takes, ≈1 s). Returns whether frames
        will be rendered in it; False if it could not start (logged once; this process then
        renders in-thread for good) or was closed."""
        with self._lock:
            if (params, grid) not in self._warm:
                self._warm.append((params, grid))
        with self._starting:
            with self._lock:
                if self._closed or self._given_up:
                    return False
                worker = self._worker
                replacing = self._restarter is not None
            if worker is None:
                if replacing:
                    return True  # the replacement warms up for every known camera
                try:
                    worker = self._spawn()
                except RenderProcessError as exc:
                    log.warning("simulated cameras render in this process: %s "
                                "(%s=0 says so without trying)", exc, ENV_VAR)
                    with self._lock:
                        self._given_up = True
                    return False
                if not self._install(worker):
                    return False
        with self._pipe:
            try:
                worker.warm(params, grid, self.start_timeout_s)
            except _Lost as exc:
                self._lost(worker, str(exc))  # replaced in the background, meanwhile in-thread
        return True

    def render(self, snapshot: WorldSnapshot, params: CameraParams, *, seed: int,
               grid: int) -> np.ndarray | None:
        """The frame ``render_camera(snapshot, params, np.random.default_rng(seed),
        grid=grid)`` rendered by the worker; None if there is no worker to render it (render
        it in-thread)."""
        with self._lock:
            worker = self._worker
        if worker is None:
            return None
        with self._pipe:
            try:
                worker.warm(params, grid, self.start_timeout_s)  # if it skipped prepare()
                reply = worker.request(("render", snapshot, params, seed, grid),
                                       self.reply_timeout_s)
                if reply[0] != "ok":
                    # Rendered in-thread, it raises again there (or, if the worker's
                    # environment was at fault, succeeds).
                    log.warning("render process: a frame failed; rendering it here:\n%s",
                                reply[1])
                    return None
                out = np.empty(frame_shape(params, grid), dtype=np.uint8)
                worker.receive_into(out)
            except _Lost as exc:
                self._lost(worker, str(exc))
                return None
        with self._lock:
            self.rendered += 1
            self._failing = 0
        return out

    def wait_running(self, timeout_s: float) -> bool:
        """Wait until a worker runs (after a failure: its replacement); whether one does."""
        with self._changed:
            return self._changed.wait_for(
                lambda: self._worker is not None or self._closed or self._given_up,
                timeout_s) and self._worker is not None

    def close(self, *, timeout_s: float = 2.0) -> None:
        """End the worker (waiting up to ``timeout_s`` for it at each step) and start no
        other."""
        with self._lock:
            self._closed = True
            worker, self._worker = self._worker, None
            restarter = self._restarter
            self._changed.notify_all()
        self._stop.set()
        if restarter is not None:
            restarter.join(timeout_s)
        if worker is None:
            return
        # A frame in flight holds the pipe: end the worker under it, which ends the wait.
        if self._pipe.acquire(timeout=timeout_s):
            try:
                worker.stop(timeout_s=timeout_s)
            finally:
                self._pipe.release()
        else:
            worker.kill()

    # -- internals -------------------------------------------------------------------------
    def _spawn(self) -> _Worker:
        """Start a worker and wait until it has warmed up (raises RenderProcessError)."""
        with self._lock:
            warm = list(self._warm)
        mine, theirs = socket.socketpair()
        process: subprocess.Popen[bytes] | None = None
        conn = Connection(mine.detach())
        try:
            with theirs:  # only the worker holds its end after this: its death is EOF here
                process = subprocess.Popen(
                    [sys.executable, "-c", _BOOT, str(theirs.fileno()), str(os.getpid()),
                     str(_ROOT)],
                    pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL)
            conn.send(warm)
            if not conn.poll(self.start_timeout_s):
                reason = f"it did not get ready within {self.start_timeout_s:g} s"
            elif conn.recv() == ("ready",):
                with self._lock:
                    self.started += 1
                return _Worker(process=process, conn=conn, warmed=set(warm))
            else:
                reason = "it answered nonsense"
        except EOFError:
            reason = f"it exited while starting (status {process and process.poll()})"
        except Exception as exc:  # whatever stops it starting: render in-thread instead
            reason = f"it could not start ({exc!r})"
        if process is not None:
            with contextlib.suppress(OSError):
                process.kill()
            process.wait()
        conn.close()
        raise RenderProcessError(f"no render process: {reason}")

    def _install(self, worker: _Worker) -> bool:
        """Make ``worker`` the one frames go to (unless closed meanwhile: then end it)."""
        with self._lock:
            if not self._closed:
                self._worker = worker
                # The same instant the worker is in place: a failure of it from now on
                # starts a replacement of its own.
                self._restarter = None
                self._changed.notify_all()
                return True
        worker.stop(timeout_s=1.0)
        return False

    def _lost(self, worker: _Worker, why: str) -> None:
        """``worker`` failed: kill it, and replace it from a background thread."""
        worker.kill()
        with self._lock:
            if self._worker is not worker or self._closed:
                return  # already replaced (another thread found it dead first), or closing
            self._worker = None
            self.failures += 1
            self._failing += 1
            log.error("render process %d lost: %s; replacing it (frames render in this "
                      "process meanwhile)", worker.pid, why)
            if self._restarter is None:
                restarter = threading.Thread(target=self._replace, daemon=True,
                                             name="ubf-render-restart")
                try:
                    restarter.start()
                except RuntimeError:  # the interpreter is shutting down: no replacement
                    return
                self._restarter = restarter

    def _replace(self) -> None:
        """The restart thread: start workers until one runs (or the process is closed)."""
        while True:
            with self._lock:
                failing = self._failing
            # Again and again failing workers are replaced less and less often.
            delay = min(0.5 * 2.0 ** (failing - 2), self.max_restart_delay_s)
            if failing > 1 and self._stop.wait(delay):
                break
            with self._starting:
                if self._stop.is_set():
                    break
                try:
                    worker = self._spawn()
                except RenderProcessError as exc:
                    with self._lock:
                        self._failing += 1
                    log.error("render process: replacing it failed: %s", exc)
                    continue
                if self._install(worker):
                    log.info("render process %d replaces the lost one", worker.pid)
                    return
                break
        with self._lock:
            self._restarter = None
            self._changed.notify_all()


_SHARED: RenderProcess | None = None
_SHARED_LOCK = threading.Lock()


def shared_render_process() -> RenderProcess:
    """The render process shared by every simulated camera of this process (created on first
    use, its worker started by the first camera's ``prepare``, closed at exit)."""
    global _SHARED
    with _SHARED_LOCK:
        if _SHARED is None:
            _SHARED = RenderProcess()
            atexit.register(_SHARED.close)  # the worker is reaped, not left to its parent check
        return _SHARED
