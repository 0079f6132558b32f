"""How a fleet scales on this machine: N robots in one simulated world, each controller in its
own process, over a zenoh router, at 50 Hz and 1× real time.

Run ``python -m bench.fleet_scaling [--robots 1,2,4,8] [--duration 20] [--json FILE]``. For
each N it starts what ``python -m ubf_async.fleet`` starts — a router, N controllers
(``launch --no-sim --sim-time --robot rI --mode client``) and the world holding the N robots
and their simulated devices (camera, IR, encoders, motors…) — runs the world for
``--duration`` simulated seconds at 1×, and reports, per N:

* **tick Hz** — each robot's rate of clock ticks (its controller's ``periodic_rate_hz`` over
  its last 1000 ticks), the worst robot's;
* **jitter p99** — each robot's p99 of how far the wall-clock gaps between those ticks stray
  from their median (``periodic_jitter_ms_p99``), the worst robot's;
* **world ×** — the world's real-time factor (simulated s per wall s; 1.0 keeps up);
* **CPU/robot** — the CPU time of each controller process over the run, as a share of one
  core (the worst robot's; a process of K controllers counts 1/K each), and the world
  process's CPU, its render process's included (its start too, ≈0.4 s of CPU once),
  divided by N (its devices are the robots' too: the world's share per robot);
* **step late** — how late the world's 5 ms steps started after their due wall time, p99 and
  worst (the world's summary, ``step_lateness``): every controller follows the world's clock,
  so this is the part of their jitter that the world's own pacing causes.

``--repeat R`` runs each size R times, interleaved, and reports each figure's median with the
jitter's range (``repeats``, ``jitter_p99_ms_range`` in the JSON): on a shared 2-core machine
one run's jitter moves by a few ms, so compare medians across commits.

``--controllers-per-process K`` runs the controllers K to a process, as
``python -m ubf_async.fleet --controllers-per-process K`` does (for small machines).

``--search`` measures the cooperative search instead (``docs/fleet.md``): N robots of
``examples/robots/fleet-whegs.yaml`` in the ``fleet-search`` room, the first placed in the far
corner, the others spread across the room, through the real launch path
(``python -m ubf_async.fleet``); it reports when the ball was first found and when every robot
had found it, and the same for a fleet that does not talk (the same tree without
``report_ball`` and ``go_to_report``).

``--json FILE`` writes ``{"runs": [{"robots": N, "tick_hz_min", "jitter_p99_ms_max",
"world_real_time_factor", "cpu_percent_per_robot", "world_cpu_percent_per_robot",
"world_step_late_p99_ms", "world_step_late_max_ms"}, …]}`` so
the figures can be compared across commits. The aim (issue 16): 8 robots hold 50 Hz with p99
jitter < 5 ms and the world at 1.0×.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.bus import Bus
from ubf_async.tools.fleet import FleetStatus
from ubf_async.wire.topics import CONTROLLER_STATUS

ROOT = Path(__file__).resolve().parent.parent
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
# Start poses in the ball-in-sight arena (3 × 3 m, ball 0.64 m ahead of the first robot).
POSES = [(0.0, 0.0, 0), (-0.4, 0.5, -45), (-0.4, -0.5, 45), (-0.8, 0.0, 0),
         (-1.0, 0.9, -30), (-1.0, -0.9, 30), (0.3, 0.9, -90), (0.3, -0.9, 90)]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


SEARCH_POSES = [(-2.5, -2.5, 45), (2.5, -2.5, 135), (-2.5, 2.5, -45), (0.0, 0.0, -90),
                (0.0, -2.5, 90), (-2.5, 0.0, 0), (1.2, -1.2, 180), (-1.2, 1.2, -90)]
"""Start poses in the fleet-search room (6 × 6 m, the ball at (2.4, 2.4)): the far corner
first, then spreading across the room."""
COOPERATIVE = ROOT / "examples" / "robots" / "fleet-whegs.yaml"


def silent_robot_file(folder: Path) -> Path:
    """The cooperative robot file without its two fleet behaviours (the control)."""
    lines = COOPERATIVE.read_text().splitlines()
    out, skip = [], 0
    for line in lines:
        if skip:
            skip -= 1
            continue
        if line.split("#")[0].strip() in ("- behavior: report_ball",
                                           "- behavior: go_to_report"):
            skip = 2  # its priority and params lines
            continue
        out.append(line)
    path = folder / "silent-whegs.yaml"
    path.write_text("\n".join(out) + "\n")
    return path


def run_search(n: int, *, robot_file: Path, duration_s: float, folder: Path) -> dict[str, Any]:
    import subprocess

    fleet = folder / f"search-{n}-{robot_file.stem}.yaml"
    robots = "\n".join(
        f"  - {{name: s{i + 1}, robot_file: {robot_file}, start: {{x_m: {x}, y_m: {y}, "
        f"heading_deg: {h}}}}}" for i, (x, y, h) in enumerate(SEARCH_POSES[:n]))
    fleet.write_text(f"world: {{scenario: fleet-search, speed: 1, duration_s: {duration_s}}}\n"
                     f"router: tcp/127.0.0.1:{free_port()}\nrobots:\n{robots}\n")
    summary = folder / f"{fleet.stem}.json"
    done = subprocess.run([sys.executable, "-m", "ubf_async.fleet", str(fleet), "--summary",
                           str(summary), "--quiet", "--log-dir", str(folder / fleet.stem)],
                          cwd=ROOT, capture_output=True, text=True,
                          timeout=duration_s * 4 + 120)
    if done.returncode != 0:
        raise SystemExit(f"the fleet failed:\n{done.stdout}\n{done.stderr}")
    result = json.loads(summary.read_text())
    return {"robots": n, "first_found_s": result["first_found_s"],
            "all_found_s": result["all_found_s"],
            "found": sum(r["found_s"] is not None for r in result["robots"].values()),
            "real_time_factor": result["real_time_factor"]}


def search_main(sizes: list[int], duration_s: float, json_path: Path | None) -> int:
    def when(value: float | None) -> str:
        return f"{value:.1f} s" if value is not None else "never"

    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="bench-search-") as tmp:
        folder = Path(tmp)
        silent = silent_robot_file(folder)
        for n in sizes:
            talking = run_search(n, robot_file=COOPERATIVE, duration_s=duration_s,
                                 folder=folder)
            quiet = run_search(n, robot_file=silent, duration_s=duration_s, folder=folder)
            rows.append({"robots": n, "cooperative": talking, "silent": quiet})
            print(f"{n} robot(s): first found {when(talking['first_found_s'])}, all "
                  f"{when(talking['all_found_s'])} ({talking['found']}/{n}); without the "
                  f"radio: first {when(quiet['first_found_s'])}, all "
                  f"{when(quiet['all_found_s'])} ({quiet['found']}/{n})", flush=True)
    print(f"\n{'robots':>6} {'first found':>12} {'all found':>10} {'found':>6}   "
          f"{'silent: first':>13} {'all':>8} {'found':>6}")
    for row in rows:
        c, q = row["cooperative"], row["silent"]
        print(f"{row['robots']:>6} {when(c['first_found_s']):>12} {when(c['all_found_s']):>10} "
              f"{c['found']:>4}/{row['robots']}   {when(q['first_found_s']):>13} "
              f"{when(q['all_found_s']):>8} {q['found']:>4}/{row['robots']}")
    print(f"\n(simulated seconds, {duration_s:g} s per run; found: within 1 m of the ball, "
          f"facing it)")
    if json_path is not None:
        json_path.write_text(json.dumps({"search": rows}, indent=2) + "\n")
    return 0


def cpu_s(pid: int) -> dict[int, float]:
    """User + system CPU seconds so far of a process and of its live child processes (the
    world's render process renders its cameras), per pid (Linux /proc; FileNotFoundError
    once the process is gone)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    out = {pid: (int(fields[11]) + int(fields[12])) / CLOCK_TICKS}
    with contextlib.suppress(FileNotFoundError):  # a child that ends meanwhile
        for task in Path(f"/proc/{pid}/task").iterdir():
            for child in (task / "children").read_text().split():
                with contextlib.suppress(FileNotFoundError):
                    out.update(cpu_s(int(child)))
    return out


