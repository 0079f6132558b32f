"""A Python that sees only what ``pip install ubf-async`` (no extras) installs.

Every module of an installed distribution outside the closure of ``[project].dependencies``
(their own requirements followed through the installed metadata) is blocked by a meta path
finder in a ``sitecustomize`` on ``PYTHONPATH``; each attempt to import one is logged. The same
closure as a fresh venv's ``pip install .`` gets, computed from the same metadata pip reads,
without downloading or installing anything.
"""

from __future__ import annotations

import functools
import os
import re
import sys
import tomllib
from importlib import metadata
from pathlib import Path

from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parent.parent

BLOCKER = """
import os
import sys

BLOCKED = frozenset(os.environ["UBF_TEST_BLOCKED"].split(","))


class Blocker:
    \"\"\"The modules a lean install lacks, as if not installed; each attempt is logged.\"\"\"

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            with open(os.environ["UBF_TEST_BLOCKED_LOG"], "a") as log:
                log.write(name + "\\n")
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


sys.meta_path.insert(0, Blocker())
"""


def canonical(name: str) -> str:
    """A distribution's name as pip compares them (PEP 503)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def base_requirements() -> list[Requirement]:
    """``[project].dependencies`` of pyproject.toml."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text("utf-8"))["project"]
    return [Requirement(text) for text in project["dependencies"]]


def lean_closure() -> set[str]:
    """Canonical names of the distributions a lean install brings: the base requirements and,
    transitively, what each installed one requires (markers evaluated, no extras)."""
    closure: set[str] = {"ubf-async"}
    todo = [req for req in base_requirements() if req.marker is None or req.marker.evaluate()]
    while todo:
        req = todo.pop()
        name = canonical(req.name)
        if name in closure:
            continue
        closure.add(name)
        for text in metadata.requires(req.name) or []:
            sub = Requirement(text)
            if sub.marker is None or sub.marker.evaluate({"extra": ""}):
                todo.append(sub)
    return closure


@functools.cache
def blocked_modules() -> frozenset[str]:
    """Top-level modules of the installed distributions outside :func:`lean_closure` (read
    once: it scans every installed distribution's files)."""
    closure = lean_closure()
    return frozenset(module for module, dists in metadata.packages_distributions().items()
            if not any(canonical(d) in closure for d in dists)
            and module not in sys.stdlib_module_names)


def lean_environment(tmp_path: Path) -> tuple[dict[str, str], Path]:
    """Environment variables for a subprocess that sees a lean install, and the log of the
    blocked imports it attempted."""
    site = tmp_path / "lean-site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(BLOCKER, "utf-8")
    log = tmp_path / "blocked.log"
    log.touch()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)]),
           "UBF_TEST_BLOCKED": ",".join(sorted(blocked_modules())),
           "UBF_TEST_BLOCKED_LOG": str(log)}
    return env, log
