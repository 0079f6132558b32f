"""The map (docs/architecture.md) says what the code is: each room's modules as drawn, each
room's "may import" as the import-linter contracts in pyproject.toml allow, each room's
``__init__`` saying what it may import, and every import inside the project taking a name from
the module that defines it (one import path per name; the public modules re-export)."""

from __future__ import annotations

import ast
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAP = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
CONTRACTS = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))[
    "tool"]["importlinter"]["contracts"]
PACKAGE = ROOT / "ubf_async"
FLOOR = {"errors", "throttle"}


def layers() -> list[set[str]]:
    contract = next(c for c in CONTRACTS if c["id"] == "layers")
    return [{room.strip() for room in layer.split("|")} for layer in contract["layers"]]


def rooms_below(room: str) -> set[str]:
    found = layers()
    at = next(i for i, layer in enumerate(found) if room in layer)
    return set().union(*found[at + 1:])


def forbidden_for(room: str) -> set[str]:
    """Rooms a forbidden contract keeps from ``room`` although they are below it."""
    out: set[str] = set()
    for contract in CONTRACTS:
        if contract["type"] != "forbidden":
            continue
        sources = contract["source_modules"]
        if "ubf_async" in sources or f"ubf_async.{room}" in sources:
            out |= {m.removeprefix("ubf_async.") for m in contract["forbidden_modules"]
                    if m.startswith("ubf_async.")}
    return out


def mermaid_nodes() -> dict[str, str]:
    block = MAP.split("```mermaid", 1)[1].split("```", 1)[0]
    return {name: label.replace("<br/>", " ")
            for name, label in re.findall(r'^\s*(\w+)\["(.*?)"\]', block, re.M)}


def drawn_modules(label: str) -> set[str]:
    """``room/ a, b, sub/ (c, d), pkg/`` → {a, b, sub.c, sub.d, pkg}."""
    body = label.split("/", 1)[1]
    out: set[str] = set()
    for sub, inner in re.findall(r"(\w+)/ \(([^)]*)\)", body):
        out |= {f"{sub}.{m.strip()}" for m in inner.split(",")}
    body = re.sub(r"\w+/ \([^)]*\)", "", body)
    out |= {m.strip().rstrip("/") for m in body.split(",") if m.strip()}
    return out


def real_modules(room: Path) -> set[str]:
    out: set[str] = set()
    for path in room.iterdir():
        if path.suffix == ".py" and path.stem not in ("__init__", "__main__"):
            out.add(path.stem)
        elif path.is_dir() and (path / "__init__.py").exists():
            inner = {p.stem for p in path.glob("*.py") if p.stem not in ("__init__", "__main__")}
            out |= {f"{path.name}.{m}" for m in inner} if f"{path.name}/ (" in MAP else {path.name}
    return out


ROOMS = sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists())


@pytest.mark.parametrize("room", ROOMS)
def test_each_room_is_drawn_with_exactly_its_modules(room: str) -> None:
    nodes = mermaid_nodes()
    assert room in nodes, f"docs/architecture.md does not draw the room {room}/"
    assert drawn_modules(nodes[room]) == real_modules(PACKAGE / room)


def test_the_entry_modules_are_drawn_and_placed() -> None:
    entry = {p.stem for p in PACKAGE.glob("*.py")} - {"__init__"} - FLOOR - {"extras"}
    drawn = set(re.findall(r"\w+", mermaid_nodes()["entry"].split(":", 1)[1]))
    assert entry <= drawn, entry - drawn
    assert entry == layers()[0], "the entry modules are the layers contract's top layer"


def may_import_rows() -> dict[str, str]:
    table = MAP.split("## What each room owns", 1)[1].split("\n\n", 2)[1]
    rows: dict[str, str] = {}
    for line in table.splitlines()[2:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        for name in re.findall(r"`(\w+)(?:/|\.py)`", cells[0]):
            rows[name] = cells[-1]
    return rows


def said(cell: str) -> set[str]:
    """The rooms a "may import" cell names: backticked rooms, "the floor" (errors and
    throttle), "every room below" (all of them)."""
    if "nothing of the package" in cell:
        return set()
    names = set(re.findall(r"`(\w+)`", cell.split("(", 1)[0]))
    if "the floor" in cell:
        names |= FLOOR
    return names


@pytest.mark.parametrize("room", sorted(set().union(*layers()[2:])))
def test_each_rooms_may_import_is_what_the_contracts_allow(room: str) -> None:
    rows = may_import_rows()
    assert room in rows, f"docs/architecture.md has no row for {room}"
    allowed = rooms_below(room) - forbidden_for(room)
    if "every room below" in rows[room]:
        assert allowed == rooms_below(room), (room, "a forbidden contract narrows it")
        return
    assert said(rows[room]) == allowed, rows[room]


@pytest.mark.parametrize("room", [r for r in ROOMS if r not in ("tools",)])
def test_each_rooms_init_says_what_it_may_import(room: str) -> None:
    doc = ast.get_docstring(ast.parse((PACKAGE / room / "__init__.py").read_text()))
    assert doc and "May import" in doc, f"ubf_async/{room}/__init__.py"


def defined_names(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in tree.body:
        for n in [node, *(node.body + node.orelse if isinstance(node, ast.If | ast.Try) else [])]:
            if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names.add(n.name)
            elif isinstance(n, ast.Assign | ast.AnnAssign):
                targets = n.targets if isinstance(n, ast.Assign) else [n.target]
                names |= {x.id for t in targets for x in ast.walk(t) if isinstance(x, ast.Name)}
    return names


def test_every_import_inside_the_project_takes_a_name_from_its_home() -> None:
    modules = {".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"): p
               for package in ("ubf_async", "components") for p in (ROOT / package).rglob("*.py")}
    public = {m for m, p in modules.items() if p.parent == PACKAGE} | {"ubf_async"}
    defined = {m: defined_names(p) for m, p in modules.items()}
    wrong = []
    for name, path in modules.items():
        if name in public:
            continue  # the public modules re-export on purpose
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module in modules:
                wrong += [f"{path.relative_to(ROOT)}:{node.lineno}: {a.name} from {node.module}"
                          for a in node.names if f"{node.module}.{a.name}" not in modules
                          and a.name not in defined[node.module]]
    assert not wrong, "\n".join(wrong)


def test_every_module_says_what_it_offers() -> None:
    missing = [str(p.relative_to(ROOT)) for p in PACKAGE.rglob("*.py")
               if p.stem != "__main__" and p.read_text(encoding="utf-8").strip()
               and defined_names(p) - {"log"} and "__all__" not in defined_names(p)]
    assert not missing, missing
