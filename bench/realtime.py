"""How fast the simulated robot runs: launch flat out beside the in-process run, and the
real-time factor achieved at ``--speed K``.

Run ``python -m bench.realtime [--runs 3] [--duration 30] [--speed 5] [--cpu N]``. Every
set-up runs in a process of its own pinned to one core (``--cpu``, default the last core this
process may use), so the figures are of one core whatever the machine has, and one run of each
set-up goes in turn, so a slow patch of the machine hits them all:

* **launch flat out** — the main job as a user scripts it, ``python -m ubf_async.launch
  --scenario S --speed max --duration D --quiet --summary F``: the full robot with its camera.
  Two factors: *end to end*, simulated seconds over the process's whole wall time (start-up,
  imports, the zenoh session, the render process, the end); and *simulator*, the summary's
  ``real_time_factor`` (from the moment simulated time starts to its end).
* **in-process** — the same run as a library call, ``ubf_async.experiment.run(…, duration_s=D)``,
  in a process that makes two calls: the *first* (what one call costs in a fresh process,
  the simulator's imports included) and the *next* (what each further run of a sweep's worker
  costs). End to end is the call's wall time; simulator, the summary's factor.
* **full robot / no camera at ×K** — launch at ``--speed K`` with and without the camera
  (``--devices``): whether the machine keeps up with K, and what the camera costs.

It prints each run, then the medians, and the ratios in-process / launch flat out (end to end
and simulator), measured in the same session. ``--runs 1 --duration 5`` is a quick look.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench import cpu_hog
from components.sim.runner.stepper import DEVICES

ROOT = Path(__file__).resolve().parent.parent
CHILD_FLAG = "--in-process-child"


@dataclass
class Setup:
    name: str
    measure: Callable[[Path], dict[str, float]]
    """One run: its figures (``end_to_end``, ``simulator``, …)."""
    runs: list[dict[str, float]] = field(default_factory=list)

    def median(self, figure: str) -> float:
        return statistics.median(run[figure] for run in self.runs)


def pinned(args: argparse.Namespace) -> Callable[[], None]:
    """A child's set-up: pinned to ``--cpu``."""
    return functools.partial(cpu_hog.pin_to, [args.cpu])


def launch_run(args: argparse.Namespace, *, speed: str, devices: str, folder: Path
               ) -> dict[str, float]:
    summary = folder / f"launch-{time.monotonic_ns()}.json"
    cmd = [sys.executable, "-m", "ubf_async.launch", "--scenario", args.scenario, "--speed",
           speed, "--duration", f"{args.duration:g}", "--devices", devices, "--quiet",
           "--summary", str(summary), "--listen", "tcp/127.0.0.1:0"]
    started = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True,
                          timeout=args.duration * 20 + 120, preexec_fn=pinned(args))
    wall = time.perf_counter() - started
    if proc.returncode != 0:
        raise SystemExit(f"run failed ({' '.join(cmd)}):\n{proc.stdout}\n{proc.stderr}")
    result = json.loads(summary.read_text("utf-8"))
    return {"end_to_end": result["sim_time_s"] / wall, "simulator": result["real_time_factor"],
            "wall_s": wall}


def in_process_run(args: argparse.Namespace, folder: Path) -> dict[str, float]:
    cmd = [sys.executable, "-m", "bench.realtime", CHILD_FLAG, "--scenario", args.scenario,
           "--duration", f"{args.duration:g}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True,
                          timeout=args.duration * 20 + 120, preexec_fn=pinned(args))
    if proc.returncode != 0:
        raise SystemExit(f"run failed ({' '.join(cmd)}):\n{proc.stdout}\n{proc.stderr}")
    figures: dict[str, float] = json.loads(proc.stdout.strip().splitlines()[-1])
    return figures


