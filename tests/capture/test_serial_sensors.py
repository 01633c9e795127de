"""MTi and Ping protocol parsers and their sources, from bytes (no hardware).

Expected values are what the test encodes; float32 payloads must come back exactly.
"""

from __future__ import annotations

import io
import struct

import numpy as np
import pytest

from sea3d.capture.serial_sensors import (
    MtiImuSource,
    MtiParser,
    PingEchosounderSource,
    PingParser,
    decode_distance,
    encode_mtdata2,
    encode_ping_distance,
    encode_ping_message,
    open_serial,
)
from sea3d.io.session import ImuSample


def _chop(data: bytes, rng: np.random.Generator) -> list[bytes]:
    """Split a byte stream at random places, as a serial port delivers it."""
    cuts = np.sort(rng.choice(np.arange(1, len(data)), size=len(data) // 7, replace=False))
    return [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]


def test_mti_parser_recovers_every_packet_from_chopped_noisy_bytes():
    rng = np.random.default_rng(0)
    accel = rng.normal(0, 3, size=(20, 3)).astype(np.float32)
    gyro = rng.normal(0, 1, size=(20, 3)).astype(np.float32)
    stream = bytearray(b"\x00\x13garbage\xfa")
    for k in range(20):
        stream += encode_mtdata2(
            accel_mps2=accel[k],
            gyro_radps=gyro[k],
            sample_time_fine=1000 + 100 * k,
            packet_counter=k,
        )
        if k == 7:
            bad = bytearray(encode_mtdata2(accel_mps2=[1, 2, 3], gyro_radps=[4, 5, 6]))
            bad[-1] ^= 0x55  # wrong checksum
            stream += bad
        if k == 11:
            stream += bytes([0xFA, 0xFF, 0x3E, 0x00, 0xC3])  # a valid non-MTData2 message
    parser = MtiParser()
    packets = [p for piece in _chop(bytes(stream), rng) for p in parser.feed(piece)]
    assert len(packets) == 20
    assert parser.checksum_errors == 1 and parser.other_messages == 1
    for k, p in enumerate(packets):
        np.testing.assert_array_equal(p.accel_mps2, accel[k].astype(np.float64))
        np.testing.assert_array_equal(p.gyro_radps, gyro[k].astype(np.float64))
        assert p.sample_time_fine == 1000 + 100 * k and p.packet_counter == k


def test_mti_parser_reads_double_precision_and_fixed_point_and_extended_length():
    parser = MtiParser()
    [p] = parser.feed(
        encode_mtdata2(accel_mps2=[0.1, -9.81, 1e-7], gyro_radps=[1, 2, 3], double=True)
    )
    assert p.accel_mps2.tolist() == [0.1, -9.81, 1e-7]
    # fp12.20 (precision bits 01) by hand: value * 2^20 as int32.
    payload = struct.pack(">HB3i", 0x4021, 12, *(round(v * 2**20) for v in (1.5, -2.25, 9.75)))
    body = bytes([0xFF, 0x36, len(payload)]) + payload
    [q] = MtiParser().feed(b"\xfa" + body + bytes([(-sum(body)) & 0xFF]))
    assert q.accel_mps2.tolist() == [1.5, -2.25, 9.75]
    # Extended length (LEN = 0xFF then 16-bit length): pad with an unknown 300-byte item.
    pad = struct.pack(">HB", 0x7777, 250) + bytes(250) + struct.pack(">HB", 0x7778, 50) + bytes(50)
    data = pad + struct.pack(">HB3f", 0x8020, 12, 1.0, 2.0, 3.0)
    body = bytes([0xFF, 0x36, 0xFF]) + struct.pack(">H", len(data)) + data
    [r] = MtiParser().feed(b"\xfa" + body + bytes([(-sum(body)) & 0xFF]))
    assert r.gyro_radps.tolist() == [1.0, 2.0, 3.0]


def test_mti_source_stamps_from_the_device_clock_across_a_wrap():
    ticks = [2**32 - 200, 2**32 - 100, 0, 100]  # SampleTimeFine wraps after 2^32 ticks
    data = b"".join(
        encode_mtdata2(accel_mps2=[k, 0, 0], gyro_radps=[0, 0, k], sample_time_fine=t)
        for k, t in enumerate(ticks)
    )
    host = iter(range(5_000_000_000, 6_000_000_000, 1_000_000))
    src = MtiImuSource(io.BytesIO(data), clock=host.__next__)
    samples = list(src)
    assert all(isinstance(s, ImuSample) for s in samples)
    assert [s.t_ns - samples[0].t_ns for s in samples] == [0, 10_000_000, 20_000_000, 30_000_000]
    assert [s.accel_mps2[0] for s in samples] == [0.0, 1.0, 2.0, 3.0]


def test_ping_parser_decodes_distance_messages_and_skips_damage():
    rng = np.random.default_rng(0)
    dist = rng.integers(300, 60_000, size=15)
    conf = rng.integers(0, 101, size=15)
    stream = bytearray(b"BR\xff\xffjunk")
    for k in range(15):
        stream += encode_ping_distance(int(dist[k]), int(conf[k]), ping_number=k)
        if k == 4:
            bad = bytearray(encode_ping_distance(1, 1))
            bad[10] ^= 0xFF
            stream += bad
    stream += encode_ping_message(1211, struct.pack("<IB", 4321, 87))  # distance_simple
    parser = PingParser()
    msgs = [m for piece in _chop(bytes(stream), rng) for m in parser.feed(piece)]
    readings = [decode_distance(m) for m in msgs]
    assert parser.checksum_errors == 1
    assert readings[:15] == [(d / 1000.0, c / 100.0) for d, c in zip(dist, conf, strict=True)]
    assert readings[15] == (4.321, 0.87)


def test_ping_source_polls_and_reads_over_a_pyserial_loopback():
    pytest.importorskip("serial")
    port = open_serial("loop://", 115200)
    port.write(encode_ping_distance(12_345, 77) + encode_ping_distance(12_400, 80))
    src = PingEchosounderSource(port, rate_hz=50.0)
    a, b = src.read(), src.read()
    assert a is not None and b is not None
    assert (a.range_m, a.confidence) == (12.345, 0.77)
    assert (b.range_m, b.confidence) == (12.4, 0.8)
    assert b.t_ns > a.t_ns
    # It polled with general_request; the request came back through the loop and was ignored.
    assert src.requests_sent >= 1 and src.parser.checksum_errors == 0
