"""Which way imports go: devices stand on the framework, the simulator stands on the devices.

* ``ubf_async`` (the framework) imports nothing of ``components``;
* the device packages and ``components/standalone.py`` import neither the simulator
  (``components.sim``) nor launch (``ubf_async.tools.launch``): they find a simulator, like any
  backend, through the registry;
* only the simulator imports pymunk;
* only the hardware backends (and ``components/hardware.py``, what they share) import the
  hardware libraries, gpiozero and smbus2: they are an optional extra, and a robot without
  them (the simulated one) runs — checked by running it with both made unimportable.

The same directions, the rooms of the framework (``ubf_async``'s subpackages, high to low:
tools, runs, services, assembly|cli, runtime|behaviors, core|net|clocks, wire, extras,
errors|throttle), the
simulator's rooms (``components.sim``'s subpackages: plugin, runner, backends|outputs|mirror,
render|scenarios, world; every module placed), device packages independent of each other (what
two share lives beside them: ``components/quadrature.py``, ``miniwhegs.py``, ``hardware.py``)
and no import circles are contracts of
``lint-imports`` (``[tool.importlinter]`` in pyproject.toml, run by .ci/run); the last tests
here show that it refuses a deliberately upward import on a scratch copy of the packages.

Static imports only (``import``/``from … import`` anywhere in a module, including inside
functions and ``if TYPE_CHECKING:``), and imports by a literal name
(``importlib.import_module("x")``, ``hardware.require("x", ...)``); a plug-in loaded by name at
run time is the point.
"""

from __future__ import annotations

import ast
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DEVICE_PACKAGES = ("camera", "motors", "encoders", "range", "radio", "leds")
HARDWARE_LIBRARIES = ("gpiozero", "smbus2")
HARDWARE_BACKENDS = ("components/hardware.py", "components/motors/gpio.py",
                     "components/encoders/gpio.py", "components/range/i2c.py",
                     "components/leds/gpio.py")
"""The modules that may import the hardware libraries."""
IMPORTERS = {"import_module", "require", "__import__"}
"""Calls whose first argument, a literal, names a module they import."""


def imported_modules(path: Path, root: Path = ROOT) -> set[str]:
    """Every module ``path`` imports, absolute (relative imports resolved against its place
    under ``root``)."""
    tree = ast.parse(path.read_text("utf-8"), filename=str(path))
    package = ".".join(path.relative_to(root).with_suffix("").parts[:-1])
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and node.args:
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            first = node.args[0]
            if called in IMPORTERS and isinstance(first, ast.Constant) \
                    and isinstance(first.value, str):
                found.add(first.value)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                module = ".".join([*base, node.module] if node.module else base)
            else:
                module = node.module or ""
            found.add(module)
            found.update(f"{module}.{alias.name}" for alias in node.names)
    return found


def modules_under(*parts: str) -> list[Path]:
    folder = ROOT.joinpath(*parts)
    return sorted(folder.rglob("*.py")) if folder.is_dir() else [folder]


def is_within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def offending(paths: list[Path], *packages: str) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for path in paths:
        bad = sorted(m for m in imported_modules(path) if any(is_within(m, p) for p in packages))
        if bad:
            out[str(path.relative_to(ROOT))] = bad
    return out


def test_the_framework_imports_no_component() -> None:
    assert offending(modules_under("ubf_async"), "components") == {}


@pytest.mark.parametrize("where", [("components", d) for d in DEVICE_PACKAGES]
                         + [("components", "standalone.py"), ("components", "devices.py")])
def test_devices_import_neither_the_simulator_nor_launch(where: tuple[str, str]) -> None:
    paths = modules_under(*where)
    assert paths, where
    assert offending(paths, "components.sim", "ubf_async.tools", "ubf_async.launch") == {}


def python_files(*, skip: frozenset[str] = frozenset()) -> list[Path]:
    """Every ``.py`` file of the checkout, not descending into hidden folders (``.git``,
    ``.venv``, the maintainer's ``.venvs``), ``build``, any virtual environment (a folder with
    a ``pyvenv.cfg``: one made anywhere in the tree holds thousands of modules) or ``skip``."""
    found = []
    for folder, folders, files in os.walk(ROOT):
        folders[:] = sorted(
            name for name in folders
            if not name.startswith(".") and name not in {"build", "__pycache__", *skip}
            and not (Path(folder) / name / "pyvenv.cfg").exists())
        found += [Path(folder) / name for name in sorted(files) if name.endswith(".py")]
    return found


def test_only_the_simulator_imports_pymunk() -> None:
    everywhere = python_files()
    simulator = ROOT / "components" / "sim"
    outside = [p for p in everywhere if simulator not in p.parents]
    assert offending(outside, "pymunk") == {}
    assert offending(modules_under("components", "sim"), "pymunk"), "the check finds nothing"


def project_sources() -> list[Path]:
    """Every module of the project but its tests (which use the libraries' own test
    facilities, gpiozero's mock pins among them)."""
    return python_files(skip=frozenset({"tests"}))


