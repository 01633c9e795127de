"""Serial readers for an MTi-style IMU and a Ping-style echosounder.

Both protocols are parsed from bytes by incremental parsers (:class:`MtiParser`,
:class:`PingParser`) that resynchronise after garbage or a bad checksum and count what they
dropped, so they are tested without hardware. The sources (:class:`MtiImuSource`,
:class:`PingEchosounderSource`) read from any object with ``read(n)`` (and ``write`` for the
echosounder's requests); given a port name they open it with pyserial (optional dependency,
``pip install pyserial``), which also accepts URLs such as ``loop://`` or ``socket://host:port``.

Xsens MT binary messages (MTData2)::

    0xFA  0xFF  MID=0x36  LEN [EXTLEN_hi EXTLEN_lo if LEN == 0xFF]  DATA...  CHECKSUM
    DATA = repeated (XDI uint16 big-endian, size uint8, payload); checksum makes the byte sum
    from 0xFF to CHECKSUM zero modulo 256. Used XDIs (low two bits = precision: float32,
    fp12.20, fp16.32, float64): 0x1020 PacketCounter, 0x1060 SampleTimeFine (10 kHz ticks),
    0x4020 Acceleration (m/s^2), 0x8020 RateOfTurn (rad/s).

Blue Robotics Ping protocol::

    'B' 'R'  payload_length u16  message_id u16  src u8  dst u8  payload  checksum u16
    (little-endian; checksum = byte sum of everything before it, modulo 65536).
    1211 distance_simple: distance u32 mm, confidence u8 %.
    1212 distance: distance u32 mm, confidence u16 %, transmit_duration u16 us,
         ping_number u32, scan_start u32 mm, scan_length u32 mm, gain_setting u32.
    6 general_request: requested_id u16 (the echosounder answers with that message).
"""

from __future__ import annotations

import logging
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from sea3d.capture.sources import Source
from sea3d.errors import CaptureError
from sea3d.io.session import ImuSample, SonarSample

__all__ = [
    "MtiImuSource",
    "MtiPacket",
    "MtiParser",
    "PingEchosounderSource",
    "PingMessage",
    "PingParser",
    "encode_mtdata2",
    "encode_ping_message",
    "open_serial",
]

_log = logging.getLogger(__name__)


class ByteStream(Protocol):
    """What the sources need from a serial port."""

    def read(self, size: int = ..., /) -> bytes: ...


def open_serial(port: str, baudrate: int, *, timeout_s: float = 0.05) -> Any:
    """Open a serial port (or pyserial URL) with pyserial.

    Raises:
        CaptureError: if pyserial is not installed or the port cannot be opened.
    """
    try:
        import serial  # type: ignore[import-untyped,unused-ignore]
    except ImportError as err:
        raise CaptureError(f"reading {port} needs pyserial: pip install pyserial") from err
    try:
        return serial.serial_for_url(port, baudrate=baudrate, timeout=timeout_s)
    except (serial.SerialException, ValueError, OSError) as err:
        raise CaptureError(f"cannot open serial port {port} at {baudrate} baud: {err}") from err


# ----------------------------------------------------------------------------- Xsens MTi

MTI_PREAMBLE, MTI_BID, MTI_MTDATA2 = 0xFA, 0xFF, 0x36
XDI_PACKET_COUNTER, XDI_SAMPLE_TIME_FINE = 0x1020, 0x1060
XDI_ACCELERATION, XDI_RATE_OF_TURN = 0x4020, 0x8020


@dataclass(frozen=True)
class MtiPacket:
    """Fields of one MTData2 message; absent fields are None.

    Attributes:
        accel_mps2: (3,) float64 acceleration in m/s^2 (sensor frame).
        gyro_radps: (3,) float64 rate of turn in rad/s.
        sample_time_fine: device clock in 100 us ticks (uint32, wraps).
        packet_counter: uint16 counter (wraps).
    """

    accel_mps2: np.ndarray | None = None
    gyro_radps: np.ndarray | None = None
    sample_time_fine: int | None = None
    packet_counter: int | None = None


