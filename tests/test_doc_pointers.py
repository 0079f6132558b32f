"""Every pointer from a file of the repository to a section of its docs leads to a section that
exists (issue 50, item 3): a renamed or misnamed section fails here, naming each file and line
that still points at the old name.

Pointers are found in the README, the docs, robot and scenario files, the project's
configuration and every Python file's strings (error messages, help texts, docstrings) and
comments:

* links with an anchor — ``docs/x.md#anchor`` in prose, ``[text](x.md#anchor)`` and
  ``[text](#anchor)`` in Markdown — must name one of GitHub's anchors of that file (its
  headings, lower case, punctuation dropped, spaces as ``-``, repeats numbered);
* prose naming a section — ``docs/x.md, "Name"``, ``(docs/x.md, section *Name*)``,
  ``[x.md](x.md), *Name*``, ``(docs/x.md, Name)`` — must name a heading of that file (without
  its number, ``5. ``; or only its part before a colon, a parenthesis or a dash: ``How a fleet
  scales`` for ``How a fleet scales: python -m bench.fleet_scaling``) or a paragraph that
  opens with the name in bold (``**Publishing simulation time** (a third-party …``).

Headings are read as GitHub reads them: one inside a code block is none, and a code block
left open hides every heading after it.
"""

from __future__ import annotations

import ast
import bisect
import functools
import io
import re
import tokenize
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCANNED = ("README.md", "pyproject.toml", ".ci", "bench", "components", "docs", "examples",
           "requirements", "tests", "ubf_async")
SKIPPED_SUFFIXES = {".png", ".jpg", ".jpeg", ".json", ".pyc", ".mcap", ".avi", ".so"}
THIS_FILE = Path(__file__).resolve()
"""Left out of the scan: its own examples point at sections that do not exist, on purpose."""

HOLE = "\x00"
"""Stands for what an f-string or a conditional inserts: a name in prose ends there."""

_DOC = r"`{0,2}(?P<doc>(?:[\w.-]+/)*[\w.-]+\.md|README)`{0,2}"
_LINKED_DOC = r"\[[^\]]*\]\((?P<linked>[^)#\s]+\.md)\)"
_NAME = (r"(?:section\s+)?(?:\"(?P<q1>[^\"]{1,80})\"|'(?P<q2>[^']{1,80})'|“(?P<q3>[^”]{1,80})”"
         r"|\*(?P<q4>[^*]{1,80})\*)")
QUOTED = re.compile(rf"(?:{_DOC}|{_LINKED_DOC}),?\s+{_NAME}")
"""``docs/x.md, "Name"``, ``docs/x.md "Name"``, ``(docs/x.md, section *Name*)``,
``[x.md](x.md), *Name*``, in straight, single or curly quotes or emphasis."""
BARE = re.compile(rf"{_DOC},\s+(?P<name>[A-Z][\w -]{{0,40}}?)(?=[);\]{HOLE}])")
"""``(docs/x.md, Name)``: a capitalised name of a few words, closed by a parenthesis or a
semicolon (or the end of a Markdown link's text)."""
MENTIONS_DOC = re.compile(r"\.md\b|README")
COMMENT_MENTIONS_DOC = re.compile(r"#[^\n]*(?:\.md\b|README)")
LINK = re.compile(r"\]\((?P<doc>[^)#\s]*)#(?P<anchor>[^)\s]+)\)")
PATH_ANCHOR = re.compile(r"(?P<doc>(?:[\w.-]+/)*[\w.-]+\.md)#(?P<anchor>[\w-]+)")
HEADING = re.compile(r"#{1,6}\s+(?P<text>.*?)\s*#*\s*")
LEAD = re.compile(r"\*\*([^*]{1,80})\*\*")
FENCE = re.compile(r"\s*(?P<fence>`{3,}|~{3,})(?P<info>.*)")
SECTION_ENDS = (":", " (", " —", " –", ",")
"""What may follow a section's name in its heading when prose names only the part before."""


@dataclass(frozen=True, slots=True)
class Pointer:
    """A place in a file that points at a section of a doc: by ``anchor`` or by ``name``."""

    source: Path
    line: int
    doc: str
    anchor: str | None = None
    name: str | None = None
    relative: bool = False
    """The doc's path is relative to the source's folder (a Markdown link), not guessed."""

    def __str__(self) -> str:
        what = f"#{self.anchor}" if self.anchor is not None else f', "{self.name}"'
        return f"{self.source.relative_to(ROOT)}:{self.line}: {self.doc or '(this file)'}{what}"


