"""Test helpers: decode Foxglove protobuf messages from their schemas, and a minimal client of
the Foxglove WebSocket protocol (``foxglove.sdk.v1`` / ``foxglove.websocket.v1``) on top of
websocket-client.

Protocol (https://github.com/foxglove/ws-protocol, spec/ws-protocol.md): the server sends JSON
text frames ``serverInfo`` and ``advertise`` (channels with id, topic, encoding, schemaName,
schema, schemaEncoding; protobuf schemas are a base64 FileDescriptorSet); the client sends
``{"op": "subscribe", "subscriptions": [{"id": SUB, "channelId": CH}]}``; the server then sends
binary frames ``0x01 | uint32 LE subscription id | uint64 LE log time ns | payload``.
"""

from __future__ import annotations

import base64
import json
import struct
import threading
import time
from collections import defaultdict
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory


class ProtobufDecoder:
    """Decode messages given a schema name and its FileDescriptorSet bytes."""

    def __init__(self) -> None:
        self.pool = descriptor_pool.DescriptorPool()
        self._classes: dict[str, Any] = {}

    def add(self, name: str, fds_bytes: bytes) -> None:
        if name in self._classes:
            return
        fds = descriptor_pb2.FileDescriptorSet.FromString(fds_bytes)
        for f in fds.file:
            try:
                self.pool.Add(f)
            except TypeError:  # already there (shared imports such as timestamp.proto)
                pass
        self._classes[name] = message_factory.GetMessageClass(self.pool.FindMessageTypeByName(name))

    def decode(self, name: str, data: bytes) -> Any:
        return self._classes[name].FromString(data)


class FoxgloveClient:
    """Connect, collect advertised channels, subscribe to topics, and gather decoded messages
    in a background thread."""

    def __init__(self, url: str, *, timeout_s: float = 5.0) -> None:
        import websocket

        self.ws = websocket.create_connection(
            url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"], timeout=timeout_s
        )
        self.channels: dict[str, dict[str, Any]] = {}
        self.by_sub: dict[int, dict[str, Any]] = {}
        self.messages: dict[str, list[tuple[int, Any]]] = defaultdict(list)
        self.raw_counts: dict[str, int] = defaultdict(int)
        self.server_info: dict[str, Any] | None = None
        self.decoder = ProtobufDecoder()
        self._lock = threading.Lock()
        self._next_sub = 1
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import websocket

        self.ws.settimeout(0.2)
        while not self._stop.is_set():
            try:
                frame = self.ws.recv()
            except websocket.WebSocketTimeoutException:
                continue
            except (websocket.WebSocketConnectionClosedException, OSError):
                return
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "serverInfo":
                    self.server_info = msg
                elif msg["op"] == "advertise":
                    with self._lock:
                        for ch in msg["channels"]:
                            self.channels[ch["topic"]] = ch
                continue
            op, sub_id, log_time = struct.unpack_from("<BIQ", frame, 0)
            if op != 1:
                continue
            ch = self.by_sub.get(sub_id)
            if ch is None:
                continue
            payload = frame[13:]
            topic = ch["topic"]
            self.raw_counts[topic] += 1
            if ch["encoding"] == "json":
                value: Any = json.loads(payload)
            elif ch["encoding"] == "protobuf":
                value = self.decoder.decode(ch["schemaName"], payload)
            else:
                value = payload
            with self._lock:
                self.messages[topic].append((log_time, value))

    def wait_for_channels(self, topics: list[str], timeout_s: float = 5.0) -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self._lock:
                if all(t in self.channels for t in topics):
                    return
            time.sleep(0.02)
        raise AssertionError(f"channels {topics} not advertised; have {sorted(self.channels)}")

    def subscribe(self, topics: list[str]) -> None:
        self.wait_for_channels(topics)
        subs = []
        with self._lock:
            for t in topics:
                ch = self.channels[t]
                if ch["encoding"] == "protobuf":
                    self.decoder.add(ch["schemaName"], base64.b64decode(ch["schema"]))
                sid = self._next_sub
                self._next_sub += 1
                self.by_sub[sid] = ch
                subs.append({"id": sid, "channelId": ch["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def wait_for(
        self, topic: str, count: int = 1, timeout_s: float = 10.0
    ) -> list[tuple[int, Any]]:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self._lock:
                got = list(self.messages.get(topic, []))
            if len(got) >= count:
                return got
            time.sleep(0.02)
        raise AssertionError(f"{topic}: {len(self.messages.get(topic, []))} of {count} messages")

    def close(self) -> None:
        self._stop.set()
        try:
            self.ws.close()
        finally:
            self._thread.join(timeout=2)

    def drop(self) -> None:
        """Vanish without a close handshake (a client whose link dies)."""
        sock = self.ws.sock
        self._stop.set()
        if sock is not None:
            sock.shutdown(2)
            sock.close()
        self._thread.join(timeout=2)
