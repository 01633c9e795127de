"""Scenes: Open3D triangle meshes with materials and object ids, built in or read from YAML.

The world frame is z up (gravity along -z), metres. Every object's mesh is stored in the world
frame, together with ``T_world_object`` so that its material can evaluate the texture in the
object's own frame. Object ids are the objects' indices in :attr:`Scene.objects`; ground truth
uses -1 for "nothing hit".

Built-in scenes:

- ``tank``: the paper's cylindrical test tank (1.23 m diameter, 1.25 m deep) with a sandy bottom,
  the ArUco cube and the bottle on the floor.
- ``lake``: a sandy slope with ripples, the ArUco cube, the bottle and a few rocks.
- ``reef``: a rough rocky floor strewn with rocks.

A YAML scene lists a seafloor and objects; see ``docs/simulator.md`` for the schema.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
import yaml

from sea3d._typing import FloatArray
from sea3d.calib.targets import BoardSpec, board_origin_offset_m, parse_board, render_board
from sea3d.errors import ConfigError, SimulationError
from sea3d.sim.materials import (
    ArucoCubeMaterial,
    CheckerboardMaterial,
    ImageMaterial,
    Material,
    RockMaterial,
    SandMaterial,
    SolidMaterial,
)
from sea3d.sim.noise import fbm

__all__ = [
    "Scene",
    "SceneObject",
    "builtin_scene",
    "load_scene",
    "make_board",
    "scene_from_dict",
    "sim_board",
]

_log = logging.getLogger(__name__)

BUILTIN_SCENES = ("tank", "lake", "reef")


@dataclass(eq=False)
class SceneObject:
    """One object of a scene.

    Attributes:
        name: a label ("seafloor", "aruco_cube", ...).
        mesh: Open3D legacy triangle mesh with vertices in the world frame, metres.
        material: the object's :class:`~sea3d.sim.materials.Material`.
        T_world_object: ``(4, 4)`` float64, the object frame the material is evaluated in.
    """

    name: str
    mesh: o3d.geometry.TriangleMesh
    material: Material
    T_world_object: FloatArray = field(default_factory=lambda: np.eye(4))


@dataclass(eq=False)
class Scene:
    """A set of objects under water.

    Attributes:
        name: scene label.
        objects: the objects; an object's id is its index here.
        surface_z_m: world z of the water surface (sunlight and caustics come from there).
        floor_height: ``f(x, y) -> z`` of the seafloor, vectorised over arrays, metres; None
            if the scene has no floor.
    """

    name: str
    objects: list[SceneObject] = field(default_factory=list)
    surface_z_m: float = 3.0
    floor_height: Any = None

    def add(self, obj: SceneObject) -> int:
        """Add an object; return its id."""
        self.objects.append(obj)
        return len(self.objects) - 1

    def combined_mesh(self) -> o3d.geometry.TriangleMesh:
        """All objects' meshes in one mesh (world frame), vertex colours = mean albedo."""
        out = o3d.geometry.TriangleMesh()
        for obj in self.objects:
            m = o3d.geometry.TriangleMesh(obj.mesh)
            verts = np.asarray(m.vertices)
            pts_obj = _to_object(obj.T_world_object, verts)
            col = obj.material.albedo(pts_obj, np.full(len(verts), 0.01))
            m.vertex_colors = o3d.utility.Vector3dVector(
                np.clip(col, 0, 1).astype(np.float64) ** (1 / 2.2)
            )
            out += m
        return out

    def bounds_m(self) -> tuple[FloatArray, FloatArray]:
        """Axis-aligned bounds of all meshes: ``(min (3,), max (3,))`` metres."""
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for obj in self.objects:
            v = np.asarray(obj.mesh.vertices)
            lo = np.minimum(lo, v.min(axis=0))
            hi = np.maximum(hi, v.max(axis=0))
        return lo, hi


def _to_object(T_world_object: FloatArray, points_world: FloatArray) -> FloatArray:
    R = T_world_object[:3, :3]
    t = T_world_object[:3, 3]
    return (points_world - t) @ R


