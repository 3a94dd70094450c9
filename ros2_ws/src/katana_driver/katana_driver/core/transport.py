"""TCP and serial links to the Katana controller: one request at a time, exact-length reads.

The vendor library read TCP replies with one read and no timeout and hung when a reply was
split or never came. Here every read gathers exactly the expected number of bytes before a
deadline; a short reply or a bad CRC is re-sent up to ``retries`` times (after an echo that
flushes late replies, so that a stale reply is never taken for the next one), then a
TransportError says what went wrong. A refusal (0xC0) is followed by the raw 0xC1 request
and raised as protocol.ControllerError, which is not retried: the controller meant it.

Only idempotent requests (reads, echo, hold, flush, off, limits) are re-sent. A command whose
repetition would act twice (a spline segment, a motor move, calibration) goes through
``command``: sent once; on a lost, corrupt or late reply the echo that resynchronises the link
also tells what happened, because the controller answers in order: a late or corrupt reply
before the echo's means it took the command; nothing before the echo's raises NoReply.
"""

from __future__ import annotations

import socket
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass, field

import serial

from .protocol import (
    ERROR_BYTE,
    ERROR_QUERY,
    ERROR_REPLY_LEN,
    CrcError,
    ProtocolError,
    check_reply,
    decode_error_reply,
    frame_reply,
    frame_request,
)

_ERROR_FRAME = frame_reply(bytes((ERROR_BYTE,)))  # C0 and its CRC
_ECHO_FRAME = frame_request(b"Z")
_ECHO_REPLY = frame_reply(b"z")


class TransportError(Exception):
    """No valid reply after every retry, or the link is not usable."""


class LinkDown(TransportError):
    """The connection is closed or broken; reconnecting may help."""


class NoReply(TransportError):
    """A command sent once got no reply at all, not even late: whether the controller applied
    it is unknown, so the caller reads the controller's state to learn it (never re-sends)."""


@dataclass
class LinkStats:
    retries: int = 0
    timeouts: int = 0
    crc_errors: int = 0
    replies: int = 0  # valid replies, whose request-to-reply times `latency_s` keeps (last 100)
    latency_s: deque = field(default_factory=lambda: deque(maxlen=100))

    def note_reply(self, seconds: float) -> None:
        self.replies += 1
        self.latency_s.append(seconds)


