"""End-to-end latency of ubf_async beside the transport floor and its peers, in one run.

    python -m bench.latency [--quick] [--json FILE] [--only SECTION ...]

Sections (each prints n, median, p90, p99 and max, and the ratios the issue asks for):

1. floor     raw zenoh-python round trip between two processes on loopback, small msgpack
             payloads, at 100 Hz (the reflex path's rate) and back-to-back.
2. reflex    a sensor process publishes stamped ``range/front`` samples at 100 Hz; the
             controller process (event mode, trigger range/front: the tick runs inside the
             aggregator's ingest, through its on_sample hook) turns each into a
             ``cmd/drive``; the sensor matches it through ``based_on.seq`` and records the
             round trip. Ratio to the floor (aim ≤ 1.25×), for the controller as it runs
             (no observers); the same controller observed through its hooks shows where the
             time goes, and on asyncio's plain loop what the lending loop saves. Beside them
             the Python floor: the echo running the same tree in its zenoh callback (decode,
             store, evaluate, encode; nothing else). 1 and 2 run at the same time from one
             sensor process, their samples interleaved (2 ms apart at 100 Hz; taking turns
             back-to-back), so every ratio compares them under the same load on the host.
3. periodic  age of a sample when the first command based on it is published, periodic mode
             (no reflexes) at 50 and 100 Hz (samples at random moments, slower than the
             tick); tick jitter with the whole simulated robot (simulator, camera, encoders,
             IR, motors, radio) and the launch's default controller in one process.
4. obstacle  an IR reading < 200 mm appears at a random moment; time until the first drive
             command that reflects it (speed −50 from the bench's avoid behaviour) in the sync
             mode that waits for each camera frame, in the default controller of
             ``python -m ubf_async.launch`` (periodic 50 Hz, reflexes on ``range/``), in
             periodic 50 Hz without reflexes and in event mode on the IR. Ratio sync/async
             (aim ≥ 20×, for the default controller).
5. camera    capture stamp → command, sync (stand-in camera) and periodic (simulated camera).
6. peers     the reflex round trip as a dora-rs dataflow of Python nodes (``dora run``) and
             py_trees tick cost beside the UBF tick cost for 3/30/100 children. A peer that is
             not installed is reported as skipped.
7. breakdown in-process costs of the pieces: zenoh same-session delivery, the bridge hand-off,
             decode, snapshot + evaluate, encode, put.
8. loops     the event loop decision: the reflex round trip (controller as it runs, at 100 Hz
             and back-to-back) and the obstacle reaction of the launch's default controller,
             on asyncio's plain loop (the baseline), the lending loop and uvloop (if
             installed), in rounds: in each round every loop is measured, in an order that
             rotates from round to round (the reflex's servers interleaved sample by sample),
             so the host's noise falls on each loop alike. Medians and p99 of all rounds
             pooled, ratios to the plain loop, and the spread of the per-round median ratios.
9. dora      dora-rs/dora-benchmark on its own terms: its sizes (8 B … 4 MB), its method (the
             sender's ``perf_counter_ns`` in the payload, one-way), our path (a Bus raw
             publisher → a Bus subscription's handler on the event loop) and dora's Python
             nodes taking turns in rounds, its published figures beside; our path refuses
             payloads over 256 KiB by design.

Section 2 runs in rounds (``--rounds``), the servers' order rotating, and reports the reflex
against the Python floor (median, p90, p99, max and their ratios; aim ≤ 1.10×, issue 40);
``--baseline DIR`` adds the controller of another checkout to the same rounds.

Every figure comes from ``time.monotonic_ns()`` stamps carried in the messages and read on
the same host (CLOCK_MONOTONIC is shared by all processes), by the process that observed the
event; warm-up samples are discarded. See docs/latency.md for how to read each figure.
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import datetime
import importlib.metadata
import itertools
import json
import os
import queue
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench.latency_stats import fmt_us, header, ratio, row, summarize

ROOT = Path(__file__).resolve().parent.parent
SECTIONS = ("floor", "reflex", "periodic", "obstacle", "camera", "peers", "breakdown",
            "loops", "dora")
CAMERA_PERIOD_S = 0.11
REFLEX_AIM = 1.25
"""Issue 12's aim: the reflex round trip's median at most this many times the floor's."""
IR_PERIOD_S = 0.04


# ---------------------------------------------------------------------------------------------
# Child processes


def free_endpoint() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


