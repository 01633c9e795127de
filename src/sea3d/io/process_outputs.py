"""The files of ``sea3d process``: summary.json, status.csv, results.mcap, trajectory, mesh, cloud.

Each is written under a temporary name and renamed into place, so a reader (or a rerun) sees
the previous file or the new one, never half of one.

- ``trajectory.tum``: ``T_world_left`` of every processed stereo frame (TUM: seconds of session
  time, metres, ``qx qy qz qw``).
- ``status.csv``: one row per frame: ``t_ns, status, segment, keyframe_id,
  anchor_keyframe_id, loop_closure, tracked_features, depth, valid_depth_fraction, fusion``.
- ``summary.json``: the run's figures (numpy scalars and arrays as JSON numbers and lists).
- ``results.mcap``: trajectory (with each frame's status), cloud and mesh in Foxglove schemas,
  so a finished dive opens in Foxglove beside its recording.
"""

from __future__ import annotations

import csv
import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import SessionError
from sea3d.io._atomic import (
    atomic_open,
    atomic_path,
    atomic_write,
    remove_stale_temps,  # an output folder's leftovers of a killed run
)

__all__ = ["FrameRow", "process_files", "read_status_csv", "read_summary_json",
           "remove_stale_temps", "write_process_outputs", "write_status_csv",
           "write_summary_json"]

_log = logging.getLogger(__name__)

_FILES = ("trajectory.tum", "mesh.ply", "cloud.ply", "status.csv", "summary.json",
          "results.mcap")


@dataclass(frozen=True, kw_only=True)
class FrameRow:
    """One row of status.csv (what the ordered stages said about one frame)."""

    t_ns: int
    status: str
    segment: int
    keyframe_id: int | None
    anchor_keyframe_id: int | None
    loop_closure: bool
    tracked_features: int
    depth: str
    valid_depth_fraction: float
    fusion: str


def process_files(out_dir: Path) -> dict[str, Path]:
    """The output files of a run in ``out_dir`` by name (``trajectory``, ``mesh``, ``cloud``,
    ``status``, ``summary``, ``results_mcap``)."""
    names = ("trajectory", "mesh", "cloud", "status", "summary", "results_mcap")
    return {n: Path(out_dir) / f for n, f in zip(names, _FILES, strict=True)}


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_summary_json(path: Path, data: dict[str, Any],
                       default: Callable[[Any], Any] | None = None) -> None:
    """summary.json (atomic). ``default`` turns what JSON cannot hold into what it can
    (numpy scalars and arrays and paths by default; ``str`` takes anything).

    Raises:
        SessionError: it cannot be written (the previous one, if any, is left as it was).
    """
    try:
        atomic_write(path, json.dumps(data, indent=2, default=default or _json_default) + "\n")
    except OSError as err:
        raise SessionError(f"cannot write {path}: {err}") from err


def write_status_csv(path: Path, rows: Sequence[FrameRow]) -> None:
    """status.csv (atomic), one row per frame."""
    with atomic_open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_ns", "status", "segment", "keyframe_id", "anchor_keyframe_id",
                    "loop_closure", "tracked_features", "depth", "valid_depth_fraction",
                    "fusion"])
        for r in rows:
            w.writerow([r.t_ns, r.status, r.segment,
                        "" if r.keyframe_id is None else r.keyframe_id,
                        "" if r.anchor_keyframe_id is None else r.anchor_keyframe_id,
                        int(r.loop_closure), r.tracked_features, r.depth,
                        f"{r.valid_depth_fraction:.4f}", r.fusion])


def read_summary_json(path: Path) -> dict[str, Any] | None:
    """A summary.json as a dict; None when it is missing, unreadable or not a JSON object."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def read_status_csv(path: Path) -> list[dict[str, str]]:
    """The rows of a status.csv by column name, as text (the report reads them)."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _write_results_mcap(path: Path, t_ns: NDArray[np.int64], T: NDArray[np.float64],
                        statuses: Sequence[str], mesh: Any, cloud: Any, rig: Any) -> None:
    from sea3d.io.foxglove_mcap import write_results_mcap

    with atomic_path(path) as tmp:
        counts = write_results_mcap(
            tmp, trajectory=(t_ns, T), status=list(statuses),
            cloud=(cloud.points, cloud.colors),
            mesh=(mesh.vertices, mesh.triangles, mesh.colors_rgb), rig=rig,
        )
    _log.info("wrote %s: %s", path, counts)  # under its own name, not the temporary one


def write_process_outputs(out_dir: Path, *, t_ns: NDArray[np.int64], T_world_left: NDArray[
        np.float64], rows: Sequence[FrameRow], mesh: Any, cloud: Any, rig: Any
                          ) -> dict[str, Path]:
    """trajectory.tum, mesh.ply, cloud.ply, status.csv and results.mcap of a run (summary.json
    comes last, with :func:`write_summary_json`); returns :func:`process_files`.

    Args:
        out_dir: the output folder.
        t_ns, T_world_left: (N,) stamps and (N, 4, 4) final poses of every processed frame.
        rows: status.csv's rows, one per frame.
        mesh: a mesh with ``vertices``, ``triangles``, ``colors_rgb`` (world frame).
        cloud: a cleaned cloud with ``points``, ``colors``, ``normals``.
        rig: the stereo rig (for ``/tf`` in results.mcap).

    Raises:
        SessionError, ReconError, OdometryError: a file cannot be written (a full disk
            included); each file is whole under its name, or not there.
    """
    from sea3d.io.mesh_files import write_mesh, write_point_cloud
    from sea3d.io.trajectory_files import write_tum

    files = process_files(out_dir)
    write_tum(files["trajectory"], t_ns, T_world_left,
              header="t x y z qx qy qz qw: T_world_left of every stereo frame (t in seconds "
                     "of session time, metres); trust only frames tracking/relocalised in "
                     "status.csv")
    write_mesh(files["mesh"], mesh)
    write_point_cloud(files["cloud"], cloud.points, cloud.colors, cloud.normals)
    try:
        write_status_csv(files["status"], rows)
        _write_results_mcap(files["results_mcap"], t_ns, T_world_left,
                            [r.status for r in rows], mesh, cloud, rig)
    except OSError as err:
        raise SessionError(f"cannot write the outputs in {out_dir}: {err}") from err
    return files
