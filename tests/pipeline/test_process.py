"""``sea3d process`` end to end on a short simulated survey: outputs, ground truth, statuses,
loop closures, resuming, local processes and a Dask cluster.

Every run after the first reuses its cached per-frame results (copied), so only the first
pays for stereo matching.
"""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from scripted_odometry import ScriptedOdometry
from sea3d.cli import main
from sea3d.errors import ConfigError, SessionError
from sea3d.geometry.se3 import rotvec_to_R
from sea3d.io.mesh_files import read_mesh
from sea3d.io.result_cache import FrameCache
from sea3d.io.session import SessionWriter, open_session
from sea3d.io.trajectory_files import read_trajectory
from sea3d.pipeline.odometry import session_odometry
from sea3d.pipeline.process import (
    ColourConfig,
    ExecutorConfig,
    MapConfig,
    PoseConfig,
    ProcessConfig,
    run_process,
)
from sea3d.stereo.recipe import DepthConfig

# Mesh accuracy with true poses at 320x180 and 2 cm voxels (measured median 3.7 mm, 90th
# percentile 12 mm): the budget leaves room for noise, and a scale or refraction error (5 %
# of 1-2 m = 5-10 cm) or a misplaced submap (the planted drift below, 8 cm) fails it.
MESH_MEDIAN_TOL_M = 0.008
MESH_P90_TOL_M = 0.025
KEYFRAMES_PER_SUBMAP = 2


def _config(out: Path, *, workers: int | None = 0, scheduler=None, **kw) -> ProcessConfig:
    return ProcessConfig(out_dir=out, executor=ExecutorConfig(workers=workers, scheduler=scheduler),
                         map=MapConfig(keyframes_per_submap=KEYFRAMES_PER_SUBMAP), **kw)


def _gt_dir(session: Path) -> Path:
    return session.with_name(session.stem + "_gt")


def _gt(session: Path):
    return read_trajectory(_gt_dir(session) / "poses_left.tum")


def _with_cache(src: Path, dst: Path) -> Path:
    shutil.copytree(src / "cache", dst / "cache")
    return dst


@pytest.fixture(scope="module")
def first_run(sim_session, tmp_path_factory):
    """The session processed with its true poses, per-frame stage in this process."""
    out = tmp_path_factory.mktemp("process") / "gt_poses"
    gt = _gt(sim_session)
    result = run_process(sim_session, _config(out), odometry=lambda rig, maps: ScriptedOdometry(
        gt.t_ns, gt.T_world_x))
    return out, result


def test_outputs_and_summary(first_run, sim_session):
    out, _ = first_run
    for name in ("trajectory.tum", "mesh.ply", "cloud.ply", "status.csv", "summary.json",
                 "report.html"):
        assert (out / name).is_file(), name
    s = json.loads((out / "summary.json").read_text())
    for key in ("frames", "keyframes", "frames_lost", "loop_closures", "path_length_m",
                "timings_s"):
        assert key in s, key
    assert s["frames"] == 30 and s["keyframes"] == 10 and s["frames_lost"] == 0
    # T_world_left for every stereo frame, stamped with the session's time.
    traj = read_trajectory(out / "trajectory.tum")
    with open_session(sim_session) as session:
        left = session.stamps("left").tolist()
    assert traj.t_ns.tolist() == left
    np.testing.assert_allclose(traj.T_world_x, _gt(sim_session).T_world_x, atol=1e-8)
    assert s["path_length_m"] == pytest.approx(
        float(np.linalg.norm(np.diff(traj.T_world_x[:, :3, 3], axis=0), axis=1).sum()))
    assert s["timings_s"]["total_s"] > 0 and "match_s" in s["worker_timings_s"]
    assert "rectify_maps_s" in s["one_off_s"]
    html = (out / "report.html").read_text()
    assert html.count("data:image/") >= 3 and "Status timeline" in html


