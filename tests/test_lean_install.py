"""A lean install: ``pip install ubf-async`` (no extras) runs a robot of real devices, and a
feature whose extra is missing says which extra and how to install it.

The subprocesses see exactly the distributions a fresh venv's ``pip install .`` brings
(tests/lean_install.py blocks every other installed one), so this costs seconds, not an
install; the true fresh-venv install is .ci/run's last step.
"""

from __future__ import annotations

import functools
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement

from tests.lean_install import (
    ROOT,
    base_requirements,
    blocked_modules,
    canonical,
    lean_environment,
)
from ubf_async import extras
from ubf_async.errors import MissingExtraError, PluginError

PI_WHEGS = "examples/robots/pi-whegs.yaml"


def _extras_of_pyproject() -> dict[str, list[Requirement]]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text("utf-8"))["project"]
    return {name: [Requirement(text) for text in texts]
            for name, texts in project["optional-dependencies"].items()}


@functools.cache
def _modules_of() -> dict[str, set[str]]:
    """Top-level modules of each installed distribution (canonical name); read once: it
    scans every distribution's files."""
    found: dict[str, set[str]] = {}
    for module, dists in metadata.packages_distributions().items():
        for dist in dists:
            found.setdefault(canonical(dist), set()).add(module)
    return found


def _provided_by(requirement: Requirement) -> set[str]:
    """Top-level modules of the (installed) distribution ``requirement`` names."""
    return _modules_of().get(canonical(requirement.name), set())


def _with_included(name: str, table: dict[str, list[Requirement]]) -> list[Requirement]:
    """An extra's requirements, the extras it includes (``ubf-async[sim]``) followed."""
    out: list[Requirement] = []
    for req in table[name]:
        if req.name == "ubf-async":
            for included in req.extras:
                out += _with_included(included, table)
        else:
            out.append(req)
    return out


def test_each_optional_module_is_in_its_extra_and_not_in_the_base() -> None:
    table = _extras_of_pyproject()
    base = set().union(*(_provided_by(req) for req in base_requirements()))
    for module, extra in extras.EXTRA_OF.items():
        provided = set().union(*(_provided_by(r) for r in _with_included(extra, table)))
        assert module in provided, f"{module}: not brought by the {extra!r} extra"
        assert module not in base, f"{module}: in [project].dependencies, not only {extra!r}"
    everything = {r.name for r in _with_included("all", table)}
    for extra in ("sim", "view", "record", "ros2", "tune", "hardware"):
        assert {r.name for r in _with_included(extra, table)} <= everything, extra
    assert everything <= {r.name for r in _with_included("test", table)}  # [test] pulls [all]
    # What a lean install lacks is exactly what the extras bring (and what the tests use).
    assert set(extras.EXTRA_OF) - {"uvloop", "ray", "pyarrow", "cmaes"} <= blocked_modules()


def test_require_names_the_extra_and_the_command() -> None:
    assert extras.require("sim", "json", who="x").dumps([]) == "[]"
    with pytest.raises(MissingExtraError) as caught:
        extras.require("record", "ubf_async_no_such_module.writer", who="recording")
    assert str(caught.value) == (
        "recording needs the 'record' extra (ubf_async_no_such_module is not installed): "
        "pip install 'ubf-async[record]'")
    assert isinstance(caught.value, PluginError) and isinstance(caught.value, ImportError)
    # A module that is there but breaks inside is not a missing extra: it raises as it is.
    with pytest.raises(ModuleNotFoundError, match="no_such_inner"):
        extras.require("sim", "tests.lean_broken_probe", who="x")
    missing = extras.missing_extra(ModuleNotFoundError(name="pymunk.vec2d"), who="simulator 'x'")
    assert str(missing) == ("simulator 'x' needs the 'sim' extra (pymunk.vec2d is not "
                            "installed): pip install 'ubf-async[sim]'")
    assert extras.missing_extra(ModuleNotFoundError(name="yaml"), who="x") is None
    assert extras.missing_extra(ValueError("pymunk"), who="x") is None


def _lean_run(tmp_path: Path, *args: str) -> tuple[subprocess.CompletedProcess[str], set[str]]:
    env, log = lean_environment(tmp_path)
    log.write_text("")
    result = subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True,
                            text=True, timeout=120)
    return result, set(log.read_text().split())


def test_a_robot_of_real_devices_checks_on_the_lean_install(tmp_path: Path) -> None:
    # launch's --check, then every device kind of the file and its backend's module, as the
    # launch would build them: none of it reaches for an extra.
    code = f"""
import runpy, sys
from ubf_async.assembly.registry import DEVICES, get_backend
from ubf_async.assembly.robotfile import load_robot
sys.argv = ["launch", {PI_WHEGS!r}, "--check"]
try:
    runpy.run_module("ubf_async.launch", run_name="__main__")
except SystemExit as exc:
    print("exit", exc.code)
for device in load_robot({PI_WHEGS!r}).devices:
    DEVICES.get(device.kind)
    get_backend(device.kind, device.backend)
    print("loaded", device.kind, device.backend)
"""
    result, attempted = _lean_run(tmp_path, "-c", code)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert "robot 'pi-whegs' — OK" in lines[0]
    assert "exit 0" in lines
    assert [line for line in lines if line.startswith("loaded")] == [
        "loaded motors gpio", "loaded encoders gpio", "loaded range i2c",
        "loaded range ads1115", "loaded camera video", "loaded leds gpio"]
    assert not attempted & set(extras.EXTRA_OF), attempted  # not even tried


@pytest.mark.parametrize(("args", "line"), [
    (["-m", "ubf_async.launch", "--check"],
     "mini-whegs.yaml:14: the simulator needs the 'sim' extra (pymunk is not installed): "
     "pip install 'ubf-async[sim]'"),
    (["-m", "ubf_async.launch", PI_WHEGS, "--check", "--record", "out"],
     "launch --record needs the 'record' extra (mcap is not installed): "
     "pip install 'ubf-async[record]'"),
])
def test_a_feature_says_which_extra_it_needs(tmp_path: Path, args: list[str],
                                             line: str) -> None:
    result, _ = _lean_run(tmp_path, *args)
    assert result.returncode == 2, result.stderr
    assert result.stderr.splitlines() == [f"python -m ubf_async.launch: error: {line}"]


def test_a_library_call_without_an_extra_raises_it_as_a_missing_extra(tmp_path: Path) -> None:
    """A simulated run asked of the library on the lean install: a MissingExtraError (what a
    caller catches to offer the install), still told where the robot file asked for it."""
    code = """
from ubf_async import MissingExtraError, experiment
try:
    experiment.run("mini-whegs", scenario="ball-in-sight", duration_s=0.1)
except MissingExtraError as exc:
    print(exc.extra, exc.where, sep="|")
    print(exc)
"""
    result, _ = _lean_run(tmp_path, "-c", code)
    assert result.returncode == 0, result.stderr
    extra, where = result.stdout.splitlines()[0].split("|")
    assert (extra, Path(where).name) == ("sim", "mini-whegs.yaml:14"), result.stdout
    assert result.stdout.splitlines()[1].endswith(
        "mini-whegs.yaml:14: the simulator needs the 'sim' extra (pymunk is not installed): "
        "pip install 'ubf-async[sim]'"), result.stdout
