"""A small client of the Foxglove WebSocket protocol (``foxglove.sdk.v1``) for tests, written
from the protocol's specification: it reads the server's ``advertise`` messages, subscribes to
channels by topic and decodes each message with the schema the server advertised (protobuf via
the file descriptor set, or JSON). Nothing of ubf_async is imported.

A subscription sent just as a channel is advertised can reach foxglove-sdk's server before it
has registered the channel for this client (seen with foxglove-sdk 0.30.3: a ``status``
"Unknown channel ID: N" and no messages); the client then subscribes again, a few times at
most."""

from __future__ import annotations

import base64
import contextlib
import json
import re
import struct
import time
from dataclasses import dataclass
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.sync.client import ClientConnection, connect

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01
UNKNOWN_CHANNEL = re.compile(r"Unknown channel ID: (\d+)")
RESUBSCRIBE_ATTEMPTS = 5


@dataclass
class Received:
    topic: str
    schema_name: str
    encoding: str
    log_time_ns: int
    payload: bytes
    decoded: Any


class FoxgloveClient:
    def __init__(self, url: str, *, timeout_s: float = 10.0) -> None:
        self._stack = contextlib.ExitStack()
        self.ws: ClientConnection = self._stack.enter_context(
            connect(url, subprotocols=[SUBPROTOCOL], open_timeout=timeout_s, max_size=None))
        self.channels: dict[int, dict[str, Any]] = {}
        self.server_info: dict[str, Any] | None = None
        self.subscriptions: dict[int, int] = {}
        self.resubscribed: dict[int, int] = {}
        """Subscribe messages sent again, per channel (see the module docstring)."""
        self._classes: dict[int, Any] = {}
        self._next_id = 1

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> FoxgloveClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def by_topic(self) -> dict[str, dict[str, Any]]:
        return {c["topic"]: c for c in self.channels.values()}

    def _handle_text(self, text: str) -> None:
        message = json.loads(text)
        if message["op"] == "serverInfo":
            self.server_info = message
        elif message["op"] == "advertise":
            for channel in message["channels"]:
                self.channels[channel["id"]] = channel
        elif message["op"] == "unadvertise":
            for channel_id in message["channelIds"]:
                self.channels.pop(channel_id, None)
        elif message["op"] == "status" and (unknown := UNKNOWN_CHANNEL.search(
                message.get("message", ""))):
            self._subscribe_again(int(unknown[1]))

    def _subscribe_again(self, channel_id: int) -> None:
        again = [{"id": sub_id, "channelId": channel_id}
                 for sub_id, subscribed in self.subscriptions.items() if subscribed == channel_id]
        tries = self.resubscribed.get(channel_id, 0)
        if again and channel_id in self.channels and tries < RESUBSCRIBE_ATTEMPTS:
            self.resubscribed[channel_id] = tries + 1
            self.ws.send(json.dumps({"op": "subscribe", "subscriptions": again}))

    def _receive(self, deadline: float) -> Received | None:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise TimeoutError("nothing more from the Foxglove server")
        frame = self.ws.recv(timeout=remaining)
        if isinstance(frame, str):
            self._handle_text(frame)
            return None
        if frame[0] != MESSAGE_DATA:
            return None
        subscription, log_time_ns = struct.unpack_from("<IQ", frame, 1)
        payload = bytes(frame[13:])
        channel = self.channels[self.subscriptions[subscription]]
        return Received(topic=channel["topic"], schema_name=channel["schemaName"],
                        encoding=channel["encoding"], log_time_ns=log_time_ns,
                        payload=payload, decoded=self._decode(channel, payload))

    def wait_for_topics(self, topics: set[str], *, timeout_s: float = 20.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not topics <= set(self.by_topic()):
            self._receive(deadline)

    def subscribe(self, topics: set[str]) -> None:
        by_topic = self.by_topic()
        subscriptions = []
        for topic in sorted(topics):
            sub_id, self._next_id = self._next_id, self._next_id + 1
            self.subscriptions[sub_id] = by_topic[topic]["id"]
            subscriptions.append({"id": sub_id, "channelId": by_topic[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def collect(self, topics: set[str], *, per_topic: int = 1,
                timeout_s: float = 20.0,
                at_least: dict[str, int] | None = None) -> dict[str, list[Received]]:
        """Messages of each of ``topics`` until every one has ``per_topic`` (or its own count
        in ``at_least``)."""
        got: dict[str, list[Received]] = {t: [] for t in topics}
        wanted = {t: (at_least or {}).get(t, per_topic) for t in topics}
        deadline = time.monotonic() + timeout_s
        while any(len(v) < wanted[t] for t, v in got.items()):
            try:
                received = self._receive(deadline)
            except TimeoutError:
                short = {t: f"{len(v)} of {wanted[t]}" for t, v in sorted(got.items())
                         if len(v) < wanted[t]}
                raise TimeoutError(f"in {timeout_s} s, too few messages of {short}") from None
            if received is not None and received.topic in got:
                got[received.topic].append(received)
        return got

    def _decode(self, channel: dict[str, Any], payload: bytes) -> Any:
        if channel["encoding"] == "json":
            return json.loads(payload)
        if channel["encoding"] != "protobuf":
            raise ValueError(f"cannot decode {channel['encoding']}")
        cls = self._classes.get(channel["id"])
        if cls is None:
            files = descriptor_pb2.FileDescriptorSet.FromString(
                base64.b64decode(channel["schema"]))
            pool = descriptor_pool.DescriptorPool()
            for file in files.file:
                pool.Add(file)
            cls = message_factory.GetMessageClass(
                pool.FindMessageTypeByName(channel["schemaName"]))
            self._classes[channel["id"]] = cls
        return cls.FromString(payload)


def protobuf_class(schema_name: str, descriptor_set: bytes) -> Any:
    """The protobuf message class of ``schema_name`` from a serialized file descriptor set (as
    MCAP files and the server carry it)."""
    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set)
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))
