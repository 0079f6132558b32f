"""Which event loop the entry points run on (:func:`ubf_async.cli.run.loop_factory`,
``UBF_LOOP``): by default asyncio's selector loop that lends itself to no thread (it only
tells the lockstep when it is idle); the lending loop and uvloop are opt-in. The decision and
its figures: docs/latency.md, "Which event loop"."""

from __future__ import annotations

import asyncio
import importlib.util
import subprocess
import sys

import pytest

from tests.conftest import REPOSITORY, repository_env
from ubf_async.cli import run as cli
from ubf_async.errors import ConfigurationError
from ubf_async.runtime import lending


def test_without_ubf_loop_the_default_is_the_loop_that_lends_nothing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(cli.LOOP_ENV, raising=False)
    assert cli.DEFAULT_LOOP == "asyncio"
    assert cli.loop_factory() is lending.new_idle_event_loop
    monkeypatch.setenv(cli.LOOP_ENV, "  ")  # set but empty: the default too
    assert cli.loop_factory() is lending.new_idle_event_loop


@pytest.mark.asyncio
async def test_tests_run_on_the_default_loop_as_the_entry_points_do(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(cli.LOOP_ENV, raising=False)
    loop = asyncio.get_running_loop()
    assert isinstance(loop, lending.IdleEventLoop) and not loop.lends
    assert cli.loop_factory() is lending.new_idle_event_loop


def test_the_loop_is_chosen_by_ubf_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(cli.LOOP_ENV, "asyncio")
    assert cli.loop_factory() is lending.new_idle_event_loop
    monkeypatch.setenv(cli.LOOP_ENV, "Lending")
    assert cli.loop_factory() is lending.new_event_loop


def test_an_unknown_ubf_loop_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(cli.LOOP_ENV, "tokio")
    with pytest.raises(ConfigurationError) as caught:
        cli.loop_factory()
    assert str(caught.value) == ("UBF_LOOP='tokio': unknown event loop; expected one of "
                                 "asyncio (the default), lending, uvloop")


@pytest.mark.skipif(importlib.util.find_spec("uvloop") is None, reason="uvloop not installed")
def test_uvloop_is_opt_in_and_cannot_run_a_lockstep(monkeypatch: pytest.MonkeyPatch) -> None:
    import uvloop

    monkeypatch.setenv(cli.LOOP_ENV, "uvloop")
    assert cli.loop_factory() is uvloop.new_event_loop
    with pytest.raises(ConfigurationError, match="UBF_LOOP='uvloop' cannot tell"):
        cli.check_lockstep_loop()
    for choice in ("asyncio", "lending"):  # both tell when they are idle
        monkeypatch.setenv(cli.LOOP_ENV, choice)
        cli.check_lockstep_loop()


def test_an_unknown_ubf_loop_stops_an_entry_point_with_one_line() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "ubf_async.router", "--listen", "tcp/127.0.0.1:0"],
        cwd=REPOSITORY, env={**repository_env(), "UBF_LOOP": "tokio"}, capture_output=True,
        text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "UBF_LOOP='tokio': unknown event loop" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


@pytest.mark.parametrize("module", ["ubf_async.launch", "ubf_async.inspector",
                                    "ubf_async.record", "ubf_async.router"])
def test_the_help_says_which_loop_runs_and_what_is_opt_in(module: str) -> None:
    proc = subprocess.run([sys.executable, "-m", module, "--help"], cwd=REPOSITORY,
                          env=repository_env(), capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    text = " ".join(proc.stdout.split())
    assert "UBF_LOOP=lending" in text and "UBF_LOOP=uvloop" in text
    assert "opt-in" in text.lower() and "default" in text