def _pose(position_m: Any = (0.0, 0.0, 0.0), rotation_deg: Any = (0.0, 0.0, 0.0)) -> FloatArray:
    """4x4 pose from a position and XYZ Euler angles in degrees (extrinsic x, then y, then z)."""
    rx, ry, rz = np.deg2rad(np.asarray(rotation_deg, dtype=np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx
    T[:3, 3] = np.asarray(position_m, dtype=np.float64)
    return T


def _transformed(mesh: o3d.geometry.TriangleMesh, T: FloatArray) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh(mesh)
    m.transform(T)
    m.compute_triangle_normals()
    return m


# ----------------------------------------------------------------------------------------------
# Geometry builders
# ----------------------------------------------------------------------------------------------


def height_field_mesh(
    x_range_m: tuple[float, float],
    y_range_m: tuple[float, float],
    resolution_m: float,
    height: Any,
) -> o3d.geometry.TriangleMesh:
    """A grid mesh of ``z = height(x, y)`` over a rectangle.

    Args:
        x_range_m: ``(x_min, x_max)`` metres.
        y_range_m: ``(y_min, y_max)`` metres.
        resolution_m: grid spacing, metres.
        height: vectorised ``f(x, y) -> z`` in metres.

    Raises:
        SimulationError: for a non-positive resolution or an empty rectangle.
    """
    if resolution_m <= 0 or x_range_m[1] <= x_range_m[0] or y_range_m[1] <= y_range_m[0]:
        raise SimulationError(
            f"height field needs resolution_m > 0 and a non-empty extent; got resolution_m="
            f"{resolution_m}, x {x_range_m}, y {y_range_m}"
        )
    nx = int(np.ceil((x_range_m[1] - x_range_m[0]) / resolution_m)) + 1
    ny = int(np.ceil((y_range_m[1] - y_range_m[0]) / resolution_m)) + 1
    xs = np.linspace(x_range_m[0], x_range_m[1], nx)
    ys = np.linspace(y_range_m[0], y_range_m[1], ny)
    X, Y = np.meshgrid(xs, ys)
    Z = np.asarray(height(X, Y), dtype=np.float64)
    verts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(tris)
    )
    mesh.compute_triangle_normals()
    return mesh


def seafloor_height(
    *,
    slope_deg: float = 0.0,
    slope_azimuth_deg: float = 0.0,
    roughness_m: float = 0.03,
    base_z_m: float = 0.0,
    feature_m: float = 0.8,
    seed: int = 3,
) -> Any:
    """A smooth seafloor height function ``f(x, y) -> z``: a plane with a slope plus fBm bumps.

    Args:
        slope_deg: slope of the mean plane; the floor rises along ``slope_azimuth_deg``.
        slope_azimuth_deg: direction of rise in the xy plane, degrees from +x.
        roughness_m: amplitude of the bumps, metres.
        base_z_m: floor height at the origin.
        feature_m: size of the largest bumps, metres.
        seed: noise field.
    """
    g = np.tan(np.deg2rad(slope_deg))
    az = np.deg2rad(slope_azimuth_deg)

    def height(x: Any, y: Any) -> Any:
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        pts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
        bumps = fbm(pts, base_freq_per_m=1.0 / feature_m, octaves=4, seed=seed).reshape(x.shape)
        return base_z_m + g * (x * np.cos(az) + y * np.sin(az)) + 2.0 * roughness_m * (bumps - 0.5)

    return height


def rock_mesh(radius_m: float, *, seed: int = 0, squash: float = 0.6) -> o3d.geometry.TriangleMesh:
    """A rock: an icosphere displaced by noise, flattened in z, centred at the origin."""
    m = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=24)
    v = np.asarray(m.vertices)
    bump = fbm(v, base_freq_per_m=1.6, octaves=4, seed=seed + 101).astype(np.float64)
    r = 1.0 + 0.9 * (bump - 0.5)
    v = v * r[:, None] * radius_m
    v[:, 2] *= squash
    m.vertices = o3d.utility.Vector3dVector(v)
    m.compute_triangle_normals()
    return m


