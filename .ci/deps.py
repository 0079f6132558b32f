"""The test environment's lock, and the releases beyond it tried on purpose.

CI and the README's test command install ``requirements/test.txt``: every package the ``test``
extra brings, pinned, so a fresh machine gets what the suite last passed with. This tool keeps
that lock and tries what upstream released since (README, "Upgrading dependencies")::

    python .ci/deps.py lock               # re-resolve after editing pyproject.toml; say what moved
    python .ci/deps.py lock --upgrade     # every pin to its newest release within the ranges
    python .ci/deps.py lock --upgrade-package numpy
    python .ci/deps.py latest             # a fresh venv at the newest releases, ranges' upper
                                          # bounds ignored: the linters and the suite
    python .ci/deps.py lowest             # the project's own requirements at their lower
                                          # bounds: the suite

``latest`` and ``lowest`` build their venv under ``.venvs/`` and run ``.ci/checks`` in it; they
print the versions they got beside the lock's, and ``latest`` names every release outside a
declared range (``pip check``): the upper bound to move once the suite passes with it.
Resolving needs ``uv`` (in the test extra).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LOCK = ROOT / "requirements" / "test.txt"
VENVS = ROOT / ".venvs"
PYTHON = "3.11"
"""The oldest Python the project supports (``requires-python``): the lock is resolved for it
and, with ``--universal``, for every newer one and every platform."""
PROJECT = "ubf-async"
COMPILE = ["uv", "pip", "compile", "pyproject.toml", "--extra", "test", "--quiet",
           "--python-version", PYTHON, "--custom-compile-command", "python .ci/deps.py lock"]


class DepsError(Exception):
    """A step that cannot go on: the message says which and why."""


def normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def pins(text: str) -> dict[str, list[str]]:
    """``name -> versions`` of a requirements file (one per environment marker: the lock
    pins numpy twice)."""
    found: dict[str, list[str]] = {}
    for line in text.splitlines():
        match = re.match(r"^([A-Za-z0-9._-]+)==([^\s;]+)", line)
        if match:
            found.setdefault(normalise(match[1]), []).append(match[2])
    return found


def moved(before: dict[str, list[str]], after: dict[str, list[str]]) -> list[str]:
    """One line per package added, removed or moved, sorted by name."""
    lines = []
    for name in sorted(before.keys() | after.keys()):
        old, new = " / ".join(before.get(name, [])), " / ".join(after.get(name, []))
        if old != new:
            lines.append(f"  {name}: {old or '(new)'} -> {new or '(gone)'}")
    return lines


def run(command: list[str]) -> None:
    print("+", " ".join(command), flush=True)
    status = subprocess.run(command, cwd=ROOT).returncode
    if status:
        raise DepsError(f"{command[0]} {' '.join(command[1:3])} failed (exit {status})")


def need_uv() -> None:
    if shutil.which("uv") is None:
        raise DepsError("uv is not on PATH: pip install uv (it is in the test extra)")


def lock(upgrade: bool, packages: list[str]) -> None:
    need_uv()
    before = pins(LOCK.read_text("utf-8")) if LOCK.exists() else {}
    command = [*COMPILE, "--universal", "-o", str(LOCK.relative_to(ROOT))]
    if upgrade:
        command.append("--upgrade")
    for package in packages:
        command += ["--upgrade-package", package]
    run(command)
    lines = moved(before, pins(LOCK.read_text("utf-8")))
    print(f"{LOCK.relative_to(ROOT)}: " + (f"{len(lines)} moved\n" + "\n".join(lines)
                                          if lines else "nothing moved"))
    if lines:
        print("Next: bash .ci/run from a clean clone, then commit the lock with what moved.")


def project_requirements() -> list[str]:
    """The test extra's requirements, the project's own extras unfolded (the project's base
    requirements among them)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text("utf-8"))["project"]
    extras = project["optional-dependencies"]
    wanted, seen, todo = list(project["dependencies"]), set(), ["test"]
    while todo:
        extra = todo.pop()
        if extra not in seen:
            seen.add(extra)
            for text in extras[extra]:
                match = re.match(rf"^{re.escape(PROJECT)}\[([^\]]+)\]$", text.strip())
                if match:
                    todo += [name.strip() for name in match[1].split(",")]
                else:
                    wanted.append(text)
    return wanted


def without_upper_bound(requirement: str) -> str:
    """``name[extras]>=low,<high; marker`` as ``name[extras]>=low; marker``."""
    spec, _, marker = requirement.partition(";")
    match = re.match(r"^\s*([A-Za-z0-9._-]+(?:\[[^\]]*\])?)\s*(.*)$", spec)
    if match is None:
        raise DepsError(f"cannot read the requirement {requirement!r}")
    name, clauses = match[1], [c.strip() for c in match[2].split(",") if c.strip()]
    kept = ",".join(c for c in clauses if c.startswith((">=", ">", "!=")))
    return name + kept + (f"; {marker.strip()}" if marker else "")


