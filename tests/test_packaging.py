"""What a user gets from `pip install`: console scripts, --version everywhere, py.typed, a
licence file that matches the metadata."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from importlib import metadata, resources
from pathlib import Path

import pytest

import ubf_async

ROOT = Path(__file__).resolve().parent.parent

ENTRY_POINTS = [
    "ubf_async.launch", "ubf_async.inspector", "ubf_async.robotfile", "ubf_async.sweep",
    "components.camera",
    "components.motors", "components.encoders", "components.range", "components.radio",
]


@pytest.mark.parametrize("module", ENTRY_POINTS)
def test_every_entry_point_has_version(module: str) -> None:
    out = subprocess.run([sys.executable, "-m", module, "--version"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"python -m {module} {ubf_async.__version__}"


@pytest.mark.parametrize(("script", "target"), [("ubf-launch", "ubf_async.tools.launch:main"),
                                                 ("ubf-inspect", "ubf_async.tools.inspector:main"),
                                                 ("ubf-evolve", "ubf_async.tools.evolve:main")])
def test_console_scripts(script: str, target: str) -> None:
    scripts = {ep.name: ep.value for ep in metadata.entry_points(group="console_scripts")}
    assert scripts.get(script) == target
    installed = Path(sys.executable).parent / script
    assert installed.exists(), f"{script} not installed beside {sys.executable}"
    out = subprocess.run([str(installed), "--version"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0 and ubf_async.__version__ in out.stdout


def test_version_is_the_distributions() -> None:
    assert ubf_async.__version__ == metadata.version("ubf-async")


def test_typed_and_licensed() -> None:
    assert (resources.files("ubf_async") / "py.typed").is_file()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"
    assert project["license-files"] == ["LICENSE"]
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    assert metadata.metadata("ubf-async")["License-Expression"] == "MIT"


def test_the_shipped_robot_file_and_schema_are_package_data() -> None:
    assert (resources.files("ubf_async") / "robots" / "mini-whegs.yaml").is_file()
    assert (resources.files("ubf_async") / "robot-file.schema.json").is_file()
