"""Soak: the default robot for an hour of simulated time, its memory sampled throughout.

Run ``python -m bench.soak [--sim-s 3600] [--speed 100] [--warmup-s 300]``. It starts the real
main job, ``python -m ubf_async.launch --speed K --duration D --summary …`` (the shipped
Mini-WHEGS robot and the default scenario, exactly as ``python -m ubf_async.launch`` runs it),
in its own process, and

* samples that process's resident set size (``VmRSS`` in ``/proc/<pid>/status``) every
  ``--sample-period-s`` wall seconds;
* follows simulated time from launch's status lines (one every ``--status-period-s``), so
  each RSS sample is placed in simulated time (interpolated between status lines);
* at the end prints the RSS after the warm-up (the first ``--warmup-s`` simulated seconds:
  imports, caches, the allocator's arenas and every bounded buffer filling up), at the end,
  the largest after the warm-up, the growth (end − after warm-up, each the median of the
  samples in a short window) and the slope of a least-squares line through the samples after
  the warm-up, in MiB per simulated hour; and the real-time factor achieved (the run's
  summary: over the whole run, and the median 0.25 s window).

The default ``--speed 100`` is more than any machine holds, so the run goes as fast as this
machine can; the factor achieved is the figure to quote. The exit status is 0 when the growth
is below ``--limit-mib`` (10 MiB, the safety issue's aim), 1 otherwise.
"""

from __future__ import annotations

import argparse
import bisect
import json
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from bench.processes import terminate

ROOT = Path(__file__).resolve().parent.parent
MIB = 1024 * 1024
STATUS_RE = re.compile(r"^\[[^\]]*\]\s+(?P<sim_s>[0-9]+(?:\.[0-9]*)?)s\b")
"""launch's status line begins ``[<robot>] <elapsed>s`` (simulated seconds when simulating)."""
STALL_S = 120.0
"""Give up when simulated time has not moved for this long (wall seconds)."""


def rss_bytes(pid: int) -> int | None:
    """Resident set size of ``pid`` from ``/proc`` (``None`` once it is gone)."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


@dataclass
class Trace:
    """What the soak saw: (wall, simulated) time pairs and (wall, RSS) samples."""

    progress: list[tuple[float, float]] = field(default_factory=list)
    rss: list[tuple[float, int]] = field(default_factory=list)
    output: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def sim_at(self, wall_s: float) -> float | None:
        """Simulated time at ``wall_s``, interpolated between status lines."""
        points = self.progress
        if len(points) < 2 or wall_s < points[0][0]:
            return None
        i = bisect.bisect_right(points, wall_s, key=lambda p: p[0])
        if i >= len(points):
            return points[-1][1]
        (w0, s0), (w1, s1) = points[i - 1], points[i]
        return s0 + (s1 - s0) * (wall_s - w0) / (w1 - w0) if w1 > w0 else s1


def read_output(proc: subprocess.Popen[str], trace: Trace) -> None:
    """Collect launch's output (a thread: the pipe must never fill up)."""
    assert proc.stdout is not None
    for line in proc.stdout:
        now = time.monotonic()
        match = STATUS_RE.match(line)
        with trace.lock:
            if match:
                trace.progress.append((now, float(match["sim_s"])))
            elif len(trace.output) < 200:
                trace.output.append(line.rstrip())


def median_rss(samples: list[tuple[float, int]]) -> float:
    return statistics.median(r for _, r in samples)


def slope_per_hour(points: list[tuple[float, int]]) -> float:
    """Least-squares slope of RSS (bytes) against simulated seconds, in MiB per hour."""
    if len(points) < 2:
        return 0.0
    xs = [x for x, _ in points]
    ys = [float(y) for _, y in points]
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    if sxx == 0:
        return 0.0
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx * 3600 / MIB


def run(args: argparse.Namespace) -> int:
    with tempfile.TemporaryDirectory(prefix="ubf-soak-") as tmp:
        return run_in(args, Path(tmp))