def bottle_meshes(
    height_m: float = 0.25, radius_m: float = 0.035
) -> tuple[o3d.geometry.TriangleMesh, o3d.geometry.TriangleMesh]:
    """A bottle lying along the object's x axis, resting on z = 0: ``(body, cap)`` meshes.

    The body is a cylinder with a waist (the indentation a third of the way down, as the paper's
    bottle has), a conical shoulder and a neck; the cap is a short wider cylinder.
    """
    n_around = 48
    # Profile along the bottle axis: (position along axis, radius).
    L = height_m
    prof = [
        (0.0, 0.0),
        (0.0, radius_m * 0.95),
        (0.01 * L, radius_m),
        (0.30 * L, radius_m),
        (0.34 * L, radius_m * 0.88),
        (0.38 * L, radius_m),
        (0.68 * L, radius_m),
        (0.82 * L, radius_m * 0.42),
        (0.88 * L, radius_m * 0.38),
        (0.88 * L, 0.0),
    ]
    body = _lathe(prof, n_around)
    cap_prof = [(0.87 * L, 0.0), (0.87 * L, radius_m * 0.45), (L, radius_m * 0.45), (L, 0.0)]
    cap = _lathe(cap_prof, n_around)
    # Lathe axis is z; lay it along x and lift onto the floor.
    T = np.eye(4)
    T[:3, :3] = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], dtype=np.float64)
    T[2, 3] = radius_m
    return _transformed(body, T), _transformed(cap, T)


def _lathe(profile: list[tuple[float, float]], n_around: int) -> o3d.geometry.TriangleMesh:
    ang = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    verts = []
    for z, r in profile:
        verts.append(np.stack([r * np.cos(ang), r * np.sin(ang), np.full(n_around, z)], 1))
    v = np.concatenate(verts)
    tris = []
    for k in range(len(profile) - 1):
        a = k * n_around + np.arange(n_around)
        b = k * n_around + (np.arange(n_around) + 1) % n_around
        c, d = a + n_around, b + n_around
        tris.append(np.stack([a, b, d], 1))
        tris.append(np.stack([a, d, c], 1))
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(np.concatenate(tris))
    )
    mesh.remove_degenerate_triangles()
    mesh.compute_triangle_normals()
    return mesh


def box_mesh(size_m: float) -> o3d.geometry.TriangleMesh:
    """A cube of side ``size_m`` centred at the origin."""
    m = o3d.geometry.TriangleMesh.create_box(size_m, size_m, size_m)
    m.translate((-size_m / 2, -size_m / 2, -size_m / 2))
    m.compute_triangle_normals()
    return m


def plane_mesh(x_min: float, x_max: float, y_min: float, y_max: float) -> o3d.geometry.TriangleMesh:
    """A rectangle in the plane z = 0 (two triangles)."""
    v = np.array(
        [[x_min, y_min, 0], [x_max, y_min, 0], [x_max, y_max, 0], [x_min, y_max, 0]], float
    )
    t = np.array([[0, 1, 2], [0, 2, 3]])
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
    m.compute_triangle_normals()
    return m


def tank_wall_mesh(
    radius_m: float, depth_m: float, n_around: int = 128
) -> o3d.geometry.TriangleMesh:
    """The open cylindrical wall of a tank, floor at z = 0, rim at z = depth_m."""
    return _lathe([(0.0, radius_m), (depth_m, radius_m)], n_around)


# ----------------------------------------------------------------------------------------------
# Calibration boards
# ----------------------------------------------------------------------------------------------


# The simulator renders the chessboard-based kinds of sea3d.calib.targets (tag grids need
# another outline and pose sampler, see render_calibration_set).
SIM_BOARD_KINDS = ("checkerboard", "charuco")
_TEXELS_PER_SQUARE = 40  # ChArUco texture resolution


def sim_board(board: BoardSpec | str, where: str = "board") -> BoardSpec:
    """The :class:`sea3d.calib.targets.BoardSpec` of ``board``, checked for the simulator.

    ``board`` is a spec or a board string as :func:`sea3d.calib.targets.parse_board` reads it
    (``checkerboard:9x6:40mm`` counts inner corners, ``charuco:5x7:40mm:30mm[:DICT_6X6_250]``
    counts squares), so a string means the same physical board to ``sea3d sim calibration`` and
    to ``sea3d calibrate``.

    Raises:
        SimulationError: the string is malformed or the kind is not a checkerboard or ChArUco
            board, naming ``where`` and the text.
    """
    if isinstance(board, str):
        try:
            spec = parse_board(board)
        except ConfigError as err:
            raise SimulationError(f"{where}: bad board spec {board!r}: {err}") from err
    else:
        spec = board
    if spec.kind not in SIM_BOARD_KINDS:
        raise SimulationError(
            f"{where}: the simulator renders {' and '.join(SIM_BOARD_KINDS)} boards, "
            f"got {spec.kind!r} ({spec.name})"
        )
    return spec