@dataclass(frozen=True, slots=True)
class Passage:
    """Lines of prose read as one: a docstring, a string, a run of comments, a whole file."""

    lines: tuple[tuple[int, str], ...]
    """(line number, text) with indentation and comment markers taken off."""

    def joined(self) -> tuple[str, list[int]]:
        """The lines joined by single spaces, and where each line starts in the result."""
        starts, parts, at = [], [], 0
        for _, text in self.lines:
            starts.append(at)
            parts.append(text)
            at += len(text) + 1
        return " ".join(parts), starts

    def pointers(self, source: Path) -> Iterator[Pointer]:
        text, starts = self.joined()
        if not MENTIONS_DOC.search(text) and "](#" not in text:
            return

        def line(offset: int) -> int:
            return self.lines[bisect.bisect_right(starts, offset) - 1][0]

        for match in LINK.finditer(text):
            if "://" not in match["doc"]:  # another site's page
                yield Pointer(source, line(match.start()), match["doc"],
                              anchor=match["anchor"], relative=True)
        for match in PATH_ANCHOR.finditer(text):
            linked = text[:match.start()].endswith("](")  # a Markdown link: read above
            if not linked and not _in_url(text, match.start()):
                yield Pointer(source, line(match.start()), match["doc"], anchor=match["anchor"])
        for match in QUOTED.finditer(text):
            name = next(match[g] for g in ("q1", "q2", "q3", "q4") if match[g] is not None)
            doc = match["doc"] or match["linked"]
            yield Pointer(source, line(match.start()), doc, name=name)
        for match in BARE.finditer(text):
            yield Pointer(source, line(match.start()), match["doc"], name=match["name"])


def _in_url(text: str, offset: int) -> bool:
    return re.search(r"[a-z]+://\S*$", text[:offset]) is not None


def _lines(text: str, first: int = 1, *, comment: str = "") -> tuple[tuple[int, str], ...]:
    """``text``'s lines numbered from ``first``, stripped of indentation and of a leading
    ``comment`` marker."""
    found = []
    for number, raw in enumerate(text.split("\n"), start=first):
        stripped = raw.strip()
        if comment and stripped.startswith(comment):
            stripped = stripped.lstrip(comment).strip()
        found.append((number, stripped))
    return tuple(found)


def _string(node: ast.expr) -> str | None:
    """A string expression's text, as far as it is literal: implicit and ``+`` concatenations
    joined, an f-string's or conditional's parts as :data:`HOLE`."""
    if isinstance(node, ast.Constant):
        return node.value if isinstance(node.value, str) else None
    if isinstance(node, ast.JoinedStr):
        return "".join(part.value if isinstance(part, ast.Constant) else HOLE
                       for part in node.values)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        left, right = _string(node.left), _string(node.right)
        return None if left is None or right is None else left + right
    if isinstance(node, ast.IfExp):
        return HOLE
    return None


def python_passages(text: str) -> Iterator[Passage]:
    """A Python file's strings (each outermost string expression) and runs of comments."""
    nodes: list[ast.AST] = [ast.parse(text)]
    while nodes:
        node = nodes.pop()
        value = _string(node) if isinstance(node, ast.expr) and not isinstance(
            node, ast.IfExp) else None
        if value is None:
            nodes.extend(ast.iter_child_nodes(node))
        elif isinstance(node, ast.expr):
            yield Passage(_lines(value, node.lineno))
    if not COMMENT_MENTIONS_DOC.search(text):  # tokenizing is the slow part: only if needed
        return
    run: list[tuple[int, str]] = []
    for token in tokenize.generate_tokens(io.StringIO(text).readline):
        if token.type == tokenize.COMMENT:
            run.append((token.start[0], token.string.lstrip("#").strip()))
        elif token.type not in (tokenize.NL, tokenize.NEWLINE, tokenize.INDENT,
                                tokenize.DEDENT) and run:
            yield Passage(tuple(run))
            run = []
    if run:
        yield Passage(tuple(run))


def scanned_files() -> Iterator[Path]:
    for top in SCANNED:
        path = ROOT / top
        candidates = [path] if path.is_file() else sorted(path.rglob("*"))
        for candidate in candidates:
            if (candidate.is_file() and candidate.suffix not in SKIPPED_SUFFIXES
                    and "__pycache__" not in candidate.parts and candidate != THIS_FILE):
                yield candidate