def _mti_vector(payload: bytes, precision: int) -> np.ndarray:
    if precision == 0 and len(payload) == 12:
        return np.array(struct.unpack(">3f", payload), dtype=np.float64)
    if precision == 3 and len(payload) == 24:
        return np.array(struct.unpack(">3d", payload), dtype=np.float64)
    if precision == 1 and len(payload) == 12:
        return np.array(struct.unpack(">3i", payload), dtype=np.float64) / 2.0**20
    if precision == 2 and len(payload) == 18:
        vals = [struct.unpack(">Ih", payload[6 * k : 6 * k + 6]) for k in range(3)]
        return np.array([(i * 2**32 + f) / 2.0**32 for f, i in vals], dtype=np.float64)
    raise ValueError(f"unexpected vector payload of {len(payload)} bytes, precision {precision}")


def encode_mtdata2(
    *,
    accel_mps2: Any = None,
    gyro_radps: Any = None,
    sample_time_fine: int | None = None,
    packet_counter: int | None = None,
    double: bool = False,
) -> bytes:
    """One complete MTData2 message (float32, or float64 with ``double``), for tests and
    simulators."""
    data = b""
    if packet_counter is not None:
        data += struct.pack(">HBH", XDI_PACKET_COUNTER, 2, packet_counter & 0xFFFF)
    if sample_time_fine is not None:
        data += struct.pack(">HBI", XDI_SAMPLE_TIME_FINE, 4, sample_time_fine & 0xFFFFFFFF)
    fmt, prec = (">3d", 3) if double else (">3f", 0)
    for xdi, vec in ((XDI_ACCELERATION, accel_mps2), (XDI_RATE_OF_TURN, gyro_radps)):
        if vec is not None:
            payload = struct.pack(fmt, *(float(v) for v in vec))
            data += struct.pack(">HB", xdi | prec, len(payload)) + payload
    if len(data) < 0xFF:
        body = bytes([MTI_BID, MTI_MTDATA2, len(data)]) + data
    else:
        body = bytes([MTI_BID, MTI_MTDATA2, 0xFF]) + struct.pack(">H", len(data)) + data
    checksum = (-sum(body)) & 0xFF
    return bytes([MTI_PREAMBLE]) + body + bytes([checksum])


@dataclass
class MtiParser:
    """Incremental MTData2 parser; feed bytes, get packets.

    Attributes:
        checksum_errors: messages dropped for a bad checksum.
        skipped_bytes: bytes discarded while looking for a preamble.
        other_messages: valid messages that are not MTData2 (acks, errors ...).
    """

    checksum_errors: int = 0
    skipped_bytes: int = 0
    other_messages: int = 0
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[MtiPacket]:
        """Add bytes; return the packets completed by them."""
        self._buf += data
        out: list[MtiPacket] = []
        buf = self._buf
        while True:
            start = buf.find(bytes([MTI_PREAMBLE, MTI_BID]))
            if start < 0:
                keep = 1 if buf[-1:] == bytes([MTI_PREAMBLE]) else 0
                self.skipped_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.skipped_bytes += start
                del buf[:start]
            if len(buf) < 4:
                break
            length, head = buf[3], 4
            if length == 0xFF:
                if len(buf) < 6:
                    break
                length, head = struct.unpack(">H", buf[4:6])[0], 6
            total = head + length + 1
            if len(buf) < total:
                break
            if sum(buf[1:total]) & 0xFF:
                self.checksum_errors += 1
                self.skipped_bytes += 1
                del buf[:1]  # resync from the next byte
                continue
            mid, payload = buf[2], bytes(buf[head : head + length])
            del buf[:total]
            if mid != MTI_MTDATA2:
                self.other_messages += 1
                continue
            try:
                out.append(self._decode(payload))
            except (ValueError, struct.error) as err:
                _log.warning("MTi: malformed MTData2 payload (%s); skipped", err)
        return out

    @staticmethod
    def _decode(payload: bytes) -> MtiPacket:
        fields: dict[str, Any] = {}
        pos = 0
        while pos + 3 <= len(payload):
            xdi, size = struct.unpack(">HB", payload[pos : pos + 3])
            item = payload[pos + 3 : pos + 3 + size]
            if len(item) != size:
                raise ValueError(f"data item 0x{xdi:04x} runs past the message")
            kind, precision = xdi & 0xFFF0, xdi & 0x0003
            if kind == XDI_ACCELERATION:
                fields["accel_mps2"] = _mti_vector(item, precision)
            elif kind == XDI_RATE_OF_TURN:
                fields["gyro_radps"] = _mti_vector(item, precision)
            elif xdi == XDI_SAMPLE_TIME_FINE and size == 4:
                fields["sample_time_fine"] = struct.unpack(">I", item)[0]
            elif xdi == XDI_PACKET_COUNTER and size == 2:
                fields["packet_counter"] = struct.unpack(">H", item)[0]
            pos += 3 + size
        return MtiPacket(**fields)


