"""A command's ``main(argv)`` run in the test's process, for what the command decides before
anything starts: a refusal (status 2, one line on stderr) or ``--check``'s plan.

The command itself (``python -m ...``: its entry point, the interpreter's exit status) stays
run in a subprocess for one case of each kind, where the test using this says; the other cases
run the same ``main`` here, without an interpreter's start-up each. Output is captured at the
file descriptors (``capfd``), as a subprocess's would be: a trace a native library printed
would show. ``main`` must not start the robot: :func:`launch_main` makes its start fail the
test."""

from __future__ import annotations

import logging
import subprocess
import sys
from collections.abc import Callable, Sequence

import pytest

from ubf_async.tools import launch


def run_main(main: Callable[[Sequence[str]], int], argv: Sequence[str],
             capfd: pytest.CaptureFixture[str], *, name: str) -> subprocess.CompletedProcess[str]:
    """``main(argv)`` here; its status (argparse's ``SystemExit`` too) and what it printed, as
    :func:`subprocess.run` gives them. The logging set-up it makes is undone."""
    capfd.readouterr()  # only what main prints
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    logging.getLogger("ubf_async.services.live")  # launch sets its level
    levels = {key: logging.getLogger(key).level for key in logging.root.manager.loggerDict}
    try:
        try:
            code = main(list(argv))
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)
        for logger, old in levels.items():
            logging.getLogger(logger).setLevel(old)
    out, err = capfd.readouterr()
    return subprocess.CompletedProcess([name, *argv], code, out, err)


def launch_main(argv: Sequence[str], capfd: pytest.CaptureFixture[str],
                monkeypatch: pytest.MonkeyPatch) -> subprocess.CompletedProcess[str]:
    """``python -m ubf_async.launch ARGV`` decided here; if it went on to run the robot, the
    test fails (nothing may start)."""

    def started(*args: object, **kwargs: object) -> int:
        raise AssertionError(f"launch {' '.join(argv)}: the robot was started")

    plan = launch.print_plan

    def print_plan(planned: object, out: object = None) -> None:
        # Its default stream is the sys.stdout of launch's import; the command's is the one
        # it runs with.
        plan(planned, out or sys.stdout)  # type: ignore[arg-type]

    with monkeypatch.context() as patch:
        patch.setattr(launch, "run_main", started)
        patch.setattr(launch, "print_plan", print_plan)
        return run_main(launch.main, argv, capfd, name="ubf_async.launch")
