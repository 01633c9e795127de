"""H.264 Annex B byte streams: NAL units, and sea3d's frame stamps in SEI messages.

sea3d's tether stream carries, in every access unit, one SEI message of type 5
(``user_data_unregistered``, ITU-T H.264 section D.1.6 / D.2.6) with the 16-byte UUID
:data:`SEA3D_SEI_UUID` and this payload (little-endian)::

    version u8 (1) | layout u8 | seq u32 | t_ns i64 | sent_ns i64 | width u16 | height u16

- ``layout``: 0 left and right side by side, 1 left only, 2 right only;
- ``seq``: frame counter of the sender (0 at its start), to count lost frames;
- ``t_ns``: the frame's sensor stamp (integer nanoseconds), kept through the link;
- ``sent_ns``: the sender's wall clock (``time.time_ns``) when the frame went to the encoder,
  for the end-to-end latency (exact on one machine, as good as the clock sync otherwise);
- ``width``, ``height``: one camera's image size in the stream.

Decoders ignore SEI messages they do not know, so the stream stays a plain H.264 stream that
ffplay, VLC or GStreamer show as it is.
"""

from __future__ import annotations

import itertools
import struct
import uuid
from dataclasses import dataclass

from sea3d.errors import SessionError

__all__ = [
    "LAYOUT_BOTH",
    "LAYOUT_LEFT",
    "LAYOUT_RIGHT",
    "SEA3D_SEI_UUID",
    "FrameMeta",
    "escape_rbsp",
    "find_frame_meta",
    "insert_frame_meta",
    "nal_units",
    "sei_nal",
    "split_access_units",
    "unescape_rbsp",
]

SEA3D_SEI_UUID = uuid.UUID("5ea3d000-5ea3-4d1e-8a7e-73747265616d").bytes  # "...stream"
LAYOUT_BOTH, LAYOUT_LEFT, LAYOUT_RIGHT = 0, 1, 2
_PAYLOAD = struct.Struct("<BBIqqHH")
_VERSION = 1
_START = b"\x00\x00\x01"
_NAL_SEI, _NAL_AUD = 6, 9
_VCL = (1, 5)


@dataclass(frozen=True, kw_only=True)
class FrameMeta:
    """What the sender says about one frame (see the module docstring).

    Attributes:
        layout: :data:`LAYOUT_BOTH`, :data:`LAYOUT_LEFT` or :data:`LAYOUT_RIGHT`.
        seq: the sender's frame counter.
        t_ns: the frame's sensor stamp, nanoseconds.
        sent_ns: sender wall clock when the frame went to the encoder, nanoseconds.
        width, height: one camera's image size in the stream, pixels.
    """

    layout: int
    seq: int
    t_ns: int
    sent_ns: int
    width: int
    height: int

    def pack(self) -> bytes:
        """The 16-byte UUID followed by the packed payload."""
        return SEA3D_SEI_UUID + _PAYLOAD.pack(
            _VERSION, self.layout, self.seq & 0xFFFFFFFF, self.t_ns, self.sent_ns,
            self.width, self.height,
        )  # fmt: skip


def escape_rbsp(rbsp: bytes) -> bytes:
    """Insert emulation-prevention bytes (``00 00 0x`` with x <= 3 -> ``00 00 03 0x``)."""
    out = bytearray()
    zeros = 0
    for b in rbsp:
        if zeros >= 2 and b <= 3:
            out.append(3)
            zeros = 0
        out.append(b)
        zeros = zeros + 1 if b == 0 else 0
    return bytes(out)


def unescape_rbsp(ebsp: bytes) -> bytes:
    """Remove emulation-prevention bytes (``00 00 03`` -> ``00 00``)."""
    out = bytearray()
    zeros = 0
    for b in ebsp:
        if zeros >= 2 and b == 3:
            zeros = 0
            continue
        out.append(b)
        zeros = zeros + 1 if b == 0 else 0
    return bytes(out)