def test_results_mcap_holds_the_trajectory_cloud_and_mesh(first_run):
    """OUT/results.mcap (Foxglove schemas) carries the same poses as trajectory.tum, with one
    status per frame, and the cloud and mesh once each."""
    from mcap.reader import make_reader

    from sea3d.io.foxglove_msgs import TOPICS

    out, _ = first_run
    traj = read_trajectory(out / "trajectory.tum")
    stamps: dict[str, list[int]] = {}
    statuses = []
    with open(out / "results.mcap", "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            stamps.setdefault(channel.topic, []).append(message.log_time)
            if channel.topic == "/odometry/status":
                statuses.append(json.loads(message.data)["status"])
    assert stamps[TOPICS["pose"]] == traj.t_ns.tolist()
    assert len(statuses) == len(traj) and set(statuses) <= {"tracking", "initialising"}
    assert len(stamps[TOPICS["cloud"]]) == 1 and len(stamps[TOPICS["mesh"]]) == 1
    assert not list(out.glob("*.partial"))


def test_mesh_matches_the_scene(first_run):
    out, result = first_run
    mv = result.summary["mesh_vs_gt"]
    assert mv["completeness_reference"].startswith("surface seen")
    assert mv["accuracy_m"]["median"] < MESH_MEDIAN_TOL_M
    assert mv["accuracy_m"]["p90"] < MESH_P90_TOL_M
    assert mv["completeness_m"]["median"] < MESH_MEDIAN_TOL_M
    mesh = read_mesh(out / "mesh.ply")
    assert len(mesh.triangles) == result.summary["mesh"]["triangles"] > 10_000
    assert mesh.colors_rgb is not None and mesh.colors_rgb.std() > 5  # coloured, not flat


def _scripted_run(sim_session, first_run, tmp_path, **script):
    out = _with_cache(first_run[0], tmp_path / "run")
    gt = _gt(sim_session)
    return run_process(sim_session, _config(out), odometry=lambda rig, maps: ScriptedOdometry(
        gt.t_ns, gt.T_world_x, **script))


# The planted drift lifts the camera 8 cm and rolls it 2 degrees: off the floor, which is what
# surface accuracy sees (a shift along the floor would hardly change it).
_DRIFT = np.eye(4)
_DRIFT[:3, :3] = rotvec_to_R(np.array([np.deg2rad(2.0), 0.0, 0.0]))
_DRIFT[:3, 3] = (0.0, 0.0, 0.08)
# Keyframes every 3 frames and 2 per submap: submaps start at frames 0, 6, 12, 18, 24, so the
# drift (frames 12-23) fills submaps 2 and 3, and the loop closes at frame 24.
_LOOP = {"drift_from": 12, "loop_at": 24, "drift": _DRIFT}


def test_a_loop_closure_re_anchors_the_drifted_submaps(sim_session, first_run, tmp_path):
    res = _scripted_run(sim_session, first_run, tmp_path, **_LOOP)
    s = res.summary
    assert s["loop_closures"] == 1 and s["submaps_moved_by_loop_closures"] == 2
    assert s["frames_from_cache"] == 30
    good = first_run[1].summary["mesh_vs_gt"]["accuracy_m"]
    fixed = s["mesh_vs_gt"]["accuracy_m"]
    assert fixed["p90"] < good["p90"] + 0.003


def test_without_re_anchoring_the_drift_stays_in_the_mesh(sim_session, first_run, tmp_path):
    res = _scripted_run(sim_session, first_run, tmp_path, forget_loop=True, **_LOOP)
    good = first_run[1].summary["mesh_vs_gt"]["accuracy_m"]
    assert res.summary["mesh_vs_gt"]["accuracy_m"]["p90"] > good["p90"] + 0.01


def test_lost_frames_are_in_the_trajectory_but_not_fused(sim_session, first_run, tmp_path):
    res = _scripted_run(sim_session, first_run, tmp_path, lost=(5, 6, 7, 20))
    s = res.summary
    assert s["frames_lost"] == 4 and s["frames_fused"] == 26
    with open(res.files["status"], newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 30
    assert [r["fusion"] for r in rows[5:8]] == ["skipped_untrusted"] * 3
    assert rows[5]["status"] == "lost"
    # The planted 0.5 m pose error of the lost frames did not reach the mesh.
    good = first_run[1].summary["mesh_vs_gt"]["accuracy_m"]
    assert s["mesh_vs_gt"]["accuracy_m"]["p90"] < good["p90"] + 0.003


def test_odometry_and_process_report_one_path_length(sim_session, first_run, tmp_path,
                                                     monkeypatch):
    """``sea3d odometry`` and ``sea3d process`` report the same path length for the same
    trajectory: the steps between trusted frames, none into or out of a lost frame."""
    import sea3d.odometry

    lost = (5, 6, 7, 20)
    gt = _gt(sim_session)
    processed = _scripted_run(sim_session, first_run, tmp_path, lost=lost).summary
    monkeypatch.setattr(sea3d.odometry, "create_odometry", lambda rig, maps, **kw:
                        ScriptedOdometry(gt.t_ns, gt.T_world_x, lost=lost))
    odometry = session_odometry(sim_session, use_imu=False).summary
    step = np.linalg.norm(np.diff(gt.T_world_x[:, :3, 3], axis=0), axis=1)
    counted = [i for i in range(len(step)) if i not in lost and i + 1 not in lost]
    assert len(counted) == len(step) - 6
    assert odometry.frames_lost == processed["frames_lost"] == len(lost)
    assert odometry.path_length_m == pytest.approx(float(step[counted].sum()), rel=1e-12)
    assert processed["path_length_m"] == odometry.path_length_m


def test_an_interrupted_run_resumes_from_its_cache(sim_session, first_run, tmp_path):
    out = _with_cache(first_run[0], tmp_path / "resume")
    cache = FrameCache(out / "cache", {})
    stamps = sorted(cache.stamps())
    for t in stamps[10:]:
        cache.path(t).unlink()  # as if killed after 10 frames
    p = cache.path(stamps[3])
    p.write_bytes(p.read_bytes()[:-100])  # a damaged entry is computed again
    gt = _gt(sim_session)
    res = run_process(sim_session, _config(out, max_frames=14),
                      odometry=lambda rig, maps: ScriptedOdometry(gt.t_ns, gt.T_world_x))
    assert res.summary["frames_from_cache"] == 9 and res.summary["frames"] == 14
    assert len(cache.stamps()) == 14


def test_a_damaged_cache_configuration_is_named_and_rebuilt_keeping_the_frames(
        sim_session, first_run, tmp_path, capsys):
    out = _with_cache(first_run[0], tmp_path / "cut")
    cfg = out / "cache" / "config.json"
    cfg.write_bytes(cfg.read_bytes()[:40])  # cut short, as by a full disk
    capsys.readouterr()
    assert main(["process", str(sim_session), "-o", str(out), "--max-frames", "14"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(cfg) in err and "damaged" in err
    assert "another configuration" not in err
    assert "--rebuild-cache-config" in err and "--fresh" in err
    gt = _gt(sim_session)
    res = run_process(sim_session, _config(out, max_frames=14, rebuild_cache_config=True),
                      odometry=lambda rig, maps: ScriptedOdometry(gt.t_ns, gt.T_world_x))
    assert res.summary["frames_from_cache"] == 14 and res.summary["frames"] == 14
    assert json.loads(cfg.read_text()) == json.loads(
        (first_run[0] / "cache" / "config.json").read_text())


def test_a_cache_of_another_configuration_is_refused(sim_session, first_run, tmp_path):
    out = _with_cache(first_run[0], tmp_path / "other")
    with pytest.raises(ConfigError, match="another configuration"):
        run_process(sim_session, _config(
            out, depth=DepthConfig(max_depth_m=3.0),
            poses=PoseConfig(poses_path=_gt_dir(sim_session) / "poses_left.tum")))


def test_local_processes_give_the_inline_depth(sim_session, first_run, tmp_path):
    """Two worker processes (the default executor) and the same frames inline agree exactly."""
    gt = _gt(sim_session)
    res = run_process(sim_session, _config(tmp_path / "procs", workers=2, max_frames=6),
                      odometry=lambda rig, maps: ScriptedOdometry(gt.t_ns, gt.T_world_x))
    assert res.summary["executor"]["kind"] == "processes"
    _same_depth(tmp_path / "procs", first_run[0], 6)


@pytest.mark.cluster
def test_dask_local_cluster_gives_the_inline_depth(sim_session, first_run, tmp_path):
    distributed = pytest.importorskip("distributed")
    gt = _gt(sim_session)
    with (
        # TCP on loopback, so frames and results are serialised as between machines.
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                 protocol="tcp", host="127.0.0.1",
                                 dashboard_address=None) as cluster,
        distributed.Client(cluster) as client,
    ):
        res = run_process(sim_session, _config(tmp_path / "dask", workers=None,
                                               scheduler=client, max_frames=6),
                          odometry=lambda rig, maps: ScriptedOdometry(gt.t_ns, gt.T_world_x))
    assert res.summary["executor"] == {"kind": "dask", "workers": 2, "in_flight": 6}
    _same_depth(tmp_path / "dask", first_run[0], 6)


def _same_depth(out_a: Path, out_b: Path, n: int) -> None:
    a, b = FrameCache(out_a / "cache", {}), FrameCache(out_b / "cache", {})
    stamps = sorted(a.stamps())
    assert len(stamps) == n
    for t in stamps:
        ea, eb = a.get(t), b.get(t)
        assert ea is not None and eb is not None
        np.testing.assert_array_equal(ea[0]["depth_m"], eb[0]["depth_m"])
        np.testing.assert_array_equal(ea[0]["fusion_depth_m"], eb[0]["fusion_depth_m"])


def test_cli_process_with_known_poses(sim_session, first_run, tmp_path, capsys):
    out = _with_cache(first_run[0], tmp_path / "cli")
    code = main(["process", str(sim_session), "-o", str(out), "--poses",
                 str(_gt_dir(sim_session) / "poses_left.tum"), "--workers", "0", "--json"])
    assert code == 0
    s = json.loads(capsys.readouterr().out)
    assert s["frames_from_cache"] == 30 and s["odometry"].startswith("known poses")
    assert s["ground_truth"].endswith("lake_gt")  # found beside the MCAP file
    assert s["trajectory_vs_gt"]["ate_m"]["rmse"] < 1e-6


def test_cli_process_bad_input_is_one_line(tmp_path, sim_session, capsys):
    empty = tmp_path / "empty"
    (empty / "left").mkdir(parents=True)
    (empty / "right").mkdir()
    assert main(["process", str(empty), "-o", str(tmp_path / "o"), "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sea3d: error:") and err.count("\n") == 1
    with pytest.raises(SystemExit) as stop:  # argparse refuses both
        main(["process", str(sim_session), "-o", str(tmp_path / "o2"), "--workers", "2",
              "--scheduler", "tcp://127.0.0.1:1"])
    assert stop.value.code == 2
    assert main(["process", str(sim_session), "-o", str(tmp_path / "o3"),
                 "--scheduler", "tcp://127.0.0.1:9"]) == 2
    assert "cannot reach the Dask scheduler tcp://127.0.0.1:9" in capsys.readouterr().err


def test_no_rig_is_a_clear_error(tmp_path, rng):
    bare = tmp_path / "bare"
    img = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    with SessionWriter(bare, format="folder") as w:
        w.write_stereo(0, img, img)
        w.write_stereo(100_000_000, img, img)
    with pytest.raises(SessionError, match="stores no rig; give a rig file"):
        run_process(bare, _config(tmp_path / "o"))
    from sea3d.io.rig_file import save_rig
    from sea3d.refraction.presets import paper_rig

    save_rig(paper_rig("dome"), tmp_path / "rig.yaml")
    with pytest.raises(SessionError, match="images are 64x48 but the rig is 1920x1080"):
        run_process(bare, _config(tmp_path / "o", rig_path=tmp_path / "rig.yaml",
                                  size_px=(64, 48)))


def test_the_enhancement_hook_colours_the_mesh(sim_session, first_run, tmp_path):
    from scripted_odometry import tint_red

    gt = _gt(sim_session)
    res = run_process(sim_session, _config(tmp_path / "enh", colours=ColourConfig(enhance=tint_red),
                                              max_frames=3),
                      odometry=lambda rig, maps: ScriptedOdometry(gt.t_ns, gt.T_world_x))
    plain = read_mesh(first_run[0] / "mesh.ply").colors_rgb.astype(float).mean(axis=0)
    tinted = res.mesh.colors_rgb.astype(float).mean(axis=0)
    assert tinted[0] == pytest.approx(plain[0], rel=0.1)
    assert tinted[1] < 0.6 * plain[1] and tinted[2] < 0.6 * plain[2]


def test_a_cached_rerun_lists_no_matching_as_if_it_had_run(sim_session, first_run, tmp_path):
    """Stage timings of cached frames belong to the run that computed them."""
    fresh = first_run[1].summary["worker_timings_s"]
    assert sum(fresh.values()) > 0  # the first run did match
    res = _scripted_run(sim_session, first_run, tmp_path)
    s = res.summary
    assert s["frames_from_cache"] == s["frames"] == 30
    assert sum(s["worker_timings_s"].values()) == 0.0
    page = (res.out_dir / "report.html").read_text()
    assert "all 30 frames came from the cache: no matching ran in this run" in page


def test_mesh_in_the_ground_truths_frame_and_eval_surface_agree(first_run, sim_session, capsys):
    """README's ``process`` then ``eval surface`` gives the process report's figure."""
    out, _ = first_run
    s = json.loads((out / "summary.json").read_text())
    assert s["frame_of_file"]["mesh.ply"].startswith("the odometry's world")
    assert s["frame_of_file"]["mesh_gt_frame.ply"] == "the ground truth's world"
    scene = _gt_dir(sim_session) / "scene.ply"
    want = s["mesh_vs_gt"]["accuracy_m"]["median"]
    for mesh, how in ((out / "mesh.ply", "trajectory-se3"), (out / "mesh_gt_frame.ply", "none")):
        assert main(["eval", "surface", str(mesh), str(scene), "--json",
                     "--samples", "100000"]) == 0
        d = json.loads(capsys.readouterr().out)
        assert d["alignment"]["method"] == how
        # Same alignment and mesh, another random sample of it: within a millimetre.
        assert abs(d["accuracy_m"]["median"] - want) < 0.001
    page = (out / "report.html").read_text()
    assert "results.mcap" in page and "mesh_gt_frame.ply" in page


def test_cli_floater_options_reach_fusion(sim_session, first_run, tmp_path, capsys):
    """``--hole-margin-px``, ``--carve-free-space``, ``--fusion-min-confidence``,
    ``--fusion-confidence-full``, ``--min-observations`` and ``--min-piece-triangles`` reach
    the fusion's TSDF (the summary says so) and change the mesh: the margin leaves out the
    pixels beside holes."""
    poses = str(_gt_dir(sim_session) / "poses_left.tum")
    meshes, summaries = [], []
    for i, extra in enumerate(([], ["--hole-margin-px", "2", "--carve-free-space",
                                    "--fusion-min-confidence", "0.1",
                                    "--fusion-confidence-full", "0.5",
                                    "--min-observations", "1",
                                    "--min-piece-triangles", "0"])):
        out = _with_cache(first_run[0], tmp_path / f"cli{i}")
        assert main(["process", str(sim_session), "-o", str(out), "--poses", poses,
                     "--workers", "0", "--json", *extra]) == 0
        summaries.append(json.loads(capsys.readouterr().out))
        meshes.append(read_mesh(out / "mesh.ply"))
    plain, opts = summaries
    assert plain["frames_from_cache"] == opts["frames_from_cache"] == 30
    noise = plain["fusion"].pop("depth_noise_per_m")
    assert plain["fusion"] == {"min_observations": 2, "min_piece_triangles": 100,
                               "hole_margin_px": 0, "carve_free_space": False,
                               "min_confidence": 0.0, "confidence_full": None}
    f = opts["fusion"]
    assert (f["min_observations"], f["min_piece_triangles"], f["hole_margin_px"],
            f["carve_free_space"], f["min_confidence"], f["confidence_full"]) == (
        1, 0, 2, True, 0.1, 0.5)
    # the carving margin's noise from the rig: 0.25 px over f B (f B of the 320x180 dome
    # rig: about 19 px m)
    assert 0.25 / 30 < f["depth_noise_per_m"] < 0.25 / 10 and f["depth_noise_per_m"] == noise
    assert len(meshes[1].vertices) != len(meshes[0].vertices)
    code = main(["process", str(sim_session), "-o", str(tmp_path / "bad"), "--poses", poses,
                 "--workers", "0", "--hole-margin-px", "40"])
    err = capsys.readouterr().err
    assert code == 2 and "--hole-margin-px must be 0..16" in err and err.count("\n") == 1


def test_cli_no_loop_closure_reaches_the_odometry(sim_session, first_run, tmp_path, capsys):
    seen = []
    for i, extra in enumerate(([], ["--no-loop-closure"])):
        out = _with_cache(first_run[0], tmp_path / f"lc{i}")
        assert main(["process", str(sim_session), "-o", str(out), "--workers", "0", "--json",
                     "--no-report", *extra]) == 0
        seen.append(json.loads(capsys.readouterr().out)["loop_checks"])
    assert seen[0]["enabled"] is True and seen[1]["enabled"] is False
    assert seen[1]["candidates"] == 0
    assert set(seen[0]) == {"enabled", "candidates", "verified", "accepted", "rejected_geometry",
                            "rejected_odometry", "rejected_graph", "rejected_solver",
                            "rejected_unconfirmed"}


def test_cache_entries_are_compact_and_old_ones_still_read(first_run, tmp_path):
    """Entries hold float32 depth (exact: a resumed run equals a fresh one) and uint8
    confidence in 16 levels; an entry written before (no confidence) reads back and fuses
    whole, and a float16 entry reads back as float32."""
    from sea3d.io.result_cache import write_entry
    from sea3d.pipeline.frame_stage import FrameResult

    cache = FrameCache(first_run[0] / "cache", {})
    t = sorted(cache.stamps())[5]
    got = cache.get(t)
    assert got is not None
    arrays, meta = got
    assert arrays["depth_m"].dtype == np.float32 and arrays["fusion_depth_m"].dtype == np.float32
    conf = arrays["fusion_confidence"]
    assert conf.dtype == np.uint8 and set(np.unique(conf)) <= set(range(0, 256, 17))
    fused = np.isfinite(arrays["fusion_depth_m"])
    assert (conf[~fused] == 0).all() and np.median(conf[fused]) > 100
    res = FrameResult.from_cache(t, arrays, meta)
    assert res.depth_m.dtype == np.float32 and res.fusion_depth_m.dtype == np.float32
    again = res.to_cache()[0]
    np.testing.assert_array_equal(again["depth_m"], arrays["depth_m"])
    np.testing.assert_array_equal(again["fusion_confidence"], conf)
    half = {k: (v.astype(np.float16) if k.endswith("depth_m") else v) for k, v in arrays.items()}
    write_entry(tmp_path / "half.s3c", half, meta)
    from sea3d.io.result_cache import read_entry as _read

    res_half = FrameResult.from_cache(t, *_read(tmp_path / "half.s3c"))
    assert res_half.fusion_depth_m.dtype == np.float32
    # an entry as written before this format: float32 depth, no confidence
    old = {k: v for k, v in arrays.items() if k != "fusion_confidence"}
    write_entry(tmp_path / "old.s3c", old, meta)
    from sea3d.io.result_cache import read_entry

    res_old = FrameResult.from_cache(t, *read_entry(tmp_path / "old.s3c"))
    assert res_old.fusion_confidence.size == 0 and res_old.fusion_depth_m.dtype == np.float32
    np.testing.assert_array_equal(res_old.fusion_depth_m, res.fusion_depth_m)