def test_only_the_hardware_backends_import_the_hardware_libraries() -> None:
    allowed = {ROOT / p for p in HARDWARE_BACKENDS}
    outside = [p for p in project_sources() if p not in allowed]
    assert offending(outside, *HARDWARE_LIBRARIES) == {}
    found = offending(sorted(allowed), *HARDWARE_LIBRARIES)
    # The check finds what the backends import, statically and by name.
    assert "gpiozero" in found["components/motors/gpio.py"]
    assert "smbus2" in found["components/range/i2c.py"]  # hardware.require("smbus2", ...)


def test_the_checker_sees_relative_and_nested_imports(tmp_path: Path) -> None:
    # A module placed as if in the tree, under tmp_path: the source tree stays untouched
    # (other workers scan it, and a checkout may be read-only).
    module = tmp_path / "components" / "camera" / "_probe_for_test.py"
    module.parent.mkdir(parents=True)
    module.write_text("def f():\n    from ..sim import world\n    import pymunk\n"
                      "    hardware.require('gpiozero.pins', who='x')\n"
                      "    importlib.import_module('smbus2')\n", "utf-8")
    assert {"components.sim", "components.sim.world", "pymunk", "gpiozero.pins",
            "smbus2"} <= imported_modules(module, root=tmp_path)


BLOCKER = """
import os
import sys


class Blocker:
    \"\"\"gpiozero and smbus2 as if not installed; every attempt to import them is logged.\"\"\"

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in ("gpiozero", "smbus2"):
            with open(os.environ["UBF_TEST_BLOCKED_LOG"], "a") as log:
                log.write(name + "\\n")
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


sys.meta_path.insert(0, Blocker())
"""


def without_hardware_libraries(tmp_path: Path) -> tuple[dict[str, str], Path]:
    """An environment whose Python cannot import gpiozero or smbus2 (a meta path blocker in a
    ``sitecustomize`` on ``PYTHONPATH``), and the file logging each attempt."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(BLOCKER)
    log = tmp_path / "blocked.log"
    log.touch()
    env = {**os.environ, "PYTHONPATH": str(site), "UBF_TEST_BLOCKED_LOG": str(log)}
    return env, log


def test_a_simulated_robot_runs_without_the_hardware_libraries(tmp_path: Path,
                                                               endpoint: str) -> None:
    env, log = without_hardware_libraries(tmp_path)
    probe = subprocess.run([sys.executable, "-c", "import gpiozero"], cwd=ROOT, env=env,
                           capture_output=True, text=True, timeout=60)
    assert "ModuleNotFoundError: No module named 'gpiozero'" in probe.stderr  # blocked
    log.write_text("")
    result = subprocess.run(
        [sys.executable, "-m", "ubf_async.launch", "--duration", "1", "--quiet",
         "--listen", endpoint, "--summary", str(tmp_path / "summary.json")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "ubf_async: stopped" in result.stdout
    assert (tmp_path / "summary.json").exists()
    assert log.read_text() == ""  # nothing even tried to import them


def test_hardware_backends_say_how_to_install_what_they_need(tmp_path: Path) -> None:
    # The framework, the device kinds and the backends' modules load without the libraries;
    # building a hardware backend says which extra to install.
    env, log = without_hardware_libraries(tmp_path)
    code = """
import ubf_async.tools.launch, components.motors.component, components.encoders.component
import components.range.component, components.motors.gpio, components.encoders.gpio
import components.range.i2c
from ubf_async.assembly.robotfile import load_robot
load_robot("mini-whegs")
from ubf_async.errors import ConfigurationError
from components.range.i2c import i2c_backend
from components.motors.gpio import gpio_backend
for build in (lambda: i2c_backend(context=None),
              lambda: gpio_backend(context=None, left_pin="GPIO12", right_pin="GPIO13")):
    try:
        build()
    except ConfigurationError as exc:
        print(exc)