class MtiImuSource(Source):
    """IMU samples from an Xsens MTi (MTData2 with Acceleration and RateOfTurn).

    Stamps: the host clock at the first packet, then the device's SampleTimeFine (100 us
    ticks, unwrapped) when the packets carry it, else the host clock at each packet.

    Args:
        port: a serial port name / pyserial URL, or an open byte stream with ``read``.
        baudrate: serial speed (MTi default 115200).
        clock: host clock in ns.

    Raises:
        CaptureError: when the port cannot be opened.
    """

    kind = "imu"

    def __init__(
        self,
        port: str | ByteStream,
        *,
        baudrate: int = 115200,
        clock: Callable[[], int] = time.time_ns,
        name: str | None = None,
    ) -> None:
        super().__init__(name or (port if isinstance(port, str) else "mti"))
        self.port, self.baudrate, self.clock = port, baudrate, clock
        self.parser = MtiParser()
        self._stream: Any = None if isinstance(port, str) else port
        self._pending: list[tuple[int, MtiPacket]] = []
        self._t0: tuple[int, int] | None = None
        self._last_stf: int | None = None
        self._wraps = 0
        self.incomplete_packets = 0

    def open(self) -> None:
        if self._stream is None:
            assert isinstance(self.port, str)
            self._stream = open_serial(self.port, self.baudrate)

    def _stamp(self, pkt: MtiPacket, host_ns: int) -> int:
        stf = pkt.sample_time_fine
        if stf is None:
            return host_ns
        if self._last_stf is not None and stf < self._last_stf:
            self._wraps += 1
        self._last_stf = stf
        ticks = stf + self._wraps * 2**32
        if self._t0 is None:
            self._t0 = (host_ns, ticks)
        return self._t0[0] + (ticks - self._t0[1]) * 100_000

    def read(self) -> ImuSample | None:
        self.open()
        while True:
            while self._pending:
                host_ns, pkt = self._pending.pop(0)
                if pkt.accel_mps2 is None or pkt.gyro_radps is None:
                    self.incomplete_packets += 1
                    continue
                return ImuSample(self._stamp(pkt, host_ns), pkt.accel_mps2, pkt.gyro_radps)
            data = self._stream.read(256)
            host_ns = self.clock()
            if not data:
                if isinstance(self.port, str):
                    continue  # serial timeout: keep waiting
                return None  # end of a byte log
            self._pending.extend((host_ns, p) for p in self.parser.feed(data))

    def close(self) -> None:
        if isinstance(self.port, str) and self._stream is not None:
            self._stream.close()
            self._stream = None


# ----------------------------------------------------------------------------- Ping

PING_GENERAL_REQUEST, PING_DISTANCE_SIMPLE, PING_DISTANCE = 6, 1211, 1212


@dataclass(frozen=True)
class PingMessage:
    """One Ping-protocol message: ``message_id`` and its raw little-endian ``payload``."""

    message_id: int
    payload: bytes
    src_device_id: int = 0
    dst_device_id: int = 0


def encode_ping_message(
    message_id: int, payload: bytes = b"", *, src: int = 0, dst: int = 0
) -> bytes:
    """One complete Ping message with its checksum."""
    body = b"BR" + struct.pack("<HHBB", len(payload), message_id, src, dst) + payload
    return body + struct.pack("<H", sum(body) & 0xFFFF)


def encode_ping_distance(distance_mm: int, confidence_pct: int, *, ping_number: int = 0) -> bytes:
    """A ``distance`` (1212) message as an echosounder sends it."""
    payload = struct.pack("<IHHIIII", distance_mm, confidence_pct, 100, ping_number, 0, 50_000, 0)
    return encode_ping_message(PING_DISTANCE, payload, src=1)