def pointers_in(path: Path) -> list[Pointer]:
    try:
        text = path.read_text("utf-8")
    except UnicodeDecodeError:  # not text
        return []
    if not MENTIONS_DOC.search(text):  # most files: the scan's time is parsing Python
        return []
    if path.suffix == ".py":
        passages: Iterator[Passage] = python_passages(text)
    else:  # YAML, TOML and shell comments read as prose; Markdown headings too
        passages = iter([Passage(_lines(text, comment="#"))])
    return [pointer for passage in passages for pointer in passage.pointers(path)]


@functools.cache
def every_pointer() -> tuple[Pointer, ...]:
    return tuple(pointer for path in scanned_files() for pointer in pointers_in(path))


# -- what a doc's sections are ------------------------------------------------------------------

def plain(heading: str) -> str:
    """A heading's text as GitHub shows it: links as their text, no code or emphasis marks."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)
    text = re.sub(r"<[^>]+>", "", text)
    return " ".join(text.replace("`", "").replace("*", "").split())


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, only letters, digits, spaces, ``-`` and
    ``_`` kept, each space a ``-``."""
    kept = "".join(c for c in plain(heading).lower() if c.isalnum() or c in " -_")
    return kept.replace(" ", "-")


def prose_lines(doc: Path) -> Iterator[str]:
    """The doc's lines outside its code blocks, as GitHub reads the fences: a block ends
    only at a bare fence of its own kind and at least its length (a fence left open hides
    every heading after it)."""
    fence = None  # the open code block's fence
    for line in doc.read_text("utf-8").splitlines():
        marks = FENCE.match(line)
        if fence is None and marks:
            fence = marks["fence"]
        elif fence is not None and marks and marks["fence"].startswith(fence) \
                and not marks["info"].strip():
            fence = None
        elif fence is None:
            yield line


@functools.cache
def headings(doc: Path) -> tuple[str, ...]:
    """The doc's headings, in order."""
    return tuple(match["text"] for line in prose_lines(doc)
                 if (match := HEADING.fullmatch(line)))


@functools.cache
def leads(doc: Path) -> tuple[str, ...]:
    """The doc's paragraphs that open with a name in bold (``**Publishing simulation
    time** (a third-party …``): sections in prose, without an anchor."""
    return tuple(match[1].rstrip(".:") for line in prose_lines(doc)
                 if (match := LEAD.match(line)))


@functools.cache
def anchors(doc: Path) -> frozenset[str]:
    """GitHub's anchors of the doc's headings: a repeated one numbered ``-1``, ``-2`` …"""
    seen: dict[str, int] = {}
    found = set()
    for heading in headings(doc):
        base = slug(heading)
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(base if count == 0 else f"{base}-{count}")
    return frozenset(found)


def names(heading: str) -> set[str]:
    """What prose may call a heading: its text without its number (``5. ``), or the part
    of that before a colon, parenthesis or dash."""
    text = re.sub(r"^\d+\.\s+", "", plain(heading).casefold())
    return {text} | {text.split(end, 1)[0] for end in SECTION_ENDS if end in text}


def target(pointer: Pointer) -> Path | None:
    """The doc pointed at: a Markdown link's from its own folder (as GitHub reads it); a path
    in prose from the repository's root, the pointer's folder or docs/."""
    if pointer.relative:
        doc = (pointer.source.parent / pointer.doc) if pointer.doc else pointer.source
        return doc if doc.is_file() else None
    name = "README.md" if pointer.doc == "README" else pointer.doc
    for folder in (ROOT, pointer.source.parent, ROOT / "docs"):
        if (folder / name).is_file():
            return folder / name
    return None


def broken(pointer: Pointer) -> str | None:
    """Why ``pointer`` leads nowhere, or None when its section exists."""
    doc = target(pointer)
    if doc is None:
        return "no such file"
    if pointer.anchor is not None:
        if pointer.anchor in anchors(doc):
            return None
        return f"no heading has this anchor (its anchors: {', '.join(sorted(anchors(doc)))})"
    assert pointer.name is not None
    wanted = " ".join(pointer.name.split()).casefold()
    if any(wanted in names(heading) for heading in (*headings(doc), *leads(doc))):
        return None
    return f"no such section (its headings: {'; '.join(plain(h) for h in headings(doc))})"


# -- the tests ----------------------------------------------------------------------------------

def test_every_pointer_to_a_docs_section_leads_to_one() -> None:
    pointers = every_pointer()
    problems = [f"{pointer}: {why}" for pointer in pointers
                if (why := broken(pointer)) is not None]
    assert not problems, "\n".join(problems)


