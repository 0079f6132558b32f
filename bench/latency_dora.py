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

import importlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
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


NodesOf = Callable[[str, Path, dict[str, str]], list[dict[str, Any]]]
"""``nodes(this_file, result_path, env)``: a dataflow's nodes, run as this file's roles."""


def run_dataflow(nodes: NodesOf, *, budget_s: float, timeout_s: float,
                 modules: tuple[str, ...] = ("dora", "pyarrow")) -> dict[str, Any]:
    """Run a dataflow of this file's nodes with ``dora run`` (stopped after ``budget_s``);
    returns ``{"result": <the JSON a node wrote>, "version": ...}`` or ``{"skipped":
    reason}`` when dora, one of ``modules`` or the CLI is missing, or the run wrote nothing."""
    for module in modules:
        try:
            importlib.import_module(module)
        except ImportError as exc:
            return {"skipped": f"dora-rs Python package not installed ({exc.name})"}
    exe = dora_executable()
    if exe is None:
        return {"skipped": "dora CLI not found (pip install dora-rs-cli)"}
    with tempfile.TemporaryDirectory(prefix="ubf-dora-") as tmp:
        out = Path(tmp) / "result.json"
        flow = Path(tmp) / "dataflow.yml"
        flow.write_text(json.dumps({"nodes": nodes(str(Path(__file__).resolve()), out,
                                                   {"PYTHONPATH": str(ROOT)})}))  # JSON: YAML
        try:
            proc = subprocess.run(
                [exe, "run", str(flow), "--stop-after", f"{int(budget_s)}s"],
                cwd=tmp, capture_output=True, text=True, timeout=min(timeout_s, budget_s + 30),
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
    return {"result": result, "version": version}


def run_dora(*, warmup: int, count: int, timeout_s: float = 120.0) -> dict[str, Any]:
    """Run the two-node dataflow; returns ``{"rtt_ns": [...], "sent": n, ...}`` or
    ``{"skipped": reason}``."""

    def nodes(me: str, out: Path, env: dict[str, str]) -> list[dict[str, Any]]:
        return [
            {"id": "sensor", "path": sys.executable,
             "args": f"{me} sensor {out} {warmup} {count}", "env": env,
             "inputs": {"tick": "dora/timer/millis/10", "cmd": "controller/cmd"},
             "outputs": ["sample"]},
            {"id": "controller", "path": sys.executable, "args": f"{me} controller",
             "env": env, "inputs": {"sample": "sensor/sample"}, "outputs": ["cmd"]},
        ]

    ran = run_dataflow(nodes, budget_s=max(30.0, (warmup + count) * 0.01 * 3 + 20),
                       timeout_s=timeout_s)
    if "skipped" in ran:
        return ran
    result = ran["result"]
    rtts = sorted(result["rtts"])
    measured = [r - s for seq, s, r in rtts if seq > warmup]
    return {"rtt_ns": measured, "sent": result["sent"] - warmup,
            "lost": max(0, count - len(measured)), "version": ran["version"]}


# ---------------------------------------------------------------------------------------------
# dora's own benchmark, on its terms: one-way latency of a payload of each size, the sender's
# time.perf_counter_ns() in its first 8 bytes, read by the receiver as the sample arrives
# (CLOCK_MONOTONIC on Linux: one clock for every process of the host).

DORA_SIZES = (8, 64, 512, 4096, 40_960, 409_600, 4_194_304)
"""dora-rs/dora-benchmark's sizes up to 4 MB (8 B, 64 B, 512 B, 4 KB, 40 KB, 400 KB, 4 MB)."""
OURS_LIMIT_BYTES = 256 * 1024
"""The protocol's largest payload (``MAX_PAYLOAD_BYTES``): a robot's session refuses more on
``ubf/**`` (``ubf_async.net.options.INGRESS_LIMIT_BYTES``), by design, so our path is not
measured beyond it."""
DORA_PUBLISHED_US = {8: 398, 4096: 824, 409_600: 864, 4_194_304: 1170}
"""dora-rs/dora-benchmark's published average one-way latency of Python nodes (µs; 1 000
samples per size, on the authors' machine)."""
SIZES_PERIOD_S = 0.01
"""Both senders send every 10 ms (100 Hz, the reflex's rate): a sample at a time."""


def stamped(size: int) -> bytearray:
    """A payload of ``size`` bytes (at least 8): the send time, then zeros."""
    buf = bytearray(max(8, size))
    buf[0:8] = time.perf_counter_ns().to_bytes(8, "little")
    return buf


class SizesCollector:
    """The receiver's records: one-way latency per size, the first ``warmup`` samples of each
    size discarded."""

    def __init__(self, warmup: int) -> None:
        self.warmup = warmup
        self.seen: dict[int, int] = {}
        self.values: dict[int, list[int]] = {}

    def add(self, payload: bytes | memoryview, received_ns: int) -> None:
        view = memoryview(payload)
        size = len(view)
        n = self.seen[size] = self.seen.get(size, 0) + 1
        if n > self.warmup:
            self.values.setdefault(size, []).append(
                received_ns - int.from_bytes(view[0:8], "little"))


def dora_sizes_sender(sizes: str, count: int) -> None:
    import numpy as np
    import pyarrow as pa
    from dora import Node

    node = Node()
    for size in map(int, sizes.split(",")):
        for _ in range(count):
            buf = stamped(size)  # stamped first: dora's own copy counts, as in its bench
            node.send_output("data", pa.array(np.frombuffer(buf, dtype=np.uint8)))
            time.sleep(SIZES_PERIOD_S)


def dora_sizes_receiver(out: str, warmup: int, total: int) -> None:
    from dora import Node

    node = Node()
    got = SizesCollector(warmup)
    n = 0
    for event in node:
        if event["type"] == "INPUT":
            received = time.perf_counter_ns()
            got.add(event["value"].to_numpy(zero_copy_only=False).data, received)
            n += 1
            if n >= total:
                break
        elif event["type"] == "STOP":
            break
    Path(out).write_text(json.dumps({str(k): v for k, v in got.values.items()}))


def run_dora_sizes(*, sizes: tuple[int, ...], warmup: int, count: int) -> dict[str, Any]:
    """dora's two Python nodes sending each size ``warmup + count`` times; returns
    ``{"values": {size: [ns, ...]}, "version": ...}`` or ``{"skipped": reason}``."""
    total = (warmup + count) * len(sizes)
    listing = ",".join(map(str, sizes))

    def nodes(me: str, out: Path, env: dict[str, str]) -> list[dict[str, Any]]:
        return [
            {"id": "sender", "path": sys.executable,
             "args": f"{me} sizes-sender {listing} {warmup + count}", "env": env,
             "outputs": ["data"]},
            {"id": "receiver", "path": sys.executable,
             "args": f"{me} sizes-receiver {out} {warmup} {total}", "env": env,
             "inputs": {"data": "sender/data"}},
        ]

    budget = 30 + total * SIZES_PERIOD_S * 3
    ran = run_dataflow(nodes, budget_s=budget, timeout_s=budget + 30,
                       modules=("dora", "numpy", "pyarrow"))
    if "skipped" in ran:
        return ran
    return {"values": {int(k): v for k, v in ran["result"].items()}, "version": ran["version"]}


async def ours_sizes_receiver(cfg: dict[str, Any]) -> dict[str, Any]:
    """Our path's receiving end: a :class:`~ubf_async.runtime.bus.Bus` subscription, each
    sample handed from zenoh's thread to the handler on the event loop (the bridge), the
    arrival stamped there. Prints ``READY``, serves until every sample has come or stdin
    closes."""
    import asyncio
    import threading

    from ubf_async.net.options import ConnectionOptions
    from ubf_async.runtime.bus import Bus

    got = SizesCollector(cfg["warmup"])
    bus = await Bus.open(ConnectionOptions(robot=cfg["robot"], listen=[cfg["endpoint"]]))
    loop = asyncio.get_running_loop()
    done = asyncio.Event()

    def stdin_closed() -> None:
        sys.stdin.read()
        loop.call_soon_threadsafe(done.set)

    expected = len(cfg["sizes"]) * (cfg["warmup"] + cfg["count"])

    def handler(key: str, payload: bytes, received_ns: int) -> None:
        got.add(payload, time.perf_counter_ns())
        if sum(got.seen.values()) == expected:
            done.set()  # all there: the sender sees this subscriber go and stops

    threading.Thread(target=stdin_closed, daemon=True).start()
    try:
        bus.subscribe(bus.keys.prefix + "/bench/sizes", handler, latest=False)
        print("READY", flush=True)
        await done.wait()
    finally:
        await bus.aclose()
    return {"values": {str(k): v for k, v in got.values.items()}}


async def ours_sizes_sender(cfg: dict[str, Any]) -> dict[str, Any]:
    """Our path's sending end: a :class:`~ubf_async.runtime.bus.Bus` raw publisher (the
    payload as it is: the protocol's envelope carries at most 256 KiB), one sample every
    :data:`SIZES_PERIOD_S`, each size ``warmup + count`` times."""
    import asyncio
    import contextlib

    from ubf_async.net.options import ConnectionOptions
    from ubf_async.runtime.bus import Bus

    bus = await Bus.open(ConnectionOptions(robot=cfg["robot"], connect=[cfg["endpoint"]]))
    try:
        pub = bus.raw_publisher(bus.keys.prefix + "/bench/sizes")
        await pub.wait_for_subscribers(10)
        for size in cfg["sizes"]:
            for _ in range(cfg["warmup"] + cfg["count"]):
                pub.put(bytes(stamped(size)))
                await asyncio.sleep(SIZES_PERIOD_S)  # the pace: one sample a period
        # The receiver leaves once it has every sample: closing before would drop the last.
        # (A sample lost on the way keeps it there: then the samples it has are what count.)
        with contextlib.suppress(TimeoutError):
            await pub.wait_for_subscribers(10, present=False)
    finally:
        await bus.aclose()
    return {"sent": len(cfg["sizes"]) * (cfg["warmup"] + cfg["count"])}


def _run_ours(kind: str, cfg_json: str) -> None:
    from ubf_async.cli.run import run_loop

    cfg = json.loads(cfg_json)
    result = run_loop(ours_sizes_receiver(cfg) if kind == "receiver" else ours_sizes_sender(cfg))
    sys.stdout.write("RESULT " + json.dumps(result) + "\n")
    sys.stdout.flush()


if __name__ == "__main__":
    role = sys.argv[1]
    if role.startswith("{"):  # our path's ends, run by bench.latency's Worker
        _run_ours(json.loads(role)["side"], role)
        raise SystemExit(0)
    if role == "sensor":
        sensor_node(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
    elif role == "controller":
        controller_node()
    elif role == "sizes-sender":
        dora_sizes_sender(sys.argv[2], int(sys.argv[3]))
    elif role == "sizes-receiver":
        dora_sizes_receiver(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
    else:
        raise SystemExit(f"unknown role {role!r}")
