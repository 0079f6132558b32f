"""Running a sweep's runs: what a worker does with one run, and the pools of workers.

One mechanism for both executors: a pool with :class:`multiprocessing.pool.Pool`'s interface,
``imap_unordered`` over the runs, one run at a time per worker, each worker process running
many runs. ``local``: processes of this machine (multiprocessing, ``spawn``: a fresh
interpreter, nothing inherited but the code). ``ray``: :class:`ray.util.multiprocessing.Pool`,
the same interface on the actors of a Ray cluster; Ray schedules, restarts and ships the code
(its ``runtime_env``) — nothing of that is done here.

A run that raises is a result like any other: :func:`run_task` returns it as ``failed`` with
its error, and the sweep goes on.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import logging
import multiprocessing
import os
import signal
import sys
import tempfile
import traceback
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, Literal, Protocol

import msgspec

from ubf_async import extras
from ubf_async.cli import ending
from ubf_async.errors import ConfigurationError, RunsLostError
from ubf_async.runs import inprocess, overrides
from ubf_async.runs.sweep import cluster
from ubf_async.runs.sweep.spec import RunTask

__all__ = ["CODE_PACKAGES", "EXECUTORS", "MAX_LOG_LINES", "MAX_TEXT", "Pool", "RunRecord",
           "code_runtime_env", "default_workers", "init_local_worker", "init_worker", "open_pool",
           "pool_workers", "run_task", "scenario_file", "scenario_path"]

EXECUTORS = ("local", "ray")
MAX_LOG_LINES = 20
"""Log lines kept per run (warnings and errors): the first ones, then a count."""
MAX_TEXT = 4000
CODE_PACKAGES = ("ubf_async", "components")
"""The packages a Ray worker needs, shipped by default (:func:`code_runtime_env`)."""


class RunRecord(msgspec.Struct, frozen=True, omit_defaults=True):
    """What one run gave: its summary, or why it failed. A line of the journal."""

    id: str
    status: Literal["ok", "failed"]
    key: dict[str, Any]
    summary: dict[str, Any] | None = None
    error: str | None = None
    """``Type: message`` of what the run raised."""
    traceback: str | None = None
    log: list[str] = []
    """Warnings and errors the run logged (the first :data:`MAX_LOG_LINES`)."""


class Pool(Protocol):
    """What the sweep uses of a pool: multiprocessing's and Ray's alike."""

    def imap_unordered(self, func: Callable[[RunTask], RunRecord], iterable: Iterable[RunTask],
                       chunksize: int = 1) -> Iterator[RunRecord]: ...

    def close(self) -> None: ...

    def join(self) -> None: ...

    def terminate(self) -> None: ...


class _Kept(logging.Handler):
    """A run's warnings and errors, kept for its record rather than printed over the
    progress bar by every worker."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        self.lines: list[str] = []
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.count += 1
        if len(self.lines) < MAX_LOG_LINES:
            self.lines.append(self.format(record)[:MAX_TEXT])

    def kept(self) -> list[str]:
        more = self.count - len(self.lines)
        return self.lines + ([f"... and {more} more"] if more else [])


def scenario_path(scenario: str, text: str | None) -> str:
    """What to run a scenario from: a built-in's name (``text`` is ``None``), or its file
    written anew on this machine (a worker of a cluster may not have the spec's files), one
    file per text."""
    if text is None:
        return scenario
    return scenario_file(Path(scenario).name, text)


def scenario_file(name: str, text: str) -> str:
    """A scenario file named ``name`` holding ``text``, in a folder of this machine's temporary
    files kept for that text (written once, whole)."""
    folder = Path(tempfile.gettempdir()) / "ubf_async-sweep" / hashlib.sha256(
        text.encode()).hexdigest()[:16]
    path = folder / name
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        part = folder / f".{name}.{os.getpid()}"
        part.write_text(text, encoding="utf-8")
        part.replace(path)  # whole, even with another worker writing the same file
    return str(path)


def run_task(task: RunTask) -> RunRecord:
    """Run ``task`` in this process (:func:`ubf_async.runs.inprocess.run`); whatever it raises
    makes a ``failed`` record."""
    kept = _Kept()
    root = logging.getLogger()
    root.addHandler(kept)
    try:
        robot = overrides.load_robot_text_with(task.robot_text, dict(task.overrides),
                                               source=task.robot_source)
        result = inprocess.run(robot, scenario_path(task.scenario, task.scenario_text),
                               seed=task.seed, duration_s=task.duration_s)
    # SystemExit too: a plug-in calling sys.exit() would end the worker, and a pool waits for
    # a lost task forever.
    except (Exception, SystemExit) as exc:
        return RunRecord(id=task.run_id, status="failed", key=task.key,
                         error=f"{type(exc).__name__}: {exc}"[:MAX_TEXT],
                         traceback=traceback.format_exc()[-MAX_TEXT:], log=kept.kept())
    finally:
        root.removeHandler(kept)
    return RunRecord(id=task.run_id, status="ok", key=task.key, summary=result.summary,
                     log=kept.kept())


def init_worker() -> None:
    """Every worker: Python's warnings go to the log, so a run's record keeps them."""
    logging.captureWarnings(True)


