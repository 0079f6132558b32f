"""docs/your-robot.md, executed: every fenced code block of the tutorial, in order.

What each block is comes from its info string:

* ``python title="PATH"``, ``yaml title="PATH"``, ``toml title="PATH"`` — written to PATH in
  the tutorial's folder (a fresh temporary one);
* ``sh`` — run there with ``bash -euo pipefail``; it must exit 0. ``sh expect-fail`` must exit
  non-zero;
* ``python`` (no title) — run there with ``python -c``; it must exit 0;
* ``text`` — the output (stdout and stderr together) of the block just before it: its lines
  must appear in that order among the output's lines, where ``...`` stands for any text (a
  line of its own: any lines) and a run of spaces for any run of spaces. ``text varies``:
  also every number matches any number (tick rates, ages, wall-clock timing).

Any other block fails the test, so a block added to the page is either executed or noticed.

The commands run in a throw-away virtual environment (created ``--without-pip``) whose
``site-packages`` holds a ``.pth`` file adding this interpreter's ``site-packages``: it sees
ubf_async and its dependencies (and pip) as installed here, while the tutorial's
``pip install`` lands in the throw-away environment only.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import sysconfig
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.conftest import free_port

ROOT = Path(__file__).resolve().parent.parent
TUTORIAL = ROOT / "docs" / "your-robot.md"
DEFAULT_ENDPOINT = "127.0.0.1:7447"
BLOCK_TIMEOUT_S = 60.0

FENCE = re.compile(r"^```(.*)$")
NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")


@dataclass
class Block:
    line: int
    lang: str
    attrs: dict[str, str]
    flags: set[str]
    text: str
    page: str = TUTORIAL.name

    def where(self) -> str:
        return f"{self.page}:{self.line} ({self.lang} {' '.join(sorted(self.flags))})"


def parse_blocks(markdown: str, page: str = TUTORIAL.name) -> list[Block]:
    """The fenced code blocks of ``markdown`` (the page ``page``), in order."""
    blocks: list[Block] = []
    lines = markdown.splitlines()
    i = 0
    while i < len(lines):
        assert not lines[i].lstrip().startswith("```") or lines[i].startswith("```"), (
            f"{page}:{i + 1}: indented fence — not executed, write it unindented")
        match = FENCE.match(lines[i])
        if not match:
            i += 1
            continue
        info = match.group(1).strip()
        assert info, f"{page}:{i + 1}: a code block without an info string"
        lang, _, rest = info.partition(" ")
        attrs = dict(re.findall(r'(\w[\w-]*)="([^"]*)"', rest))
        flags = set(re.sub(r'\w[\w-]*="[^"]*"', " ", rest).split())
        start = i + 1
        i = start
        while i < len(lines) and lines[i] != "```":
            assert not lines[i].startswith("```"), f"{page}:{i + 1}: nested fence"
            i += 1
        assert i < len(lines), f"{page}:{start}: unclosed code block"
        blocks.append(Block(start, lang, attrs, flags, "\n".join(lines[start:i]) + "\n", page))
        i += 1
    return blocks


def line_pattern(expected: str, *, numbers_vary: bool) -> re.Pattern[str]:
    """``...`` → any text, spaces → any run of spaces, a number → any number if they vary."""
    parts = []
    for chunk in expected.split("..."):
        pieces = []
        last = 0
        for number in NUMBER.finditer(chunk) if numbers_vary else ():
            pieces.append(re.escape(chunk[last:number.start()]))
            pieces.append(NUMBER.pattern)
            last = number.end()
        pieces.append(re.escape(chunk[last:]))
        parts.append("".join(pieces))
    pattern = ".*".join(parts)
    pattern = re.sub(r"(\\ )+", r" +", pattern)
    return re.compile(pattern)


def check_output(expected: str, output: str, where: str, *, numbers_vary: bool) -> None:
    got = [" ".join(line.split()) for line in output.splitlines()]
    position = 0
    for wanted in expected.splitlines():
        if wanted.strip() in ("", "..."):
            continue
        pattern = line_pattern(" ".join(wanted.split()), numbers_vary=numbers_vary)
        for index in range(position, len(got)):
            if pattern.fullmatch(got[index]):
                position = index + 1
                break
        else:
            raise AssertionError(
                f"{where}: expected a line like\n  {wanted.strip()}\n(after line {position} of "
                f"the output), in:\n{textwrap.indent(output, '  | ')}")


def throwaway_venv(base: Path) -> Path:
    """A venv seeing this interpreter's packages through a .pth, installing into its own."""
    venv = base / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True,
                   timeout=120)
    python = venv / "bin" / "python"
    site_packages = Path(subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True).stdout.strip())
    outer = dict.fromkeys(sysconfig.get_paths()[key] for key in ("purelib", "platlib"))
    (site_packages / "_outer_env.pth").write_text(
        "".join(f"import site; site.addsitedir({path!r})\n" for path in outer))
    return venv


