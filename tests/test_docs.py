"""README.md and docs/*.md read against the code (issue 28): every command they show names an
entry point that exists, with options it takes; the numbers and messages they quote are the
ones the code uses. (Every command shown is also run, by tests/test_doc_commands.py;
docs/your-robot.md is executed whole by tests/test_tutorial.py, and docs/recording.md's
snippets by tests/test_record.py.)"""

from __future__ import annotations

import functools
import json
import re
import shlex
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ubf_async.runtime.aggregator import STALE_PERIODS

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHELL = {"sh", "bash", "shell", "console"}
CHECKED_PACKAGES = {"ubf_async", "components", "bench"}
MODULE = re.compile(r"[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*")
FLAG = re.compile(r"--?[A-Za-z][\w-]*")


# -- the commands the docs show -----------------------------------------------------------------

def shell_texts(markdown: str, *, inline: bool = True) -> Iterator[tuple[int, str]]:
    """``(line, text)``: each command of a shell code block (a line, with its ``\\``
    continuations) and (``inline``) each inline code span outside code blocks that starts with
    ``python``."""
    prose: list[str] = []
    block: str | None = None  # the open code block's language
    command: tuple[int, str] | None = None
    for number, line in enumerate(markdown.splitlines(), start=1):
        prose.append("" if block is not None or line.lstrip().startswith("```") else line)
        if line.lstrip().startswith("```"):
            info = line.strip().removeprefix("```").split()
            block = (info[0] if info else "") if block is None else None
            continue
        if block not in SHELL:
            continue
        start, text = command if command is not None else (number, "")
        text += " " + line.rstrip().removesuffix("\\")
        command = (start, text) if line.rstrip().endswith("\\") else None
        if command is None:
            yield start, text
    if not inline:
        return
    joined = "\n".join(prose)
    for match in re.finditer(r"`(python[^`]*)`", joined):
        yield joined.count("\n", 0, match.start()) + 1, match.group(1)


