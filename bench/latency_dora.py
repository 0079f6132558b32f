"""Peer comparison: the reflex round trip as a dora-rs dataflow of Python nodes (``dora run``).

Two nodes, like the ubf_async reflex path (see ``bench/latency.py``):

* ``sensor`` — on a ``dora/timer/millis/10`` tick (100 Hz) it stamps a ``range`` sample with
  ``time.monotonic_ns()``, packs it as the ubf_async msgpack envelope and sends it; when a
  command comes back it matches ``based_on.seq`` to its sample and records the round trip
  (``time.monotonic_ns()`` at the event minus the sample's stamp).
* ``controller`` — decodes and validates the sample with ``ubf_async.wire.protocol.decode``,
  evaluates the same behaviour tree as the ubf_async controller (avoid above the thesis's
  seek-the-pink-ball) on a :class:`~ubf_async.core.state.State` of that sample, and sends a
  ``drive`` command encoded with ``ubf_async.wire.protocol.encode`` carrying ``based_on``.

So both sides do the work the ubf_async path does, minus its aggregator and asyncio bridge;
what differs is the middleware (dora's shared-memory/TCP daemon) and its node runtime.

``run_dora(...)`` writes the dataflow, runs ``dora run`` and returns the sensor's samples, or
a ``{"skipped": reason}`` when dora is not installed or fails.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def _payload_bytes(value: Any) -> bytes:
    """dora hands inputs over as a pyarrow array; ours carry one msgpack payload."""
    if hasattr(value, "to_numpy"):
        return value.to_numpy(zero_copy_only=False).tobytes()
    return bytes(value)


def sensor_node(out: str, warmup: int, count: int) -> None:
    import msgpack
    import pyarrow as pa
    from dora import Node

    node = Node()
    sent: dict[int, int] = {}
    rtts: list[tuple[int, int, int]] = []  # (seq, stamp_ns, received_ns)
    seq = 0
    total = warmup + count
    for event in node:
        if event["type"] != "INPUT":
            if event["type"] == "STOP":
                break
            continue
        if event["id"] == "tick":
            if seq >= total:
                if len(rtts) >= total or seq >= total + 200:  # done, or 2 s of stragglers
                    break
                continue
            seq += 1
            stamp = time.monotonic_ns()
            payload = msgpack.packb({
                "schema": "range", "v": 1, "stamp_ns": stamp, "seq": seq, "period_s": 0.01,
                "data": {"range_mm": 500, "status": "ok"},
            })
            sent[seq] = stamp
            node.send_output("sample", pa.array(memoryview(payload), type=pa.uint8()))
        elif event["id"] == "cmd":
            received = time.monotonic_ns()
            reply = msgpack.unpackb(_payload_bytes(event["value"]))
            based = reply["data"].get("based_on") or {}
            s = based.get("seq")
            if s in sent:
                rtts.append((s, sent.pop(s), received))
    Path(out).write_text(json.dumps({"sent": seq, "rtts": rtts, "warmup": warmup}))


def controller_node() -> None:
    import pyarrow as pa
    from dora import Node

    from bench.latency_robot import reflex_tree
    from ubf_async.core.state import Reading, State
    from ubf_async.wire.protocol import decode, encode

    node = Node()
    tree = reflex_tree()
    tick = 0
    for event in node:
        if event["type"] == "STOP":
            break
        if event["type"] != "INPUT" or event["id"] != "sample":
            continue
        message = decode(_payload_bytes(event["value"]), schema="range")
        now = time.monotonic_ns()
        reading = Reading(value=message.data, stamp_ns=message.stamp_ns, seq=message.seq,
                          age_s=(now - message.stamp_ns) / 1e9)
        state = State({"range/front": reading}, now_ns=now)
        trace = tree.evaluate(state)
        action = trace.action
        tick += 1
        payload = encode("drive", {
            "speed": (action.speed if action and action.speed is not None else 0.0),
            "turn": (action.turn if action and action.turn is not None else 0.0),
            "based_on": {"source": "range/front", "seq": message.seq,
                         "stamp_ns": message.stamp_ns},
            "tick": tick, "winners": trace.winning_leaves(),
        }, stamp_ns=time.monotonic_ns(), seq=tick)
        node.send_output("cmd", pa.array(memoryview(payload), type=pa.uint8()))


def dora_executable() -> str | None:
    here = Path(sys.executable).parent / "dora"
    if here.exists():
        return str(here)
    return shutil.which("dora")


def run_dora(*, warmup: int, count: int, timeout_s: float = 120.0) -> dict[str, Any]:
    """Run the two-node dataflow; returns ``{"rtt_ns": [...], "sent": n, ...}`` or
    ``{"skipped": reason}``."""
    try:
        import dora  # noqa: F401
        import pyarrow  # noqa: F401
    except ImportError as exc:
        return {"skipped": f"dora-rs Python package not installed ({exc.name})"}
    exe = dora_executable()
    if exe is None:
        return {"skipped": "dora CLI not found (pip install dora-rs-cli)"}
    with tempfile.TemporaryDirectory(prefix="ubf-dora-") as tmp:
        out = Path(tmp) / "result.json"
        me = str(Path(__file__).resolve())
        env = {"PYTHONPATH": str(ROOT)}
        dataflow = {
            "nodes": [
                {"id": "sensor", "path": sys.executable,
                 "args": f"{me} sensor {out} {warmup} {count}", "env": env,
                 "inputs": {"tick": "dora/timer/millis/10", "cmd": "controller/cmd"},
                 "outputs": ["sample"]},
                {"id": "controller", "path": sys.executable, "args": f"{me} controller",
                 "env": env, "inputs": {"sample": "sensor/sample"}, "outputs": ["cmd"]},
            ]
        }
        flow = Path(tmp) / "dataflow.yml"
        flow.write_text(json.dumps(dataflow))  # JSON is YAML
        budget = max(30.0, (warmup + count) * 0.01 * 3 + 20)
        try:
            proc = subprocess.run(
                [exe, "run", str(flow), "--stop-after", f"{int(budget)}s"],
                cwd=tmp, capture_output=True, text=True, timeout=min(timeout_s, budget + 30),
                env={**os.environ, "PYTHONPATH": str(ROOT)},
            )
        except (OSError, subprocess.TimeoutExpired) as exc:
            return {"skipped": f"dora run failed: {exc}"}
        if not out.exists():
            tail = (proc.stderr or proc.stdout or "").strip().splitlines()[-5:]
            return {"skipped": f"dora run produced no result (exit {proc.returncode}): "
                               + " | ".join(tail)}
        result = json.loads(out.read_text())
    version = subprocess.run([exe, "--version"], capture_output=True, text=True).stdout.strip()
    rtts = sorted(result["rtts"])
    measured = [r - s for seq, s, r in rtts if seq > warmup]
    return {"rtt_ns": measured, "sent": result["sent"] - warmup,
            "lost": max(0, count - len(measured)), "version": version}


if __name__ == "__main__":
    role = sys.argv[1]
    if role == "sensor":
        sensor_node(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
    elif role == "controller":
        controller_node()
    else:
        raise SystemExit(f"unknown role {role!r}")