def nal_units(data: bytes) -> list[tuple[int, int, int]]:
    """``(start, end, nal_type)`` of each NAL unit in an Annex B byte stream; ``start`` is the
    first byte after the start code, ``end`` one past the last byte."""
    starts = []
    i = data.find(_START)
    while i >= 0:
        starts.append(i + 3)
        i = data.find(_START, i + 3)
    out = []
    for k, s in enumerate(starts):
        e = starts[k + 1] - 3 if k + 1 < len(starts) else len(data)
        # a 4-byte start code leaves a zero at the end of the previous unit
        while k + 1 < len(starts) and e > s and data[e - 1] == 0:
            e -= 1
        if s < len(data):
            out.append((s, e, data[s] & 0x1F))
    return out


def sei_nal(meta: FrameMeta) -> bytes:
    """A complete SEI NAL unit (start code included) carrying ``meta``."""
    payload = meta.pack()
    size = len(payload)
    body = bytearray([5])  # payloadType 5: user_data_unregistered
    while size >= 255:
        body.append(255)
        size -= 255
    body.append(size)
    body += payload
    body.append(0x80)  # rbsp_trailing_bits
    return b"\x00\x00\x00\x01" + bytes([_NAL_SEI]) + escape_rbsp(bytes(body))


def insert_frame_meta(access_unit: bytes, meta: FrameMeta) -> bytes:
    """The access unit with sea3d's SEI placed just before its first slice (after any AUD,
    SPS and PPS), as H.264 7.4.1.2.3 orders them.

    Raises:
        SessionError: the data holds no slice NAL unit.
    """
    for s, _e, t in nal_units(access_unit):
        if t in _VCL:
            cut = s - 3
            if cut > 0 and access_unit[cut - 1] == 0:
                cut -= 1
            return access_unit[:cut] + sei_nal(meta) + access_unit[cut:]
    raise SessionError(f"H.264 access unit of {len(access_unit)} bytes holds no slice")


def _sei_messages(rbsp: bytes) -> list[tuple[int, bytes]]:
    out = []
    i = 1  # skip the NAL header
    while i < len(rbsp) and rbsp[i] != 0x80:
        ptype, i = _sei_number(rbsp, i)
        if ptype < 0:
            break
        psize, i = _sei_number(rbsp, i)
        if psize < 0:
            break
        out.append((ptype, rbsp[i : i + psize]))
        i += psize
    return out


def _sei_number(rbsp: bytes, i: int) -> tuple[int, int]:
    """An SEI payload type or size read at ``i`` (H.264 7.3.2.3.1: 0xFF bytes add 255 each,
    the first other byte ends it) and the index after it; ``(-1, i)`` when the data ends first."""
    value = 0
    while i < len(rbsp) and rbsp[i] == 255:
        value += 255
        i += 1
    if i >= len(rbsp):
        return -1, i
    return value + rbsp[i], i + 1


def find_frame_meta(access_unit: bytes) -> FrameMeta | None:
    """sea3d's :class:`FrameMeta` from an access unit, or None when it carries none (a
    stream from another sender) or a damaged one."""
    for s, e, t in nal_units(access_unit):
        if t != _NAL_SEI:
            continue
        for ptype, payload in _sei_messages(unescape_rbsp(access_unit[s:e])):
            if ptype != 5 or payload[:16] != SEA3D_SEI_UUID or len(payload) < 16 + _PAYLOAD.size:
                continue
            version, layout, seq, t_ns, sent_ns, w, h = _PAYLOAD.unpack_from(payload, 16)
            if version != _VERSION:
                continue
            return FrameMeta(layout=layout, seq=seq, t_ns=t_ns, sent_ns=sent_ns, width=w, height=h)
    return None


def split_access_units(buffer: bytearray) -> list[bytes]:
    """Take the complete access units out of an Annex B byte stream whose access units each
    begin with an access unit delimiter (NAL type 9), as hardware encoders emit them with
    AUD insertion on (GStreamer's ``nvv4l2h264enc insert-aud=true``). The unfinished last
    unit stays in ``buffer``."""
    cuts = [s - 3 - (1 if s >= 4 and buffer[s - 4] == 0 else 0)
            for s, _e, t in nal_units(bytes(buffer)) if t == _NAL_AUD]  # fmt: skip
    if len(cuts) < 2:
        return []
    units = [bytes(buffer[a:b]) for a, b in itertools.pairwise(cuts)]
    del buffer[: cuts[-1]]
    return units
