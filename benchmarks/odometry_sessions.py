"""The simulated sessions the odometry benchmark runs on, rendered once into a cache folder.

- ``lawnmower_dome``: 3,000 frames (300 s at 10 Hz) of a lawnmower survey, lanes 4.5 m long and
  0.5 m apart at 1.5 m over a 13 x 14 m sloping seafloor strewn with rocks and bottles, through
  the paper's dome-port rig at 640x360 in coastal water (the built-in ``lake`` is 10 x 10 m
  with five objects: too small and too bare for a survey this long, hence this scene).
- ``orbit_dome``: 600 frames, one full circle of 1.2 m radius round the ArUco cube.
- ``lawnmower_flat``: the first 600 frames of the lawnmower through flat ports.

Each session is a folder session (``left/``, ``right/``, ``imu.csv``, ``rig.yaml`` with the IMU)
with its ground truth in ``gt/``. Rendering takes about a second per frame on one core; run

    nice python benchmarks/odometry_sessions.py [--cache /tmp/sea3d_cache] [NAME ...]

once; the benchmark reuses what is there (a session is complete when ``DONE`` exists).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT_CACHE = Path("/tmp/sea3d_cache/odometry")
SIZE_PX = (640, 360)


def survey_scene() -> Any:
    """The benchmark's survey scene (see the module docstring)."""
    from sea3d.sim.scene import scene_from_dict

    g = np.random.default_rng(7)
    objs: list[dict[str, Any]] = [
        {
            "type": "aruco_cube",
            "size_m": 0.2,
            "position_m": [0.0, 0.0, 0.0],
            "rotation_deg": [0, 0, 20],
        }
    ]
    for k in range(40):
        x, y = g.uniform(-3.5, 3.5), g.uniform(-4.0, 4.0)
        objs.append(
            {
                "type": "rock",
                "radius_m": float(g.uniform(0.08, 0.35)),
                "position_m": [float(x), float(y), 0.0],
                "seed": k + 10,
            }
        )
    for _ in range(6):
        x, y = g.uniform(-3.0, 3.0), g.uniform(-4.0, 4.0)
        objs.append(
            {
                "type": "bottle",
                "position_m": [float(x), float(y), 0.0],
                "rotation_deg": [0, 0, float(g.uniform(0, 180))],
            }
        )
    cfg = {
        "name": "survey",
        "surface_z_m": 3.5,
        "seafloor": {
            "size_m": [13.0, 14.0],
            "resolution_m": 0.04,
            "slope_deg": 3.0,
            "roughness_m": 0.06,
            "feature_m": 1.0,
        },
        "objects": objs,
    }
    return scene_from_dict(cfg, source="benchmark:survey")


@dataclass(frozen=True)
class SessionSpec:
    name: str
    port: str
    frames: int
    trajectory: str


SESSIONS = {
    "lawnmower_dome": SessionSpec("lawnmower_dome", "dome", 3000, "lawnmower"),
    "orbit_dome": SessionSpec("orbit_dome", "dome", 600, "orbit"),
    "lawnmower_flat": SessionSpec("lawnmower_flat", "flat", 600, "lawnmower"),
}


def _trajectory(kind: str, duration_s: float) -> Any:
    from sea3d.sim.motion import Lawnmower, Orbit

    if kind == "lawnmower":
        return Lawnmower(
            center_m=(0.0, -3.2),
            z_m=1.5,
            width_m=4.5,
            lane_spacing_m=0.5,
            speed_mps=0.25,
            duration_s=duration_s,
        )
    return Orbit(
        target_m=(0.0, 0.0, 0.1),
        radius_m=1.2,
        height_m=1.0,
        period_s=duration_s,
        duration_s=duration_s,
        camera_tilt_deg=30.0,
    )


def session_dir(cache: Path, name: str) -> Path:
    return cache / name


def is_ready(cache: Path, name: str) -> bool:
    return (session_dir(cache, name) / "DONE").is_file()


def render(cache: Path, name: str) -> Path:
    """Render one session into ``cache/name`` unless it is there already."""
    from tqdm import tqdm

    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter
    from sea3d.refraction.presets import paper_rig
    from sea3d.sim.survey import SurveyConfig, simulate_survey, survey_mount, with_survey_sensors

    spec = SESSIONS[name]
    out = session_dir(cache, name)
    if is_ready(cache, name):
        return out
    if out.exists():
        import shutil

        shutil.rmtree(out)
    out.mkdir(parents=True)
    rig = paper_rig(spec.port, size_px=SIZE_PX)  # type: ignore[arg-type]
    config = SurveyConfig(
        frames=spec.frames, fps=10.0, trajectory=spec.trajectory, water="coastal", seed=0
    )
    mount = survey_mount(rig, config)
    session_rig = with_survey_sensors(rig, config, mount)
    traj = _trajectory(spec.trajectory, (spec.frames - 1) / config.fps)
    t0 = time.perf_counter()
    with (
        tqdm(total=spec.frames, desc=f"render {name}", unit="frame") as bar,
        SessionWriter(out / "session", format="folder", rig_yaml=rig_to_yaml(session_rig)) as w,
    ):
        simulate_survey(
            survey_scene(),
            rig,
            config,
            w,
            out / "gt",
            trajectory=traj,
            mount=mount,
            progress=bar.update,
        )
    (out / "DONE").write_text(f"rendered in {time.perf_counter() - t0:.0f} s\n")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument(
        "names", nargs="*", metavar="NAME", help=f"sessions (default all: {list(SESSIONS)})"
    )
    p.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    args = p.parse_args(argv)
    for name in args.names or list(SESSIONS):
        if name not in SESSIONS:
            p.error(f"unknown session {name!r}; choose from {list(SESSIONS)}")
        print(f"{name}: {render(args.cache, name)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
