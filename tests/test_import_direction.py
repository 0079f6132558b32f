"""Which way imports go: devices stand on the framework, the simulator stands on the devices.

* ``ubf_async`` (the framework) imports nothing of ``components``;
* the device packages and ``components/standalone.py`` import neither the simulator
  (``components.sim``) nor launch (``ubf_async.launch``): they find a simulator, like any
  backend, through the registry;
* only the simulator imports pymunk.

Static imports only (``import``/``from … import`` anywhere in a module, including inside
functions and ``if TYPE_CHECKING:``); a plug-in loaded by name at run time is the point.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DEVICE_PACKAGES = ("camera", "motors", "encoders", "range", "radio")


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, absolute (relative imports resolved)."""
    tree = ast.parse(path.read_text("utf-8"), filename=str(path))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
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
    assert offending(paths, "components.sim", "ubf_async.launch") == {}


def test_only_the_simulator_imports_pymunk() -> None:
    everywhere = [p for p in ROOT.rglob("*.py")
                  if not {".venv", ".git", "build"} & set(p.relative_to(ROOT).parts)]
    simulator = ROOT / "components" / "sim"
    outside = [p for p in everywhere if simulator not in p.parents]
    assert offending(outside, "pymunk") == {}
    assert offending(modules_under("components", "sim"), "pymunk"), "the check finds nothing"


def test_the_checker_sees_relative_and_nested_imports(tmp_path: Path) -> None:
    module = ROOT / "components" / "camera" / "_probe_for_test.py"
    source = "def f():\n    from ..sim import world\n    import pymunk\n"
    try:
        module.write_text(source, "utf-8")
        assert {"components.sim", "components.sim.world", "pymunk"} <= imported_modules(module)
    finally:
        module.unlink()