def test_the_pointers_are_found_where_the_repository_has_them() -> None:
    """The scan sees every form the repository writes (so a zero above is not a blind one)."""
    found = {(str(p.source.relative_to(ROOT)), p.doc, p.anchor or p.name)
             for p in every_pointer()}
    assert {
        ("examples/robots/pi-whegs.yaml", "docs/hardware.md", "Calibration"),  # quoted, YAML
        ("components/hardware.py", "docs/hardware.md", "Pin factories"),  # bare, in an f-string
        ("ubf_async/clocks/clockdomain.py", "docs/protocol.md", "The robot clock"),  # joined
        ("ubf_async/services/live.py", "docs/protocol.md", "Live tree changes"),  # section *…*
        ("docs/fleet.md", "protocol.md", "The robot clock"),  # [protocol.md](protocol.md), *…*
        ("docs/evolve.md", "scenarios.md", "outputs"),  # a Markdown link's anchor
        ("pyproject.toml", "README", "Upgrading dependencies"),  # a TOML comment
    } <= found
    assert len(found) > 60


def pointers_of(tmp_path: Path, name: str, text: str) -> list[str]:
    source = tmp_path / name
    source.write_text(text, "utf-8")
    return [f"{p.doc}|{p.anchor or p.name}" for p in pointers_in(source)]


@pytest.mark.parametrize(("name", "text", "expected"), [
    ("robot.yaml", '    # calibration (docs/hardware.md, "Calibrating the\n    # motors"): it\n',
     ["docs/hardware.md|Calibrating the motors"]),
    ("page.md", "see [protocol.md, \"Schemas\"](protocol.md#schemas) and (docs/x.md, Pin "
                "factories; more)", ["protocol.md|schemas", "protocol.md|Schemas",
                                     "docs/x.md|Pin factories"]),
    ("page.md", "[x](https://example.org/docs/x.md#y) `docs/y.md#z-1`", ["docs/y.md|z-1"]),
    ("tool.py", 'def f(who):\n    raise ValueError(f"{who}: bad (docs/hardware.md, Pin "\n'
                '                     f"factories{who})")\n',
     ["docs/hardware.md|Pin factories"]),
    ("tool.py", "# see ``docs/protocol.md``, section\n# *Remote behaviours*.\nx = 1\n",
     ["docs/protocol.md|Remote behaviours"]),
], ids=["yaml comment over two lines", "markdown link and bare name", "urls are not pointers",
        "python f-string", "python comments"])
def test_each_form_of_pointer_is_read(tmp_path: Path, name: str, text: str,
                                      expected: list[str]) -> None:
    assert pointers_of(tmp_path, name, text) == expected


def test_a_misnamed_section_is_caught_naming_file_and_line(tmp_path: Path) -> None:
    """The pi-whegs robot file's old pointer, "Calibrating the motors", is refused; the
    section's real name and a prefix before its colon are not."""
    source = tmp_path / "robot.yaml"
    source.write_text('# (docs/hardware.md, "Calibration")\n\n'
                      '# (docs/hardware.md, "Calibrating the motors")\n'
                      "# docs/fleet.md, *How a fleet scales*; docs/hardware.md#calibration\n"
                      "# docs/hardware.md#calibrating-the-motors\n", "utf-8")
    problems = [(pointer.line, why) for pointer in pointers_in(source)
                if (why := broken(pointer)) is not None]
    assert sorted(line for line, _ in problems) == [3, 5]
    assert all(why.startswith(("no such section", "no heading has this anchor"))
               for _, why in problems)


@pytest.mark.parametrize(("heading", "anchor"), [
    ("How a fleet scales: `python -m bench.fleet_scaling`",
     "how-a-fleet-scales-python--m-benchfleet_scaling"),
    ("The data path: sample → tick → drive → PWM", "the-data-path-sample--tick--drive--pwm"),
    ("Scenarios, [fleets](fleet.md) and *the* clock", "scenarios-fleets-and-the-clock"),
])
def test_anchors_are_githubs(heading: str, anchor: str) -> None:
    assert slug(heading) == anchor


def test_a_repeated_heading_gets_a_numbered_anchor(tmp_path: Path) -> None:
    doc = tmp_path / "page.md"
    doc.write_text("# Page\n\n## Set-up\n\n```sh\n# not a heading\n```\n\n## Set-up\n", "utf-8")
    assert anchors(doc) == {"page", "set-up", "set-up-1"}