def run_in(args: argparse.Namespace, folder: Path) -> int:
    summary_path = folder / "summary.json"
    cmd = [sys.executable, "-m", "ubf_async.launch", "--speed", f"{args.speed:g}",
           "--duration", f"{args.sim_s:g}", "--summary", str(summary_path),
           "--status-period-s", f"{args.status_period_s:g}", "--listen", "tcp/127.0.0.1:0",
           "--log-level", "WARNING"]
    if args.record:
        cmd += ["--record", str(folder / "record"), "--record-every-s", "60"]
    print("running:", " ".join(cmd[1:]), flush=True)
    trace = Trace()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, bufsize=1)
    reader = threading.Thread(target=read_output, args=(proc, trace), daemon=True)
    reader.start()
    wall0 = time.monotonic()
    next_report = wall0 + args.report_every_s
    last_sim, last_move = -1.0, wall0
    try:
        while proc.poll() is None:
            now = time.monotonic()
            rss = rss_bytes(proc.pid)
            if rss is not None:
                trace.rss.append((now, rss))
            with trace.lock:
                sim = trace.progress[-1][1] if trace.progress else 0.0
            if sim > last_sim:
                last_sim, last_move = sim, now
            elif now - last_move > STALL_S:
                print(f"simulated time stuck at {sim:.1f} s for {STALL_S:g} s: giving up")
                return 1
            if now >= next_report:
                print(f"  wall {now - wall0:6.0f} s  sim {sim:7.1f} s  "
                      f"RSS {(rss or 0) / MIB:7.1f} MiB", flush=True)
                next_report += args.report_every_s
            time.sleep(args.sample_period_s)
    except KeyboardInterrupt:
        print("interrupted")
        return 1
    finally:
        terminate(proc)
        reader.join(timeout=5)
    if proc.returncode != 0 or not summary_path.exists():
        print(f"launch failed (exit {proc.returncode}):\n" + "\n".join(trace.output))
        return 1
    return report(args, trace, json.loads(summary_path.read_text("utf-8")))


def report(args: argparse.Namespace, trace: Trace, summary: dict) -> int:
    placed = [(sim, rss) for wall, rss in trace.rss
              if (sim := trace.sim_at(wall)) is not None]
    after = [(sim, rss) for sim, rss in placed if sim >= args.warmup_s]
    if len(after) < 4:
        print(f"too few RSS samples after the warm-up ({len(after)}): run longer "
              "(--sim-s) or sample more often (--sample-period-s)")
        return 1
    window = max(2, len(after) // 20)  # 5 % of the samples at each end
    start_rss = median_rss(after[:window])
    end_rss = median_rss(after[-window:])
    peak = max(r for _, r in after)
    growth = end_rss - start_rss
    windows = summary.get("real_time_factor_windows") or {}
    print()
    print(f"simulated {summary['sim_time_s']:.0f} s in {summary['wall_time_s']:.0f} s wall "
          f"(--speed {args.speed:g}); {len(placed)} RSS samples, "
          f"{len(after)} after the {args.warmup_s:g} s warm-up")
    print(f"real-time factor achieved: {summary['real_time_factor']:.2f} over the run, "
          f"median window {windows.get('median', float('nan')):.2f}, "
          f"p1 {windows.get('p1', float('nan')):.2f}")
    first = placed[0][1] if placed else 0
    print(f"RSS: {first / MIB:.1f} MiB at start, {start_rss / MIB:.1f} MiB after warm-up, "
          f"{end_rss / MIB:.1f} MiB at the end, {peak / MIB:.1f} MiB largest after warm-up")
    print(f"growth after warm-up: {growth / MIB:+.2f} MiB (largest {(peak - start_rss) / MIB:+.2f}"
          f" MiB); slope {slope_per_hour(after):+.2f} MiB per simulated hour")
    print(f"trajectory: {summary.get('trajectory_samples')} samples taken, "
          f"{summary.get('trajectory_samples_kept')} kept in memory; "
          f"ticks {summary['ticks'].get('ticks')}, camera frames {summary.get('camera_frames')}")
    ok = growth < args.limit_mib * MIB
    print(f"{'PASS' if ok else 'FAIL'}: growth {'<' if ok else '>='} {args.limit_mib:g} MiB")
    return 0 if ok else 1


def _interrupted(signum: int, frame: object) -> None:
    raise KeyboardInterrupt  # so the robot's process is stopped on the way out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.soak", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sim-s", type=float, default=3600.0,
                        help="simulated seconds to run (default 3600)")
    parser.add_argument("--speed", type=float, default=100.0,
                        help="--speed asked of launch (default 100: as fast as it goes)")
    parser.add_argument("--warmup-s", type=float, default=300.0,
                        help="simulated seconds of warm-up before growth is measured "
                             "(default 300)")
    parser.add_argument("--sample-period-s", type=float, default=1.0,
                        help="wall seconds between RSS samples (default 1)")
    parser.add_argument("--status-period-s", type=float, default=1.0,
                        help="wall seconds between launch's status lines (default 1)")
    parser.add_argument("--report-every-s", type=float, default=30.0,
                        help="wall seconds between progress lines (default 30)")
    parser.add_argument("--limit-mib", type=float, default=10.0,
                        help="growth allowed after the warm-up (default 10 MiB)")
    parser.add_argument("--record", action="store_true",
                        help="also --record (trajectory.csv streamed, a frame a minute)")
    args = parser.parse_args(argv)
    if not (args.sim_s > 0 and args.speed > 0 and 0 <= args.warmup_s < args.sim_s
            and args.sample_period_s > 0 and args.status_period_s > 0):
        parser.error("need --sim-s, --speed, --sample-period-s, --status-period-s > 0 and "
                     "0 <= --warmup-s < --sim-s")
    if not Path("/proc/self/status").exists():
        parser.error("needs /proc (Linux) to read the resident set size")
    signal.signal(signal.SIGTERM, _interrupted)
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
