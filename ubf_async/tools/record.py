"""Recording a robot's bus to MCAP: ``python -m ubf_async.record``, or ``launch --record DIR``.

Every message on the robot's keys (``ubf/<robot>/**``: samples, commands, votes, heartbeats,
status, the clock and each tick's trace) goes into an `MCAP <https://mcap.dev>`_ file with its
**original bytes**: one channel per key (the channel's topic is the zenoh key), message
encoding ``msgpack``, and for each schema name a ``jsonschema`` schema of the whole envelope
(``schema``, ``v``, ``stamp_ns``, ``seq``, *opt* ``pub``, ``period_s``, and the topic's
``data``), generated from :mod:`ubf_async.wire.topics` — so any MCAP reader can list, decode and
check the messages without this package. Beside them go the live view's Foxglove channels
(:mod:`ubf_async.services.liveview`: the camera's image, the robot's pose and trail, the arena, the
IR beams as protobuf ``foxglove.*`` messages, and every message as JSON on ``/ubf/<key>``), so a
recording opens in Foxglove with the live layout (``docs/foxglove-layout.json``); their topics
start with ``/``, the keys never do. ``--no-live-channels`` leaves them out. ``log_time`` is
when the recorder received the message on the robot's clock (simulated time on a simulated
robot), ``publish_time`` the envelope's ``stamp_ns`` (the ``log_time`` for a message that is
not a valid envelope: those are recorded too, and counted).

Nothing of it runs on the event loop but a queue put: a writer thread encodes, compresses
(zstd, per chunk) and writes. The queue is bounded (``max_queue``); when the disk cannot keep
up, messages are dropped, counted (``stats.dropped``), logged and reported when the recording
ends — never silently. The writer closes its chunk every ``flush_s`` (1 s), hands it to the
kernel and has the file synced to the disk (``fsync``, on a thread of its own: ≈0.4–0.7 ms
once per flush on this project's idle machine, seconds on a busy disk, which must not hold
up the writer), so a recorder that is killed (``SIGKILL``, a crash) leaves a file whose
complete chunks any MCAP reader recovers, streaming: at most the last ``flush_s`` of
messages, plus those still queued, are lost (on a power cut, also what a slow disk had not
synced yet). ``split_bytes`` starts a new file
(``<name>_1.mcap``, ``_2``…) when one grows past it, so a long run never needs one huge file;
memory stays bounded by the queue and one chunk either way.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import msgspec

from ubf_async import __version__, extras, throttle
from ubf_async.cli import ending
from ubf_async.cli.args import HelpFormatter, add_connection_arguments
from ubf_async.cli.attach import add_attach_arguments, attached_bus, run_until_stopped
from ubf_async.cli.run import run_main
from ubf_async.errors import ConfigurationError, ProtocolError
from ubf_async.net.options import DEFAULT_LISTEN
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import EveryMessageComponent, ensure_name_free
from ubf_async.services.liveview import LiveMessage, LiveView
from ubf_async.wire.protocol import PROTOCOL_VERSION, Message, decode
from ubf_async.wire.topics import BY_SCHEMA, PlainData, Topic

__all__ = ["ABANDON_S", "DEFAULT_CHUNK_BYTES", "DEFAULT_DRAIN_S", "DEFAULT_FLUSH_S",
           "DEFAULT_MAX_QUEUE", "GENERIC_SCHEMA_NAME", "MESSAGE_ENCODING", "PROG",
           "SCHEMA_ENCODING", "McapRecorder", "RecorderStats", "build_parser", "envelope_schema",
           "main", "record", "require_recording"]

log = logging.getLogger(__name__)

MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
GENERIC_SCHEMA_NAME = "ubf.generic"
"""The schema of messages whose schema name :mod:`ubf_async.wire.topics` does not declare."""
DEFAULT_FLUSH_S = 1.0
DEFAULT_MAX_QUEUE = 20_000
DEFAULT_CHUNK_BYTES = 1 << 20
DEFAULT_DRAIN_S = 2.0
"""How long closing a recorder waits for the disk to take what is queued (part of a bounded
stop: ubf_async.cli.run.STOP_BOUND_S); the rest is dropped, counted, and the file finished."""
ABANDON_S = 0.5
"""How long finishing the file (its index) may then take."""


def envelope_schema(topic: Topic[Any] | None) -> dict[str, Any]:
    """The JSON Schema of a whole envelope carrying ``topic``'s data (any map of plain
    values for ``None``: an undeclared schema)."""
    data_type: Any = topic.type if topic is not None else PlainData
    (data,), components = msgspec.json.schema_components([data_type],
                                                         ref_template="#/$defs/{name}")
    properties: dict[str, Any] = {
        "schema": ({"const": topic.schema} if topic is not None
                   else {"type": "string", "minLength": 1, "maxLength": 64}),
        "v": {"type": "integer", "minimum": 1},
        "stamp_ns": {"type": "integer", "minimum": 0,
                     "description": "when the data was true, on the robot's clock (ns)"},
        "seq": {"type": "integer", "minimum": 0},
        "pub": {"type": "integer", "minimum": 1, "description": "the publisher's identity"},
        "period_s": {"type": "number", "description": "the publisher's nominal period"},
        "data": data,
    }
    data, components = _msgpack_bytes(data), _msgpack_bytes(components)
    schema: dict[str, Any] = {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": topic.schema if topic is not None else GENERIC_SCHEMA_NAME,
        "description": (f"ubf_async envelope (protocol v{PROTOCOL_VERSION}), msgpack-encoded: "
                        + (topic.doc if topic is not None else "data of an undeclared schema")),
        "type": "object",
        "properties": properties,
        "required": ["schema", "v", "stamp_ns", "seq", "data"],
    }
    if components:
        schema["$defs"] = components
    return schema


def _msgpack_bytes(node: Any) -> Any:
    """JSON Schema has no bytes: msgspec writes them as base64 strings, msgpack carries them
    as ``bin``. Such a field is described (``x-msgpack: bin``) and left unconstrained."""
    if isinstance(node, dict):
        if node.get("contentEncoding") == "base64":
            return {"description": "bytes (msgpack bin)", "x-msgpack": "bin"}
        return {k: _msgpack_bytes(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_msgpack_bytes(v) for v in node]
    return node


@dataclass
class RecorderStats:
    """What a recorder did (read from any thread; written by the loop, the writer and the
    writer's fsyncs)."""

    received: int = 0
    written: int = 0
    dropped: int = 0
    """Messages the writer could not keep up with (the queue was full)."""
    invalid: int = 0
    """Messages that are not a valid envelope (recorded all the same)."""
    flushes: int = 0
    """Chunks closed and synced to the disk (``fsync``)."""
    synced: int = 0
    """Of the messages written, those on the disk: written before the last flush whose
    ``fsync`` returned."""
    sync_s_max: float = 0.0
    """The longest ``fsync`` so far (s): what durability costs the writer."""
    live: int = 0
    """Messages of the live view's Foxglove channels written beside them."""
    files: list[Path] = field(default_factory=list)
    error: str | None = None
    """Why writing stopped, if it did (a full disk)."""


def require_recording(*, live_channels: bool = True, who: str) -> None:
    """The record extra (mcap, and foxglove-sdk for the live view's channels), or one line
    saying how to install it: called where a recording is asked for, before anything starts."""
    extras.require("record", "mcap", who=who)
    if live_channels:
        extras.require("record", "foxglove", who=who)


_WAKE: tuple[str, bytes, int] = ("", b"", 0)
"""Queued (by identity) to wake the writer thread at once when the file must be finished now."""


class McapRecorder(EveryMessageComponent):
    """Records every message on the robot's keys to MCAP (module docstring).

    ``out`` is a directory (the file is ``<robot>.mcap`` in it) or a ``.mcap`` file.
    Start it before the components whose messages it should catch; closing it (``aclose``,
    idempotent) writes what is queued and finishes the file with its index.
    """

    def __init__(self, *, bus: Bus, out: Path, name: str = "recorder",
                 flush_s: float = DEFAULT_FLUSH_S, split_bytes: int | None = None,
                 max_queue: int = DEFAULT_MAX_QUEUE, chunk_bytes: int = DEFAULT_CHUNK_BYTES,
                 on_flush: Any = None, live_channels: bool = True,
                 drain_s: float = DEFAULT_DRAIN_S) -> None:
        require_recording(live_channels=live_channels, who="recording")
        super().__init__(bus=bus, name=name)
        self.drain_s = drain_s
        if not flush_s > 0:
            raise ConfigurationError(f"flush_s must be > 0, got {flush_s}")
        if split_bytes is not None and split_bytes < 1 << 16:
            raise ConfigurationError(f"split_bytes must be at least 64 KiB, got {split_bytes}")
        self.path = out / f"{bus.robot}.mcap" if out.suffix != ".mcap" else out
        self.flush_s = flush_s
        self.split_bytes = split_bytes
        self.chunk_bytes = chunk_bytes
        self.stats = RecorderStats()
        self._queue: queue.Queue[tuple[str, bytes, int]] = queue.Queue(maxsize=max_queue)
        self._stop = threading.Event()
        self._abandon = threading.Event()
        """Finish the file now, dropping what is still queued (an exit that cannot wait)."""
        self._thread: threading.Thread | None = None
        self._unregister_exit_now: Callable[[], None] | None = None
        self._on_flush = on_flush
        """Called on the writer thread after each flush with the stats (progress output)."""
        self.live_view = LiveView(robot_prefix=bus.keys.prefix) if live_channels else None
        """Converts on the writer thread what it records into the live view's Foxglove
        channels (:mod:`ubf_async.services.liveview`), written beside the original messages."""

    async def start(self) -> None:
        """Start the writer, then subscribe. A folder that cannot be made raises ``OSError``
        here; a file that cannot be written stops the writer (``stats.error``, logged)."""
        if self._thread is None and not self.closed:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._thread = threading.Thread(target=self._write_all, name=f"{self.name}:mcap",
                                            daemon=True)
            self._thread.start()
            # Even a process that exits at once (a second Ctrl-C) leaves a finished file.
            self._unregister_exit_now = ending.on_exit_now(self._finish_now)
        await super().start()

    def _on_message(self, key: str, payload: bytes, received_ns: int) -> None:
        self.stats.received += 1
        try:
            self._queue.put_nowait((key, payload, self.bus.clock.now_ns()))
        except queue.Full:
            self.stats.dropped += 1
            if throttle.first_and_every(self.stats.dropped, 1000):
                log.warning("%s: the writer is behind; %d messages dropped so far", self.name,
                            self.stats.dropped)

    def _finish_now(self, timeout_s: float) -> None:
        """For :func:`ubf_async.cli.ending.exit_now` (another thread): finish the file at once."""
        self._abandon.set()
        self._stop.set()
        with contextlib.suppress(queue.Full):  # full: the writer is not waiting for one
            self._queue.put_nowait(_WAKE)  # now, not at the end of its wait for a message
        thread = self._thread
        if thread is not None:
            thread.join(timeout_s)

    @property
    def queued(self) -> int:
        """Messages received and not yet written (what a kill now would lose besides the
        last ``flush_s``)."""
        return self._queue.qsize()

    async def aclose(self) -> None:
        """Stop receiving, write what is queued — for at most ``drain_s``: past it the rest
        is dropped (counted) — and finish the file with its index."""
        if self.closed:
            return
        await super().aclose()  # no more messages arrive
        self._stop.set()
        thread = self._thread
        if thread is not None:
            await asyncio.to_thread(thread.join, self.drain_s)
            if thread.is_alive():
                left = self._queue.qsize()
                log.warning("%s: the disk did not take the last %d messages within %g s: "
                            "finishing the file without them", self.name, left, self.drain_s)
                self.stats.dropped += left
                self._abandon.set()
                await asyncio.to_thread(thread.join, ABANDON_S)
            self._thread = None
        if self._unregister_exit_now is not None:
            self._unregister_exit_now()
        if self.stats.dropped:
            log.warning("%s: %d of %d messages dropped (the writer could not keep up)",
                        self.name, self.stats.dropped, self.stats.received)

    # -- the writer thread ---------------------------------------------------------------------
    def _write_all(self) -> None:
        file: _File | None = None
        try:
            file = _File(self, 0)
            last_flush = time.monotonic()
            while True:
                try:
                    item = self._queue.get(timeout=self.flush_s / 4)
                except queue.Empty:
                    item = None
                if item is _WAKE:
                    item = None
                if item is not None:
                    file.write(*item)
                    self.stats.written += 1
                if (time.monotonic() - last_flush >= self.flush_s
                        and not self._abandon.is_set()):  # finishing now: finish() syncs
                    file.flush()
                    last_flush = time.monotonic()
                    if self.split_bytes is not None and file.size() >= self.split_bytes:
                        file.finish()
                        file = _File(self, len(self.stats.files))
                if self._abandon.is_set() or (item is None and self._stop.is_set()
                                              and self._queue.empty()):
                    break
        except OSError as exc:
            self.stats.error = str(exc)
            log.error("%s: writing %s failed: %s; recording stopped", self.name,
                      file.path if file is not None else self.path, exc)
        finally:
            if file is not None:
                with contextlib.suppress(OSError):
                    file.finish()


class _File:
    """One MCAP file of a recording, used by the writer thread only (its fsyncs run on a
    thread of their own)."""

    def __init__(self, recorder: McapRecorder, index: int) -> None:
        self.recorder = recorder
        base = recorder.path
        self.path = base if index == 0 else base.with_name(f"{base.stem}_{index}{base.suffix}")
        self.stream: IO[bytes] = self.path.open("wb")
        recorder.stats.files.append(self.path)
        from mcap.writer import CompressionType, Writer  # the record extra: McapRecorder

        self.writer = Writer(self.stream, chunk_size=recorder.chunk_bytes,
                             compression=CompressionType.ZSTD)
        self.writer.start(profile="", library=f"ubf_async {__version__}")
        self.writer.add_metadata("ubf_async", {
            "robot": recorder.bus.robot, "version": __version__,
            "protocol": str(PROTOCOL_VERSION), "part": str(index),
            "clock": "simulated" if recorder.bus.clock.is_simulated
            else "monotonic"})
        self.schemas: dict[str, int] = {}
        self.channels: dict[tuple[str, int], int] = {}
        self.sequence = 0
        self.finished = False
        self.synced_dir = False
        self._syncing: threading.Thread | None = None
        """The fsync of the last flush, while it runs."""

    def _schema_id(self, name: str) -> int:
        topic = BY_SCHEMA.get(name)
        key = name if topic is not None else GENERIC_SCHEMA_NAME
        found = self.schemas.get(key)
        if found is None:
            found = self.writer.register_schema(
                name=key, encoding=SCHEMA_ENCODING,
                data=json.dumps(envelope_schema(topic)).encode())
            self.schemas[key] = found
        return found

    def write(self, key: str, payload: bytes, log_ns: int) -> None:
        message: Message[Any] | None
        try:
            message = decode(payload)
            schema_name, publish_ns = message.schema, message.stamp_ns
        except ProtocolError:
            self.recorder.stats.invalid += 1
            message, schema_name, publish_ns = None, GENERIC_SCHEMA_NAME, log_ns
        schema_id = self._schema_id(schema_name)
        channel = self.channels.get((key, schema_id))
        if channel is None:
            channel = self.writer.register_channel(topic=key, message_encoding=MESSAGE_ENCODING,
                                                   schema_id=schema_id)
            self.channels[(key, schema_id)] = channel
        self.sequence += 1
        self.writer.add_message(channel_id=channel, log_time=log_ns, data=payload,
                                publish_time=publish_ns, sequence=self.sequence)
        if self.recorder.live_view is not None and message is not None:
            for live in self.recorder.live_view.convert(key, message, log_ns):
                self._write_live(live, publish_ns)

    def _write_live(self, live: LiveMessage, publish_ns: int) -> None:
        """A live view's message, on its own channel (its topic starts with ``/``; the
        original messages' topics are the keys, which never do)."""
        schema_key = f"{live.schema.encoding}:{live.schema.name}"
        schema_id = self.schemas.get(schema_key)
        if schema_id is None:
            schema_id = self.writer.register_schema(
                name=live.schema.name, encoding=live.schema.encoding, data=live.schema.data)
            self.schemas[schema_key] = schema_id
        channel = self.channels.get((live.topic, schema_id))
        if channel is None:
            channel = self.writer.register_channel(topic=live.topic,
                                                   message_encoding=live.encoding,
                                                   schema_id=schema_id)
            self.channels[(live.topic, schema_id)] = channel
        self.sequence += 1
        self.recorder.stats.live += 1
        self.writer.add_message(channel_id=channel, log_time=live.log_time_ns, data=live.data,
                                publish_time=publish_ns, sequence=self.sequence)

    def flush(self) -> None:
        self.writer.flush()  # closes the chunk
        self.stream.flush()  # ... and hands it to the kernel: a killed process loses nothing
        # ... then onto the disk, without which a power cut loses what the kernel still
        # caches: on a thread of its own, not this one. On a busy disk one fsync can wait
        # seconds (ext4 commits other files' data with it), and this thread must stay free to
        # finish the file within the second an exit at once gives it. A sync still running
        # covers this chunk's turn: the next flush syncs it.
        if self._syncing is None or not self._syncing.is_alive():
            self._syncing = threading.Thread(target=self._sync,
                                             args=(self.recorder.stats.written,), daemon=True,
                                             name=f"{self.recorder.name}:fsync")
            self._syncing.start()

    def _sync(self, written: int) -> None:
        """Sync the file, whose first ``written`` messages the kernel has."""
        started = time.monotonic()
        try:
            os.fsync(self.stream.fileno())
            if not self.synced_dir:  # the new file's directory entry too, once
                self.synced_dir = True
                _fsync_dir(self.path.parent)
        except OSError as exc:  # the writes themselves went through: said, not fatal
            log.warning("%s: syncing %s to the disk failed: %s", self.recorder.name,
                        self.path, exc)
            return
        stats = self.recorder.stats
        stats.sync_s_max = max(stats.sync_s_max, time.monotonic() - started)
        stats.synced = max(stats.synced, written)
        stats.flushes += 1
        if self.recorder._on_flush is not None:
            self.recorder._on_flush(self.recorder.stats)

    def size(self) -> int:
        return self.stream.tell()

    def finish(self) -> None:
        if self.finished:
            return
        self.finished = True
        try:
            self.writer.finish()  # leaves its last bytes (the footer's magic) in our buffer
            # Handed to the kernel before any fsync, not after: a process that exits at once
            # (a second signal: exit_now's budget) while an fsync waits on a busy disk still
            # leaves a finished file; the last fsync then covers the whole of it.
            self.stream.flush()
            if self._syncing is not None:
                self._syncing.join()  # (the descriptor it syncs is closed below)
            os.fsync(self.stream.fileno())
        finally:
            self.stream.close()


def _fsync_dir(path: Path) -> None:
    """Make a new file's directory entry durable (POSIX: fsync the directory). Some file
    systems refuse it; the file's own data is synced regardless."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# -- python -m ubf_async.record --------------------------------------------------------------

PROG = "python -m ubf_async.record"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=HelpFormatter,
        description="Record every message on a running robot's keys to an MCAP file "
                    "(docs/recording.md), from another process. Ctrl-C or SIGTERM ends the "
                    "recording and finishes the file.")
    add_connection_arguments(parser, default_connect=[DEFAULT_LISTEN])
    parser.add_argument("--out", type=Path, default=Path("recordings"), metavar="DIR|FILE",
                        help="a directory (the file is <robot>.mcap in it) or a .mcap file")
    add_attach_arguments(parser, name="recorder", who="the recorder")
    parser.add_argument("--flush-s", type=float, default=DEFAULT_FLUSH_S, metavar="S",
                        help="close a chunk and fsync the file every S seconds: a killed "
                             "recorder loses at most the last S seconds, plus what is queued")
    parser.add_argument("--split-mb", type=float, default=None, metavar="MB",
                        help="start a new file when one grows past MB megabytes")
    parser.add_argument("--no-live-channels", dest="live_channels", action="store_false",
                        help="record only the original messages (by default the live view's "
                             "Foxglove channels are recorded beside them)")
    parser.add_argument("--progress", action="store_true",
                        help="print a line after every flush: messages written (on the disk), "
                             "dropped and still queued")
    return parser


async def record(args: argparse.Namespace) -> int:
    require_recording(live_channels=args.live_channels, who=PROG)
    async with attached_bus(args) as bus:
        await ensure_name_free(bus, args.name, hint="give this recorder another --name")

        def progress(stats: RecorderStats) -> None:
            # After a flush's fsync: the synced messages are on the disk; the queued ones, and
            # those written since, not yet.
            print(f"recorded {stats.synced} messages ({stats.dropped} dropped, "
                  f"{recorder.queued} queued) to {stats.files[-1]}", flush=True)

        recorder = McapRecorder(
            bus=bus, out=args.out, name=args.name, flush_s=args.flush_s,
            split_bytes=None if args.split_mb is None else int(args.split_mb * 1e6),
            on_flush=progress if args.progress else None, live_channels=args.live_channels)
        await recorder.start()
        try:
            print(f"{PROG}: recording robot {bus.robot!r} to {recorder.path}", flush=True)
            await run_until_stopped(args.duration)
            return 0
        finally:
            await recorder.aclose()
            stats = recorder.stats
            print(f"{PROG}: {stats.written} messages"
                  + (f" and {stats.live} in the live view's Foxglove channels"
                     if stats.live else "")
                  + f" in {', '.join(map(str, stats.files))}"
                  + (f"; {stats.dropped} dropped" if stats.dropped else "")
                  + (f"; writing failed: {stats.error}" if stats.error else ""), flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level="WARNING", format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return run_main(lambda: record(args), prog=PROG)


if __name__ == "__main__":
    raise SystemExit(main())