def cpu_used_s(before: dict[int, float], after: dict[int, float]) -> float:
    """CPU seconds between two :func:`cpu_s` readings (a child started in between counts from
    its start)."""
    return sum(seconds - before.get(pid, 0.0) for pid, seconds in after.items())


async def spawn(args: list[str], log: Path) -> asyncio.subprocess.Process:
    with log.open("wb") as sink:
        return await asyncio.create_subprocess_exec(
            sys.executable, *args, cwd=ROOT, stdout=sink, stderr=asyncio.subprocess.STDOUT)


async def read(path: Path) -> str:
    return await asyncio.to_thread(path.read_text, errors="replace")


async def wait_for_line(log: Path, text: str, timeout_s: float = 60.0, *,
                        times: int = 1) -> None:
    """Until ``log`` holds ``text`` ``times`` times."""
    deadline = time.monotonic() + timeout_s
    while (printed := await read(log)).count(text) < times:
        if time.monotonic() > deadline:
            raise SystemExit(f"timed out waiting for {text!r} in {log}:\n{printed}")
        await asyncio.sleep(0.05)


async def run_fleet(n: int, *, duration_s: float, folder: Path,
                    per_process: int = 1) -> dict[str, Any]:
    router = f"tcp/127.0.0.1:{free_port()}"
    names = [f"r{i + 1}" for i in range(n)]
    fleet = folder / f"fleet-{n}.yaml"
    robots = "\n".join(f"  - {{name: {name}, start: {{x_m: {x}, y_m: {y}, heading_deg: {h}}}}}"
                       for name, (x, y, h) in zip(names, POSES, strict=False))
    fleet.write_text(f"world: {{scenario: ball-in-sight, speed: 1, duration_s: {duration_s}}}\n"
                     f"router: {router}\nrobots:\n{robots}\n")
    procs: dict[str, asyncio.subprocess.Process] = {}
    tool: Bus | None = None
    try:
        procs["router"] = await spawn(["-m", "ubf_async.router", "--listen", router, "--quiet"],
                                      folder / "router.log")
        await wait_for_line(folder / "router.log", "join with")
        groups = [names[i:i + per_process] for i in range(0, n, per_process)]
        for group in groups:
            label = "+".join(group)
            command = (["-m", "ubf_async.launch", "--no-sim", "--sim-time", "--robot", group[0],
                        "--mode", "client", "--connect", router, "--quiet"]
                       if per_process == 1 else
                       ["-m", "ubf_async.fleet", str(fleet), "--controllers-only",
                        ",".join(group), "--router", router])
            procs[label] = await spawn(command, folder / f"{label}-{n}.log")
        for group in groups:
            await wait_for_line(folder / f"{'+'.join(group)}-{n}.log", "controller:",
                                times=len(group))
        tool = await Bus.open(ConnectionOptions(mode="client", connect=[router]))
        status = FleetStatus(names)
        tool.subscribe_topic("ubf/*/status/controller", CONTROLLER_STATUS, status.on_status,
                             status.malformed, latest=False)
        summary = folder / f"world-{n}.json"
        world_log = folder / f"world-{n}.log"
        procs["world"] = world = await spawn(
            # Real time as before: the jitter measured is the wall-time one lockstep removes.
            ["-m", "ubf_async.fleet", str(fleet), "--world-only", "--summary", str(summary),
             "--no-lockstep"],
            world_log)
        await wait_for_line(world_log, "robots (")
        cpu0 = cpu1 = {name: cpu_s(p.pid) for name, p in procs.items()}
        wall0 = wall1 = time.monotonic()
        # The last status of each controller is the one heard just before the world ends.
        last: dict[str, dict[str, Any]] = {}
        while world.returncode is None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(world.wait(), 0.25)
            if world.returncode is None:
                # The world may already be reaped while its return code is not yet known:
                # then the previous reading stands. A child that has ended (the render
                # process, as the world shuts down) keeps its last reading.
                with contextlib.suppress(FileNotFoundError):
                    cpu1 = {name: {**cpu1[name], **cpu_s(p.pid)} for name, p in procs.items()}
                    wall1 = time.monotonic()
                last = {name: dict(view.status) for name, view in status.robots.items()}
        if world.returncode != 0:
            raise SystemExit(f"the world failed:\n{await read(world_log)}")
        result = json.loads(await read(summary))
        wall = wall1 - wall0
        cpu = {label: cpu_used_s(cpu0[label], cpu1[label]) / wall * 100 for label in cpu1}
        per_robot_cpu = {name: cpu[label] / len(group) for group in groups
                         for label in ["+".join(group)] for name in group}
        rows = {name: {"tick_hz": last.get(name, {}).get("periodic_rate_hz"),
                       "jitter_p99_ms": last.get(name, {}).get("periodic_jitter_ms_p99"),
                       "cpu_percent": per_robot_cpu[name]} for name in names}
        return {
            "robots": n,
            "tick_hz_min": min(r["tick_hz"] or 0.0 for r in rows.values()),
            "jitter_p99_ms_max": max(r["jitter_p99_ms"] or float("inf") for r in rows.values()),
            "world_real_time_factor": result["real_time_factor"],
            "world_step_late_p99_ms": (result.get("step_lateness") or {}).get("p99_ms"),
            "world_step_late_max_ms": (result.get("step_lateness") or {}).get("max_ms"),
            "controllers_per_process": per_process,
            "cpu_percent_per_robot": max(per_robot_cpu.values()),
            "world_cpu_percent_per_robot": cpu["world"] / n,
            "per_robot": rows,
        }
    finally:
        if tool is not None:
            await tool.aclose()
        for proc in procs.values():
            with contextlib.suppress(ProcessLookupError):
                proc.kill()
            await proc.wait()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.fleet_scaling", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robots", default="1,2,4,8",
                        help="fleet sizes to run, comma-separated (at most 8)")
    parser.add_argument("--duration", type=float, default=20.0, metavar="S",
                        help="simulated seconds per run")
    parser.add_argument("--json", type=Path, default=None, metavar="FILE")
    parser.add_argument("--controllers-per-process", type=int, default=1, metavar="K",
                        help="run the controllers K to a process (python -m ubf_async.fleet "
                             "--controllers-per-process)")
    parser.add_argument("--search", action="store_true",
                        help="time the cooperative search instead (--duration default 90)")
    parser.add_argument("--repeat", type=int, default=1, metavar="R",
                        help="run each fleet size R times, interleaved (1 2 4 8 1 2 4 8 …), "
                             "and report each figure's median over the R runs, with the "
                             "jitter's range: this machine's runs vary by a few ms")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat: at least 1")
    sizes = [int(n) for n in args.robots.split(",")]
    if not all(1 <= n <= len(POSES) for n in sizes):
        parser.error(f"--robots: each size from 1 to {len(POSES)}")
    if args.search:
        return search_main(sizes, args.duration if args.duration != 20.0 else 90.0, args.json)
    measured: dict[int, list[dict[str, Any]]] = {n: [] for n in sizes}
    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        for n in [n for _ in range(args.repeat) for n in sizes]:
            run = asyncio.run(run_fleet(n, duration_s=args.duration, folder=Path(tmp),
                                        per_process=min(n, args.controllers_per_process)))
            measured[n].append(run)
            print(f"{n} robot(s): tick {run['tick_hz_min']:.1f} Hz (worst robot), jitter p99 "
                  f"{run['jitter_p99_ms_max']:.2f} ms (worst), world "
                  f"{run['world_real_time_factor']:.3f}x, CPU {run['cpu_percent_per_robot']:.1f}"
                  f" % per controller + {run['world_cpu_percent_per_robot']:.1f} % of the "
                  f"world's per robot; the world's steps late by {late(run)}", flush=True)
    runs = [median_run(measured[n]) for n in sizes]
    if args.repeat > 1:
        print(f"\nmedians of {args.repeat} runs each; jitter p99 range: " + ", ".join(
            f"{run['robots']} robot(s) {run['jitter_p99_ms_range'][0]:.2f}–"
            f"{run['jitter_p99_ms_range'][1]:.2f} ms" for run in runs))
    print(f"\n{'robots':>6} {'tick Hz min':>11} {'jitter p99 ms':>13} {'world x':>8} "
          f"{'CPU %/ctl':>9} {'world CPU %/robot':>17} {'step late p99/max ms':>20}")
    for run in runs:
        print(f"{run['robots']:>6} {run['tick_hz_min']:>11.1f} {run['jitter_p99_ms_max']:>13.2f} "
              f"{run['world_real_time_factor']:>8.3f} {run['cpu_percent_per_robot']:>9.1f} "
              f"{run['world_cpu_percent_per_robot']:>17.1f} {late(run):>20}")
    print(f"\ncores: {os.cpu_count()}; aim: 8 robots at 50 Hz, jitter p99 < 5 ms, world 1.0x")
    if args.json is not None:
        args.json.write_text(json.dumps({"runs": runs}, indent=2) + "\n")
    return 0