@dataclass
class PingParser:
    """Incremental Ping-protocol parser; counts checksum errors and skipped bytes."""

    checksum_errors: int = 0
    skipped_bytes: int = 0
    max_payload: int = 4096
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[PingMessage]:
        """Add bytes; return the messages completed by them."""
        self._buf += data
        buf, out = self._buf, []
        while True:
            start = buf.find(b"BR")
            if start < 0:
                keep = 1 if buf[-1:] == b"B" else 0
                self.skipped_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.skipped_bytes += start
                del buf[:start]
            if len(buf) < 8:
                break
            plen, mid, src, dst = struct.unpack("<HHBB", buf[2:8])
            if plen > self.max_payload:
                self.skipped_bytes += 1
                del buf[:1]
                continue
            total = 8 + plen + 2
            if len(buf) < total:
                break
            (checksum,) = struct.unpack("<H", buf[total - 2 : total])
            if sum(buf[: total - 2]) & 0xFFFF != checksum:
                self.checksum_errors += 1
                self.skipped_bytes += 1
                del buf[:1]
                continue
            out.append(PingMessage(mid, bytes(buf[8 : 8 + plen]), src, dst))
            del buf[:total]
        return out


def decode_distance(msg: PingMessage) -> tuple[float, float] | None:
    """(range_m, confidence 0..1) from a distance or distance_simple message, else None."""
    if msg.message_id == PING_DISTANCE and len(msg.payload) >= 6:
        dist_mm, conf = struct.unpack("<IH", msg.payload[:6])
        return dist_mm / 1000.0, conf / 100.0
    if msg.message_id == PING_DISTANCE_SIMPLE and len(msg.payload) >= 5:
        dist_mm, conf = struct.unpack("<IB", msg.payload[:5])
        return dist_mm / 1000.0, conf / 100.0
    return None


class PingEchosounderSource(Source):
    """Ranges from a Ping-style echosounder, polled with ``general_request(distance)``.

    Args:
        port: a serial port name / pyserial URL, or an open stream with ``read`` (and
            ``write`` for polling; without ``write`` it only listens, e.g. to a byte log).
        baudrate: serial speed (Ping default 115200).
        rate_hz: how often to ask for a distance.
        clock: host clock in ns; a reading is stamped when its message is complete.

    Raises:
        CaptureError: when the port cannot be opened.
    """

    kind = "sonar"

    def __init__(
        self,
        port: str | ByteStream,
        *,
        baudrate: int = 115200,
        rate_hz: float = 10.0,
        clock: Callable[[], int] = time.time_ns,
        name: str | None = None,
    ) -> None:
        super().__init__(name or (port if isinstance(port, str) else "ping"))
        self.port, self.baudrate, self.clock = port, baudrate, clock
        self.period_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self.parser = PingParser()
        self._stream: Any = None if isinstance(port, str) else port
        self._pending: list[SonarSample] = []
        self._next_poll = 0.0
        self._last_t = -1
        self.requests_sent = 0

    def open(self) -> None:
        if self._stream is None:
            assert isinstance(self.port, str)
            self._stream = open_serial(self.port, self.baudrate)

    def _poll(self) -> None:
        write = getattr(self._stream, "write", None)
        now = time.monotonic()
        if write is not None and self.period_s and now >= self._next_poll:
            write(
                encode_ping_message(PING_GENERAL_REQUEST, struct.pack("<H", PING_DISTANCE), dst=1)
            )
            self._next_poll = now + self.period_s
            self.requests_sent += 1

    def read(self) -> SonarSample | None:
        self.open()
        while not self._pending:
            self._poll()
            data = self._stream.read(64)
            if not data:
                if isinstance(self.port, str) or hasattr(self._stream, "write"):
                    continue
                return None
            t_ns = self.clock()
            for msg in self.parser.feed(data):
                reading = decode_distance(msg)
                if reading is None:
                    continue
                t_ns = max(t_ns, self._last_t + 1)  # two replies in one read: keep stamps unique
                self._last_t = t_ns
                self._pending.append(SonarSample(t_ns, reading[0], reading[1]))
        return self._pending.pop(0)

    def close(self) -> None:
        if isinstance(self.port, str) and self._stream is not None:
            self._stream.close()
            self._stream = None