"""
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("range.i2c needs the 'hardware' extra (smbus2 is not installed")
    assert lines[1].startswith("motors.gpio needs the 'hardware' extra (gpiozero")
    assert all(line.endswith("pip install 'ubf-async[hardware]'") for line in lines)
    assert log.read_text().split() == ["smbus2", "gpiozero"]  # only when a backend is built


def lint_imports_on_a_copy(tmp_path: Path,
                           edits: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """``lint-imports`` with the project's contracts over a scratch copy of both packages, each
    module named in ``edits`` (a path under the copy) given that line at its end."""
    for package in ("ubf_async", "components"):
        shutil.copytree(ROOT / package, tmp_path / package,
                        ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    for path, line in edits.items():
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)  # a new room
        with (tmp_path / path).open("a", encoding="utf-8") as module:
            module.write(f"\n{line}\n")
    # lint-imports puts its working directory first on the path, so the copy is what it reads.
    command = [str(Path(sys.executable).with_name("lint-imports")), "--no-cache"]
    return subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=120)


def test_lint_imports_keeps_the_contracts_of_an_unchanged_copy(tmp_path: Path) -> None:
    result = lint_imports_on_a_copy(tmp_path, {})
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


@pytest.mark.parametrize(("edits", "broken"), [
    # Upward without a circle: errors (the floor) takes the clock.
    ({"ubf_async/errors.py": "import ubf_async.clocks.clock  # noqa"},
     ["ubf_async's rooms"]),
    # The runtime reaching up for the plug-in registry (the assembly's).
    ({"ubf_async/runtime/controller.py": "from ubf_async.assembly import registry  # noqa"},
     ["ubf_async's rooms", "No import circles"]),
    # The core reaching for the network, a room beside it.
    ({"ubf_async/core/state.py": "import ubf_async.net.transport  # noqa"},
     ["ubf_async's rooms"]),
    # The circle this package had, inside one room: topics taking the key builders back from
    # protocol.
    ({"ubf_async/wire/topics.py": "from ubf_async.wire.protocol import decode  # noqa"},
     ["No import circles"]),
    # The framework reaching for a component.
    ({"ubf_async/runtime/bus.py": "import components.sim.world.physics  # noqa"},
     ["The framework imports no component"]),
    # A component reaching for a tool.
    ({"components/sim/mirror/arena.py": "import ubf_async.tools.liveview  # noqa"},
     ["No component imports a tool"]),
    # A new room nobody placed in the layers (the contract is exhaustive) — here one that
    # reaches for the launch tool, which an unplaced room could otherwise do unseen.
    ({"ubf_async/newroom/__init__.py": "import ubf_async.tools.launch  # noqa"},
     ["ubf_async's rooms"]),
    # A behaviour doing I/O: the network, an event loop.
    ({"ubf_async/behaviors/basic.py": "import ubf_async.net.transport  # noqa"},
     ["The UBF core and the behaviours do no I/O"]),
    ({"ubf_async/core/state.py": "import asyncio  # noqa"},
     ["The UBF core and the behaviours do no I/O"]),
    # A room below the tools reaching up for one.
    ({"ubf_async/services/status.py": "import ubf_async.tools.launch  # noqa"},
     ["ubf_async's rooms"]),
    # The simulator's world reaching up for the renderer.
    ({"components/sim/world/physics.py": "import components.sim.render.camera  # noqa"},
     ["The simulator's rooms"]),
    # Two simulator rooms of one layer: the backends taking a run's outputs.
    ({"components/sim/backends/devices.py": "import components.sim.outputs.trajectory  # noqa"},
     ["The simulator's rooms"]),
    # A new simulator module nobody placed in the rooms.
    ({"components/sim/helpers.py": "import math  # noqa"}, ["The simulator's rooms"]),
    # A device package taking another's module: the motors' check the encoders' component
    # (the circle motors <-> encoders that was excused once).
    ({"components/motors/check.py": "import components.encoders.component  # noqa"},
     ["The device packages import none of each other"]),
    # ... and even through a third module: the LEDs reaching the camera by way of the
    # simulator's backends is refused twice (devices never import the simulator either).
    ({"components/leds/bank.py": "import components.sim.backends.devices  # noqa"},
     ["The device packages import none of each other", "Devices stand on the framework"]),
    # The clocks reaching up for the bus that stamps with them (they go through clocks.port).
    ({"ubf_async/clocks/clockdomain.py": "from ubf_async.runtime.bus import Bus  # noqa"},
     ["ubf_async's rooms"]),
    # zenoh anywhere but the network: the bus, the ROS 2 bridge, the command line, a device.
    ({"ubf_async/runtime/bus.py": "import zenoh  # noqa"},
     ["Only the network (ubf_async.net) imports zenoh"]),
    ({"ubf_async/services/ros2/bridge.py": "import zenoh  # noqa"},
     ["Only the network (ubf_async.net) imports zenoh"]),
    ({"ubf_async/cli/args.py": "from zenoh import Config  # noqa"},
     ["Only the network (ubf_async.net) imports zenoh"]),
    ({"components/standalone.py": "import zenoh  # noqa"},
     ["Only the network (ubf_async.net) imports zenoh"]),
    # The network reaching for the wire, below it but not its business.
    ({"ubf_async/net/transport.py": "from ubf_async.wire.keys import ROOT  # noqa"},
     ["The network does not import the wire"]),
    # I/O in the wire: an event loop, a socket, a thread.
    ({"ubf_async/wire/protocol.py": "import asyncio  # noqa"},
     ["The wire does no I/O"]),
    ({"ubf_async/wire/keys.py": "import socket  # noqa"},
     ["The wire does no I/O"]),
    ({"ubf_async/wire/topics.py": "import threading  # noqa"},
     ["The wire does no I/O"]),
])
def test_lint_imports_refuses_an_upward_import(tmp_path: Path, edits: dict[str, str],
                                               broken: list[str]) -> None:
    result = lint_imports_on_a_copy(tmp_path, edits)
    assert result.returncode != 0, result.stdout
    report = " ".join(result.stdout.split())  # long contract names are wrapped
    for name in broken:
        verdict = re.search(re.escape(name) + r".*? (KEPT|BROKEN)\b", report)
        assert verdict and verdict[1] == "BROKEN", (name, result.stdout)