def make_board(
    spec: BoardSpec, T_world_board: FloatArray, margin_m: float | None = None
) -> SceneObject:
    """A calibration board as a textured plane at ``T_world_board``.

    Board frame (that of :mod:`sea3d.calib.targets`): origin at the first inner corner, x along
    ``cols``, y along ``rows``, z into the board, metres. Checkerboards are analytic; ChArUco
    boards are :func:`sea3d.calib.targets.render_board`'s image at 40 texels per square.

    Raises:
        SimulationError: ``spec`` is not a checkerboard or ChArUco board.
    """
    spec = sim_board(spec)
    margin = spec.square_m * 0.75 if margin_m is None else margin_m
    material: Any
    if spec.kind == "checkerboard":
        cols, rows = spec.corner_grid
        material = CheckerboardMaterial(
            cols=cols, rows=rows, square_m=spec.square_m, margin_m=margin
        )
        x0, x1, y0, y1 = material.extent_m()
    else:
        img = render_board(spec, px_per_m=_TEXELS_PER_SQUARE / spec.square_m)
        rgb = np.repeat((img.astype(np.float32) / 255.0)[:, :, None], 3, axis=2)
        rgb = (0.03 + (0.85 - 0.03) * rgb).astype(np.float32)
        ox, oy = board_origin_offset_m(spec)
        material = ImageMaterial(
            image_rgb=rgb, texel_m=spec.square_m / _TEXELS_PER_SQUARE, x0_m=-ox, y0_m=-oy
        )
        x0, x1, y0, y1 = material.extent_m()
        x0, x1, y0, y1 = x0 - margin, x1 + margin, y0 - margin, y1 + margin
    mesh = _transformed(plane_mesh(x0, x1, y0, y1), T_world_board)
    return SceneObject(
        name=f"board_{spec.kind}",
        mesh=mesh,
        material=material,
        T_world_object=np.asarray(T_world_board, dtype=np.float64),
    )


# ----------------------------------------------------------------------------------------------
# Scene assembly
# ----------------------------------------------------------------------------------------------

_MATERIALS: dict[str, Any] = {"sand": SandMaterial, "rock": RockMaterial, "solid": SolidMaterial}


def _material(cfg: Any, where: str) -> Material:
    if isinstance(cfg, str):
        cfg = {"type": cfg}
    if not isinstance(cfg, dict) or cfg.get("type") not in _MATERIALS:
        raise SimulationError(f"{where}: material must be one of {sorted(_MATERIALS)}, got {cfg!r}")
    kwargs = {k: (tuple(v) if isinstance(v, list) else v) for k, v in cfg.items() if k != "type"}
    try:
        return _MATERIALS[cfg["type"]](**kwargs)
    except TypeError as err:
        raise SimulationError(f"{where}: bad material options {kwargs}: {err}") from err


def _on_floor(scene: Scene, pos: list[float], lift_m: float) -> list[float]:
    if scene.floor_height is None:
        return pos
    z = float(np.asarray(scene.floor_height(np.array([pos[0]]), np.array([pos[1]])))[0])
    return [pos[0], pos[1], z + lift_m]


def scene_from_dict(cfg: dict[str, Any], *, source: str = "<dict>") -> Scene:
    """Build a scene from its YAML mapping (schema in ``docs/simulator.md``).

    Raises:
        SimulationError: on an unknown key, object type or material, naming ``source``.
    """
    if not isinstance(cfg, dict):
        raise SimulationError(f"{source}: a scene must be a mapping, got {type(cfg).__name__}")
    scene = Scene(
        name=str(cfg.get("name", Path(source).stem)), surface_z_m=float(cfg.get("surface_z_m", 3.0))
    )
    floor = cfg.get("seafloor")
    if floor is not None:
        if not isinstance(floor, dict):
            raise SimulationError(f"{source}: seafloor must be a mapping, got {floor!r}")
        allowed = {
            "size_m",
            "center_m",
            "resolution_m",
            "slope_deg",
            "slope_azimuth_deg",
            "roughness_m",
            "feature_m",
            "z_m",
            "seed",
            "material",
        }
        unknown = set(floor) - allowed
        if unknown:
            raise SimulationError(
                f"{source}: unknown seafloor keys {sorted(unknown)} (allowed {sorted(allowed)})"
            )
        h = seafloor_height(
            slope_deg=float(floor.get("slope_deg", 0.0)),
            slope_azimuth_deg=float(floor.get("slope_azimuth_deg", 0.0)),
            roughness_m=float(floor.get("roughness_m", 0.03)),
            base_z_m=float(floor.get("z_m", 0.0)),
            feature_m=float(floor.get("feature_m", 0.8)),
            seed=int(floor.get("seed", 3)),
        )
        sx, sy = (float(v) for v in floor.get("size_m", [8.0, 8.0]))
        cx, cy = (float(v) for v in floor.get("center_m", [0.0, 0.0]))
        mesh = height_field_mesh(
            (cx - sx / 2, cx + sx / 2),
            (cy - sy / 2, cy + sy / 2),
            float(floor.get("resolution_m", 0.04)),
            h,
        )
        scene.floor_height = h
        scene.add(
            SceneObject(
                name="seafloor",
                mesh=mesh,
                material=_material(floor.get("material", "sand"), f"{source}: seafloor"),
            )
        )
    for k, obj in enumerate(cfg.get("objects", []) or []):
        _add_object(scene, obj, f"{source}: objects[{k}]")
    unknown = set(cfg) - {"name", "surface_z_m", "seafloor", "objects"}
    if unknown:
        raise SimulationError(f"{source}: unknown scene keys {sorted(unknown)}")
    return scene