class Transport(ABC):
    """Request/reply framing over a byte link, serialised by a lock."""

    def __init__(self, timeout: float = 0.5, retries: int = 3) -> None:
        if timeout <= 0.0:
            raise ValueError("timeout must be positive")
        if retries < 0:
            raise ValueError("retries must be >= 0")
        self.timeout = timeout
        self.retries = retries
        self.stats = LinkStats()
        self._lock = threading.Lock()
        self._dirty = False  # a request failed: late replies may still come
        self._link = None  # the open socket or serial port; None while closed

    # -------------------------------------------------------------- link primitives
    @property
    @abstractmethod
    def name(self) -> str:
        """Where the link goes, for messages (``tcp 192.168.1.1:5566``)."""

    @property
    def is_open(self) -> bool:
        return self._link is not None

    def open(self) -> None:
        """Open the link (closing an open one first); raises LinkDown with the reason when it
        cannot."""
        self.close()
        try:
            self._link = self._connect()
        except OSError as exc:  # pyserial's SerialException is an OSError too
            raise LinkDown(f"{self.name}: cannot connect ({exc})") from exc

    @abstractmethod
    def _connect(self):
        """A new open link: a socket, or a serial port (raises OSError when it cannot)."""

    def _open_link(self):
        """The open link; OSError (the link is lost, for `_guarded`) when it was closed."""
        if self._link is None:
            raise OSError("the link is closed")
        return self._link

    def close(self) -> None:
        link, self._link = self._link, None
        if link is not None:
            try:
                link.close()
            except OSError:
                pass

    @abstractmethod
    def _write(self, data: bytes) -> None:
        """All of ``data``; raises OSError when the link is closed or broken."""

    @abstractmethod
    def _read_some(self, n: int, timeout: float) -> bytes:
        """At most ``n`` bytes, waiting at most ``timeout`` s for the first (b"": none came);
        raises OSError when the link is closed or broken."""

    def _read_until(self, n: int, deadline: float) -> bytes:
        """Up to ``n`` bytes; fewer only when ``deadline`` (time.monotonic) passed."""
        buf = bytearray()
        while len(buf) < n:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                break
            buf += self._read_some(n - len(buf), remaining)
        return bytes(buf)

    def _resync(self) -> bool:
        """Send an echo and discard every byte up to its reply.

        The controller answers in order, so once the echo's reply is in, no late reply of an
        earlier attempt is left to be taken for the next one (a quiet period cannot promise
        that: replies may be late by any amount).
        """
        return self._resync_collect() is not None

    # -------------------------------------------------------------- requests
    def request(self, payload: bytes, reply_len: int) -> bytes:
        """Send one command and return its reply payload (CRC checked)."""
        frame = frame_request(payload)
        letter = chr(payload[0]) if 32 <= payload[0] < 127 else f"0x{payload[0]:02X}"
        with self._lock:
            if not self.is_open:
                raise LinkDown(f"{self.name}: not connected")
            problems: list[str] = []
            for attempt in range(self.retries + 1):
                if attempt or self._dirty:
                    if attempt:
                        self.stats.retries += 1
                    if not self._guarded(self._resync):
                        self._dirty = True
                        problems.append("no reply to the resynchronising echo")
                        continue
                    self._dirty = False
                sent = time.monotonic()
                self._guarded(self._write, frame)
                data = self._guarded(self._read_until, 1, time.monotonic() + self.timeout)
                if not data:
                    self.stats.timeouts += 1
                    problems.append(f"no reply within {self.timeout:.3g} s")
                    continue
                deadline = time.monotonic() + self.timeout
                if data[0] == ERROR_BYTE:
                    data += self._guarded(self._read_until, 2, deadline)
                    if data == _ERROR_FRAME:
                        raise self._fetch_error()
                data += self._guarded(self._read_until, reply_len + 2 - len(data), deadline)
                if len(data) < reply_len + 2:
                    self.stats.timeouts += 1
                    problems.append(f"short reply ({len(data)} of {reply_len + 2} bytes)")
                    continue
                try:
                    reply = check_reply(data, reply_len)
                except CrcError:
                    self.stats.crc_errors += 1
                    problems.append("bad CRC")
                else:
                    self.stats.note_reply(time.monotonic() - sent)
                    return reply
            self._dirty = True
            raise TransportError(
                f"{self.name}: no valid reply to '{letter}' after {self.retries + 1} attempts "
                f"({'; '.join(dict.fromkeys(problems))})"
            )

    def command(self, payload: bytes, reply_len: int) -> bytes | None:
        """Send a non-idempotent command ONCE. Returns its reply payload, or None when the
        controller answered but the reply was unreadable (corrupt: it took the command).
        Raises NoReply when nothing came back, ControllerError on a refusal."""
        frame = frame_request(payload)
        letter = chr(payload[0]) if 32 <= payload[0] < 127 else f"0x{payload[0]:02X}"
        with self._lock:
            if not self.is_open:
                raise LinkDown(f"{self.name}: not connected")
            if self._dirty:
                if not self._guarded(self._resync):
                    raise NoReply(f"{self.name}: the controller does not answer; '{letter}' "
                                  "not sent")
                self._dirty = False
            sent = time.monotonic()
            self._guarded(self._write, frame)
            deadline = time.monotonic() + self.timeout
            data = self._guarded(self._read_until, 1, deadline)
            if data and data[0] == ERROR_BYTE:
                data += self._guarded(self._read_until, 2, deadline)
                if data == _ERROR_FRAME:
                    raise self._fetch_error()
            if data:
                data += self._guarded(self._read_until, reply_len + 2 - len(data), deadline)
            if len(data) == reply_len + 2:
                try:
                    reply = check_reply(data, reply_len)
                except CrcError:
                    self.stats.crc_errors += 1
                    return None  # it answered: the command was taken
                self.stats.note_reply(time.monotonic() - sent)
                return reply
            self.stats.timeouts += 1
            late = self._guarded(self._resync_collect)
            if late is None:
                self._dirty = True
                raise NoReply(f"{self.name}: no reply to '{letter}' and none to the echo after "
                              "it; not re-sent")
            data += late
            if data[:3] == _ERROR_FRAME:
                raise self._fetch_error()
            if len(data) >= reply_len + 2:
                try:
                    return check_reply(data[: reply_len + 2], reply_len)
                except CrcError:
                    return None
            if data:
                return None  # a partial reply: it answered
            raise NoReply(f"{self.name}: no reply to '{letter}' within {self.timeout:.3g} s; "
                          "not re-sent")

    def _resync_collect(self) -> bytes | None:
        """Echo, and return the bytes that came before its reply (None: no echo reply)."""
        self._write(_ECHO_FRAME)
        deadline = time.monotonic() + self.timeout * (self.retries + 1)
        buf = b""
        while True:
            chunk = self._read_until(1, deadline)
            if not chunk:
                return None
            buf += chunk
            if buf.endswith(_ECHO_REPLY):
                return buf[: -len(_ECHO_REPLY)]

    def query_error(self) -> Exception:
        """The controller's last error (raw 0xC1 request), or a TransportError if unreadable."""
        with self._lock:
            if not self.is_open:
                raise LinkDown(f"{self.name}: not connected")
            return self._fetch_error()

    def _fetch_error(self) -> Exception:
        """Ask for the refusal's explanation (raw 0xC1 request, 57-byte reply)."""
        problem = ""
        for attempt in range(self.retries + 1):
            if attempt and not self._guarded(self._resync):
                problem = "no reply to the resynchronising echo"
                continue
            self._guarded(self._write, ERROR_QUERY)
            data = self._guarded(self._read_until, ERROR_REPLY_LEN, time.monotonic() + self.timeout)
            if len(data) < ERROR_REPLY_LEN:
                problem = f"short error reply ({len(data)} of {ERROR_REPLY_LEN} bytes)"
                continue
            try:
                return decode_error_reply(data)
            except ProtocolError as exc:
                problem = str(exc)
        return TransportError(
            f"{self.name}: the controller refused a command and its explanation was unreadable "
            f"({problem})"
        )

    def _guarded(self, fn, *args):
        try:
            return fn(*args)
        except OSError as exc:
            self.close()
            raise LinkDown(f"{self.name}: connection lost ({exc})") from exc


