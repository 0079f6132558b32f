"""Where a simulated second goes: the in-process run's CPU time, part by part.

Run ``python -m bench.simsecond [--scenario ball-in-sight] [--runs 3] [--duration 25]``. It
runs :func:`ubf_async.experiment.run` (flat out, the full robot with its camera) with a timer
around each part of the work — the physics, the camera's render and seekcolor (in the
camera's thread), the controller's ticks (tree, arbiter, drive command), the device
components' work (encoders, motors, range finder), the aggregator's ingest (decode included),
publishing (encoding included), the trajectory's samples, the simulator's step bookkeeping —
and prints each part's share of the run's CPU time (every thread's) and its cost per
simulated second; the rest is the event loop itself (its rounds, the hand-offs between tasks,
the clock's wake-ups). The timers read each thread's own CPU clock (``time.thread_time``), so
a thread waiting for the GIL counts nothing; they cost a microsecond or two per call (the
untimed runs' speed is printed too).
``--profile`` runs cProfile over one more run and prints its top functions too.

The parts are exclusive where they nest: a publish inside a tick counts as publishing, not
as the tick (each timer pauses the one around it).
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import pstats
import statistics
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from ubf_async import experiment

PARTS: dict[str, list[tuple[str, str, str]]] = {
    "physics (pymunk + wheel forces)": [("components.sim.world.physics", "World", "advance")],
    "camera: render": [("components.sim.backends.devices", "SimCameraBackend", "capture")],
    "camera: seekcolor": [("components.camera.component", "", "seekcolor")],
    "controller tick (tree, arbiter)": [("ubf_async.runtime.controller", "Controller", "tick")],
    "encoders (quadrature, odometry)": [("components.sim.backends.devices", "SimEncoderBackend",
                                         "read_phases"),
                                        ("components.quadrature", "QuadratureDecoder",
                                         "feed"),
                                        ("components.encoders.odometry", "WheelOdometry",
                                         "update")],
    "motors (PWM, watchdog)": [("components.motors.component", "MotorsComponent",
                                "_on_drive")],
    "range finder (IR model)": [("components.sim.backends.devices", "SimRangeBackend",
                                 "distance_m")],
    "aggregator ingest (decode, order)": [("ubf_async.runtime.aggregator", "_SensorScreen",
                                           "check"),
                                          ("ubf_async.runtime.aggregator", "StateAggregator",
                                           "_on_decoded")],
    "publish (encode, deliver)": [("ubf_async.runtime.bus", "Publisher", "publish")],
    "trajectory samples": [("components.sim.runner.run", "SimulationRun", "_take_sample")],
    "simulator step bookkeeping": [("components.sim.runner.stepper", "SimulatorComponent",
                                    "_step")],
}


class Timers:
    """Exclusive CPU time per part: a part's timer pauses the one it runs inside (per thread:
    the camera's thread has its own stack)."""

    def __init__(self) -> None:
        self.spent: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._stacks: dict[int, list[tuple[str, list[float]]]] = defaultdict(list)

    @contextmanager
    def part(self, name: str) -> Iterator[None]:
        import threading

        stack = self._stacks[threading.get_ident()]
        now = time.thread_time()
        if stack:
            outer, outer_since = stack[-1]
            self.spent[outer] += now - outer_since[0]
        since = [now]
        stack.append((name, since))
        try:
            yield
        finally:
            end = time.thread_time()
            self.spent[name] += end - since[0]
            self.calls[name] += 1
            stack.pop()
            if stack:
                stack[-1][1][0] = end


def instrument(timers: Timers) -> Callable[[], None]:
    """Wrap every function of :data:`PARTS`; return what undoes it."""
    import importlib

    undo: list[Callable[[], None]] = []
    for name, targets in PARTS.items():
        for module_name, owner_name, attribute in targets:
            module = importlib.import_module(module_name)
            owner: Any = getattr(module, owner_name) if owner_name else module
            original = getattr(owner, attribute)

            def wrap(original: Callable[..., Any], name: str) -> Callable[..., Any]:
                @functools.wraps(original)
                def timed(*args: Any, **kwargs: Any) -> Any:
                    with timers.part(name):
                        return original(*args, **kwargs)
                return timed

            setattr(owner, attribute, wrap(original, name))
            undo.append(functools.partial(setattr, owner, attribute, original))

    def undo_all() -> None:
        for step in undo:
            step()

    return undo_all


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.simsecond", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="ball-in-sight")
    parser.add_argument("--duration", type=float, default=25.0, help="simulated s per run")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--profile", action="store_true",
                        help="also cProfile one run and print its top functions")
    args = parser.parse_args(argv)
    experiment.run("mini-whegs", args.scenario, duration_s=2.0)  # imports, caches
    plain = []
    for _ in range(args.runs):
        started = time.perf_counter()
        experiment.run("mini-whegs", args.scenario, duration_s=args.duration)
        plain.append(time.perf_counter() - started)
    timers = Timers()
    undo = instrument(timers)
    walls = []
    cpu_started = time.process_time()
    try:
        for _ in range(args.runs):
            started = time.perf_counter()
            experiment.run("mini-whegs", args.scenario, duration_s=args.duration)
            walls.append(time.perf_counter() - started)
    finally:
        undo()
    cpu = time.process_time() - cpu_started
    sim_s = args.duration * args.runs
    print(f"{args.scenario}, {args.duration:g} simulated s x {args.runs} runs: "
          f"{statistics.median(plain):.3f} s a run untimed "
          f"(x{args.duration / statistics.median(plain):.1f} real time), "
          f"{statistics.median(walls):.3f} s timed")
    print(f"{'part (CPU time)':<36}{'share':>7}{'ms per sim s':>14}{'calls per sim s':>17}")
    accounted = 0.0
    for name in PARTS:
        spent = timers.spent.get(name, 0.0)
        accounted += spent
        print(f"{name:<36}{spent / cpu:>7.1%}{spent / sim_s * 1e3:>14.2f}"
              f"{timers.calls.get(name, 0) / sim_s:>17.1f}")
    rest = max(0.0, cpu - accounted)
    print(f"{'the event loop and the rest':<36}{rest / cpu:>7.1%}{rest / sim_s * 1e3:>14.2f}")
    print(f"{'all (CPU time, every thread)':<36}{1:>7.0%}{cpu / sim_s * 1e3:>14.2f}")
    if args.profile:
        profiler = cProfile.Profile()
        profiler.runcall(experiment.run, "mini-whegs", args.scenario,
                         duration_s=args.duration)
        pstats.Stats(profiler).sort_stats("tottime").print_stats(25)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
