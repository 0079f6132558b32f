"""The README's test command, run again and again: how often the gate is red, and how long.

::

    python .ci/repeat.py --runs 5               # idle
    python .ci/repeat.py --runs 5 --hog         # beside python -m bench.cpu_hog

Each run is ``python -m pytest`` (with ``bench.cpu_hog`` around it under ``--hog``) in the
active venv, from the repository's root; its output goes to ``--logs DIR/run-N.log``. One
line a run (status, wall time, the failed tests' names), then the count of failed runs and the
median wall time. Exit status 1 when any run failed. Stops early with ``--stop-on-failure``.
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def one_run(number: int, hog: bool, logs: Path) -> tuple[bool, float, list[str]]:
    command = [sys.executable, "-m", "pytest"]
    if hog:
        command = [sys.executable, "-m", "bench.cpu_hog", "--", *command]
    log = logs / f"run-{number}.log"
    start = time.monotonic()
    with log.open("w", encoding="utf-8") as out:
        status = subprocess.run(command, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT).returncode
    wall = time.monotonic() - start
    text = log.read_text("utf-8", errors="replace")
    failed = re.findall(r"^(?:FAILED|ERROR) (\S+)", text, re.M)
    return status == 0, wall, failed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python .ci/repeat.py",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="how many runs (default 5)")
    parser.add_argument("--hog", action="store_true",
                        help="each run beside python -m bench.cpu_hog (every core busy)")
    parser.add_argument("--logs", type=Path, default=Path("out/repeat"),
                        help="folder of the runs' outputs (default out/repeat)")
    parser.add_argument("--stop-on-failure", action="store_true")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    args.logs.mkdir(parents=True, exist_ok=True)
    walls, failures = [], 0
    label = "beside bench.cpu_hog" if args.hog else "idle"
    for number in range(1, args.runs + 1):
        passed, wall, failed = one_run(number, args.hog, args.logs)
        walls.append(wall)
        failures += not passed
        print(f"run {number}/{args.runs} ({label}): {'passed' if passed else 'FAILED'} "
              f"in {wall:.0f} s" + (f": {', '.join(failed) or 'see the log'}" if not passed
                                    else ""), flush=True)
        if failures and args.stop_on_failure:
            break
    print(f"{len(walls) - failures} of {len(walls)} runs passed ({label}); wall time median "
          f"{statistics.median(walls):.0f} s, min {min(walls):.0f} s, max {max(walls):.0f} s")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