class TcpTransport(Transport):
    """Katana 400/450: TCP port 5566 on the controller (USB network interface)."""

    def __init__(self, host: str = "192.168.1.1", port: int = 5566, timeout: float = 0.5,
                 retries: int = 3, connect_timeout: float = 2.0) -> None:
        super().__init__(timeout=timeout, retries=retries)
        self.host, self.port, self.connect_timeout = host, port, connect_timeout

    @property
    def name(self) -> str:
        return f"tcp {self.host}:{self.port}"

    def _connect(self) -> socket.socket:
        sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return sock

    def _write(self, data: bytes) -> None:
        self._open_link().sendall(data)

    def _read_some(self, n: int, timeout: float) -> bytes:
        sock = self._open_link()
        sock.settimeout(timeout)
        try:
            chunk = sock.recv(n)
        except TimeoutError:
            return b""
        if not chunk:
            raise ConnectionResetError("the controller closed the connection")
        return chunk


class SerialTransport(Transport):
    """Katana 300: RS-232 at 57600 baud, 8N1, no flow control (pyserial)."""

    def __init__(self, device: str = "/dev/ttyUSB0", baudrate: int = 57600, timeout: float = 0.5,
                 retries: int = 3) -> None:
        super().__init__(timeout=timeout, retries=retries)
        self.device, self.baudrate = device, baudrate

    @property
    def name(self) -> str:
        return f"serial {self.device}"

    def _connect(self):
        return serial.Serial(
            self.device,
            baudrate=self.baudrate,
            bytesize=serial.EIGHTBITS,
            parity=serial.PARITY_NONE,
            stopbits=serial.STOPBITS_ONE,
            timeout=self.timeout,
            xonxoff=False,
            rtscts=False,
            dsrdtr=False,
        )

    # pyserial's SerialException is an OSError: `_guarded` takes it for a lost link
    def _write(self, data: bytes) -> None:
        self._open_link().write(data)

    def _read_some(self, n: int, timeout: float) -> bytes:
        port = self._open_link()
        port.timeout = timeout
        return port.read(n)


def make_transport(
    kind: str,
    host: str = "192.168.1.1",
    port: int = 5566,
    device: str = "/dev/ttyUSB0",
    timeout: float = 0.5,
    retries: int = 3,
) -> Transport:
    """``kind`` is "tcp" (Katana 400/450) or "serial" (Katana 300)."""
    if kind == "tcp":
        return TcpTransport(host, port, timeout=timeout, retries=retries)
    if kind == "serial":
        return SerialTransport(device, timeout=timeout, retries=retries)
    raise ValueError(f"transport '{kind}' is not 'tcp' or 'serial'")
