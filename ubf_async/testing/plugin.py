"""The pytest plugin of :mod:`ubf_async.testing`, registered through the ``pytest11`` entry
point: a project that installs ``ubf-async`` gets these fixtures with no import.

* ``ubf_run`` — :func:`ubf_async.testing.run_script` for a plain (synchronous) test:
  ``ubf_run("my-robot.yaml", script, until_s=2.0)``; in an ``async`` test, ``await``
  :func:`ubf_async.testing.run_script_async` instead;
* ``ubf_robot_file`` — writes a robot file's text into the test's temporary folder and gives
  its path (a variant of one's robot for one test).

Imports nothing of the framework until a fixture is used: the plugin loads in every pytest run
of an environment that has ``ubf-async``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from ubf_async.testing._run import ScriptRun

__all__ = ["ubf_robot_file", "ubf_run"]


@pytest.fixture
def ubf_run() -> Callable[..., ScriptRun]:
    """:func:`ubf_async.testing.run_script`."""
    from ubf_async.testing._run import run_script

    return run_script


@pytest.fixture
def ubf_robot_file(tmp_path: Path) -> Callable[[str], Path]:
    """``ubf_robot_file(text, name="robot.yaml")``: the robot file written, its path."""
    def write(text: str, name: str = "robot.yaml") -> Path:
        path = tmp_path / name
        path.write_text(text, "utf-8")
        return path

    return write
