"""The public surface (issue 39): the names of ``ubf_async``, loaded on first use; every import
the docs show resolves; the paths of before the rooms still work, with a DeprecationWarning.

One subprocess does all the importing, so that what ``import ubf_async`` alone loads is seen
from a fresh interpreter.
"""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import ubf_async

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PROJECT_PACKAGES = ("ubf_async", "components")
FENCE = re.compile(r"^```python[^\n]*\n(.*?)^```", re.M | re.S)


IMPORT = re.compile(r"^[ \t]*(?:from|import)[ \t]+(?:\([^)]*\)|[^\n(])*(?:\([^)]*\))?", re.M)


def documented_imports() -> list[tuple[str, str]]:
    """``(FILE:LINE, statement)`` for each import of the project's packages in a Python code
    block of README.md and docs/*.md (a block may hold prose or ``...``: each import
    statement is read on its own)."""
    found: list[tuple[str, str]] = []
    for doc in DOCS:
        text = doc.read_text("utf-8")
        for block in FENCE.finditer(text):
            for match in IMPORT.finditer(block.group(1)):
                node = ast.parse(match.group(0).strip()).body[0]
                if isinstance(node, ast.ImportFrom) and node.level == 0:
                    modules = [node.module or ""]
                elif isinstance(node, ast.Import):
                    modules = [alias.name for alias in node.names]
                else:
                    continue
                if any(m.partition(".")[0] in PROJECT_PACKAGES for m in modules):
                    line = text.count("\n", 0, block.start(1) + match.start()) + 1
                    found.append((f"{doc.relative_to(ROOT)}:{line}", ast.unparse(node)))
    return found


def stub_names() -> dict[str, str]:
    """Each name ``ubf_async/__init__.pyi`` imports, and the module it comes from."""
    stub = ast.parse((ROOT / "ubf_async" / "__init__.pyi").read_text("utf-8"))
    return {alias.name: node.module or "" for node in stub.body
            if isinstance(node, ast.ImportFrom) for alias in node.names}


PROBE = """
import json, sys, warnings
import ubf_async
report = {"light": sorted(m for m in ("zenoh", "msgspec", "numpy", "yaml") if m in sys.modules)}
failed = []
for place, statement in json.loads(sys.argv[1]):
    try:
        exec(statement, {})
    except Exception as exc:
        failed.append(f"{place}: {statement}: {type(exc).__name__}: {exc}")
report["failed"] = failed
import importlib
report["unlike_home"] = [name for name, home in ubf_async._HOMES.items()
                         if getattr(ubf_async, name) is not
                         getattr(importlib.import_module(home), name)]
shims = {}
for old, name in (("ubf_async.bus", "Bus"), ("ubf_async.component", "Component")):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = __import__(old, fromlist=[name])
    shims[old] = [getattr(module, name) is getattr(ubf_async, name),
                  [(w.category.__name__, str(w.message)) for w in caught]]
report["shims"] = shims
print(json.dumps(report))
"""


def test_the_public_names_the_docs_imports_and_the_old_paths() -> None:
    imports = documented_imports()
    assert len(imports) >= 15, imports  # the scan finds the docs' imports at all
    result = subprocess.run([sys.executable, "-c", PROBE, json.dumps(imports)], cwd=ROOT,
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["light"] == []  # import ubf_async loads none of them
    assert report["failed"] == []
    homes = ubf_async._HOMES
    # One list of names: __all__ (kept sorted by ruff), the homes __getattr__ loads from, and
    # the stub type checkers read
    assert set(ubf_async.__all__) == {*homes, "__version__"}
    assert stub_names() == homes
    assert report["unlike_home"] == []  # each name resolves, to the object of its home
    for old, name in (("ubf_async.bus", "Bus"), ("ubf_async.component", "Component")):
        same, warned = report["shims"][old]
        assert same, old
        assert warned == [["DeprecationWarning",
                           f"{old} is deprecated and goes in the next release: "
                           f"use `from ubf_async import {name}`"]]


def test_an_unknown_name_is_an_attribute_error() -> None:
    try:
        ubf_async.NoSuchThing  # type: ignore[attr-defined]  # noqa: B018
    except AttributeError as exc:
        assert str(exc) == "module 'ubf_async' has no attribute 'NoSuchThing'"
    else:
        raise AssertionError("ubf_async.NoSuchThing resolved")
    assert {"Bus", "Behavior", "__version__"} <= set(dir(ubf_async))