def run(argv: list[str], *, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """Run in a session of its own and, whatever happens, kill what it left behind (a robot
    started with ``&`` by a block that failed halfway)."""
    proc = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=BLOCK_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        raise AssertionError(f"timed out after {BLOCK_TIMEOUT_S}s:\n{out}") from None
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    return subprocess.CompletedProcess(argv, proc.returncode, out)


def run_blocks(blocks: list[Block], *, work: Path, env: dict[str, str], endpoint: str,
               python: str, handled: Callable[[Block], bool] = lambda block: False
               ) -> list[tuple[Block, str]]:
    """Execute a page's ``blocks`` in order by the rules of this module's docstring, in the
    folder ``work`` with the environment ``env``, the page's endpoint replaced by
    ``endpoint`` and ``python`` running its python blocks; ``handled(block)`` may take a
    block upon itself first (then it is not run). Returns each command block with its
    output."""
    outputs: list[tuple[Block, str]] = []
    previous_output: str | None = None
    for block in blocks:
        text = block.text.replace(DEFAULT_ENDPOINT, endpoint)
        if handled(block):
            previous_output = None
        elif "title" in block.attrs and block.lang in ("python", "yaml", "toml"):
            assert not block.flags, f"{block.where()}: unknown flags"
            path = work / block.attrs["title"]
            assert path.resolve().is_relative_to(work.resolve()), block.where()
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(block.text, encoding="utf-8")
            previous_output = None
        elif block.lang == "sh" and block.flags <= {"expect-fail"} and not block.attrs:
            proc = run(["bash", "-euo", "pipefail", "-c", text], cwd=work, env=env)
            if "expect-fail" in block.flags:
                assert proc.returncode != 0, f"{block.where()} should fail:\n{proc.stdout}"
            else:
                assert proc.returncode == 0, (
                    f"{block.where()} exited {proc.returncode}:\n{proc.stdout}")
            previous_output = proc.stdout
            outputs.append((block, proc.stdout))
        elif block.lang == "python" and not block.flags and not block.attrs:
            proc = run([python, "-c", text], cwd=work, env=env)
            assert proc.returncode == 0, f"{block.where()} exited {proc.returncode}:\n{proc.stdout}"
            previous_output = proc.stdout
            outputs.append((block, proc.stdout))
        elif block.lang == "text" and block.flags <= {"varies"} and not block.attrs:
            assert previous_output is not None, (
                f"{block.where()}: expected output must follow the command it belongs to")
            check_output(text, previous_output, block.where(),
                         numbers_vary="varies" in block.flags)
            previous_output = None
        else:
            raise AssertionError(f"{block.where()}: no rule to execute this block")
    return outputs


@pytest.mark.slow
def test_every_code_block_of_the_tutorial_runs(tmp_path: Path) -> None:
    blocks = parse_blocks(TUTORIAL.read_text(encoding="utf-8"))
    work = tmp_path / "my-robot"
    work.mkdir()
    venv = throwaway_venv(tmp_path)
    env = {key: value for key, value in os.environ.items()
           if key not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSAFEPATH", "PIP_USER",
                          "PIP_TARGET", "PIP_PREFIX", "PIP_REQUIRE_VIRTUALENV")}
    env.update(PATH=f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
               VIRTUAL_ENV=str(venv), PYTHONUNBUFFERED="1", PIP_DISABLE_PIP_VERSION_CHECK="1",
               PIP_NO_INPUT="1")
    # The page uses zenoh's documented default endpoint; a free port instead, so that the test
    # neither collides with a robot already running here nor with another test.
    endpoint = f"127.0.0.1:{free_port()}"
    assert DEFAULT_ENDPOINT in TUTORIAL.read_text(encoding="utf-8")

    outputs = run_blocks(blocks, work=work, env=env, endpoint=endpoint, python="python")

    # What the page claims beyond its printed output.
    # The typo is reported at the line that holds it.
    typo_line = next(number for number, line in enumerate(
        (work / "typo.yaml").read_text().splitlines(), 1) if "perod_s" in line)
    assert any(f"typo.yaml:{typo_line}: " in out for _, out in outputs)
    assert f"typo.yaml:{typo_line}: " in TUTORIAL.read_text(encoding="utf-8")
    # Wander found the ball; chase and flee then held it at the comfortable distance.
    summary = json.loads((work / "out" / "summary.json").read_text())
    shares = summary["ticks"]["winner_share"]
    assert set(shares) == {"wander", "chase", "flee"} and shares["wander"] < 0.5, shares
    assert 0.35 <= summary["ball_distance_m"] <= 0.6
    # The plug-in went into the throw-away environment, not into the one running the tests.
    assert list(venv.glob("lib/python*/site-packages/my_robot-0.1.0.dist-info"))
    from importlib.metadata import PackageNotFoundError, version
    with pytest.raises(PackageNotFoundError):
        version("my-robot")