def _add_object(scene: Scene, obj: Any, where: str) -> None:
    if not isinstance(obj, dict) or "type" not in obj:
        raise SimulationError(f"{where}: an object must be a mapping with a 'type', got {obj!r}")
    kind = obj["type"]
    pos = [float(v) for v in obj.get("position_m", [0.0, 0.0, 0.0])]
    rot = obj.get("rotation_deg", [0.0, 0.0, 0.0])
    on_floor = bool(obj.get("on_floor", True))
    if kind == "aruco_cube":
        size = float(obj.get("size_m", 0.2))
        if on_floor:
            pos = _on_floor(scene, pos, size / 2 - 0.01)
        T = _pose(pos, rot)
        mat = ArucoCubeMaterial(
            size_m=size,
            marker_ids=tuple(obj.get("marker_ids", (0, 1, 2, 3, 4, 5))),
            dictionary=str(obj.get("dictionary", "DICT_4X4_50")),
        )
        scene.add(
            SceneObject(
                name="aruco_cube",
                mesh=_transformed(box_mesh(size), T),
                material=mat,
                T_world_object=T,
            )
        )
    elif kind == "bottle":
        if on_floor:
            pos = _on_floor(scene, pos, -0.005)
        T = _pose(pos, rot)
        body, cap = bottle_meshes(
            float(obj.get("length_m", 0.25)), float(obj.get("radius_m", 0.035))
        )
        colour = tuple(obj.get("colour_rgb", (0.08, 0.30, 0.10)))
        scene.add(
            SceneObject(
                name="bottle",
                mesh=_transformed(body, T),
                T_world_object=T,
                material=SolidMaterial(colour_rgb=colour, noise=0.15, noise_freq_per_m=40.0),
            )
        )
        scene.add(
            SceneObject(
                name="bottle_cap",
                mesh=_transformed(cap, T),
                T_world_object=T,
                material=SolidMaterial(colour_rgb=(0.02, 0.15, 0.04), noise=0.1),
            )
        )
    elif kind == "rock":
        r = float(obj.get("radius_m", 0.15))
        if on_floor:
            pos = _on_floor(scene, pos, 0.2 * r)
        T = _pose(pos, rot)
        mesh = rock_mesh(r, seed=int(obj.get("seed", 0)), squash=float(obj.get("squash", 0.6)))
        scene.add(
            SceneObject(
                name="rock",
                mesh=_transformed(mesh, T),
                T_world_object=T,
                material=_material(obj.get("material", "rock"), where),
            )
        )
    elif kind == "board":
        spec = sim_board(str(obj.get("board", "checkerboard:9x6:40mm")), where)
        T = (
            np.asarray(obj["T_world_board"], dtype=np.float64)
            if "T_world_board" in obj
            else _pose(pos, rot)
        )
        if T.shape != (4, 4):
            raise SimulationError(f"{where}: T_world_board must be 4x4, got shape {T.shape}")
        scene.add(make_board(spec, T))
    elif kind == "tank":
        radius = float(obj.get("diameter_m", 1.23)) / 2
        depth = float(obj.get("depth_m", 1.25))
        T = _pose(pos, rot)
        scene.add(
            SceneObject(
                name="tank_wall",
                mesh=_transformed(tank_wall_mesh(radius, depth), T),
                T_world_object=T,
                material=SolidMaterial(
                    colour_rgb=(0.35, 0.40, 0.42), noise=0.35, noise_freq_per_m=30.0
                ),
            )
        )
    else:
        raise SimulationError(
            f"{where}: unknown object type {kind!r} (aruco_cube, bottle, rock, board, tank)"
        )


