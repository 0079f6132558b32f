"""The gate itself: the lock CI installs from agrees with the declared ranges, and a hung test
fails with its name and every thread's stack (README, "Upgrading dependencies")."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parent.parent


def maintainer_tool() -> ModuleType:
    """.ci/deps.py, the lock's own reader (not a package: loaded from its path)."""
    spec = importlib.util.spec_from_file_location("deps", ROOT / ".ci" / "deps.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_lock_pins_every_requirement_within_its_declared_range() -> None:
    deps = maintainer_tool()
    pins = deps.pins(deps.LOCK.read_text("utf-8"))
    assert pins, f"{deps.LOCK} pins nothing"
    wrong = []
    for requirement in map(Requirement, deps.project_requirements()):
        versions = pins.get(canonicalize_name(requirement.name))
        if not versions:
            wrong.append(f"{requirement}: not in the lock")
        wrong += [f"{requirement}: locked at {version}" for version in versions or []
                  if not requirement.specifier.contains(version, prereleases=True)]
    assert not wrong, ("the lock is out of step with pyproject.toml (python .ci/deps.py lock):\n"
                       + "\n".join(wrong))


HANGS = '''
import ctypes
import threading
import time

import pytest


def wait_for_ever(event):
    event.wait()


def test_passes():
    pass


def test_waits_in_python():
    event = threading.Event()
    threading.Thread(target=wait_for_ever, args=(event,), name="a-helper", daemon=True).start()
    while True:
        time.sleep(1)


@pytest.fixture
def hangs_when_torn_down():
    yield
    while True:
        time.sleep(1)


def test_fails_then_hangs_in_its_teardown(hangs_when_torn_down):
    raise AssertionError("failed first")


def test_waits_in_c_with_the_gil():
    # A mutex locked twice by one thread, called with the GIL held (PyDLL): no Python runs
    # again in this process, so only a dump from C can tell where it stopped.
    libc = ctypes.PyDLL(None)
    mutex = ctypes.create_string_buffer(64)
    libc.pthread_mutex_init(mutex, None)
    libc.pthread_mutex_lock(mutex)
    libc.pthread_mutex_lock(mutex)
'''


@pytest.mark.slow
def test_a_hung_test_fails_with_its_name_and_every_threads_stack(tmp_path: Path) -> None:
    """The project's own configuration with its timeouts shortened: a test waiting in Python
    fails at pytest-timeout's timeout with every thread's stack, and the run goes on; one
    stuck in C with the GIL, or hanging in its teardown after it failed (when pytest-timeout
    and faulthandler stop watching: tests/hang_guard.py), is dumped by faulthandler, and its
    worker ends, named."""
    (tmp_path / "test_planted.py").write_text(HANGS, "utf-8")
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "-c", str(ROOT / "pyproject.toml"),
         "--rootdir", str(tmp_path), "-p", "no:cacheprovider", "-p", "no:randomly",
         "--numprocesses=2", "--timeout=2", "-o", "faulthandler_timeout=4",
         str(tmp_path / "test_planted.py")],
        cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT),  # tests.hang_guard
                               "COLUMNS": "300"},  # the summary's lines whole
        capture_output=True, text=True, timeout=120)
    out = run.stdout + run.stderr
    assert run.returncode == 1, out
    planted = r"test_planted\.py::test_waits_in_"
    assert re.search(rf"FAILED .*{planted}python - Failed: Timeout", out), out
    assert "Stack of a-helper" in out and "in wait_for_ever" in out, out
    assert re.search(rf"FAILED .*{planted}c_with_the_gil - .*crashed", out), out
    assert re.search(r'File ".*test_planted\.py", line \d+ in test_waits_in_c_with_the_gil',
                     out), out
    assert re.search(r"FAILED .*test_planted\.py::test_fails_then_hangs_in_its_teardown - "
                     r"AssertionError: failed first", out), out
    assert re.search(r"FAILED .*test_planted\.py::test_fails_then_hangs_in_its_teardown - "
                     r".*crashed", out), out
    assert re.search(r'File ".*test_planted\.py", line \d+ in hangs_when_torn_down', out), out
    assert "1 passed" in out, out
