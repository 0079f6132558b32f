"""The sensor side of the latency benchmark: a plain zenoh + msgpack process.

Run as a child process by ``bench/latency.py``::

    python -m bench.latency_sensor '<json config>'

It connects to the robot's endpoint, publishes stamped samples exactly as the protocol
says (``examples/plain_range_sensor.py`` style: no ubf_async runtime, no asyncio), and
records every ``cmd/drive`` it receives with ``time.monotonic_ns()`` taken first thing in
the zenoh callback. It prints ``RESULT <json>`` and exits. The same harness measures the
transport floor (against the raw echo) and the framework paths (against the controller), so
the two differ only in what answers.

Scenarios (``scenario`` in the config):

* ``rtt`` — ``range/front`` samples at ``rate_hz`` (or back-to-back when ``rate_hz`` is 0:
  the next sample leaves when the previous reply arrived); each reply is matched to its
  sample through ``based_on.seq``. With several ``targets`` (robot + endpoint each: the raw
  echo and the controller) the samples to each are interleaved in time, so both are measured
  under the same load on the host.
* ``ages`` — ``range/front`` samples at random moments (intervals uniform in
  ``[interval_lo_s, interval_hi_s]``); all commands recorded, so the parent can find the first
  command based on each sample.
* ``robot`` — an IR stand-in (``range/front`` every ``ir_period_s``) and a camera stand-in
  (``camera/front`` every ``camera_period_s``, stamped with the capture start, published
  ``camera_period_s`` later like the ≈0.11 s OV9655, the next capture after a random idle
  gap of up to ``camera_idle_s`` (20 ms); ``ir_period_s`` null: no IR).
  ``trials`` obstacles: at a random moment (a random gap spread evenly over two camera
  periods) a reading below 200 mm appears, published at once, off the IR grid; the reaction
  is the first command with speed −50 stamped after that reading; then the obstacle clears,
  and the next trial waits for the controller to stop avoiding. With ``trials`` 0 it runs
  ``frames`` camera frames.

The main thread paces with ``time.sleep`` until absolute deadlines (the harness's own
schedule, not a synchronisation); it waits for the controller through zenoh's matching status
and for replies through a condition variable.
"""

from __future__ import annotations

import json
import random
import sys
import threading
import time
from typing import Any

import msgpack
import zenoh

from ubf_async.net.options import ConnectionOptions
from ubf_async.wire.keys import Keys

FAR_MM = 600
NEAR_MM = 120
AVOID_SPEED = -50.0
CAMERA_BINS = [0, 0, 60, 0, 0]  # some pink straight ahead: chase (+40) when nothing is near
LAST_COMMAND_WAIT_S = 3.0
"""How long the end waits, at most, for the command based on the last camera frame."""


