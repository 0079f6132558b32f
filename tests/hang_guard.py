"""A test that fails and then hangs in its teardown is still reported, with every thread's
stack (loaded by ``-p tests.hang_guard`` in pyproject.toml's ``addopts``).

pytest-timeout (``timeout``) and pytest's faulthandler (``faulthandler_timeout``) both stop
watching a test the moment it fails — ``pytest_exception_interact``, where a debugger would
take over. The teardown that follows (fixtures closing sessions, an event loop cancelling its
tasks) then runs unwatched, and a hang there stalls its worker for ever with nothing printed:
the suite's "hung with no stack". From that moment on, faulthandler watches again: after
``faulthandler_timeout`` seconds it writes every thread's stack to the terminal and ends the
worker, which pytest-xdist reports as crashed while running that test.
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
from collections.abc import Generator

import pytest

_terminal: dict[str, int] = {}
"""The terminal's stderr, duplicated while output capture is off (``fd``): the capture's own
file would be lost with the worker."""


def pytest_configure(config: pytest.Config) -> None:
    capture = config.pluginmanager.getplugin("capturemanager")
    with capture.global_and_fixture_disabled() if capture else contextlib.nullcontext():
        _terminal["fd"] = os.dup(2)


def pytest_unconfigure(config: pytest.Config) -> None:
    fd = _terminal.pop("fd", None)
    if fd is not None:
        os.close(fd)


@pytest.hookimpl(trylast=True)
def pytest_exception_interact(node: pytest.Item | pytest.Collector, call: pytest.CallInfo[object],
                              report: pytest.TestReport | pytest.CollectReport) -> None:
    limit = float(node.config.getini("faulthandler_timeout") or 0)
    if isinstance(node, pytest.Item) and call.when != "teardown" and limit > 0 \
            and "fd" in _terminal:
        faulthandler.dump_traceback_later(limit, exit=True, file=_terminal["fd"])


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None
                            ) -> Generator[None, object, object]:
    try:
        return (yield)
    finally:
        faulthandler.cancel_dump_traceback_later()
