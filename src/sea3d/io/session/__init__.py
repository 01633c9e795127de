"""Recorded sessions: one writer and one reader interface over two storages.

- An MCAP file of ROS 2 messages (``*.mcap``), readable by other ROS 2 tools; see
  :mod:`sea3d.io.session.storage_mcap` for topics and types.
- The paper's folder layout (``left/<t_ns>.png``, ``right/<t_ns>.png``, ``imu.csv``,
  ``sonar.csv``, ``rig.yaml``, ``session.json``); see :mod:`sea3d.io.session.storage_folder`.

Write::

    with SessionWriter("dive.mcap", rig_yaml=rig_text) as w:
        w.write_stereo(t_ns, left_rgb, right_rgb)
        w.write_imu(t_ns, accel_mps2, gyro_radps)
        w.write_sonar(t_ns, range_m, confidence)

Read::

    with open_session("dive.mcap") as s:
        for pair in s.pairs():          # nearest stamps within half a frame interval
            ...
        imu = s.imu()                   # ImuSeries: t_ns (N,), accel_mps2 (N,3), gyro_radps (N,3)

Stamps are integer nanoseconds. Within one stream the writer accepts only increasing stamps;
readers sort what they find and warn about duplicates and disorder.

The package, as rosbags lays out its own: :mod:`.reader` (the :class:`SessionReader`
interface, :func:`open_session`), :mod:`.writer` (:class:`SessionWriter` over a storage),
:mod:`.storage` (the storage protocol and the storages by name), :mod:`.storage_folder`,
:mod:`.storage_mcap` (with :mod:`.mcap_chunks`, the chunked file layout, :mod:`.ros_messages`,
the ROS 2 messages, and :mod:`.mcap_reader`, the salvaging reader), :mod:`.common` (records,
image codecs, stamp helpers) and :mod:`.tools` (convert, verify).
"""

from sea3d.errors import SessionWriteError
from sea3d.io.session.common import (
    ImuSample,
    ImuSeries,
    PairMatch,
    SonarSample,
    SonarSeries,
    StereoPair,
)
from sea3d.io.session.reader import SessionReader, is_session, layout_of, open_session
from sea3d.io.session.tools import convert_session, verify_session
from sea3d.io.session.writer import SessionWriter, check_new_session

__all__ = [
    "ImuSample",
    "ImuSeries",
    "PairMatch",
    "SessionReader",
    "SessionWriteError",
    "SessionWriter",
    "SonarSample",
    "SonarSeries",
    "StereoPair",
    "check_new_session",
    "convert_session",
    "is_session",
    "layout_of",
    "open_session",
    "verify_session",
]