def init_local_worker() -> None:
    """A local worker: Ctrl-C is the parent's to handle (it ends the workers), and the worker
    dies with its parent — a sweep killed outright leaves no run going on unseen."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    ending.die_with_parent()
    init_worker()


def default_workers() -> int:
    """Every core this process may run on."""
    if sys.version_info >= (3, 13):
        return os.process_cpu_count() or 1
    if sys.platform == "linux":
        return len(os.sched_getaffinity(0)) or 1
    return os.cpu_count() or 1


def pool_workers(executor: str, workers: int | None, runs: int) -> int | None:
    """The pool's size for ``runs`` runs: on this machine, ``workers`` (default: every core)
    but no more processes than runs; Ray's as given (default: every CPU of the cluster)."""
    if executor != "local":
        return workers
    return min(workers or default_workers(), runs)


def code_runtime_env() -> dict[str, Any]:
    """Ray's ``runtime_env`` shipping this process's ``ubf_async`` and ``components`` packages
    to every worker (Ray uploads them once per content), so the workers run the same code as
    this process — the robot files and scenario files go with each run."""
    folders = []
    for package in CODE_PACKAGES:
        found = importlib.util.find_spec(package)  # located, not imported (components is not
        assert found is not None and found.submodule_search_locations  # the framework's)
        folders.append(str(Path(next(iter(found.submodule_search_locations)))))
    return {"py_modules": folders, "excludes": ["__pycache__/"]}


@contextlib.contextmanager
def open_pool(executor: str = "local", *, workers: int | None = None,
              address: str | None = None,
              runtime_env: dict[str, Any] | None = None) -> Iterator[Pool]:
    """A pool of ``workers`` processes (default: every core; on Ray: every CPU of the
    cluster), ended when the block ends: ``terminate`` if it ends early (in-flight runs are
    lost), else once the workers are done. ``address`` and ``runtime_env`` are Ray's (default
    environment: :func:`code_runtime_env`); a Ray this process already joined is used as it
    is. Raises :class:`ConfigurationError`, and :class:`~ubf_async.errors.ClusterError` for a
    cluster that cannot be joined; on Ray, the pool's ``imap_unordered`` raises
    :class:`RunsLostError` at its end when a worker was lost with runs."""
    if executor not in EXECUTORS:
        raise ConfigurationError(f"executor {executor!r}: expected one of {', '.join(EXECUTORS)}")
    if workers is not None and workers < 1:
        raise ConfigurationError(f"workers must be at least 1, got {workers}")
    if executor == "local":
        if address is not None or runtime_env is not None:
            raise ConfigurationError("an address and a runtime environment are Ray's: "
                                     "use them with the ray executor")
        context = multiprocessing.get_context("spawn")
        with _ended(context.Pool(workers or default_workers(),
                                 initializer=init_local_worker)) as pool:
            yield pool
        return
    with _ray_pool(workers, address, runtime_env) as pool:
        yield pool


@contextlib.contextmanager
def _ended(pool: Any) -> Iterator[Pool]:
    done = False
    try:
        yield pool
        pool.close()
        pool.join()
        done = True
    finally:
        if not done:
            pool.terminate()


class _LossesTold:
    """Ray's pool, its lost runs told: where a worker is lost (its node died), Ray's pool gives
    the error in place of each run it held and goes on with the other workers. Here the runs
    that finish come out as ever, and once the others are done, :class:`RunsLostError` says
    how many were lost — a caller keeps what finished, and runs the lost ones again."""

    def __init__(self, pool: Any) -> None:
        self._pool = pool

    def imap_unordered(self, func: Callable[[RunTask], RunRecord], iterable: Iterable[RunTask],
                       chunksize: int = 1) -> Iterator[RunRecord]:
        lost: list[BaseException] = []
        for result in self._pool.imap_unordered(func, iterable, chunksize=chunksize):
            if isinstance(result, BaseException):
                lost.append(result)
            else:
                yield result
        if lost:
            runs = len(lost) * chunksize
            raise RunsLostError(f"{runs} run{'s' if runs > 1 else ''} lost with the Ray worker "
                                f"that held {'them' if runs > 1 else 'it'} (a node that died? "
                                f"{type(lost[0]).__name__}: {cluster.ray_said(lost[0])})")

    def close(self) -> None:
        self._pool.close()

    def join(self) -> None:
        self._pool.join()

    def terminate(self) -> None:
        self._pool.terminate()


def _alive_cpus(ray: Any) -> int:
    """The CPUs of the cluster's live nodes. Ray's pool sizes itself from the cluster's
    resources, which go on counting a node that died until Ray's resource view catches up:
    an actor asked for there is never placed, and a resumed sweep waited forever (seen under
    load after a killed node)."""
    return max(1, int(sum(node["Resources"].get("CPU", 0) for node in ray.nodes()
                          if node.get("Alive"))))


@contextlib.contextmanager
def _ray_pool(workers: int | None, address: str | None,
              runtime_env: dict[str, Any] | None) -> Iterator[Pool]:
    ray = extras.require("cluster", "ray", who="the ray executor (docs/experiments.md)")
    from ray.util.multiprocessing import Pool as RayPool
    joined = not ray.is_initialized()
    if joined:
        cluster.join(address, ray, code_runtime_env() if runtime_env is None else runtime_env)
    try:
        try:
            # An actor per CPU asked for: the pool's actors spread over the cluster's nodes
            # (they take none by default, and would all start on one).
            made = RayPool(processes=workers or _alive_cpus(ray), initializer=init_worker,
                           ray_remote_args={"num_cpus": 1})
        except ValueError as exc:  # more workers than the cluster has CPUs
            raise ConfigurationError(f"workers: {exc}") from None
        with _ended(_LossesTold(made)) as pool:
            yield pool
    finally:
        if joined:
            ray.shutdown()
