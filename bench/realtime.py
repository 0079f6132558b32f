"""How fast the simulated robot runs: the real-time factor achieved at ``--speed K``.

Run ``python -m bench.realtime [--speed 5] [--runs 3] [--duration 30]``. Each run is the real
main job, ``python -m ubf_async.launch --scenario S --speed K --duration D --quiet --summary``,
in its own process; the figures come from its summary (``docs/scenarios.md``, Outputs). Three
set-ups are measured in the same session, one run of each in turn so a slow patch of the
machine hits all three:

* **full robot** — every simulated device, the camera rendering the pixels of its
  1280×1024 frames that seekcolor reads (the ``camera.sim`` backend's sparse frames);
* **no camera** — the same run without the camera (``--devices motors,encoders,range,radio``):
  the baseline, what the machine manages when nothing is rendered;
* **flat out** — the full robot asked to run at ``--flat-out-speed`` (default 100×), which no
  machine reaches: the factor achieved is the headroom above ``--speed``.

For each it prints the real-time factor over whole runs (median and min over runs), over
0.25 s windows of wall time (the median over runs of each run's median window; the worst
run's p1 — the window 99 % of that run's windows beat — and the slowest window of all), and
ratios: achieved / requested, and full robot / no camera.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from components.sim.component import DEVICES

ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Setup:
    name: str
    speed: float
    devices: str
    runs: list[dict] = field(default_factory=list)

    def factors(self) -> list[float]:
        return [run["real_time_factor"] for run in self.runs]

    def windows(self, stat: str) -> list[float]:
        return [run["real_time_factor_windows"][stat] for run in self.runs]


def run_once(setup: Setup, *, scenario: str, duration_s: float, folder: Path) -> dict:
    summary = folder / f"{setup.name.replace(' ', '-')}-{len(setup.runs)}.json"
    cmd = [sys.executable, "-m", "ubf_async.launch", "--scenario", scenario,
           "--speed", f"{setup.speed:g}", "--duration", f"{duration_s:g}", "--devices",
           setup.devices, "--quiet", "--summary", str(summary), "--listen", "tcp/127.0.0.1:0"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True,
                          timeout=duration_s * 10 + 60)
    if proc.returncode != 0:
        raise SystemExit(f"run failed ({' '.join(cmd)}):\n{proc.stdout}\n{proc.stderr}")
    result = json.loads(summary.read_text("utf-8"))
    setup.runs.append(result)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.realtime", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--speed", type=float, default=5.0, help="requested speed (default 5)")
    parser.add_argument("--flat-out-speed", type=float, default=100.0,
                        help="speed asked for the flat-out runs (default 100)")
    parser.add_argument("--runs", type=int, default=3, help="runs per set-up (default 3)")
    parser.add_argument("--duration", type=float, default=30.0,
                        help="simulated seconds per run (default 30)")
    parser.add_argument("--scenario", default="ball-in-sight",
                        help="scenario to run (default ball-in-sight)")
    args = parser.parse_args(argv)
    if args.runs < 1 or not args.speed > 0 or not args.duration > 0:
        parser.error("--runs must be >= 1, --speed and --duration > 0")

    no_camera = ",".join(d for d in DEVICES if d != "camera")
    setups = [
        Setup("full robot", args.speed, ",".join(DEVICES)),
        Setup("no camera", args.speed, no_camera),
        Setup("flat out", args.flat_out_speed, ",".join(DEVICES)),
    ]
    print(f"scenario {args.scenario}, {args.duration:g} s simulated per run, "
          f"{args.runs} run(s) per set-up", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.runs):
            for setup in setups:
                result = run_once(setup, scenario=args.scenario, duration_s=args.duration,
                                  folder=Path(tmp))
                print(f"  run {i + 1} {setup.name:<10} x{setup.speed:<5g} -> "
                      f"x{result['real_time_factor']:.2f}  (camera frames "
                      f"{result['camera_frames']}, ends {result['ball_distance_m']:.3f} m "
                      f"from the ball)", flush=True)

    print()
    print(f"{'set-up':<12}{'asked':>7}{'run med':>9}{'run min':>9}{'win med':>9}"
          f"{'win p1':>8}{'win min':>9}{'achieved/asked':>16}")
    for setup in setups:
        f = setup.factors()
        print(f"{setup.name:<12}{setup.speed:>7g}{statistics.median(f):>9.2f}{min(f):>9.2f}"
              f"{statistics.median(setup.windows('median')):>9.2f}"
              f"{min(setup.windows('p1')):>8.2f}{min(setup.windows('min')):>9.2f}"
              f"{statistics.median(f) / setup.speed:>16.3f}")
    full, bare, flat = (statistics.median(s.factors()) for s in setups)
    print()
    print(f"full robot / no camera at x{args.speed:g}: {full / bare:.3f}")
    print(f"headroom: flat out reaches x{flat:.2f}, {flat / args.speed:.2f}x the requested "
          f"x{args.speed:g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