def child(scenario: str, duration_s: float) -> int:
    """Two calls in this (fresh) process: the first, then the next; one line of JSON."""
    from ubf_async import experiment

    figures: dict[str, Any] = {}
    for label in ("first", "next"):
        started = time.perf_counter()
        result = experiment.run("mini-whegs", scenario, duration_s=duration_s)
        wall = time.perf_counter() - started
        figures[f"{label}_end_to_end"] = result.summary["sim_time_s"] / wall
        figures[f"{label}_simulator"] = result.summary["real_time_factor"]
        figures[f"{label}_wall_s"] = wall
    figures["end_to_end"] = figures["next_end_to_end"]
    figures["simulator"] = figures["next_simulator"]
    print(json.dumps(figures))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.realtime", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--speed", type=float, default=5.0,
                        help="the paced speed of the full robot / no camera runs (default 5)")
    parser.add_argument("--runs", type=int, default=3, help="runs per set-up (default 3)")
    parser.add_argument("--duration", type=float, default=30.0,
                        help="simulated seconds per run (default 30)")
    parser.add_argument("--scenario", default="ball-in-sight",
                        help="scenario to run (default ball-in-sight)")
    parser.add_argument("--cpu", type=int, default=max(os.sched_getaffinity(0)),
                        help="the core every run is pinned to (default: the last one)")
    parser.add_argument(CHILD_FLAG, action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.in_process_child:
        return child(args.scenario, args.duration)
    if args.runs < 1 or not args.speed > 0 or not args.duration > 0:
        parser.error("--runs must be >= 1, --speed and --duration > 0")
    if args.cpu not in os.sched_getaffinity(0):
        parser.error(f"--cpu {args.cpu}: not one of this process's cores "
                     f"{sorted(os.sched_getaffinity(0))}")

    every = ",".join(DEVICES)
    no_camera = ",".join(d for d in DEVICES if d != "camera")
    setups = [
        Setup("launch flat out", lambda f: launch_run(args, speed="max", devices=every,
                                                      folder=f)),
        Setup("in-process", lambda f: in_process_run(args, f)),
        Setup(f"full robot x{args.speed:g}",
              lambda f: launch_run(args, speed=f"{args.speed:g}", devices=every, folder=f)),
        Setup(f"no camera x{args.speed:g}",
              lambda f: launch_run(args, speed=f"{args.speed:g}", devices=no_camera, folder=f)),
    ]
    print(f"scenario {args.scenario}, {args.duration:g} s simulated per run, {args.runs} "
          f"run(s) per set-up, each process pinned to core {args.cpu}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.runs):
            for setup in setups:
                figures = setup.measure(Path(tmp))
                setup.runs.append(figures)
                extra = (f" (first call x{figures['first_end_to_end']:.1f})"
                         if "first_end_to_end" in figures else "")
                print(f"  run {i + 1} {setup.name:<18} end to end x{figures['end_to_end']:6.2f}"
                      f"  simulator x{figures['simulator']:6.2f}{extra}", flush=True)

    print()
    print(f"{'set-up':<20}{'end to end':>12}{'simulator':>11}   (medians, x real time)")
    for setup in setups:
        print(f"{setup.name:<20}{setup.median('end_to_end'):>12.2f}"
              f"{setup.median('simulator'):>11.2f}")
    launch, inproc, paced, bare = setups
    first = statistics.median(run["first_end_to_end"] for run in inproc.runs)
    print(f"{'in-process, first':<20}{first:>12.2f}")
    print()
    print(f"in-process / launch flat out: end to end "
          f"{inproc.median('end_to_end') / launch.median('end_to_end'):.2f}x "
          f"(first call {first / launch.median('end_to_end'):.2f}x), simulator "
          f"{inproc.median('simulator') / launch.median('simulator'):.2f}x")
    print(f"at x{args.speed:g}: full robot reaches x{paced.median('simulator'):.2f} "
          f"({paced.median('simulator') / args.speed:.3f} of asked), no camera "
          f"x{bare.median('simulator'):.2f}; full / no camera "
          f"{paced.median('simulator') / bare.median('simulator'):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
