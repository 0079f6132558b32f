"""Codec micro-benchmark: decode + validate and encode, per message type, in a tight loop.

    python -m bench.codec [--calls N] [--json FILE]

For each message type the robot exchanges (``range``, ``camera.seekcolor``, ``encoders``,
``drive``, ``vote``, ``heartbeat``, ``clock``) it times, on one realistic payload:

* ``decode``: :func:`ubf_async.wire.protocol.decode` of the payload (msgpack unpacking, the
  envelope's and the schema's validation) — whatever codec ``ubf_async.wire.protocol`` holds when
  it runs;
* ``encode``: :func:`ubf_async.wire.protocol.encode` of the decoded data (validation and packing),
  handed back exactly as ``decode`` returned it, so the figure holds for a codec of plain
  dicts and for one of typed structs alike;
* the floor beside each: plain ``msgpack.unpackb`` / ``msgpack.packb`` of the same
  envelope, no validation at all.

The payloads are built with plain ``msgpack`` (as a third-party client following
docs/protocol.md would build them), not with the codec under test. Every figure is a
per-call time: the calls run in batches of ``--batch`` (default 20) between two
``time.perf_counter_ns()`` readings, so the timer's own cost is spread over the batch; the
median and p99 are over the batches (hot caches, one busy core: what a call costs at best —
``bench.latency`` shows what the same work costs at 100 Hz). The first batches are discarded
as warm-up.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack

import ubf_async.services.remote  # noqa: F401  (the current codec registers the vote schema there)
from bench.latency_stats import fmt_us, percentile
from ubf_async.wire import protocol

STAMP_NS = 1_700_000_000_000_000_000
PUB = 4_242_424_242


def envelopes() -> dict[str, dict[str, Any]]:
    """One realistic envelope per message type (what a device or the controller sends)."""

    def env(schema: str, data: dict[str, Any], period_s: float | None = None
            ) -> dict[str, Any]:
        out: dict[str, Any] = {"schema": schema, "v": 1, "stamp_ns": STAMP_NS, "seq": 12345,
                               "pub": PUB, "data": data}
        if period_s is not None:
            out["period_s"] = period_s
        return out

    return {
        "range": env("range", {"range_mm": 512, "status": "ok", "model": "GP2Y0A21YK",
                               "min_mm": 100, "max_mm": 800}, 0.04),
        "camera.seekcolor": env("camera.seekcolor", {
            "bins": [0, 3, 140, 5, 0], "total": 148, "bearing_rad": 0.012,
            "latency_s": 0.11, "width": 160, "height": 128}, 0.11),
        "encoders": env("encoders", {"left_edges": 40960, "right_edges": 40412,
                                     "left_counts": 10240.0, "right_counts": 10103.0,
                                     "errors": 0, "mode": "commanded"}, 0.02),
        "drive": env("drive", {"speed": -50.0, "turn": 0.0,
                               "based_on": {"source": "range/front", "seq": 12344,
                                            "stamp_ns": STAMP_NS - 400_000},
                               "tick": 9001, "winners": ["avoid"]}, 0.02),
        "vote": env("vote", {"speed": 20.0, "turn": -30.0, "vote": 0.8, "ttl_s": 0.5,
                             "priority": 1, "weight": 1.0}),
        "heartbeat": env("heartbeat", {"component": "controller", "restarts": 0,
                                       "loop_lag_s": 0.00012, "running": "yes"}, 1.0),
        "clock": env("clock", {"real_time_factor": 1.0, "epoch": "run-7f3a"}),
    }


def per_call_us(fn: Callable[[], object], *, calls: int, batch: int) -> dict[str, Any]:
    """Per-call time of ``fn`` in µs: median, p99 and max over batches of ``batch`` calls."""
    batches = max(1, calls // batch)
    warmup = max(10, batches // 10)
    values: list[float] = []
    timer = time.perf_counter_ns
    for i in range(warmup + batches):
        t0 = timer()
        for _ in range(batch):
            fn()
        t1 = timer()
        if i >= warmup:
            values.append((t1 - t0) / batch / 1e3)
    values.sort()
    return {"n": len(values) * batch, "batch": batch, "median_us": percentile(values, 50),
            "p99_us": percentile(values, 99), "max_us": values[-1]}


def measure(calls: int, batch: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, envelope in envelopes().items():
        payload = msgpack.packb(envelope, use_bin_type=True)
        message = protocol.decode(payload)
        assert message.schema == name and message.seq == envelope["seq"]

        def encode(message: protocol.Message = message) -> bytes:
            return protocol.encode(message.schema, message.data, stamp_ns=message.stamp_ns,
                                   seq=message.seq, period_s=message.period_s,
                                   pub=message.pub)

        # The codec must round-trip what a plain client sent: the same message (a field the
        # client set to its default may be left out on the way back).
        assert protocol.decode(encode()) == message, name

        def decode(p: bytes = payload) -> object:
            return protocol.decode(p)

        def unpackb(p: bytes = payload) -> object:
            return msgpack.unpackb(p, raw=False)

        def packb(e: dict[str, Any] = envelope) -> object:
            return msgpack.packb(e, use_bin_type=True)

        out[name] = {
            "payload_bytes": len(payload),
            "decode": per_call_us(decode, calls=calls, batch=batch),
            "msgpack_unpackb": per_call_us(unpackb, calls=calls, batch=batch),
            "encode": per_call_us(encode, calls=calls, batch=batch),
            "msgpack_packb": per_call_us(packb, calls=calls, batch=batch),
        }
    return out


def report(res: dict[str, Any]) -> str:
    head = (f"{'message':<18} {'bytes':>5}   {'decode':>8} {'p99':>8} {'unpackb':>8}"
            f" {'×':>5}   {'encode':>8} {'p99':>8} {'packb':>8} {'×':>5}")
    lines = [f"ubf_async codec, µs per call (median and p99 over batches of "
             f"{res['batch']}; hot loop) — codec: {res['codec']}", "", head]
    for name, r in res["types"].items():
        d, u, e, p = r["decode"], r["msgpack_unpackb"], r["encode"], r["msgpack_packb"]
        lines.append(
            f"{name:<18} {r['payload_bytes']:>5}   {fmt_us2(d['median_us']):>8} "
            f"{fmt_us2(d['p99_us']):>8} {fmt_us2(u['median_us']):>8} "
            f"{d['median_us'] / u['median_us']:>4.1f}×   {fmt_us2(e['median_us']):>8} "
            f"{fmt_us2(e['p99_us']):>8} {fmt_us2(p['median_us']):>8} "
            f"{e['median_us'] / p['median_us']:>4.1f}×")
    lines.append("")
    lines.append("decode/encode: ubf_async.wire.protocol (validation included); unpackb/packb: "
                 "plain msgpack of the same envelope, no validation (the floor); "
                 "×: codec / floor.")
    return "\n".join(lines)


def fmt_us2(value_us: float) -> str:
    """Sub-µs figures with two decimals, larger ones as bench.latency prints them."""
    return f"{value_us:.2f} µs" if value_us < 10 else fmt_us(value_us)


def codec_name() -> str:
    """Which implementation ``ubf_async.wire.protocol`` holds (its decoder's module)."""
    return f"{protocol.decode.__module__}.decode"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.codec",
        description="Decode + validate and encode costs per message type through "
                    "ubf_async.wire.protocol, beside plain msgpack of the same payload. "
                    "A few seconds.")
    parser.add_argument("--calls", type=int, default=40_000,
                        help="calls timed per figure")
    parser.add_argument("--batch", type=int, default=20,
                        help="calls between two timer readings")
    parser.add_argument("--json", metavar="FILE", help="also write every figure as JSON")
    args = parser.parse_args(argv)
    if args.calls < 1 or args.batch < 1:
        parser.error("--calls and --batch must be ≥ 1")
    res = {"python": sys.version.split()[0], "msgpack": msgpack.version,
           "codec": codec_name(), "calls": args.calls, "batch": args.batch,
           "types": measure(args.calls, args.batch)}
    print(report(res))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
