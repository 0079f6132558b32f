"""docs/your-device.md, executed: every fenced code block of the guide, in order, by the rules
tests/test_tutorial.py runs the tutorial with — files written to a fresh folder, ``sh`` blocks
run there with ``bash -euo pipefail`` (``sh expect-fail``: must fail), ``python`` blocks with
``python -c``, ``text`` blocks checked against the output of the block before them; any other
block fails the test.

One block is not run as written: ``python -m pip install -e .``. It would build the package
(setuptools in an isolated environment: the network, and seconds) to do the part that matters
here — put the entry points of the page's ``pyproject.toml`` into the metadata Python reads.
The test writes that metadata itself, as pip would: a ``.dist-info`` beside the package, on
the path of every command the page runs. (tests/test_tutorial.py runs a real ``pip install
-e .`` of a package with an entry point.)

The commands run with this interpreter first on PATH and this repository's code; the page's
endpoint becomes a free loopback port. The robot the page launches runs for about 3 s."""

from __future__ import annotations

import os
import sys
import tomllib
from pathlib import Path

import pytest

from tests.conftest import free_port, repository_env
from tests.test_tutorial import DEFAULT_ENDPOINT, Block, parse_blocks, run_blocks

ROOT = Path(__file__).resolve().parent.parent
GUIDE = ROOT / "docs" / "your-device.md"

INSTALL = "python -m pip install -e .\n"


def install_metadata(work: Path) -> None:
    """What ``pip install -e .`` leaves for importlib.metadata: the distribution's name and
    version, and its entry points, from ``work/pyproject.toml``."""
    project = tomllib.loads((work / "pyproject.toml").read_text("utf-8"))["project"]
    name, version = project["name"], project["version"]
    info = work / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(
        f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n", "utf-8")
    groups = [f"[{group}]\n" + "".join(f"{n} = {target}\n" for n, target in points.items())
              for group, points in project["entry-points"].items()]
    (info / "entry_points.txt").write_text("\n".join(groups), "utf-8")


@pytest.mark.slow
def test_every_code_block_of_the_device_guide_runs(tmp_path: Path) -> None:
    text = GUIDE.read_text("utf-8")
    assert DEFAULT_ENDPOINT in text
    blocks = parse_blocks(text, page=GUIDE.name)
    work = tmp_path / "work"
    work.mkdir()
    env = repository_env()
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    endpoint = f"127.0.0.1:{free_port()}"
    installed = []

    def install(block: Block) -> bool:
        """The one block not run as written (the module docstring)."""
        if block.lang == "sh" and block.text == INSTALL and not block.flags | block.attrs.keys():
            install_metadata(work)
            installed.append(block)
            return True
        return False

    run_blocks(blocks, work=work, env=env, endpoint=endpoint, python=sys.executable,
               handled=install)
    assert installed, f"{GUIDE.name}: no `{INSTALL.strip()}` block"