MEDIAN_FIELDS = ("tick_hz_min", "jitter_p99_ms_max", "world_real_time_factor",
                 "cpu_percent_per_robot", "world_cpu_percent_per_robot",
                 "world_step_late_p99_ms", "world_step_late_max_ms")


def median_run(repeats: list[dict[str, Any]]) -> dict[str, Any]:
    """One fleet size's runs as one: each figure's median (a single run as it is), with
    ``repeats`` and the jitter's ``jitter_p99_ms_range`` over them; ``per_robot`` of the
    run whose jitter is the median's (the lower middle one for an even count)."""
    out = dict(sorted(repeats, key=lambda r: r["jitter_p99_ms_max"])[(len(repeats) - 1) // 2])
    for field in MEDIAN_FIELDS:
        values = [r[field] for r in repeats if r.get(field) is not None]
        out[field] = statistics.median(values) if values else None
    jitters = [r["jitter_p99_ms_max"] for r in repeats]
    out["repeats"] = len(repeats)
    out["jitter_p99_ms_range"] = [min(jitters), max(jitters)]
    return out


def late(run: dict[str, Any]) -> str:
    """The world's step lateness of a run: ``p99/max`` ms."""
    p99, worst = run.get("world_step_late_p99_ms"), run.get("world_step_late_max_ms")
    return "--" if p99 is None or worst is None else f"{p99:.1f}/{worst:.1f}"


if __name__ == "__main__":
    raise SystemExit(main())
