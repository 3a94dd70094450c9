"""A minimal Foxglove WebSocket protocol (v1) client for the tests, on the standard library.

The venv has no WebSocket client library, and the test should not trust foxglove-sdk to check
itself: this speaks RFC 6455 over a plain socket (the opening handshake with the subprotocol,
masked client frames, fragmented server frames, ping/pong, close) and the protocol's JSON ops
and binary message frames. Every read is bounded by the socket's timeout.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import select
import socket
import struct
import time
from dataclasses import dataclass

_GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"
TEXT, BINARY, CLOSE, PING, PONG = 0x1, 0x2, 0x8, 0x9, 0xA
#: binary op of a message data frame (server to client)
MESSAGE_DATA = 0x01


@dataclass
class MessageFrame:
    subscription: int
    log_time_ns: int
    payload: bytes


class FoxgloveClient:
    def __init__(self, port: int, host: str = "127.0.0.1",
                 subprotocol: str = "foxglove.sdk.v1", timeout_s: float = 10.0) -> None:
        """Connect offering `subprotocol` (comma-separated names: several, as apps offer)."""
        self.sock = socket.create_connection((host, port), timeout=timeout_s)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
             f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
             f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {subprotocol}\r\n\r\n"
             ).encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(1)
            if not chunk:
                raise ConnectionError(f"handshake cut short: {head!r}")
            head += chunk
        lines = head.decode("latin-1").split("\r\n")
        self.status = lines[0]
        self.headers = {k.strip().lower(): v.strip()
                        for k, _, v in (line.partition(":") for line in lines[1:] if line)}
        if " 101 " not in self.status + " ":
            raise ConnectionError(f"no upgrade: {self.status}")
        accept = base64.b64encode(hashlib.sha1((key + _GUID).encode()).digest()).decode()
        if self.headers.get("sec-websocket-accept") != accept:
            raise ConnectionError("bad Sec-WebSocket-Accept")
        self.subprotocol = self.headers.get("sec-websocket-protocol")
        self.ops: list[dict] = []  # every JSON op received, in order
        self._next_subscription = 1

    # -- frames ----------------------------------------------------------------------------
    def _exact(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("connection closed")
            data += chunk
        return data

    def _frame(self) -> tuple[bool, int, bytes]:
        b0, b1 = self._exact(2)
        length = b1 & 0x7F
        if length == 126:
            length = struct.unpack("!H", self._exact(2))[0]
        elif length == 127:
            length = struct.unpack("!Q", self._exact(8))[0]
        mask = self._exact(4) if b1 & 0x80 else None
        data = self._exact(length)
        if mask:
            data = bytes(b ^ mask[i % 4] for i, b in enumerate(data))
        return bool(b0 & 0x80), b0 & 0x0F, data

    def _send(self, opcode: int, data: bytes) -> None:
        mask = os.urandom(4)
        n = len(data)
        head = bytes([0x80 | opcode])
        if n < 126:
            head += bytes([0x80 | n])
        elif n < 1 << 16:
            head += bytes([0x80 | 126]) + struct.pack("!H", n)
        else:
            head += bytes([0x80 | 127]) + struct.pack("!Q", n)
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))

    def receive(self) -> tuple[int, bytes]:
        """The next whole data message (opcode, payload); pings are answered."""
        opcode, parts = None, []
        while True:
            fin, op, data = self._frame()
            if op == PING:
                self._send(PONG, data)
                continue
            if op == PONG:
                continue
            if op == CLOSE:
                raise ConnectionError(f"closed by the server: {data!r}")
            if op != 0:
                opcode = op
            parts.append(data)
            if fin:
                return opcode, b"".join(parts)

    # -- the protocol ----------------------------------------------------------------------
    def send_op(self, op: str, **fields) -> None:
        self._send(TEXT, json.dumps({"op": op, **fields}).encode())

    def next_event(self) -> dict | MessageFrame:
        """The next JSON op (also kept in `ops`) or message data frame."""
        opcode, data = self.receive()
        if opcode == TEXT:
            op = json.loads(data)
            self.ops.append(op)
            return op
        if data[0] != MESSAGE_DATA:
            return {"op": f"binary-{data[0]}"}
        sub, stamp = struct.unpack_from("<IQ", data, 1)
        return MessageFrame(sub, stamp, data[13:])

    def poll(self, wait_s: float) -> dict | MessageFrame | None:
        """The next event if one starts arriving within `wait_s`, else None (a frame begun is
        read whole, within the socket's timeout)."""
        ready, _, _ = select.select([self.sock], [], [], wait_s)
        return self.next_event() if ready else None

    def channels(self) -> dict[str, dict]:
        """topic -> channel of every advertise op received so far (unadvertised ones gone)."""
        out: dict[str, dict] = {}
        for op in self.ops:
            if op["op"] == "advertise":
                out.update({c["topic"]: c for c in op["channels"]})
            elif op["op"] == "unadvertise":
                gone = set(op["channelIds"])
                out = {t: c for t, c in out.items() if c["id"] not in gone}
        return out

    def wait_for_channels(self, topics: set[str], timeout_s: float = 30.0) -> dict[str, dict]:
        deadline = time.monotonic() + timeout_s
        while not topics <= set(self.channels()):
            if time.monotonic() > deadline:
                raise TimeoutError(f"advertised: {sorted(self.channels())}, wanted {topics}")
            self.next_event()
        return self.channels()

    def subscribe(self, channels: dict[str, dict]) -> dict[int, str]:
        """Subscribe to each channel; subscription id (new ones) -> topic."""
        subs = {i: topic for i, topic in enumerate(sorted(channels), start=self._next_subscription)}
        self._next_subscription += len(subs)
        self.send_op("subscribe", subscriptions=[
            {"id": i, "channelId": channels[topic]["id"]} for i, topic in subs.items()])
        return subs

    def close(self) -> None:
        try:
            self._send(CLOSE, struct.pack("!H", 1000))
        except OSError:
            pass
        self.sock.close()

    def __enter__(self) -> FoxgloveClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