class Harness:
    def __init__(self, cfg: dict[str, Any]) -> None:
        self.cfg = cfg
        self.keys = Keys(cfg["robot"])
        self.session = zenoh.open(
            ConnectionOptions(robot=cfg["robot"], connect=[cfg["endpoint"]]).zenoh_config()
        )
        self.cond = threading.Condition()
        self.commands: list[tuple[int, int, int | None, str | None, float, int, int | None]] = []
        """(received_ns, cmd_stamp_ns, based_on_seq, based_on_source, speed, cmd_seq,
        based_on_stamp_ns)"""
        self.replied: dict[int, int] = {}  # range seq -> index in commands (first reply)
        self.sub = self.session.declare_subscriber(self.keys.cmd("drive"), self._on_command)
        self.ir = self.session.declare_publisher(self.keys.sensor("range", "front"))
        self.cam = self.session.declare_publisher(self.keys.sensor("camera", "front"))
        self.ir_seq = 0
        self.cam_seq = 0

    # zenoh thread ---------------------------------------------------------------------------
    def _on_command(self, sample: zenoh.Sample) -> None:
        received = time.monotonic_ns()
        msg = msgpack.unpackb(sample.payload.to_bytes())
        data = msg["data"]
        based = data.get("based_on") or {}
        seq, source = based.get("seq"), based.get("source")
        with self.cond:
            self.commands.append((received, msg["stamp_ns"], seq, source, float(data["speed"]),
                                  msg["seq"], based.get("stamp_ns")))
            if source == "range/front" and seq is not None and seq not in self.replied:
                self.replied[seq] = len(self.commands) - 1
            self.cond.notify_all()

    # publishing ----------------------------------------------------------------------------
    def put_range(self, mm: int, period_s: float) -> tuple[int, int]:
        self.ir_seq += 1
        stamp = time.monotonic_ns()
        self.ir.put(msgpack.packb({
            "schema": "range", "v": 1, "stamp_ns": stamp, "seq": self.ir_seq,
            "period_s": period_s, "data": {"range_mm": mm, "status": "ok"},
        }))
        return self.ir_seq, stamp

    def put_camera(self, capture_ns: int, period_s: float) -> tuple[int, int, int]:
        self.cam_seq += 1
        self.cam.put(msgpack.packb({
            "schema": "camera.seekcolor", "v": 1, "stamp_ns": capture_ns, "seq": self.cam_seq,
            "period_s": period_s, "data": {"bins": CAMERA_BINS, "total": sum(CAMERA_BINS),
                                           "latency_s": period_s},
        }))
        return self.cam_seq, capture_ns, time.monotonic_ns()

    def wait_matching(self, *publishers: Any, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        for pub in publishers:
            while not pub.matching_status.matching:
                if time.monotonic() > deadline:
                    raise TimeoutError("the robot's subscriber never appeared")
                time.sleep(0.002)

    def wait_first_reply(self, timeout_s: float = 10.0) -> None:
        """Send samples at 100 Hz until a command based on one of them comes back."""
        deadline = time.monotonic() + timeout_s
        while True:
            self.put_range(FAR_MM, 0.01)
            with self.cond:
                if self.cond.wait_for(lambda: bool(self.replied), timeout=0.01):
                    return
            if time.monotonic() > deadline:
                raise TimeoutError("no command came back")

    def close(self) -> None:
        for x in (self.sub, self.ir, self.cam):
            x.undeclare()
        self.session.close()


def sleep_until(deadline_ns: int) -> None:
    delay = (deadline_ns - time.monotonic_ns()) / 1e9
    if delay > 0:
        time.sleep(delay)


def scenario_rtt(hs: list[Harness], cfg: dict[str, Any]) -> dict[str, Any]:
    """Round trips against one or more robots, interleaved: at 100 Hz each robot gets a
    sample every 10 ms, the robots' samples offset by 10 ms / len(hs); back-to-back, the
    robots take turns. Interleaving puts every server under the same host load."""
    rate = cfg["rate_hz"]
    warmup, count = cfg["warmup"], cfg["count"]
    for h in hs:
        h.wait_matching(h.ir)
        h.wait_first_reply()
    first = [h.ir_seq + 1 for h in hs]
    sent: list[dict[int, int]] = [{} for _ in hs]
    period_ns = int(1e9 / rate) if rate else 0
    offset_ns = period_ns // len(hs)
    deadline = time.monotonic_ns()
    for i in range(warmup + count):
        for j, h in enumerate(hs):
            if rate:
                sleep_until(deadline + (i + 1) * period_ns + j * offset_ns)
            seq, stamp = h.put_range(FAR_MM, 1.0 / rate if rate else 0.01)
            if i >= warmup:
                sent[j][seq] = stamp
            if not rate:
                with h.cond:
                    # A def, not a lambda: mypy cannot type a lambda's default arguments.
                    def answered(h: Harness = h, s: int = seq) -> bool:
                        return s in h.replied

                    h.cond.wait_for(answered, timeout=1.0)
    out = []
    for j, h in enumerate(hs):
        def all_answered(h: Harness = h, j: int = j) -> bool:
            return all(s in h.replied for s in sent[j])

        with h.cond:  # the last replies of a paced run
            h.cond.wait_for(all_answered, timeout=2.0)
            commands = list(h.commands)
            replied = dict(h.replied)
        rows: list[tuple[int, int, int | None, int | None]] = []
        mismatched = 0
        for seq, stamp in sent[j].items():
            index = replied.get(seq)
            if index is None:
                rows.append((seq, stamp, None, None))
                continue
            received, cmd_stamp = commands[index][0], commands[index][1]
            if commands[index][6] != stamp:
                mismatched += 1
            rows.append((seq, stamp, cmd_stamp, received))
        based = [c[2] for c in commands if c[3] == "range/front" and c[2] is not None
                 and c[2] >= first[j]]
        out.append({"rows": rows, "duplicates": len(based) - len(set(based)),
                    "unmatched": sum(1 for s in based if s > h.ir_seq),
                    "mismatched": mismatched})
    return {"targets": out}


def scenario_ages(h: Harness, cfg: dict[str, Any]) -> dict[str, Any]:
    rng = random.Random(cfg.get("seed", 1))
    lo, hi = cfg["interval_lo_s"], cfg["interval_hi_s"]
    h.wait_matching(h.ir)
    h.wait_first_reply()
    samples = []
    deadline = time.monotonic_ns()
    for i in range(cfg["warmup"] + cfg["count"]):
        deadline += int(rng.uniform(lo, hi) * 1e9)
        sleep_until(deadline)
        seq, stamp = h.put_range(FAR_MM, hi)
        if i >= cfg["warmup"]:
            samples.append((seq, stamp))
    with h.cond:
        h.cond.wait_for(lambda: all(s in h.replied for s, _ in samples), timeout=2.0)
        commands = list(h.commands)
        replied = dict(h.replied)
    rows = []
    for seq, stamp in samples:
        index = replied.get(seq)
        rows.append((seq, stamp, *(commands[index][:2] if index is not None else (None, None))))
    return {"rows": rows}


def scenario_robot(h: Harness, cfg: dict[str, Any]) -> dict[str, Any]:
    """IR + camera stand-ins; obstacles at random moments (see the module docstring)."""
    rng = random.Random(cfg.get("seed", 2))
    with_ir = cfg["ir_period_s"] is not None
    ir_ns = int(cfg["ir_period_s"] * 1e9) if with_ir else 0
    cam_ns = int(cfg["camera_period_s"] * 1e9)
    # Obstacle moments: a gap after the previous trial, spread over exactly two camera periods
    # so that the moment's phase relative to the camera frames is uniform; the fractions
    # follow a golden-ratio sequence from a random start (evenly spread even for few trials).
    idle_s = cfg.get("camera_idle_s", 0.02)
    gap_lo, gap_span = cfg.get("gap_lo_s", 0.05), 2 * (cfg["camera_period_s"] + idle_s / 2)
    fraction = rng.random()
    trials = cfg["trials"]
    h.wait_matching(*((h.ir, h.cam) if with_ir else (h.cam,)))
    now = time.monotonic_ns()
    next_ir, capture, next_obstacle = (now if with_ir else None), now, None
    cameras: list[tuple[int, int, int]] = []  # (seq, capture_ns, published_ns)
    reactions: list[dict[str, int | None]] = []
    near_since: int | None = None   # stamp of the reading that brought the obstacle
    cleared_at: int | None = None   # stamp of the first far reading after a reaction
    warm_frames = cfg.get("warmup_frames", 3)
    frames_wanted = cfg.get("frames", 0)
    reaction_timeout_ns = int(cfg.get("reaction_timeout_s", 2.0) * 1e9)

    scanned = [0]
    recent: list[Any] = []

    def commands_since(stamp_ns: int) -> list[Any]:
        """Commands stamped at or after ``stamp_ns`` (scans only what arrived since last time:
        this thread must stay idle, or it would hold the GIL the zenoh callback needs)."""
        with h.cond:
            fresh = h.commands[scanned[0]:]
            scanned[0] = len(h.commands)
        recent.extend(fresh)
        del recent[: max(0, len(recent) - 64)]
        return [c for c in recent if c[1] >= stamp_ns]

    while True:
        if trials and len(reactions) >= trials:
            break
        if not trials and len(cameras) >= warm_frames + frames_wanted:
            break
        now = time.monotonic_ns()
        # State machine of the obstacle trials.
        if trials and len(cameras) >= warm_frames:
            if near_since is None and cleared_at is None and next_obstacle is None:
                fraction = (fraction + 0.6180339887498949) % 1.0
                next_obstacle = now + int((gap_lo + fraction * gap_span) * 1e9)
            elif near_since is not None:
                reacted = [c for c in commands_since(near_since) if c[4] == AVOID_SPEED]
                if reacted or now - near_since > reaction_timeout_ns:
                    first = reacted[0] if reacted else None
                    reactions.append({"reading_ns": near_since,
                                      "command_ns": first[1] if first else None,
                                      "received_ns": first[0] if first else None})
                    near_since = None
                    cleared_at = -1  # the next IR reading is far; set its stamp below
            elif cleared_at is not None and cleared_at > 0:
                calm = [c for c in commands_since(cleared_at) if c[4] != AVOID_SPEED]
                if calm:
                    cleared_at = None
        events = [capture + cam_ns]
        if next_ir is not None:
            events.append(next_ir)
        if next_obstacle is not None:
            events.append(next_obstacle)
        when = min(events)
        sleep_until(when)
        if next_obstacle is not None and when == next_obstacle:
            _, near_since = h.put_range(NEAR_MM, cfg["ir_period_s"])
            next_obstacle = None
        elif next_ir is not None and when == next_ir:
            mm = NEAR_MM if near_since is not None else FAR_MM
            _, stamp = h.put_range(mm, cfg["ir_period_s"])
            if cleared_at == -1:
                cleared_at = stamp
            next_ir += ir_ns
        else:
            cameras.append(h.put_camera(capture, cfg["camera_period_s"]))
            # The next capture starts after an idle gap of up to ``camera_idle_s``: a real
            # camera loop is not phase-locked to the controller's clock.
            capture += cam_ns + int(rng.uniform(0.0, idle_s) * 1e9)
    last_camera = cameras[-1][0] if cameras else None
    # Let the last frame's command arrive (when commands are based on frames): at once on an
    # idle machine; the bound only says when to stop waiting on a busy one (0.3 s was passed
    # there, and a frame that was commanded counted as not). Commands are based on frames
    # when the camera is the only source, or when one already was; a controller that bases
    # every command on the IR's newer samples would never send that command.
    with h.cond:
        if not with_ir or any(c[3] == "camera/front" for c in h.commands):
            h.cond.wait_for(lambda: any(c[3] == "camera/front" and c[2] == last_camera
                                        for c in h.commands[-8:]),
                            timeout=LAST_COMMAND_WAIT_S)
        commands = list(h.commands)
    camera_commands = [(c[0], c[1], c[2]) for c in commands if c[3] == "camera/front"]
    return {"reactions": reactions, "cameras": cameras[warm_frames:],
            "camera_commands": camera_commands}


def main(argv: list[str] | None = None) -> int:
    cfg = json.loads((argv or sys.argv[1:])[0])
    targets = cfg.get("targets") or [{"robot": cfg["robot"], "endpoint": cfg["endpoint"]}]
    hs: list[Harness] = []
    try:
        hs.extend(Harness({**cfg, **t}) for t in targets)
        if cfg["scenario"] == "rtt":
            result = scenario_rtt(hs, cfg)
        else:
            single = {"ages": scenario_ages, "robot": scenario_robot}[cfg["scenario"]]
            result = single(hs[0], cfg)
    finally:
        for h in hs:
            h.close()
    sys.stdout.write("RESULT " + json.dumps(result) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
