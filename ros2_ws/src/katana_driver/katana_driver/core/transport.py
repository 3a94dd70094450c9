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
from dataclasses import dataclass

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
    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    crc_errors: int = 0
    controller_errors: int = 0


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

    # -------------------------------------------------------------- link primitives
    @property
    @abstractmethod
    def name(self) -> str:
        """Where the link goes, for messages (``tcp 192.168.1.1:5566``)."""

    @property
    @abstractmethod
    def is_open(self) -> bool: ...

    @abstractmethod
    def open(self) -> None:
        """Open the link; raises LinkDown with the reason when it cannot."""

    @abstractmethod
    def close(self) -> None: ...

    @abstractmethod
    def _write(self, data: bytes) -> None: ...

    @abstractmethod
    def _read_until(self, n: int, deadline: float) -> bytes:
        """Up to ``n`` bytes; fewer only when ``deadline`` (time.monotonic) passed."""

    def _resync(self) -> bool:
        """Send an echo and discard every byte up to its reply.

        The controller answers in order, so once the echo's reply is in, no late reply of an
        earlier attempt is left to be taken for the next one (a quiet period cannot promise
        that: replies may be late by any amount).
        """
        self._write(_ECHO_FRAME)
        deadline = time.monotonic() + self.timeout * (self.retries + 1)
        tail = b""
        while True:
            chunk = self._read_until(1, deadline)
            if not chunk:
                return False
            tail = (tail + chunk)[-len(_ECHO_REPLY) :]
            if tail == _ECHO_REPLY:
                return True

    # -------------------------------------------------------------- requests
    def request(self, payload: bytes, reply_len: int) -> bytes:
        """Send one command and return its reply payload (CRC checked)."""
        frame = frame_request(payload)
        letter = chr(payload[0]) if 32 <= payload[0] < 127 else f"0x{payload[0]:02X}"
        with self._lock:
            if not self.is_open:
                raise LinkDown(f"{self.name}: not connected")
            self.stats.requests += 1
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
                        self.stats.controller_errors += 1
                        raise self._fetch_error()
                data += self._guarded(self._read_until, reply_len + 2 - len(data), deadline)
                if len(data) < reply_len + 2:
                    self.stats.timeouts += 1
                    problems.append(f"short reply ({len(data)} of {reply_len + 2} bytes)")
                    continue
                try:
                    return check_reply(data, reply_len)
                except CrcError:
                    self.stats.crc_errors += 1
                    problems.append("bad CRC")
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
            self.stats.requests += 1
            if self._dirty:
                if not self._guarded(self._resync):
                    raise NoReply(f"{self.name}: the controller does not answer; '{letter}' "
                                  "not sent")
                self._dirty = False
            self._guarded(self._write, frame)
            deadline = time.monotonic() + self.timeout
            data = self._guarded(self._read_until, 1, deadline)
            if data and data[0] == ERROR_BYTE:
                data += self._guarded(self._read_until, 2, deadline)
                if data == _ERROR_FRAME:
                    self.stats.controller_errors += 1
                    raise self._fetch_error()
            if data:
                data += self._guarded(self._read_until, reply_len + 2 - len(data), deadline)
            if len(data) == reply_len + 2:
                try:
                    return check_reply(data, reply_len)
                except CrcError:
                    self.stats.crc_errors += 1
                    return None  # it answered: the command was taken
            self.stats.timeouts += 1
            late = self._guarded(self._resync_collect)
            if late is None:
                self._dirty = True
                raise NoReply(f"{self.name}: no reply to '{letter}' and none to the echo after "
                              "it; not re-sent")
            data += late
            if data[:3] == _ERROR_FRAME:
                self.stats.controller_errors += 1
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

    def __init__(
        self,
        host: str = "192.168.1.1",
        port: int = 5566,
        timeout: float = 0.5,
        retries: int = 3,
        connect_timeout: float = 2.0,
    ) -> None:
        super().__init__(timeout=timeout, retries=retries)
        self.host = host
        self.port = port
        self.connect_timeout = connect_timeout
        self._sock: socket.socket | None = None

    @property
    def name(self) -> str:
        return f"tcp {self.host}:{self.port}"

    @property
    def is_open(self) -> bool:
        return self._sock is not None

    def open(self) -> None:
        self.close()
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        except OSError as exc:
            raise LinkDown(f"{self.name}: cannot connect ({exc})") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass

    def _write(self, data: bytes) -> None:
        if self._sock is None:
            raise OSError("socket closed")
        self._sock.sendall(data)

    def _read_until(self, n: int, deadline: float) -> bytes:
        sock = self._sock
        if sock is None:
            raise OSError("socket closed")
        buf = bytearray()
        while len(buf) < n:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                break
            sock.settimeout(remaining)
            try:
                chunk = sock.recv(n - len(buf))
            except TimeoutError:
                break
            if not chunk:
                raise ConnectionResetError("the controller closed the connection")
            buf += chunk
        return bytes(buf)


class SerialTransport(Transport):
    """Katana 300: RS-232 at 57600 baud, 8N1, no flow control (pyserial)."""

    def __init__(
        self,
        device: str = "/dev/ttyUSB0",
        baudrate: int = 57600,
        timeout: float = 0.5,
        retries: int = 3,
    ) -> None:
        super().__init__(timeout=timeout, retries=retries)
        self.device = device
        self.baudrate = baudrate
        self._port = None

    @property
    def name(self) -> str:
        return f"serial {self.device}"

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def open(self) -> None:
        import serial

        self.close()
        try:
            self._port = serial.Serial(
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
        except (OSError, serial.SerialException) as exc:
            raise LinkDown(f"{self.name}: cannot open ({exc})") from exc

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except OSError:
                pass

    def _write(self, data: bytes) -> None:
        import serial

        if self._port is None:
            raise OSError("serial port closed")
        try:
            self._port.write(data)
        except serial.SerialException as exc:
            raise OSError(str(exc)) from exc

    def _read_until(self, n: int, deadline: float) -> bytes:
        import serial

        port = self._port
        if port is None:
            raise OSError("serial port closed")
        buf = bytearray()
        try:
            while len(buf) < n:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    break
                port.timeout = remaining
                buf += port.read(n - len(buf))
        except serial.SerialException as exc:
            raise OSError(str(exc)) from exc
        return bytes(buf)


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