def tokens(text: str) -> list[str]:
    lexer = shlex.shlex(text, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    try:
        return list(lexer)
    except ValueError:  # an unbalanced quote in prose: good enough split on spaces
        return text.split()


def python_commands(text: str) -> Iterator[tuple[str, list[str]]]:
    """``(target, arguments)`` of each ``python -m MODULE …`` or ``python PATH.py …`` in a
    shell text (target: the module, or the script's path)."""
    command: list[str] = []
    skip_next = False
    for token in [*tokens(text), ";"]:
        if skip_next:
            skip_next = False
            continue
        if token and set(token) <= set("();<>|&"):  # an operator: the command ends here
            yield from _python_command(command)
            command = []
            skip_next = bool(set(token) & set("<>"))  # a redirection's file
            continue
        command.append(token)


def _python_command(command: list[str]) -> Iterator[tuple[str, list[str]]]:
    if "python" not in command:
        return
    rest = command[command.index("python") + 1:]
    if len(rest) >= 2 and rest[0] == "-m":
        target, args = rest[1], rest[2:]
        if MODULE.fullmatch(target) and target.split(".")[0] in CHECKED_PACKAGES:
            yield target, args
    elif rest and rest[0].endswith(".py"):
        yield rest[0], rest[1:]


# -- what an entry point takes: its argparse parser, as it builds it ----------------------------

# Runs each entry point as `python -m` (or `python PATH`) does, with each command's arguments
# (an entry point may pick its parser by them: `components.motors --check`), and dumps the first
# parser it parses with — its options, whether each takes a value, its subcommands' — instead
# of parsing: exact, and nothing past the parsing runs (every entry point parses its arguments
# first). argparse keeps its actions in `_actions` only. Every entry point in one process.
DUMP_PARSERS = r"""
import argparse, contextlib, io, json, runpy, sys
wanted = json.loads(sys.argv[1])

class Dumped(BaseException):  # not caught by an entry point's `except Exception`
    pass

def describe(parser):
    options, subcommands = {}, {}
    for action in parser._actions:
        for option in action.option_strings:
            options[option] = action.nargs != 0
        if isinstance(action, argparse._SubParsersAction):
            subcommands.update({n: describe(p) for n, p in action.choices.items()})
    return {"options": options, "subcommands": subcommands}

def dump(self, args=None, namespace=None):
    raise Dumped(describe(self))

argparse.ArgumentParser.parse_known_args = dump
out = {}
for target, commands in wanted.items():
    out[target] = []
    for args in commands:
        sys.argv = [target, *args]
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                if target.endswith(".py"):
                    runpy.run_path(target, run_name="__main__")
                else:
                    runpy.run_module(target, run_name="__main__", alter_sys=True)
            out[target].append("it parsed no arguments with argparse")
        except Dumped as parsed:
            out[target].append(parsed.args[0])
        except BaseException as exc:
            out[target].append(f"it failed: {exc!r}")
print(json.dumps(out))
"""

Parser = dict[str, Any]


def parsers_for(wanted: dict[str, list[list[str]]]) -> dict[str, list[Parser | str]]:
    """Per entry point and command (its arguments), the parser the entry point parses them
    with, or what failed; every entry point run in one process."""
    proc = subprocess.run([sys.executable, "-c", DUMP_PARSERS, json.dumps(wanted)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    if proc.returncode != 0:
        return {target: [f"cannot run it: {proc.stderr.strip()[-300:]}"] * len(commands)
                for target, commands in wanted.items()}
    parsed: dict[str, list[Parser | str]] = json.loads(proc.stdout.splitlines()[-1])
    return parsed


def parsers_of(target: str, commands: list[list[str]]) -> list[Parser | str]:
    """Per command (its arguments), the parser ``target`` parses them with, or what failed."""
    return parsers_for({target: commands})[target]


@functools.cache
def shown_parsers() -> dict[str, list[Parser | str]]:
    """:func:`parsers_for` every command the docs show (:func:`shown_commands`)."""
    return parsers_for({target: [args for _, args in shown]
                        for target, shown in shown_commands().items()})


def unknown_options(args: list[str], parser: Parser) -> list[str]:
    """The options among ``args`` that the (sub)parser they reach does not take."""
    level, path, unknown = parser, [], []
    i = 0
    while i < len(args):
        arg = args[i].strip("[]")  # [--quick]: an optional part in a usage line
        if arg == "--":  # the rest is another command's (bench.cpu_hog -- COMMAND)
            break
        if FLAG.fullmatch(arg.split("=", 1)[0]):
            flag = arg.split("=", 1)[0]
            if flag not in level["options"]:
                unknown.append(" ".join([*path, flag]))
            elif level["options"][flag] and "=" not in arg:
                i += 1  # its value
        elif arg in level["subcommands"]:
            level = level["subcommands"][arg]
            path.append(arg)
        i += 1
    return unknown


@functools.cache
def shown_commands() -> dict[str, list[tuple[str, list[str]]]]:
    """Per entry point, ``(where, arguments)`` of every command the docs show."""
    by_target: dict[str, list[tuple[str, list[str]]]] = {}
    for doc in DOCS:
        for line, text in shell_texts(doc.read_text("utf-8")):
            for target, args in python_commands(text):
                where = f"{doc.relative_to(ROOT)}:{line}"
                by_target.setdefault(target, []).append((where, args))
    return by_target


@pytest.mark.parametrize("target", sorted(shown_commands()))
def test_every_command_shown_exists_with_the_options_shown(target: str) -> None:
    shown = shown_commands()[target]
    problems = []
    for (where, args), parser in zip(shown, shown_parsers()[target], strict=True):
        if isinstance(parser, str):
            problems.append(f"{where}: python {target}: {parser}")
        else:
            problems += [f"{where}: python {target} … {flag}: no such option"
                         for flag in unknown_options(args, parser)]
    assert problems == []


def test_the_docs_show_commands_where_expected() -> None:
    docs = {where.split(":")[0] for shown in shown_commands().values() for where, _ in shown}
    assert {"README.md", "docs/robot-file.md", "docs/recording.md", "docs/scenarios.md"} <= docs


def test_the_command_check_sees_what_is_wrong() -> None:
    text = ("python -m ubf_async.inspector --robot r tree set-arbiter x Y --param a=1 --nope "
            "2>&1 | grep -e x; python -m ubf_async.launch [--speeed 5]")
    found = list(python_commands(text))
    assert [target for target, _ in found] == ["ubf_async.inspector", "ubf_async.launch"]
    [inspector] = parsers_of("ubf_async.inspector", [found[0][1]])
    [launch] = parsers_of("ubf_async.launch", [found[1][1]])
    assert isinstance(inspector, dict) and isinstance(launch, dict)
    assert unknown_options(found[0][1], inspector) == ["tree set-arbiter --nope"]
    assert unknown_options(found[1][1], launch) == ["--speeed"]
    [missing] = parsers_of("ubf_async.no_such_tool", [[]])
    assert isinstance(missing, str) and "No module named" in missing, missing


# -- numbers and messages the docs quote ------------------------------------------------------

def test_the_docs_state_the_staleness_the_aggregator_applies() -> None:
    """README.md said 1.5× the period, docs/robot-file.md 2 periods; the aggregator's rule
    (STALE_PERIODS times the period a sample declares) is what both must say."""
    for doc in (ROOT / "README.md", ROOT / "docs" / "robot-file.md"):
        text = doc.read_text("utf-8")
        assert f"{STALE_PERIODS:g}× " in text, doc.name
        assert not re.search(r"\b(?:2|two) of its (?:declared )?periods", text), doc.name


def as_pattern(example: str) -> str:
    """A quoted example as a regular expression: any number where it shows one."""
    return re.sub(r"\\?\d+(?:\\\.\d+)?", r"[\\d.]+", re.escape(example))


def test_a_run_that_cannot_keep_the_speed_shows_what_scenarios_md_says(tmp_path: Path) -> None:
    """docs/scenarios.md quoted 5.00× at --speed 5 as if every machine reached it; it now says
    what the status line and the end of the run show when the machine does not."""
    text = (ROOT / "docs" / "scenarios.md").read_text("utf-8")
    [status] = re.findall(r"`(sim [\d.]+s x[\d.]+)`", text)
    [warning] = [line.strip() for line in text.splitlines()
                 if line.strip().startswith("warning: the run reached")]
    proc = subprocess.run(
        [sys.executable, "-m", "ubf_async.launch", "--scenario", "ball-in-sight",
         "--speed", "1000", "--duration", "2", "--status-period-s", "0.05",
         "--listen", "tcp/127.0.0.1:0"],  # 1000x: no machine keeps up
        cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    shown = [m for m in re.finditer(as_pattern(status), proc.stdout)]
    assert shown, proc.stdout
    reached = float(shown[-1].group(0).rpartition("x")[2])
    assert 0 < reached < 1000
    assert re.search(as_pattern(warning), proc.stdout), (warning, proc.stdout)


ROBOT_FILE_MD = ROOT / "docs" / "robot-file.md"
QUOTED_ROBOT = "".join(f"# line {n}\n" for n in range(1, 15)) + """name: tester
tree:
  name: root
  arbiter: PriorityMerge
  children:
    - behavior: search
      priority: 2
      params: {period_s: 4}
    - behavior: chase
      priority: 1
"""
"""The robot file of docs/robot-file.md's quoted errors: its first child at lines 20-22."""
QUOTED_MISTAKES = [  # in the order the page quotes them
    ("behavior: chase", "behavior: chsae"),
    ("{period_s: 4}", "{perod_s: 4}"),
    ("      priority: 2\n", "      priorty: 2\n"),
    ("      priority: 2\n", "      priority: 2\n      priority: 3\n"),
    ("      priority: 2\n", "      priority 2\n"),
]


def test_robot_file_md_quotes_the_errors_the_loader_gives() -> None:
    """Issue 35: its list of known behaviours lacked go_to_report and report_ball."""
    from ubf_async.assembly.robotfile import load_robot_text
    from ubf_async.errors import UbfError

    section = ROBOT_FILE_MD.read_text("utf-8").split("## Checked before anything starts", 1)[1]
    quoted = section.split("```text\n", 1)[1].split("```", 1)[0].splitlines()
    given = []
    for old, new in QUOTED_MISTAKES:
        assert old in QUOTED_ROBOT
        with pytest.raises(UbfError) as refused:
            load_robot_text(QUOTED_ROBOT.replace(old, new, 1), source="robot.yaml")
        given.append(str(refused.value))
    assert quoted == given


def test_the_plug_in_groups_the_docs_name_are_the_registrys() -> None:
    """Issue 39: the table named modules (``ubf_async.core.arbiters``) for groups."""
    from ubf_async.assembly import registry

    project = tomllib.loads((ROOT / "pyproject.toml").read_text("utf-8"))["project"]
    registered = {group for group in project["entry-points"] if group.startswith("ubf_async.")}
    section = ROBOT_FILE_MD.read_text("utf-8").split("## Plug-ins", 1)[1].split("\n## ", 1)[0]
    named = set(re.findall(r"^\| `(ubf_async\.[\w.]+)` \|", section, re.M))
    assert named == set(registry.READ) == registered


def test_the_quick_start_installs_the_project_and_ci_what_the_test_command_installs() -> None:
    """Issue 35: the quick start installed the test extra (ruff, mypy, hypothesis, the ROS 2
    test peer …) just to run the demo; the test command installs it, and so does .ci/run."""
    readme = (ROOT / "README.md").read_text("utf-8")
    commands = [tokens(text) for _, text in shell_texts(readme, inline=False)]
    quick_start = next(c for c in commands if "ubf_async.launch" in c)
    test = next(c for c in commands if c[-3:] == ["python", "-m", "pytest"])

    def installs(words: list[str]) -> list[str]:
        """What a `pip install` of a command installs: its -e and -r arguments (issue 47: the
        tests install the lock, requirements/test.txt, with the project)."""
        start = next(i for i in range(len(words)) if words[i:i + 2] == ["pip", "install"])
        return [f"{words[i]} {words[i + 1]}" for i in range(start + 2, len(words) - 1)
                if words[i] in ("-e", "-r")]

    assert installs(quick_start) == ["-e .[all]"]  # every feature the README shows (issue 39)
    locked = ["-r requirements/test.txt", "-e .[test]"]
    assert installs(test) == locked
    ci = [tokens(line) for line in (ROOT / ".ci" / "run").read_text("utf-8").splitlines()
          if "pip install" in line and " -e " in line]
    assert [installs(line) for line in ci] == [locked]
    assert "python -m pytest" in (ROOT / ".ci" / "checks").read_text("utf-8")
    assert ".ci/checks" in (ROOT / ".ci" / "run").read_text("utf-8")


def test_transport_md_imports_the_classes_its_examples_use() -> None:
    """Issue 35: its ``Bus(...)`` example had no import line to say where Bus comes from."""
    text = (ROOT / "docs" / "transport.md").read_text("utf-8")
    code = "\n".join(re.findall(r"```python\n(.*?)```", text, re.S))
    imports = "\n".join(line for line in code.splitlines()
                        if line.startswith(("from ", "import ")))
    namespace: dict[str, Any] = {}
    exec(imports, namespace)  # every import line imports
    used = set(re.findall(r"\b([A-Z]\w+)\(", code))
    assert used and used <= set(namespace), used - set(namespace)