def fresh_venv(name: str) -> Path:
    venv = VENVS / name
    shutil.rmtree(venv, ignore_errors=True)
    run([sys.executable, "-m", "venv", str(venv)])
    python = venv / "bin" / "python"
    run([str(python), "-m", "pip", "install", "--quiet", "--upgrade", "pip"])
    return python


def report_and_check(python: Path, name: str, *, linters: bool = True) -> int:
    """Print the versions the venv got beside the lock's, what is outside a declared range,
    and run the checks in it (``linters``: all of .ci/checks; else the suite alone); the
    checks' exit status."""
    frozen = subprocess.run([str(python), "-m", "pip", "freeze", "--exclude-editable"],
                            capture_output=True, text=True, check=True).stdout
    got, locked = pins(frozen), pins(LOCK.read_text("utf-8"))
    lines = moved(locked, got)
    print(f"== {name}: {len(lines)} versions differ from the lock "
          f"(lock -> {name})\n" + "\n".join(lines))
    print(f"== {name}: releases outside the declared ranges (pip check)", flush=True)
    subprocess.run([str(python), "-m", "pip", "check"], cwd=ROOT)
    env = dict(os.environ, VIRTUAL_ENV=str(python.parent.parent),
               PATH=f"{python.parent}{os.pathsep}{os.environ.get('PATH', '')}")
    checks = (["bash", str(ROOT / ".ci" / "checks")] if linters
              else [str(python), "-m", "pytest", "--durations=15"])
    status = subprocess.run(checks, cwd=ROOT, env=env).returncode
    print(f"== {name}: the checks {'passed' if status == 0 else f'FAILED (exit {status})'}")
    return status


def latest() -> int:
    """Every requirement at its newest release, upper bounds ignored."""
    python = fresh_venv("latest")
    wanted = [without_upper_bound(r) for r in project_requirements()]
    run([str(python), "-m", "pip", "install", "--quiet", "--upgrade", *wanted])
    run([str(python), "-m", "pip", "install", "--quiet", "--no-deps", "-e", "."])
    return report_and_check(python, "latest")


def lowest() -> int:
    """The project's own requirements at their lower bounds; the test tools at the lock's pins
    (their oldest releases would test the tools, not the project)."""
    need_uv()
    project = tomllib.loads((ROOT / "pyproject.toml").read_text("utf-8"))["project"]
    names = {normalise(re.split(r"[\s\[<>=!~;]", text.strip(), maxsplit=1)[0])
             for text in project["optional-dependencies"]["test"]} - {PROJECT}
    locked = pins(LOCK.read_text("utf-8"))
    tools = [f"{name}=={locked[name][0]}" for name in sorted(names)]
    with tempfile.TemporaryDirectory() as scratch:
        constraints, resolved = Path(scratch) / "tools.txt", Path(scratch) / "lowest.txt"
        constraints.write_text("\n".join(tools) + "\n", "utf-8")
        run([*COMPILE, "--resolution", "lowest-direct", "-c", str(constraints),
             "-o", str(resolved)])
        python = fresh_venv("lowest")
        run([str(python), "-m", "pip", "install", "--quiet", "-r", str(resolved)])
    run([str(python), "-m", "pip", "install", "--quiet", "--no-deps", "-e", "."])
    # The suite alone: the type checker on a library's oldest stubs would judge the stubs.
    return report_and_check(python, "lowest", linters=False)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python .ci/deps.py", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="README, 'Upgrading dependencies', says when to run which.")
    commands = parser.add_subparsers(dest="command", required=True)
    locking = commands.add_parser("lock", help="re-resolve requirements/test.txt; say what moved")
    locking.add_argument("--upgrade", action="store_true",
                         help="every pin to its newest release within the declared ranges")
    locking.add_argument("--upgrade-package", action="append", default=[], metavar="NAME",
                         help="this package to its newest release (repeatable)")
    commands.add_parser("latest", help="a fresh venv at the newest releases (upper bounds "
                        "ignored): what moved, what is out of range, the checks")
    commands.add_parser("lowest", help="a fresh venv with the project's requirements at their "
                        "lower bounds: the checks")
    args = parser.parse_args(argv)
    try:
        if args.command == "lock":
            lock(args.upgrade, args.upgrade_package)
            return 0
        return latest() if args.command == "latest" else lowest()
    except DepsError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