_BUILTINS: dict[str, dict[str, Any]] = {
    "tank": {
        "name": "tank",
        "surface_z_m": 1.25,
        "seafloor": {
            "size_m": [1.3, 1.3],
            "resolution_m": 0.02,
            "roughness_m": 0.01,
            "feature_m": 0.3,
            "material": {
                "type": "sand",
                "colour_rgb": [0.50, 0.47, 0.40],
                "ripple_wavelength_m": 0.0,
            },
        },
        "objects": [
            {"type": "tank", "diameter_m": 1.23, "depth_m": 1.25},
            {
                "type": "aruco_cube",
                "size_m": 0.15,
                "position_m": [0.12, 0.05, 0.0],
                "rotation_deg": [0, 0, 25],
            },
            {"type": "bottle", "position_m": [-0.15, -0.08, 0.0], "rotation_deg": [0, 0, -30]},
        ],
    },
    "lake": {
        "name": "lake",
        "surface_z_m": 3.0,
        "seafloor": {
            "size_m": [10.0, 10.0],
            "resolution_m": 0.04,
            "slope_deg": 8.0,
            "roughness_m": 0.04,
        },
        "objects": [
            {
                "type": "aruco_cube",
                "size_m": 0.2,
                "position_m": [0.0, 0.0, 0.0],
                "rotation_deg": [0, 0, 20],
            },
            {"type": "bottle", "position_m": [0.45, -0.25, 0.0], "rotation_deg": [0, 0, 60]},
            {"type": "rock", "radius_m": 0.18, "position_m": [-0.8, 0.6, 0.0], "seed": 1},
            {"type": "rock", "radius_m": 0.10, "position_m": [0.9, 0.8, 0.0], "seed": 2},
            {"type": "rock", "radius_m": 0.25, "position_m": [-1.4, -1.1, 0.0], "seed": 3},
        ],
    },
    "reef": {
        "name": "reef",
        "surface_z_m": 4.0,
        "seafloor": {
            "size_m": [12.0, 12.0],
            "resolution_m": 0.04,
            "roughness_m": 0.15,
            "feature_m": 1.5,
            "material": {"type": "rock", "colour_rgb": [0.35, 0.30, 0.26]},
        },
        "objects": [
            {
                "type": "rock",
                "radius_m": float(r),
                "position_m": [float(x), float(y), 0.0],
                "seed": int(s),
                "material": {"type": "rock", "colour_rgb": [0.30 + 0.1 * (s % 3), 0.28, 0.24]},
            }
            for s, (x, y, r) in enumerate(
                [
                    (0.0, 0.0, 0.35),
                    (1.2, 0.4, 0.25),
                    (-1.0, 0.9, 0.3),
                    (0.6, -1.3, 0.2),
                    (-1.5, -0.8, 0.4),
                    (2.0, -0.6, 0.3),
                    (-0.3, 1.8, 0.22),
                    (1.6, 1.7, 0.28),
                    (-2.2, 0.2, 0.3),
                    (0.2, -2.2, 0.35),
                ]
            )
        ],
    },
}


def builtin_scene(name: str) -> Scene:
    """One of the built-in scenes ``tank``, ``lake``, ``reef``.

    Raises:
        SimulationError: for an unknown name.
    """
    if name not in _BUILTINS:
        raise SimulationError(
            f"unknown scene {name!r}; built-in scenes are {', '.join(BUILTIN_SCENES)} "
            f"(or give a path to a scene YAML file)"
        )
    return scene_from_dict(_BUILTINS[name], source=f"builtin:{name}")


def load_scene(name_or_path: str | Path) -> Scene:
    """A built-in scene by name, or a scene YAML file by path.

    Raises:
        SimulationError: for a missing or malformed file, naming it.
    """
    text = str(name_or_path)
    if text in _BUILTINS:
        return builtin_scene(text)
    path = Path(text)
    if not path.is_file():
        raise SimulationError(
            f"scene {text!r} is neither a built-in scene ({', '.join(BUILTIN_SCENES)}) nor a file"
        )
    try:
        cfg = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise SimulationError(f"cannot read scene file {path}: {err}") from err
    return scene_from_dict(cfg, source=str(path))