class Worker:
    """A child process (``python -m <module> '<json>'``) that may print ``READY`` and ends
    with ``RESULT <json>``. Servers stop when their stdin closes."""

    def __init__(self, module: str, cfg: dict[str, Any], root: Path = ROOT) -> None:
        """``root``: the checkout whose ``ubf_async`` and ``bench`` the child runs (another
        one for a before/after comparison in one run, ``--baseline``)."""
        self.module = module
        self._stderr = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 (lives with the child)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", module, json.dumps(cfg)], cwd=root,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr, text=True,
            env={**os.environ, "PYTHONPATH": str(root)},
        )
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        try:
            for line in self.proc.stdout:
                self._lines.put(line.rstrip("\n"))
        except (OSError, ValueError):  # closed under us by kill()
            pass
        self._lines.put(None)

    def _next_line(self, prefix: str, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                line = self._lines.get(timeout=max(0.01, deadline - time.monotonic()))
            except queue.Empty:
                line = ""
                if time.monotonic() < deadline:
                    continue
                self.kill()
                raise TimeoutError(f"{self.module}: no {prefix} within {timeout_s}s"
                                   f"{self._stderr_tail()}") from None
            if line is None:
                self.proc.wait()
                raise RuntimeError(f"{self.module} exited ({self.proc.returncode}) before "
                                   f"{prefix}{self._stderr_tail()}")
            if line.startswith(prefix):
                return line[len(prefix):]

    def _stderr_tail(self) -> str:
        if self._stderr.closed:
            return ""
        self._stderr.seek(0)
        tail = self._stderr.read().strip().splitlines()[-8:]
        return ("\n  " + "\n  ".join(tail)) if tail else ""

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        self._next_line("READY", timeout_s)

    def result(self, timeout_s: float) -> dict[str, Any]:
        """Close stdin (a server's cue to stop) and return the ``RESULT`` it prints."""
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()
        out = json.loads(self._next_line("RESULT ", timeout_s))
        self.proc.wait(timeout=10)
        return out

    def kill(self) -> None:
        """Stop the child if it still runs and release its pipes (idempotent)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(timeout=5)  # the child is gone: its stdout reaches EOF
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None and not stream.closed:
                stream.close()
        self._stderr.close()


def serve_and_measure(server_cfgs: list[dict[str, Any]], sensor_cfg: dict[str, Any],
                      timeout_s: float) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Start servers (echo or controller), each in its own process on its own endpoint and
    robot name, run a sensor scenario in another process against them, stop the servers;
    returns (server results, sensor result)."""
    servers: list[Worker] = []
    targets = []
    sensor: Worker | None = None
    try:
        for i, cfg in enumerate(server_cfgs):
            target = {"endpoint": free_endpoint(),
                      "robot": f"lat{os.getpid()}x{time.monotonic_ns() % 10**6}n{i}"}
            tree = cfg.get("tree")
            servers.append(Worker("bench.latency_robot", {**cfg, **target},
                                  root=Path(tree) if tree else ROOT))
            targets.append(target)
        for w in servers:
            w.wait_ready()
        sensor = Worker("bench.latency_sensor", {**sensor_cfg, **targets[0], "targets": targets})
        sensed = sensor.result(timeout_s)
        served = [w.result(30.0) for w in servers]
        return served, sensed
    finally:
        for worker in (sensor, *servers):
            if worker is not None:
                worker.kill()


# ---------------------------------------------------------------------------------------------
# Measurements (each returns a JSON-able dict; the test suite calls them with small counts)


SERVERS: dict[str, dict[str, Any]] = {
    "echo": {"role": "echo"},
    "as_run": {"role": "controller", "mode": "event", "trigger": "range/front",
               "instrument": False},
    "controller": {"role": "controller", "mode": "event", "trigger": "range/front",
                   "loop": "lending"},
    "plain_loop": {"role": "controller", "mode": "event", "trigger": "range/front",
                   "loop": "asyncio"},
    "tree_echo": {"role": "tree_echo"},
}
"""What answers the round trips: the raw echo (the floor); the controller in event mode (its
tick runs inside ingest) as it runs for a user (``as_run``: no observers, the default event
loop), the same observed through its hooks on the lending loop (``controller``: where the time
goes) and observed on asyncio's plain loop (``plain_loop``: every sample handed to the loop
thread); and the Python floor (``tree_echo``: the same tree evaluated in the echo's zenoh
callback). Section 8 adds ``loop_<name>``: ``as_run`` on each event loop."""

BASELINE_LOOP = "asyncio"
"""Section 8's baseline: asyncio's plain loop."""
LOOPS = (BASELINE_LOOP, "lending", "uvloop")
"""The event loops section 8 compares (:data:`ubf_async.cli.run.LOOP_CHOICES`)."""
for _loop in LOOPS:
    SERVERS[f"loop_{_loop}"] = {**SERVERS["as_run"], "loop": _loop}

REFLEX_SERVERS = ("echo", "as_run", "controller", "plain_loop", "tree_echo")
BASELINE_SERVER = "baseline"
"""``as_run`` from another checkout (``--baseline DIR``): before and after in the same rounds."""


def use_baseline(tree: str | None) -> tuple[str, ...]:
    """The reflex section's servers, with ``as_run`` from the checkout ``tree`` added."""
    if not tree:
        return REFLEX_SERVERS
    SERVERS[BASELINE_SERVER] = {**SERVERS["as_run"], "tree": str(Path(tree).resolve())}
    return (*REFLEX_SERVERS, BASELINE_SERVER)

CONTROLLERS: dict[str, tuple[str, dict[str, Any]]] = {
    # Section 4's controllers: (label, server config).
    "sync": ("sync (tick waits for camera frame)", {"mode": "sync"}),
    "default": ("async, default: periodic 50 Hz + reflex range/",
                {"mode": "periodic", "rate_hz": 50.0, "reflex": ["range/"]}),
    "periodic": ("async, periodic 50 Hz, no reflex", {"mode": "periodic", "rate_hz": 50.0}),
    "event": ("async, event mode on range/front", {"mode": "event", "trigger": "range/front"}),
}


def measure_rtt(*servers: str, rate_hz: float, warmup: int, count: int
                ) -> dict[str, dict[str, Any]]:
    """Round trips of ``range/front`` samples answered by each server (names of
    :data:`SERVERS`), interleaved in one run; returns a result per server name."""
    budget = 30 + (warmup + count) * len(servers) * (1.0 / rate_hz if rate_hz else 0.005) * 2
    served, sensed = serve_and_measure(
        [SERVERS[name] for name in servers],
        {"scenario": "rtt", "rate_hz": rate_hz, "warmup": warmup, "count": count},
        timeout_s=budget,
    )
    return {name: rtt_result(name, srv, sen)
            for name, srv, sen in zip(servers, served, sensed["targets"], strict=True)}


def rtt_result(server: str, served: dict[str, Any], sensed: dict[str, Any]) -> dict[str, Any]:
    rows = sensed["rows"]
    answered = [r for r in rows if r[3] is not None]
    out: dict[str, Any] = {
        "sent": len(rows), "answered": len(answered), "lost": len(rows) - len(answered),
        "duplicates": sensed["duplicates"], "unmatched": sensed["unmatched"],
        "mismatched": sensed["mismatched"],
        "rtt": summarize(r[3] - r[1] for r in answered),
        "rtt_ns": [r[3] - r[1] for r in answered],
        # Split at the drive command's own stamp (taken before it is encoded, by every
        # server): what happens before it, and what after.
        "inbound_ns": [r[2] - r[1] for r in answered],
        "outbound_ns": [r[3] - r[2] for r in answered],
    }
    if "triggered" in served:  # a controller
        out["controller"] = {k: served.get(k) for k in (
            "overruns", "errors", "malformed", "coalesced", "received", "triggered", "direct",
            "lane", "lane_waited", "lane_busy", "lane_deferred")}
    if served.get("samples"):  # observed through the hooks
        out["segments_ns"] = reflex_segments(answered, served)
        out["segments"] = {k: summarize(v) for k, v in out["segments_ns"].items()}
        # Account for every unanswered sample: superseded by a newer one before the loop
        # got to it (the bridge keeps the newest per key), stored but never ticked on, or
        # lost after its tick (neither seen so far).
        delivered = {x[1] for x in served["samples"] if x[0] == "range/front"}
        ticked = {t[4] for t in served["ticks"] if t[3] == "range/front"}
        missing = [r[0] for r in rows if r[3] is None]
        out["coalesced_by_bridge"] = sum(1 for q in missing if q not in delivered)
        out["skipped_by_controller"] = sum(1 for q in missing if q in delivered
                                           and q not in ticked)
        out["lost_after_tick"] = sum(1 for q in missing if q in ticked)
    return out


SEGMENTS = (
    "sensor put → controller zenoh callback",
    "callback → handler (lane / hand-off)",
    "decode + validate",
    "ingest: store the sample",
    "stored → tick start",
    "snapshot + evaluate tree",
    "drive publish: encode + zenoh put",
    "rest of the tick (extras, stats)",
    "command: put returned → sensor callback",
    "controller residence (callback → put)",
    "tick total",
)
"""Segments of a reflex round trip, in path order (the last two are sums)."""


def reflex_segments(rows: list[list[int]], served: dict[str, Any]) -> dict[str, list[int]]:
    """Join the sensor's rows with the controller's instrumentation by sample seq.

    The drive command's stamp is taken inside ``publish``, before encoding; ``put`` is when
    that call returned (the controller's ``on_tick`` hook runs right after it). ``stored →
    tick start`` is the ``on_sample`` hook dispatch (the tick runs inside ingest)."""
    samples = {s[1]: s for s in served["samples"] if s[0] == "range/front"}
    ticks = {t[4]: t for t in served["ticks"] if t[3] == "range/front"}
    seg: dict[str, list[int]] = {k: [] for k in SEGMENTS}
    for seq, stamp, cmd_stamp, received in rows:
        s, t = samples.get(seq), ticks.get(seq)
        if s is None or t is None or t[1] is None or t[9] is None:
            continue
        _, _, cb, h0, i0, stored = s
        t0, t1, put = t[0], t[1], t[9]
        values = (cb - stamp, h0 - cb, i0 - h0, stored - i0, t0 - stored, cmd_stamp - t0,
                  put - cmd_stamp, t1 - put, received - put, put - cb, t1 - t0)
        for key, value in zip(SEGMENTS, values, strict=True):
            seg[key].append(value)
    return seg


SPLIT = ("inbound_ns", "outbound_ns")
"""Each round trip split at the drive command's stamp: sample stamp → command stamp (the
sample's way in and the work before the command), command stamp → the sensor's callback
(encoding, the put, the way back)."""

_SUMMED = ("sent", "answered", "lost", "duplicates", "unmatched", "mismatched",
           "coalesced_by_bridge", "skipped_by_controller", "lost_after_tick")


def measure_rtt_rounds(*servers: str, rounds: int, rate_hz: float, warmup: int, count: int,
                       log: Callable[[str], None] = lambda _: None) -> dict[str, dict[str, Any]]:
    """:func:`measure_rtt` in ``rounds`` rounds, the servers' order (so their place in the
    interleaving) rotating each round; every count summed, every sample pooled, and each
    round's median kept (``round_medians_us``) for the spread of per-round ratios."""
    pooled: dict[str, dict[str, Any]] = {}
    for r in range(rounds):
        order = servers[r % len(servers):] + servers[:r % len(servers)]
        log(f"    round {r + 1}/{rounds}: {', '.join(order)}")
        got = measure_rtt(*order, rate_hz=rate_hz, warmup=warmup, count=count)
        for name in servers:
            g, acc = got[name], pooled.setdefault(name, {"round_medians_us": []})
            for key in _SUMMED:
                if key in g:
                    acc[key] = acc.get(key, 0) + g[key]
            for key in ("rtt_ns", *SPLIT):
                acc.setdefault(key, []).extend(g[key])
            if g["rtt_ns"]:
                acc["round_medians_us"].append(statistics.median(g["rtt_ns"]) / 1e3)
            if "controller" in g:
                ctl = acc.setdefault("controller", {})
                for key, value in g["controller"].items():
                    ctl[key] = (ctl.get(key) or 0) + (value or 0)
            for key, values in g.get("segments_ns", {}).items():
                acc.setdefault("segments_ns", {}).setdefault(key, []).extend(values)
    for acc in pooled.values():
        acc["rtt"] = summarize(acc["rtt_ns"])
        for key in SPLIT:
            acc[key.removesuffix("_ns")] = summarize(acc[key])
        if "segments_ns" in acc:
            acc["segments"] = {k: summarize(v) for k, v in acc["segments_ns"].items()}
    return pooled


def measure_periodic_ages(rate_hz: float, *, warmup: int, count: int,
                          interval_s: tuple[float, float] = (0.025, 0.055)) -> dict[str, Any]:
    """Samples at random moments (slower than the tick); for each, the age of the sample when
    the first command based on it was published (command stamp − sample stamp) and when it
    was received back by the sensor."""
    budget = 30 + (warmup + count) * interval_s[1] * 2
    (served,), sensed = serve_and_measure(
        [{"role": "controller", "mode": "periodic", "rate_hz": rate_hz}],
        {"scenario": "ages", "interval_lo_s": interval_s[0], "interval_hi_s": interval_s[1],
         "warmup": warmup, "count": count},
        timeout_s=budget,
    )
    rows = sensed["rows"]
    used = [r for r in rows if r[2] is not None]
    clock_ticks = [t for t in served["ticks"] if not t[8]]
    # The controller's side (its own clock, one process): when each sample was stored, and
    # when the clock ticks started (each reads the newest sample stored before it started).
    stored = {s[1]: s[5] for s in served["samples"] if s[0] == "range/front"}
    starts = sorted(t[0] for t in clock_ticks)
    waits, missed = [], 0
    for seq, _, *command in rows:
        if seq not in stored:
            continue
        at = stored[seq]
        first = bisect.bisect_right(starts, at)
        if first == len(starts):
            continue
        superseded = stored.get(seq + 1)
        if superseded is not None and starts[first] > superseded:
            continue  # a newer sample came before any tick: nothing could command this one
        if command[0] is None:
            missed += 1  # newest when a tick started, yet no command was based on it
        else:
            waits.append(starts[first] - at)
    return {
        "rate_hz": rate_hz, "samples": len(rows), "commanded": len(used),
        "never_commanded": len(rows) - len(used),
        "missed_while_newest": missed,
        "wait_for_tick": summarize(waits),
        "age_at_publish": summarize(r[2] - r[1] for r in used),
        "age_at_publish_ns": [r[2] - r[1] for r in used],
        "age_at_receipt": summarize(r[3] - r[1] for r in used),
        "tick_jitter_wall": tick_jitter([t[0] for t in clock_ticks], 1e9 / rate_hz),
        "overruns": served["overruns"],
    }


def tick_jitter(starts_ns: list[int], period_ns: float) -> dict[str, Any]:
    """|interval − period| between consecutive tick starts."""
    return summarize(abs((b - a) - period_ns) for a, b in itertools.pairwise(starts_ns))


def measure_sim_jitter(rate_hz: float, *, duration_s: float, warmup_s: float = 1.0
                       ) -> dict[str, Any]:
    """The whole simulated robot plus the launch's default controller (periodic at
    ``rate_hz``, reflexes on ``range/``) in one process. Jitter and the tick count are of the
    clock's ticks; the reflex ticks the simulated IR triggers are counted apart."""
    worker = Worker("bench.latency_robot", {
        "role": "simrobot", "rate_hz": rate_hz, "duration_s": duration_s,
        "warmup_s": warmup_s, "endpoint": free_endpoint(), "robot": f"sim{os.getpid()}",
    })
    try:
        res = worker.result(60 + duration_s * 3)
    finally:
        worker.kill()
    ticks = res["ticks"]
    clock_ticks = [t for t in ticks if not t[8]]
    period = 1e9 / rate_hz
    sim_intervals = [b[2] - a[2] for a, b in itertools.pairwise(clock_ticks)]
    wall = [t[0] for t in clock_ticks]
    newest_age = [t[2] - t[5] for t in clock_ticks if t[5] is not None]
    # Camera path in simulated time: capture stamp → the first tick that saw the frame.
    camera_age: dict[int, int] = {}
    for t in ticks:
        if t[6] > 0 and t[6] not in camera_age:
            camera_age[t[6]] = t[2] - t[7]
    if ticks and ticks[0][6] in camera_age:
        del camera_age[ticks[0][6]]  # seen before the measurement began
    return {
        "rate_hz": rate_hz, "ticks": len(clock_ticks),
        "reflex_ticks": len(ticks) - len(clock_ticks),
        "sim_s": res["sim_s"], "wall_s": res["wall_s"],
        "real_time_factor": res["sim_s"] / res["wall_s"] if res["wall_s"] else None,
        "late_steps": res["late_steps"], "overruns": res["overruns"],
        "step_s": res["step_s"], "camera_frames": res["camera_frames"],
        "jitter_wall": tick_jitter(wall, period),
        "jitter_sim": summarize(abs(i - period) for i in sim_intervals),
        "sim_interval_min_ns": min(sim_intervals) if sim_intervals else None,
        "sim_interval_median_ns": statistics.median(sim_intervals) if sim_intervals else None,
        "newest_age_sim": summarize(newest_age),
        "camera_age_sim": summarize(camera_age.values()),
    }


def measure_robot(controller: str, *, trials: int, frames: int = 0, seed: int = 2,
                  loop: str | None = None) -> dict[str, Any]:
    """IR + camera stand-ins against one of :data:`CONTROLLERS` ("sync", "default",
    "periodic", "event"). With ``trials`` > 0: obstacle reactions; camera path in any case
    (without trials the IR stays silent unless the controller needs it as its trigger).
    ``loop``: the controller's event loop (default: the entry points' default)."""
    server: dict[str, Any] = {"role": "controller", **CONTROLLERS[controller][1]}
    if loop is not None:
        server["loop"] = loop
    budget = 60 + trials * 3.0 + frames * CAMERA_PERIOD_S * 2
    (served,), sensed = serve_and_measure(
        [server],
        {"scenario": "robot", "trials": trials, "frames": frames, "seed": seed,
         "ir_period_s": IR_PERIOD_S if trials or controller == "event" else None,
         "camera_period_s": CAMERA_PERIOD_S},
        timeout_s=budget,
    )
    reactions = sensed["reactions"]
    reacted = [r for r in reactions if r["command_ns"] is not None]
    cameras = {c[0]: c for c in sensed["cameras"]}
    first_cmd: dict[int, tuple[int, int]] = {}
    for received, cmd_stamp, based_seq in sensed["camera_commands"]:
        if based_seq in cameras and based_seq not in first_cmd:
            first_cmd[based_seq] = (cmd_stamp, received)
    capture_to_cmd = [first_cmd[s][0] - cameras[s][1] for s in first_cmd]
    publish_to_cmd = [first_cmd[s][0] - cameras[s][2] for s in first_cmd]
    return {
        "controller": controller, **CONTROLLERS[controller][1],
        "ticks": len(served["ticks"]), "triggered": served["triggered"],
        "trials": len(reactions), "reacted": len(reacted),
        "missed": len(reactions) - len(reacted),
        "reaction_at_publish": summarize(r["command_ns"] - r["reading_ns"] for r in reacted),
        "reaction": summarize(r["received_ns"] - r["reading_ns"] for r in reacted),
        "reaction_ns": [r["received_ns"] - r["reading_ns"] for r in reacted],
        "camera_frames": len(cameras), "camera_commanded": len(first_cmd),
        "capture_to_command": summarize(capture_to_cmd),
        "camera_publish_to_command": summarize(publish_to_cmd),
    }


def available_loops() -> tuple[str, ...]:
    """:data:`LOOPS` without uvloop when it is not installed."""
    try:
        import uvloop  # noqa: F401
    except ImportError:
        return tuple(x for x in LOOPS if x != "uvloop")
    return LOOPS


LOOP_PATHS = {
    "reflex_100hz": "reflex round trip, 100 Hz",
    "reflex_b2b": "reflex round trip, back-to-back",
    "obstacle": "obstacle reaction, default controller",
}
"""Section 8's paths: the reflex (event mode, the controller as it runs, no observers) and
the launch's default controller (periodic 50 Hz + reflex on ``range/``) reacting to an
obstacle."""


def measure_loops(loops: tuple[str, ...], *, rounds: int, warmup: int, count: int,
                  b2b: int, trials: int, log: Callable[[str], None] = lambda _: None
                  ) -> dict[str, Any]:
    """Each path of :data:`LOOP_PATHS` on each event loop, in ``rounds`` rounds; the loops'
    order rotates every round, and the reflex's servers answer interleaved samples. Returns
    the pooled summaries, the per-round medians and ratios to :data:`BASELINE_LOOP`."""
    pooled: dict[str, dict[str, list[int]]] = {p: {x: [] for x in loops} for p in LOOP_PATHS}
    medians: dict[str, dict[str, list[float]]] = {p: {x: [] for x in loops}
                                                  for p in LOOP_PATHS}
    sent = {x: 0 for x in loops}
    lost = {x: 0 for x in loops}
    lent = {x: 0 for x in loops}
    lane = {x: 0 for x in loops}
    missed = {x: 0 for x in loops}

    def keep(path: str, loop: str, values: list[int]) -> None:
        pooled[path][loop].extend(values)
        if values:
            medians[path][loop].append(statistics.median(values) / 1e3)

    for r in range(rounds):
        order = loops[r % len(loops):] + loops[:r % len(loops)]
        log(f"    round {r + 1}/{rounds}: {', '.join(order)}")
        for path, rate, n in (("reflex_100hz", 100, count), ("reflex_b2b", 0, b2b)):
            got = measure_rtt(*(f"loop_{x}" for x in order), rate_hz=rate, warmup=warmup,
                              count=n)
            for x in order:
                g = got[f"loop_{x}"]
                keep(path, x, g["rtt_ns"])
                sent[x] += g["sent"]
                lost[x] += g["lost"]
                lent[x] += g["controller"]["direct"] or 0
                lane[x] += g["controller"].get("lane") or 0
        for x in order:
            o = measure_robot("default", trials=trials, seed=2 + r, loop=x)
            keep("obstacle", x, o["reaction_ns"])
            missed[x] += o["missed"]
    out: dict[str, Any] = {"loops": list(loops), "rounds": rounds, "baseline": BASELINE_LOOP,
                           "sent": sent, "lost": lost, "lent": lent, "lane": lane,
                           "obstacles_missed": missed,
                           "paths": {}}
    for path in LOOP_PATHS:
        base = summarize(pooled[path][BASELINE_LOOP]) if BASELINE_LOOP in loops else None
        per: dict[str, Any] = {}
        for x in loops:
            summary = summarize(pooled[path][x])
            round_ratios = [a / b for a, b in zip(medians[path][x],
                                                  medians[path].get(BASELINE_LOOP, []),
                                                  strict=False) if b]
            per[x] = {**summary, "round_medians_us": medians[path][x],
                      "ratio_median": ratio(summary, base),
                      "ratio_p99": ratio(summary, base, "p99_us"),
                      "round_ratio_lo": min(round_ratios, default=None),
                      "round_ratio_hi": max(round_ratios, default=None)}
        out["paths"][path] = per
    return out


def measure_ours_sizes(*, sizes: tuple[int, ...], warmup: int, count: int
                       ) -> dict[int, list[int]]:
    """One-way latency of each size through our path (a :class:`Bus` raw publisher in one
    process, a :class:`Bus` subscription's handler on the event loop in another), dora's
    method (``bench.latency_dora``)."""
    target = {"endpoint": free_endpoint(), "robot": f"sizes{os.getpid()}"}
    cfg = {**target, "sizes": list(sizes), "warmup": warmup, "count": count}
    receiver = Worker("bench.latency_dora", {**cfg, "side": "receiver"})
    sender: Worker | None = None
    try:
        receiver.wait_ready()
        sender = Worker("bench.latency_dora", {**cfg, "side": "sender"})
        sender.result(60 + len(sizes) * (warmup + count) * 0.05)
        got = receiver.result(30)
    finally:
        for w in (sender, receiver):
            if w is not None:
                w.kill()
    return {int(k): v for k, v in got["values"].items()}


def measure_dora_section(*, rounds: int, warmup: int, count: int,
                         log: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """dora-rs's own benchmark on its terms (its sizes, its method: the sender's
    ``perf_counter_ns`` in the payload, one-way) for our path and dora's Python nodes, taking
    turns in ``rounds`` rounds (the one first alternating), pooled per size."""
    from bench.latency_dora import (
        DORA_PUBLISHED_US,
        DORA_SIZES,
        OURS_LIMIT_BYTES,
        run_dora_sizes,
    )

    pooled: dict[str, dict[int, list[int]]] = {"ours": {}, "dora": {}}
    dora_version, skipped = None, None
    for r in range(rounds):
        order = ("ours", "dora") if r % 2 == 0 else ("dora", "ours")
        log(f"    round {r + 1}/{rounds}: {', '.join(order)}")
        for who in order:
            if who == "ours":
                values = measure_ours_sizes(sizes=tuple(x for x in DORA_SIZES
                                                        if x <= OURS_LIMIT_BYTES),
                                            warmup=warmup, count=count)
            else:
                if skipped:
                    continue
                d = run_dora_sizes(sizes=DORA_SIZES, warmup=warmup, count=count)
                if "skipped" in d:
                    skipped = d["skipped"]
                    continue
                values, dora_version = d["values"], d["version"]
            for size, v in values.items():
                pooled[who].setdefault(size, []).extend(v)
    out: dict[str, Any] = {
        "rounds": rounds, "count_per_round": count, "sizes": list(DORA_SIZES),
        "ours_limit_bytes": OURS_LIMIT_BYTES,
        "published_us": DORA_PUBLISHED_US,
        "ours": {size: summarize(pooled["ours"].get(size, ())) for size in DORA_SIZES}}
    out["dora"] = ({"skipped": skipped} if skipped else
                   {"version": dora_version, **{size: summarize(pooled["dora"].get(size, ()))
                                                 for size in DORA_SIZES}})
    return out


def dora_report(d: dict[str, Any]) -> list[str]:
    def size_label(n: int) -> str:
        return (f"{n // 1_048_576} MB" if n >= 1_048_576 and n % 1_048_576 == 0 else
                f"{n // 1024} KB" if n >= 1024 else f"{n} B")

    dora = d["dora"]
    out = [f"9. dora-rs's benchmark on its own terms: one-way latency, the sender's "
           f"perf_counter_ns in the payload, one sample every 10 ms, {d['count_per_round']} "
           f"per size and round, {d['rounds']} rounds taking turns (pooled)",
           "   ours: Bus raw publisher → zenoh → Bus subscription → handler on the event loop "
           "(default loop)"]
    if "skipped" in dora:
        out.append(f"   dora-rs Python nodes: skipped — {dora['skipped']}")
    else:
        out.append(f"   dora: two Python nodes in one `dora run` dataflow ({dora['version']})")
    out.append(f"  {'size':>7}  {'ours median':>11} {'p90':>8} {'p99':>8} {'mean':>8}"
               f"   {'dora median':>11} {'p99':>8} {'mean':>8}  {'ours/dora':>9}"
               f"  {'published (dora, mean)':>22}")
    for size in d["sizes"]:
        o = d["ours"][size] if size in d["ours"] else d["ours"].get(str(size), {})
        x = dora.get(size, dora.get(str(size), {})) if "skipped" not in dora else {}
        q = ratio(o, x)
        pub = d["published_us"].get(size, d["published_us"].get(str(size)))
        ours = (f"{fmt_us(o.get('median_us')):>11} {fmt_us(o.get('p90_us')):>8} "
                f"{fmt_us(o.get('p99_us')):>8} {fmt_us(o.get('mean_us')):>8}"
                if size <= d["ours_limit_bytes"] else f"{'refused by design (> 256 KiB)':>38}")
        out.append(f"  {size_label(size):>7}  {ours}   {fmt_us(x.get('median_us')):>11} "
                   f"{fmt_us(x.get('p99_us')):>8} {fmt_us(x.get('mean_us')):>8}  "
                   f"{(f'{q:.2f}×' if q else '—'):>9}  "
                   f"{(f'{pub} µs' if pub else '—'):>22}")
    out.append("   published: dora-rs/dora-benchmark, Python nodes, average of 1 000 samples per "
               "size on its authors' machine (not this one; its pacing and hardware differ)")
    return out


def measure_peers(*, warmup: int, count: int, ticks: int) -> dict[str, Any]:
    from bench.latency_dora import run_dora
    from bench.tick import (
        SIZES,
        Constant,
        HighestActivation,
        py_trees_selector,
        time_per_call,
        ubf_tree,
    )
    from ubf_async import Composite, State

    dora = run_dora(warmup=warmup, count=count)
    if "rtt_ns" in dora:
        dora["rtt"] = summarize(dora["rtt_ns"])
    state = State.of(now_ns=0, camera__front={"bins": [0, 3, 140, 5, 0], "total": 148})
    rows = []
    for n in SIZES:
        tree = ubf_tree(n, HighestActivation, Constant)

        # A def, not a lambda: mypy cannot type a lambda's default arguments.
        def evaluate(tree: Composite = tree) -> object:
            return tree.evaluate(state)

        ubf = statistics.median(time_per_call(evaluate, ticks))
        pt = py_trees_selector(n)
        rows.append({"children": n, "ubf_us": ubf,
                     "py_trees_us": statistics.median(time_per_call(pt, ticks)) if pt else None})
    return {"dora": dora, "tick": rows,
            "py_trees": "installed" if rows[0]["py_trees_us"] is not None else "skipped"}


def measure_breakdown(n: int = 2000) -> dict[str, Any]:
    """In-process costs of each piece of the reflex path, timed directly."""
    import msgpack
    import zenoh

    from bench.latency_robot import reflex_tree
    from ubf_async.clocks.clock import WallClock
    from ubf_async.net.options import ConnectionOptions
    from ubf_async.runtime.aggregator import StateAggregator
    from ubf_async.runtime.bus import Subscription
    from ubf_async.wire.keys import Keys
    from ubf_async.wire.protocol import decode, encode

    out: dict[str, Any] = {}
    sample = msgpack.packb({"schema": "range", "v": 1, "stamp_ns": time.monotonic_ns(),
                            "seq": 1, "period_s": 0.01,
                            "data": {"range_mm": 500, "status": "ok"}})

    def timed(fn: Callable[[], object], reps: int = n) -> dict[str, Any]:
        for _ in range(100):
            fn()
        values = []
        for _ in range(reps):
            t0 = time.perf_counter_ns()
            fn()
            values.append(time.perf_counter_ns() - t0)
        return summarize(values)

    out["decode range sample"] = timed(lambda: decode(sample))
    drive = {"speed": 0.0, "turn": 0.0, "based_on": {"source": "range/front", "seq": 1,
                                                     "stamp_ns": 1}, "tick": 1,
             "winners": ["avoid"]}
    out["encode drive command"] = timed(lambda: encode("drive", drive, stamp_ns=1, seq=1))

    class _Bus:  # just what StateAggregator.snapshot needs
        clock = WallClock()
        keys = Keys("mini")

    agg = StateAggregator(bus=_Bus())  # type: ignore[arg-type]
    agg.ingest("range/front", decode(sample), time.monotonic_ns())
    tree = reflex_tree()
    out["snapshot + evaluate tree"] = timed(lambda: tree.evaluate(agg.snapshot()))

    # zenoh, same session: put → subscriber callback, and the cost of put() itself.
    session = zenoh.open(ConnectionOptions(listen=[free_endpoint()]).zenoh_config())
    got = threading.Event()
    seen: list[int] = []

    def on_sample(s: zenoh.Sample) -> None:
        seen.append(time.monotonic_ns())
        got.set()

    sub = session.declare_subscriber("bench/latency/local", on_sample)
    pub = session.declare_publisher("bench/latency/local")
    deliver, put_cost = [], []
    for i in range(n + 100):
        got.clear()
        t0 = time.monotonic_ns()
        pub.put(sample)
        t1 = time.monotonic_ns()
        if not got.wait(1.0):
            continue
        if i >= 100:
            deliver.append(seen[-1] - t0)
            put_cost.append(t1 - t0)
    sub.undeclare()
    pub.undeclare()
    session.close()
    out["zenoh same session: put → callback"] = summarize(deliver)
    out["zenoh put() call"] = summarize(put_cost)

    # The bridge: a foreign thread pushes, the loop handler runs (an idle loop).
    async def bridge() -> list[int]:
        loop = asyncio.get_running_loop()
        lags: list[int] = []
        handled = threading.Event()

        def handler(key: str, payload: bytes, received_ns: int) -> None:
            lags.append(time.monotonic_ns() - received_ns)
            handled.set()

        sub = Subscription(loop, handler, latest=True)

        def pusher() -> None:
            for _ in range(n + 100):
                handled.clear()
                sub.push("k", sample)
                handled.wait(1.0)

        await asyncio.to_thread(pusher)
        return lags[100:]

    out["bridge hand-off, idle loop"] = summarize(asyncio.run(bridge()))
    return out


# ---------------------------------------------------------------------------------------------
# The run


def counts(quick: bool) -> dict[str, Any]:
    if quick:
        return {"warm": 30, "rtt": 150, "b2b": 200, "reflex_rounds": 2, "dora_rounds": 2,
                "dora_count": 40, "ages": 40, "sim_s": 2.0,
                "sync_trials": 10, "default_trials": 12, "periodic_trials": 12,
                "event_trials": 12, "frames": 15, "dora": 200, "ticks": 300, "micro": 500,
                "loop_rounds": 3, "loop_rtt": 150, "loop_b2b": 200, "loop_trials": 6}
    return {"warm": 200, "rtt": 500, "b2b": 800, "reflex_rounds": 4, "dora_rounds": 3,
            "dora_count": 150, "ages": 300, "sim_s": 10.0,
            "sync_trials": 60, "default_trials": 100, "periodic_trials": 100,
            "event_trials": 100, "frames": 100, "dora": 1500, "ticks": 2000, "micro": 2000,
            "loop_rounds": 8, "loop_rtt": 500, "loop_b2b": 800, "loop_trials": 12}


def run(sections: tuple[str, ...], quick: bool, log: Callable[[str], None],
        rounds: int | None = None, baseline: str | None = None) -> dict[str, Any]:
    c = counts(quick)
    if rounds is not None:
        c["loop_rounds"] = c["reflex_rounds"] = c["dora_rounds"] = rounds
    res: dict[str, Any] = {
        "date": datetime.date.today().isoformat(), "cores": os.cpu_count(),
        "python": sys.version.split()[0], "quick": quick, "counts": c,
        "loadavg_start": os.getloadavg(),
    }
    try:
        res["zenoh"] = importlib.metadata.version("eclipse-zenoh")
    except importlib.metadata.PackageNotFoundError:
        res["zenoh"] = "?"
    step = 0

    def progress(what: str) -> None:
        nonlocal step
        step += 1
        log(f"[{step}] {what} …")

    if "floor" in sections or "reflex" in sections:
        names = use_baseline(baseline) if "reflex" in sections else ("echo",)
        n = c["reflex_rounds"]
        res["reflex_rounds"] = n
        progress(f"{', '.join(names)}, interleaved, 100 Hz, {n} rounds")
        at_rate = measure_rtt_rounds(*names, rounds=n, rate_hz=100, warmup=c["warm"],
                                     count=c["rtt"], log=log)
        progress(f"{', '.join(names)}, interleaved, back-to-back, {n} rounds")
        b2b = measure_rtt_rounds(*names, rounds=n, rate_hz=0, warmup=c["warm"],
                                 count=c["b2b"], log=log)
        res["floor_100hz"], res["floor_b2b"] = at_rate["echo"], b2b["echo"]
        if "as_run" in names:
            res["reflex_100hz"], res["reflex_b2b"] = at_rate["as_run"], b2b["as_run"]
            for name in ("controller", "plain_loop", "tree_echo", BASELINE_SERVER):
                if name in names:
                    res[f"{name}_100hz"], res[f"{name}_b2b"] = at_rate[name], b2b[name]
    if "periodic" in sections:
        for hz in (50, 100):
            progress(f"periodic mode {hz} Hz (no reflex), sample age at command")
            res[f"periodic_{hz}hz"] = measure_periodic_ages(hz, warmup=10, count=c["ages"])
        for hz in (50, 100):
            progress(f"tick jitter at {hz} Hz with the full simulated robot")
            res[f"sim_{hz}hz"] = measure_sim_jitter(hz, duration_s=c["sim_s"])
    if "obstacle" in sections or "camera" in sections:
        for name, (label, _) in CONTROLLERS.items():
            progress(f"obstacle reaction, {label}")
            res[f"obstacle_{name}"] = measure_robot(name, trials=c[f"{name}_trials"])
    if "camera" in sections:
        progress("camera path, default controller (periodic 50 Hz)")
        res["camera_periodic"] = measure_robot("default", trials=0, frames=c["frames"])
    if "peers" in sections:
        progress("peers: dora-rs reflex round trip, py_trees tick cost")
        res["peers"] = measure_peers(warmup=c["warm"], count=c["dora"], ticks=c["ticks"])
    if "breakdown" in sections:
        progress("in-process breakdown")
        res["breakdown"] = measure_breakdown(c["micro"])
    if "dora" in sections:
        progress(f"dora-rs's benchmark at its sizes, ours and dora's taking turns, "
                 f"{c['dora_rounds']} rounds")
        res["dora_sizes"] = measure_dora_section(rounds=c["dora_rounds"], warmup=10,
                                                 count=c["dora_count"], log=log)
    if "loops" in sections:
        loops = available_loops()
        progress(f"event loops {', '.join(loops)}: {c['loop_rounds']} rounds, order rotating")
        res["loops"] = measure_loops(loops, rounds=c["loop_rounds"], warmup=c["warm"] // 4,
                                     count=c["loop_rtt"], b2b=c["loop_b2b"],
                                     trials=c["loop_trials"], log=log)
    res["loadavg_end"] = os.getloadavg()
    res["ratios"] = ratios(res)
    return res


def ratios(res: dict[str, Any]) -> dict[str, Any]:
    """The ratios the issue asks for, with whether each aim was met."""
    out: dict[str, Any] = {}

    def put(name: str, a: str, b: str, key: str = "median_us", field: str = "rtt") -> None:
        if a in res and b in res:
            out[name] = ratio(res[a][field], res[b][field], key)

    put("reflex_over_floor_median", "reflex_100hz", "floor_100hz")
    put("reflex_over_floor_p99", "reflex_100hz", "floor_100hz", "p99_us")
    put("reflex_over_floor_b2b_median", "reflex_b2b", "floor_b2b")
    put("observed_over_floor_median", "controller_100hz", "floor_100hz")
    put("plain_loop_over_floor_median", "plain_loop_100hz", "floor_100hz")
    put("python_floor_over_floor_median", "tree_echo_100hz", "floor_100hz")
    put("reflex_over_python_floor_median", "reflex_100hz", "tree_echo_100hz")
    put("reflex_over_python_floor_p99", "reflex_100hz", "tree_echo_100hz", "p99_us")
    put("baseline_over_python_floor_median", "baseline_100hz", "tree_echo_100hz")
    put("baseline_over_python_floor_p99", "baseline_100hz", "tree_echo_100hz", "p99_us")
    put("sync_over_default_median", "obstacle_sync", "obstacle_default", field="reaction")
    put("sync_over_periodic50_no_reflex_median", "obstacle_sync", "obstacle_periodic",
        field="reaction")
    put("sync_over_event_median", "obstacle_sync", "obstacle_event", field="reaction")
    dora = res.get("peers", {}).get("dora", {})
    if "rtt" in dora and "reflex_100hz" in res:
        out["reflex_over_dora_median"] = ratio(res["reflex_100hz"]["rtt"], dora["rtt"])
    if out.get("reflex_over_floor_median") is not None:
        out["aim_reflex_le_1.25x_met"] = out["reflex_over_floor_median"] <= REFLEX_AIM
    pf = [out.get(f"reflex_over_python_floor_{k}") for k in ("median", "p99")]
    if all(x is not None for x in pf):
        out["aim_reflex_le_1.10x_python_floor_met"] = all(
            x <= REFLEX_AIM_PYTHON_FLOOR for x in pf if x is not None)
    if out.get("reflex_over_dora_median") is not None:
        out["aim_reflex_2x_faster_than_dora_met"] = out["reflex_over_dora_median"] <= 0.5
    if out.get("sync_over_default_median") is not None:
        out["aim_sync_over_async_ge_20x_met"] = out["sync_over_default_median"] >= 20
    return out


def _aim(value: float | None, goal: str, ok: bool) -> str:
    if value is None:
        return ""
    return f"{value:.2f}×  (aim {goal}: {'met' if ok else 'MISSED'})"


def report(res: dict[str, Any]) -> str:
    lines: list[str | None] = [
        f"ubf_async latency — {res['date']}, {res['cores']} cores, Python {res['python']}, "
        f"zenoh {res.get('zenoh', '?')}{' (quick run)' if res['quick'] else ''}",
        "All figures: monotonic ns stamps carried in the messages, warm-up discarded.",
        "Load average (1/5/15 min) at start {} and end {}.".format(
            " ".join(f"{x:.2f}" for x in res["loadavg_start"]),
            " ".join(f"{x:.2f}" for x in res.get("loadavg_end", ()))),
        "", header()]
    add = lines.append

    def lost_note(r: dict[str, Any]) -> str:
        note = f"lost {r['lost']}/{r['sent']}"
        if r["lost"] and "coalesced_by_bridge" in r:
            note += (f" (superseded: {r['coalesced_by_bridge']} in the bridge, "
                     f"{r['skipped_by_controller']} by the controller; "
                     f"after tick: {r['lost_after_tick']})")
        return note + f", dup {r['duplicates']}, mismatched {r['mismatched']}"

    if "floor_100hz" in res:
        add("1. Transport floor: raw zenoh round trip, 2 processes, loopback TCP")
        add(row("at 100 Hz", res["floor_100hz"]["rtt"], lost_note(res["floor_100hz"])))
        add(row("back-to-back (servers taking turns)", res["floor_b2b"]["rtt"],
                lost_note(res["floor_b2b"])))
    if "reflex_100hz" in res:
        r, rb = res["reflex_100hz"], res["reflex_b2b"]
        floor, floor_b2b = res["floor_100hz"]["rtt"], res["floor_b2b"]["rtt"]
        add("2. Reflex path: sensor process → controller (event mode, tick inside ingest) → "
            "sensor process (interleaved with 1)")
        add(row("at 100 Hz", r["rtt"], lost_note(r)))
        add(row("back-to-back (servers taking turns)", rb["rtt"], lost_note(rb)))
        q = ratio(r["rtt"], floor)
        verdict = _aim(q, f"≤ {REFLEX_AIM}×", (q or 9) <= REFLEX_AIM)
        add(f"     ratio to the floor at 100 Hz, median: {verdict}")
        q99 = ratio(r["rtt"], floor, "p99_us")
        qb = ratio(rb["rtt"], floor_b2b)
        add(f"     p99 ratio {q99:.2f}×; back-to-back median ratio {qb:.2f}×"
            if q99 and qb else None)
        ctl = r["controller"]
        add(f"     controller: coalesced {ctl['coalesced']}, malformed {ctl['malformed']}, "
            f"errors {ctl['errors']}, triggered ticks {ctl['triggered']}, handled on "
            f"zenoh's thread: on the reflex lane {ctl.get('lane')} (waited for the loop's lock "
            f"{ctl.get('lane_waited')}, handed to the loop: lock held {ctl.get('lane_busy')}, "
            f"behind an elder {ctl.get('lane_deferred')}), loop lent {ctl['direct']}, "
            f"of {ctl['received']}")
        lines.extend(python_floor_report(res))
        o, ob = res["controller_100hz"], res["controller_b2b"]
        p, pb = res["plain_loop_100hz"], res["plain_loop_b2b"]
        t, tb = res["tree_echo_100hz"], res["tree_echo_b2b"]
        for label, x, xb in (("observed through its hooks (the breakdown below)", o, ob),
                             ("observed, on asyncio's plain loop (nothing lent)", p, pb),
                             ("Python floor: the tree in the echo's callback", t, tb)):
            add(f"  {label}")
            add(row("  at 100 Hz", x["rtt"], lost_note(x)))
            add(row("  back-to-back", xb["rtt"], lost_note(xb)))
            qx = ratio(x["rtt"], floor)
            add(f"       ratio to the floor at 100 Hz, median: {qx:.2f}×" if qx else None)
        qt = ratio(r["rtt"], t["rtt"])
        add(f"     the framework beyond the Python floor (reflex / Python floor), median: "
            f"{qt:.2f}×" if qt else None)
        add("   where the time goes (per sample, joined by seq across both processes):")
        add(f"    {'':<42} {'lent 100 Hz':>12} {'p90':>8} {'b2b':>8} {'p90':>8}"
            f" {'plain 100 Hz':>12} {'p90':>8}")
        for k, v in o["segments"].items():
            b = ob["segments"][k]
            w = p["segments"][k]
            add(f"    {k:<42} {fmt_us(v.get('median_us')):>12} {fmt_us(v.get('p90_us')):>8} "
                f"{fmt_us(b.get('median_us')):>8} {fmt_us(b.get('p90_us')):>8} "
                f"{fmt_us(w.get('median_us')):>12} {fmt_us(w.get('p90_us')):>8}")
        add("    (the reflex lane on either loop; lent: other samples handled on zenoh's thread "
            "while the loop waits; plain: through the "
            "self-pipe to the loop thread)")
    for hz in (50, 100):
        p = res.get(f"periodic_{hz}hz")
        if p is None:
            continue
        if hz == 50:
            add("3. Periodic mode (no reflex): age of a sample when its first command is "
                "published")
        add(row(f"{hz} Hz tick (half period {500 / hz:.0f} ms)", p["age_at_publish"],
                f"never commanded {p['never_commanded']}/{p['samples']}"))
        add(row("  … when the sensor receives it", p["age_at_receipt"]))
        if "wait_for_tick" in p:
            add(row("  stored → the tick that reads it", p["wait_for_tick"],
                    f"missed while newest {p['missed_while_newest']}"))
        add(row("  tick jitter |Δ−T|, wall, no sim", p["tick_jitter_wall"],
                f"overruns {p['overruns']}"))
    for hz in (50, 100):
        s = res.get(f"sim_{hz}hz")
        if s is None:
            continue
        if hz == 50:
            add("   with the full simulated robot in the controller's process (speed 1; "
                "the default controller, reflex on range/):")
        rtf = s["real_time_factor"]
        add(row(f"  {hz} Hz tick jitter |Δ−T|, wall time", s["jitter_wall"],
                f"overruns {s['overruns']}, real-time factor {rtf:.3f}, "
                f"+{s['reflex_ticks']} reflex ticks"))
        add(row(f"  {hz} Hz tick jitter |Δ−T|, sim time", s["jitter_sim"],
                f"sim step {s['step_s'] * 1e3:.0f} ms, late steps {s['late_steps']}"))
        add(row(f"  {hz} Hz newest-sample age at tick, sim time", s["newest_age_sim"],
                "(sim time moves in 5 ms steps)"))
    if "obstacle_sync" in res:
        add("4. Obstacle reaction: IR reading < 200 mm at a random moment → first drive −50")
        for name, (label, _) in CONTROLLERS.items():
            o = res.get(f"obstacle_{name}")
            if o is not None:
                add(row(label, o["reaction"], f"missed {o['missed']}/{o['trials']}, "
                        f"{o['triggered']}/{o['ticks']} ticks triggered"))
        sync = res["obstacle_sync"]["reaction"]
        for name, label in (("default", "default (periodic 50 Hz + reflex)"),
                            ("periodic", "periodic 50 Hz, no reflex"),
                            ("event", "event on IR")):
            if f"obstacle_{name}" not in res:
                continue
            q = ratio(sync, res[f"obstacle_{name}"]["reaction"])
            text = (_aim(q, '≥ 20×', (q or 0) >= 20) if name == "default"
                    else f"{q:.2f}×" if q else "—")
            add(f"     ratio sync / {label}, median: {text}")
    if "obstacle_sync" in res and "camera_periodic" in res:
        add(f"5. Camera path: capture stamp → command (stand-in camera, "
            f"{CAMERA_PERIOD_S * 1e3:.0f} ms capture latency)")
        for key, label in (("obstacle_sync", "sync"), ("camera_periodic", "default 50 Hz")):
            o = res[key]
            cap = o["capture_to_command"]
            over = None
            if cap.get("n"):
                over = {**cap, **{k: cap[k] - CAMERA_PERIOD_S * 1e6 for k in
                                  ("median_us", "p90_us", "p99_us", "max_us")}}
            add(row(f"{label}: capture → command", cap,
                    f"{o['camera_commanded']}/{o['camera_frames']} frames commanded"))
            add(row(f"{label}:   overhead beyond {CAMERA_PERIOD_S * 1e3:.0f} ms", over))
            add(row(f"{label}:   camera publish → command", o["camera_publish_to_command"]))
    if "sim_50hz" in res and res["sim_50hz"]["camera_age_sim"].get("n"):
        add(row("simulated camera, default 50 Hz, sim time", res["sim_50hz"]["camera_age_sim"],
                "capture → first tick that saw it (5 ms steps)"))
    if "peers" in res:
        peers = res["peers"]
        add("6. Peers")
        dora = peers["dora"]
        if "skipped" in dora:
            add(f"  dora-rs reflex round trip: skipped — {dora['skipped']}")
        else:
            add(row(f"dora-rs Python nodes, 100 Hz ({dora['version']})", dora["rtt"],
                    f"lost {dora['lost']}/{dora['sent']}"))
            if "reflex_100hz" in res:
                q = ratio(res["reflex_100hz"]["rtt"], dora["rtt"])
                add(f"     ubf_async reflex / dora-rs, median: "
                    f"{_aim(q, '≤ 0.5×, 2× faster', (q or 9) <= 0.5)}")
        add(f"  tick cost, µs per tick (py_trees: {peers['py_trees']}):")
        for t in peers["tick"]:
            pt = t["py_trees_us"]
            add(f"    {t['children']:>3} children: UBF {t['ubf_us']:7.1f} µs   py_trees "
                + (f"{pt:7.1f} µs   ({pt / t['ubf_us']:.1f}×)" if pt is not None
                   else "skipped (not installed)"))
    if "breakdown" in res:
        add("7. In-process costs (one process, no transport)")
        for k, v in res["breakdown"].items():
            add(row(k, v))
    if "loops" in res:
        lines.extend(loops_report(res["loops"]))
    if "dora_sizes" in res:
        lines.extend(dora_report(res["dora_sizes"]))
    return "\n".join(x for x in lines if x is not None)


PYTHON_FLOOR_ROWS = (
    ("tree_echo", "Python floor: the tree in zenoh's callback"),
    ("as_run", "reflex as run (default loop, nothing lent)"),
    (BASELINE_SERVER, "reflex as run, --baseline checkout"),
    ("controller", "observed, lending loop (UBF_LOOP=lending)"),
    ("plain_loop", "observed, default loop"),
    ("echo", "raw zenoh echo (the transport floor)"),
)
REFLEX_AIM_PYTHON_FLOOR = 1.10
"""Issue 40's aim: the reflex as run at most this many times the Python floor, median and
p99, on the default loop."""


def python_floor_report(res: dict[str, Any]) -> list[str]:
    """Section 2's reflex against the Python floor: pooled rounds, ratios of the median, p90,
    p99 and max to the Python floor's in the same rounds, and the per-round median ratios."""
    out = []
    for when, label in (("100hz", "at 100 Hz"), ("b2b", "back-to-back")):
        base = res.get(f"tree_echo_{when}")
        if base is None:
            continue
        rounds = len(base.get("round_medians_us", ())) or 1
        out.append(f"  against the Python floor, {label} ({rounds} rounds pooled; ratios to the "
                   f"Python floor of the same rounds)")
        out.append(f"    {'':<44} {'n':>6}  {'median':>9} {'p90':>9} {'p99':>9} {'max':>9}"
                   f"  {'×med':>5} {'×p90':>5} {'×p99':>5} {'×max':>5}  per-round ×med")
        for name, row_label in PYTHON_FLOOR_ROWS:
            r = res.get("floor_" + when if name == "echo" else
                        ("reflex_" + when if name == "as_run" else f"{name}_{when}"))
            if r is None:
                continue
            qs = [ratio(r["rtt"], base["rtt"], k) for k in ("median_us", "p90_us", "p99_us",
                                                            "max_us")]
            per = [a / b for a, b in zip(r.get("round_medians_us", ()),
                                         base.get("round_medians_us", ()), strict=False) if b]
            spread = f"{min(per):.2f}–{max(per):.2f}" if per else "—"
            t = r["rtt"]
            out.append(f"    {row_label:<44} {t.get('n', 0):>6}  "
                       + " ".join(f"{fmt_us(t.get(k)):>9}" for k in ("median_us", "p90_us",
                                                                       "p99_us", "max_us"))
                       + "  " + " ".join(f"{q:5.2f}" if q is not None else "    —" for q in qs)
                       + f"  {spread}")
        if when == "100hz" and "reflex_100hz" in res:
            q = ratio(res["reflex_100hz"]["rtt"], base["rtt"])
            q99 = ratio(res["reflex_100hz"]["rtt"], base["rtt"], "p99_us")
            if q is not None and q99 is not None:
                ok = q <= REFLEX_AIM_PYTHON_FLOOR and q99 <= REFLEX_AIM_PYTHON_FLOOR
                out.append(f"     reflex / Python floor at 100 Hz: median {q:.2f}×, p99 "
                           f"{q99:.2f}×  (aim ≤ {REFLEX_AIM_PYTHON_FLOOR:.2f}× both: "
                           f"{'met' if ok else 'MISSED'})")
            if BASELINE_SERVER + "_100hz" in res:
                b = res[BASELINE_SERVER + "_100hz"]["rtt"]
                now = res["reflex_100hz"]["rtt"]
                out.append(f"     this checkout / --baseline: median "
                           f"{ratio(now, b) or 0:.2f}×, p99 {ratio(now, b, 'p99_us') or 0:.2f}×")
        out.extend(split_report(res, when, base))
    return out


def split_report(res: dict[str, Any], when: str, base: dict[str, Any]) -> list[str]:
    """Medians of each server's round trip split at the drive command's stamp (:data:`SPLIT`),
    and the difference to the Python floor's: where the framework's extra time lies."""
    if "inbound" not in base:
        return []
    out = [f"    split at the drive command's stamp (median; ± the Python floor's)"
           f"{'':<3}{'sample → command':>18} {'command → sensor':>18}"]
    for name, row_label in PYTHON_FLOOR_ROWS:
        r = res.get("floor_" + when if name == "echo" else
                    ("reflex_" + when if name == "as_run" else f"{name}_{when}"))
        if r is None or "inbound" not in r:
            continue
        cells = []
        for part in ("inbound", "outbound"):
            us, floor_us = r[part].get("median_us"), base[part].get("median_us")
            diff = "" if name == "tree_echo" or us is None or floor_us is None else (
                f" ({us - floor_us:+.0f})")
            cells.append(f"{fmt_us(us)}{diff}")
        out.append(f"    {row_label:<44}{'':<25}{cells[0]:>18} {cells[1]:>18}")
    return out


def loops_report(lp: dict[str, Any]) -> list[str]:
    """Section 8's table: per path and loop, the pooled figures and the ratios to the
    baseline (pooled median, pooled p99, and the lowest–highest per-round median ratio)."""
    out = [f"8. Event loops: {lp['rounds']} rounds, each loop in every round, order rotating; "
           f"ratios to asyncio's plain loop ({lp['baseline']}) measured in the same rounds",
           f"  {'':<46} {'n':>6}  {'median':>9} {'p90':>9} {'p99':>9} {'max':>9}"
           f"  {'×median':>7} {'×p99':>6}  per-round ×median"]
    for path, label in LOOP_PATHS.items():
        out.append(f"  {label}")
        for loop, s in lp["paths"][path].items():
            def x(v: float | None) -> str:
                return f"{v:.2f}" if v is not None else "—"

            spread = (f"{x(s['round_ratio_lo'])}–{x(s['round_ratio_hi'])}"
                      if s.get("round_ratio_lo") is not None else "—")
            out.append(row(f"  {loop}", s)
                       + f"  {x(s.get('ratio_median')):>7} {x(s.get('ratio_p99')):>6}  {spread}")
    out.append("  reflex samples lost (superseded in the bridge) / sent: " + ", ".join(
        f"{x} {lp['lost'][x]}/{lp['sent'][x]}" for x in lp["loops"]))
    out.append("  handled on zenoh's thread, on the reflex lane / loop lent: " + ", ".join(
        f"{x} {lp.get('lane', {}).get(x)}/{lp['lent'][x]}" for x in lp["loops"]))
    out.append("  obstacles missed: " + ", ".join(
        f"{x} {lp['obstacles_missed'][x]}" for x in lp["loops"]))
    return out


def strip_raw(obj: Any) -> Any:
    """Drop the raw per-sample arrays (``*_ns`` lists) from what goes to --json."""
    if isinstance(obj, dict):
        return {k: strip_raw(v) for k, v in obj.items()
                if not (str(k).endswith("_ns") and isinstance(v, list | dict))}
    return obj


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.latency",
        description="End-to-end latency of ubf_async beside the raw zenoh floor and its "
                    "peers (dora-rs, py_trees), printed as median/p90/p99/max with sample "
                    "counts and ratios. Default run: a few minutes; --quick: well under one.",
        epilog="Sections: " + ", ".join(SECTIONS) + ". See docs/latency.md for how to read "
               "each figure.",
    )
    parser.add_argument("--quick", action="store_true", help="short run (fewer samples)")
    parser.add_argument("--json", metavar="FILE", help="also write every figure as JSON")
    parser.add_argument("--only", nargs="+", choices=SECTIONS, metavar="SECTION",
                        help=f"run only these sections ({', '.join(SECTIONS)})")
    parser.add_argument("--rounds", type=int, metavar="N",
                        help="rounds of sections reflex (default 4, --quick 2), loops "
                             "(default 8, --quick 3) and dora (default 3, --quick 2); more "
                             "rounds average more of a noisy host's load")
    parser.add_argument("--baseline", metavar="DIR",
                        help="section reflex: also run the controller from the checkout DIR "
                             "(e.g. git worktree add DIR <commit>), in the same rounds: "
                             "before and after under the same load")
    args = parser.parse_args(argv)
    sections = tuple(args.only) if args.only else SECTIONS
    started = time.monotonic()
    res = run(sections, args.quick, lambda m: print(m, file=sys.stderr, flush=True),
              rounds=args.rounds, baseline=args.baseline)
    res["elapsed_s"] = time.monotonic() - started
    print(report(res))
    print(f"\n(run took {res['elapsed_s']:.0f} s)")
    if args.json:
        Path(args.json).write_text(json.dumps(strip_raw(res), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
