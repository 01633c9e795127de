"""Underwater enhancement, measured: colour against clean references, effect on dense stereo
and on sparse features, caustic removal, real images, and speed (docs/enhance.md).

Sections (``--section``, default all):

- ``colour``: simulated ``lake`` and ``reef`` views in clear, coastal and turbid water (paper
  rig without ports, so the images are already rectified), each method against the clean
  reference (same view without water, same noise seed; :mod:`sea3d.sim.reference`):
  CIEDE2000 after one global exposure gain (the issue's figure) and after per-channel gains
  (white point forgiven), and against ``J`` (water removed from the line of sight only).
  Sea-thru runs with the true range and with range from our SGM (``sea3d.stereo``), and
  OpenCV's ``xphoto`` grey-world white balance is the reference tool.
- ``formation``: the headline. Clean views of ``lake`` and ``reef`` (no water) at several
  ranges (one dive per scene), degraded by an image-formation model independent of our
  simulator (:mod:`sea3d.eval.enhance_formation`: Akkaynak-Treibitz with Jerlov II, 3C and 9C
  ``K_d``), each water a table: grey world, OpenCV xphoto, per-image Sea-thru, and the dive's
  water model (:func:`sea3d.enhance.fit_water_model` over the dive's frames) with stereo range
  (our SGM on the degraded pair) and with true range, beside the oracle (the formation model
  inverted with its true parameters): CIEDE2000 after one global exposure gain.
- ``stereo``: SGM bad-2 and density (ours and OpenCV StereoSGBM) on the same pairs with and
  without each method (white balances applied jointly to the pair).
- ``features``: correct SIFT matches (against ground-truth depth and poses, 3 px) between two
  views of the lake in clear shallow water with caustics, raw, with CLAHE on L*, after caustic
  removal, and both; plus the caustic-removal error against the caustic-free render.
- ``real``: EUVP pairs (full reference), the real singles and RUIE (no reference: colour cast
  must shrink, SSIM of L* to the input must stay high); pictures for the docs.
- ``speed``: wall and CPU time per 1920x1080 image for each method, beside OpenCV's xphoto
  grey world and OpenCV's CLAHE on 8-bit L (medians of ``--repeats`` runs).
- ``process``: ``sea3d process --restore-colours seathru|seathru-per-image`` on a simulated coastal
  dive (``--process-frames``, default 12): per-image Sea-thru, the dive's one water model and
  grey world against the clean views (CIEDE2000 after one gain, colour cast and its spread
  over the frames), the fused cloud's and mesh's cast, and restoring against matching per
  frame.

Run: ``PYTHONPATH=src nice python benchmarks/bench_enhance.py [--section colour] [--size 480x270]
[--pictures docs/img]``. Figures go to stdout; ``--json FILE`` keeps them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sea3d.enhance import (
    METHODS,
    SeathruConfig,
    ciede2000_after_diagonal_gain,
    ciede2000_after_gain,
    clahe,
    colour_cast,
    compare_to_reference,
    depth_to_range,
    enhance_image,
    remove_caustics,
    uciqe,
    uiqm,
)
from sea3d.enhance._image import luminance, srgb_to_linear
from sea3d.enhance.water import WaterFitConfig, WaterModel, fit_water_model, restore
from sea3d.eval.enhance_formation import JERLOV_WATERS, degrade
from sea3d.geometry.se3 import look_at
from sea3d.pipeline.enhance_tasks import correct_feature_matches, stereo_with_enhancement
from sea3d.refraction.presets import paper_rig
from sea3d.sim import Imaging, Renderer, builtin_scene
from sea3d.sim.reference import simulate_pair_with_reference
from sea3d.stereo import OpenCVSgbmConfig, SgmConfig, match

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
VIEW_EYE = (0.35, -1.6, 0.9)
VIEW_TARGET = (0.0, 0.0, 0.1)
WATERS = ("clear", "coastal", "turbid")
SEATHRU_VARIANTS: dict[str, SeathruConfig] = {
    "sea-thru as published": SeathruConfig.as_published(),
    "envelope + fit": SeathruConfig(backscatter_fit="envelope", attenuation="fit"),
    "envelope + fit-scaled": SeathruConfig(backscatter_fit="envelope", attenuation="fit-scaled"),
    "envelope + illuminant": SeathruConfig(backscatter_fit="envelope", attenuation="illuminant"),
    "eq10 + illuminant": SeathruConfig(backscatter_fit="eq10", attenuation="illuminant"),
    "illuminant, no backscatter": SeathruConfig(backscatter=False),
}
CAUSTICS = 0.6  # the underwater presets' caustic strength
DEFAULT_VARIANT = "envelope + illuminant"  # = SeathruConfig()
OUT: dict[str, Any] = {}


def _xphoto_grey(img: np.ndarray) -> np.ndarray:
    wb = cv2.xphoto.createGrayworldWB()
    return cv2.cvtColor(wb.balanceWhite(cv2.cvtColor(img, cv2.COLOR_RGB2BGR)), cv2.COLOR_BGR2RGB)


def _stereo_range(left: np.ndarray, right: np.ndarray, rig: Any, max_d: int) -> np.ndarray:
    """Range from our SGM on an already rectified (portless) pair."""
    pin = rig.left
    disp = match(left, right, SgmConfig(max_disparity_px=max_d)).disparity_px
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(disp > 0, pin.fx * rig.baseline_m / disp, np.nan).astype(np.float32)
    return depth_to_range(depth, pin.fx, pin.fy, pin.cx, pin.cy)


def _render_cases(size: tuple[int, int], scenes: tuple[str, ...]) -> list[dict[str, Any]]:
    rig = paper_rig("none", size_px=size)
    cases = []
    for scene in scenes:
        r = Renderer(builtin_scene(scene), supersample=2)
        T = look_at(VIEW_EYE, VIEW_TARGET)
        for water in WATERS:
            for lamp in (0.0, 0.8) if scene == "lake" and water == "coastal" else (0.0,):
                im = dataclasses.replace(
                    Imaging.underwater(water), vehicle_light=lamp, vignetting=0.0
                )
                p = simulate_pair_with_reference(rig, r.scene, T, im, renderer=r, seed=1)
                cases.append({"scene": scene, "water": water, "lamp": lamp, "pair": p,
                              "rig": rig})
    return cases


def _fmt(x: float) -> str:
    return f"{x:5.2f}"


def section_colour(args: argparse.Namespace) -> None:
    cases = _render_cases(args.size, ("lake", "reef"))
    max_d = 63 if args.size[0] <= 700 else 127
    rows = []
    for c in cases:
        p, rig = c["pair"], c["rig"]
        mask = p.gt.object_id >= 0
        true_range = p.gt.range_m
        t0 = time.perf_counter()
        sgm_range = _stereo_range(p.left, p.right, rig, max_d)
        stereo_s = time.perf_counter() - t0
        outs: dict[str, np.ndarray] = {
            "input": p.left, "xphoto-grey (OpenCV)": _xphoto_grey(p.left)
        }
        for m in ("grey-world", "shades-of-grey", "red-comp", "clahe", "udcp"):
            outs[m] = enhance_image(p.left, m).images[0]
        for wb in ("auto", "grey-world", "locus"):
            wcfg = WaterFitConfig(white_balance=wb)  # type: ignore[arg-type]
            for rname, rmap in (("true range", true_range), ("stereo range", sgm_range)):
                wm = fit_water_model([(p.left, rmap)], wcfg)
                outs[f"water model, wb {wb} ({rname})"] = restore(p.left, rmap, wm, wcfg).image
        for name, cfg in SEATHRU_VARIANTS.items():
            outs[f"{name} (true range)"] = enhance_image(
                p.left, "seathru", range_m=true_range, seathru_config=cfg
            ).images[0]
            outs[f"{name} (stereo range)"] = enhance_image(
                p.left, "seathru", range_m=sgm_range, seathru_config=cfg
            ).images[0]
        case = f"{c['scene']}/{c['water']}/lamp {c['lamp']}"
        print(f"\n== colour: {case}  (stereo range valid on "
              f"{100 * np.isfinite(sgm_range)[mask].mean():.0f} % of the surface, "
              f"{stereo_s:.1f} s)")
        print(f"{'method':40s} {'dE00 gain':>9s} {'dE00 diag':>9s} {'J diag':>7s} "
              f"{'SSIM':>6s} {'PSNR':>6s}")
        for name, img in outs.items():
            g, _ = ciede2000_after_gain(img, p.left_clean, mask)
            d, _ = ciede2000_after_diagonal_gain(img, p.left_clean, mask)
            j, _ = ciede2000_after_diagonal_gain(img, p.left_unattenuated, mask)
            ssim, psnr = _ssim_psnr(img, p.left_clean, mask)
            print(f"{name:40s} {_fmt(g):>9s} {_fmt(d):>9s} {_fmt(j):>7s} {ssim:6.3f} "
                  f"{psnr:6.1f}", flush=True)
            rows.append({"case": case, "method": name, "gain": g, "diag": d, "J_diag": j,
                         "ssim": ssim, "psnr_db": psnr})
        if args.pictures and c["scene"] == "lake" and c["water"] == "coastal" and c["lamp"] == 0.0:
            _picture(
                args.pictures / "enhance_sim_coastal.jpg",
                [p.left, outs["grey-world"], outs[f"{DEFAULT_VARIANT} (stereo range)"],
                 p.left_clean],
            )
    OUT["colour"] = rows
    _summary_colour(rows)


def _ssim_psnr(img: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    a, b = img.astype(np.float32) / 255.0, ref.astype(np.float32) / 255.0
    _, smap = structural_similarity(b, a, data_range=1.0, channel_axis=2, full=True)
    return float(smap.mean(axis=2)[mask].mean()), float(
        peak_signal_noise_ratio(b[mask], a[mask], data_range=1.0)
    )


def _summary_colour(rows: list[dict[str, Any]]) -> None:
    by: dict[str, dict[str, list[float]]] = {}
    for r in rows:
        d = by.setdefault(r["method"], {"g": [], "d": [], "j": [], "s": [], "p": []})
        d["g"].append(r["gain"])
        d["d"].append(r["diag"])
        d["j"].append(r["J_diag"])
        d["s"].append(r["ssim"])
        d["p"].append(r["psnr_db"])
    print("\n== colour summary: median over scenes, waters and lamp on/off")
    print(f"{'method':40s} {'dE00 gain':>9s} {'dE00 diag':>9s} {'J diag':>7s} {'SSIM':>6s} "
          f"{'PSNR':>6s}")
    for m, d in by.items():
        med = {k: statistics.median(v) for k, v in d.items()}
        print(f"{m:40s} {_fmt(med['g']):>9s} {_fmt(med['d']):>9s} {_fmt(med['j']):>7s} "
              f"{med['s']:6.3f} {med['p']:6.1f}")
    for name in SEATHRU_VARIANTS:
        s = by.get(f"{name} (stereo range)")
        t = by.get(f"{name} (true range)")
        if s and t:
            ratio = [a / b for a, b in zip(s["d"], t["d"], strict=True)]
            print(f"{name}: stereo / true range (dE00 diag), median "
                  f"{statistics.median(ratio):.2f}, max {max(ratio):.2f}")


DIVE_EYES = ((0.35, -1.6, 0.9), (0.2, -2.4, 1.4), (0.5, -1.2, 0.6), (-0.3, -3.0, 1.6))
"""Camera positions of one simulated dive (the target stays at VIEW_TARGET)."""


def section_formation(args: argparse.Namespace) -> None:
    rig = paper_rig("none", size_px=args.size)
    max_d = 63 if args.size[0] <= 700 else 127
    rows: list[dict[str, Any]] = []
    for scene in ("lake", "reef"):
        r = Renderer(builtin_scene(scene), supersample=2)
        views = []
        for eye in DIVE_EYES:
            T = look_at(eye, VIEW_TARGET)
            lv = r.render(rig.left, T, Imaging.clean())
            rv = r.render(rig.right, T @ rig.T_left_right, Imaging.clean())
            views.append((lv, rv))
        for wname, water in JERLOV_WATERS.items():
            frames = []
            for lv, rv in views:
                left = degrade(lv.image, lv.gt.range_m, water)
                right = degrade(rv.image, rv.gt.range_m, water)
                frames.append((left, lv.gt.range_m, _stereo_range(left, right, rig, max_d)))
            t0 = time.perf_counter()
            model_true = fit_water_model([(f[0], f[1]) for f in frames])
            model_st = fit_water_model([(f[0], f[2]) for f in frames])
            keep_j = WaterFitConfig(white_balance="none")  # this judge lights its scene white
            model_j = fit_water_model([(f[0], f[2]) for f in frames], keep_j)
            fit_s = (time.perf_counter() - t0) / 2
            oracle = WaterModel(B_inf_rgb=water.B_inf_rgb, beta_B_per_m=water.beta_B_per_m,
                                beta_D_per_m=water.beta_D_per_m)
            per: dict[str, list[float]] = {}
            for k, ((left, true_r, st_r), (lv, _rv)) in enumerate(zip(frames, views,
                                                                     strict=True)):
                ref, mask = lv.image, np.isfinite(lv.gt.range_m)
                outs = {
                    "input": left,
                    "grey-world": enhance_image(left, "grey-world").images[0],
                    "xphoto-grey (OpenCV)": _xphoto_grey(left),
                    "sea-thru per image, stereo range": enhance_image(
                        left, "seathru", range_m=st_r,
                        seathru_config=SeathruConfig(attenuation="illuminant")).images[0],
                    "water model, stereo range": restore(left, st_r, model_st).image,
                    "water model, true range": restore(left, true_r, model_true).image,
                    "water model, no balance (J), stereo range": restore(
                        left, st_r, model_j, keep_j).image,
                    "oracle (true parameters)": restore(left, true_r, oracle).image,
                }
                for name, img in outs.items():
                    per.setdefault(name, []).append(ciede2000_after_gain(img, ref, mask)[0])
                if args.pictures and k == 0 and scene == "lake" and wname == "jerlov-3C":
                    _picture(args.pictures / "enhance_formation_lake_3C.jpg",
                             [left, outs["grey-world"], outs["water model, stereo range"], ref])
            print(f"\n== formation: {scene} in {wname} (beta_D true "
                  f"{np.round(water.beta_D_per_m, 2).tolist()}, fitted stereo "
                  f"{np.round(model_st.beta_D_per_m, 2).tolist()} [{model_st.status}], "
                  f"fit {fit_s:.1f} s per dive of {len(frames)} frames)")
            print(f"{'method':36s} {'dE00 gain':>9s}  (mean of the dive's frames)")
            gw = statistics.mean(per["grey-world"])
            for name, v in per.items():
                m = statistics.mean(v)
                below = f"   {100 * (1 - m / gw):5.0f} % below grey world"
                extra = below if name != "input" else ""
                print(f"{name:36s} {_fmt(m):>9s}{extra}", flush=True)
                rows.append({"scene": scene, "water": wname, "method": name, "de00_gain": m})
            st = statistics.mean(per["water model, stereo range"])
            tr = statistics.mean(per["water model, true range"])
            print(f"stereo / true range: {st / tr:.2f}x")
    OUT["formation"] = rows


SIM_REFERENCES = ("J", "clean")
"""What the simulated dive's restorations are compared to: ``J`` (the view with the water on
the line of sight removed, the lights still through water: what Sea-thru is defined to
recover) and ``clean`` (no water at all: white light; also needs the light's colour removed,
a colour-constancy step no water model holds)."""


def _sim_dive(r: Renderer, rig: Any, water: str, max_d: int) -> list[dict[str, Any]]:
    """One simulated dive: the DIVE_EYES views in one water, every effect on, with both
    references, true and stereo range."""
    frames = []
    for k, eye in enumerate(DIVE_EYES):
        p = simulate_pair_with_reference(rig, r.scene, look_at(eye, VIEW_TARGET), water,
                                         renderer=r, seed=k + 1)
        frames.append({"pair": p, "true": p.gt.range_m,
                       "stereo": _stereo_range(p.left, p.right, rig, max_d)})
    return frames


def _pooled_grey_world(imgs: list[np.ndarray], masks: list[np.ndarray]) -> np.ndarray:
    """Grey-world gains (linear) pooled over the masked pixels of several sRGB images."""
    lin = np.concatenate([srgb_to_linear(im.astype(np.float32) / np.float32(255.0))[m]
                          for im, m in zip(imgs, masks, strict=True)])
    mean = lin.mean(axis=0)
    return np.asarray(mean.mean() / np.maximum(mean, 1e-6))


def _apply_gains(img: np.ndarray, gains: np.ndarray) -> np.ndarray:
    lin = srgb_to_linear(img.astype(np.float32) / np.float32(255.0)) * gains.astype(np.float32)
    lin = lin / max(float(np.percentile(lin.max(axis=2), 99.5)), 1e-6)
    enc = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * np.power(np.clip(lin, 0, 1), 1 / 2.4)
                   - 0.055)
    return np.asarray(np.clip(enc * 255 + 0.5, 0, 255), np.uint8)


def section_simdive(args: argparse.Namespace) -> None:
    """The dive's water model on our own simulator, per water type: as ``formation`` with the
    degradation and the references from :mod:`sea3d.sim.reference` (every underwater effect
    on: sun through the water above, lamp, caustics, vignetting, blur, noise)."""
    rig = paper_rig("none", size_px=args.size)
    max_d = 63 if args.size[0] <= 700 else 127
    rows: list[dict[str, Any]] = []
    for scene in ("lake", "reef"):
        r = Renderer(builtin_scene(scene), supersample=2)
        for water in WATERS:
            t0 = time.perf_counter()
            frames = _sim_dive(r, rig, water, max_d)
            render_s = time.perf_counter() - t0
            wm = frames[0]["pair"].water
            e = float(wm["exposure"])
            oracle = WaterModel(B_inf_rgb=tuple(e * b for b in wm["B_inf_rgb"]),  # type: ignore
                                beta_B_per_m=tuple(wm["beta_B_per_m"]),
                                beta_D_per_m=tuple(wm["beta_D_per_m"]))
            models = {f"water model, {rn}": fit_water_model([(f["pair"].left, f[key])
                                                             for f in frames])
                      for rn, key in (("stereo range", "stereo"), ("true range", "true"))}
            keep_j = WaterFitConfig(white_balance="none")
            j_model = fit_water_model([(f["pair"].left, f["stereo"]) for f in frames], keep_j)
            oracle_j = [restore(f["pair"].left, f["true"], oracle).image for f in frames]
            gains = _pooled_grey_world(oracle_j, [np.isfinite(f["true"]) for f in frames])
            per: dict[str, dict[str, list[float]]] = {ref: {} for ref in SIM_REFERENCES}
            for k, f in enumerate(frames):
                p = f["pair"]
                mask = (p.gt.object_id >= 0) & np.isfinite(p.gt.range_m)
                outs = {
                    "input": p.left,
                    "grey-world": enhance_image(p.left, "grey-world").images[0],
                    "xphoto-grey (OpenCV)": _xphoto_grey(p.left),
                    "water model of each image alone, stereo": enhance_image(
                        p.left, "seathru", range_m=f["stereo"]).images[0],
                    "water model, stereo range": restore(
                        p.left, f["stereo"], models["water model, stereo range"]).image,
                    "water model, true range": restore(
                        p.left, f["true"], models["water model, true range"]).image,
                    "water model, no balance (J), stereo": restore(
                        p.left, f["stereo"], j_model, keep_j).image,
                    "oracle (true parameters, J)": oracle_j[k],
                    "oracle + pooled grey world": _apply_gains(oracle_j[k], gains),
                }
                for ref_name, ref in (("J", p.left_unattenuated), ("clean", p.left_clean)):
                    for name, img in outs.items():
                        per[ref_name].setdefault(name, []).append(
                            ciede2000_after_gain(img, ref, mask)[0])
                if args.pictures and k == 0 and scene == "lake" and water == "coastal":
                    _picture(args.pictures / "enhance_simdive_lake_coastal.jpg",
                             [p.left, outs["grey-world"], outs["water model, stereo range"],
                              p.left_unattenuated, p.left_clean])
            st = models["water model, stereo range"]
            print(f"\n== simulated dive: {scene} in {water} ({len(frames)} frames, rendered in "
                  f"{render_s:.0f} s; beta_D true {np.round(wm['beta_D_per_m'], 2).tolist()}, "
                  f"fitted stereo {np.round(st.beta_D_per_m, 2).tolist()} [{st.status}])")
            print(f"{'method':36s} {'vs J':>6s} {'below gw':>8s} {'vs clean':>8s} "
                  f"{'below gw':>8s}")
            gw = {ref: statistics.mean(per[ref]["grey-world"]) for ref in SIM_REFERENCES}
            for name in per["J"]:
                mj, mc = (statistics.mean(per[ref][name]) for ref in SIM_REFERENCES)
                print(f"{name:36s} {_fmt(mj):>6s} {100 * (1 - mj / gw['J']):7.0f}% "
                      f"{_fmt(mc):>8s} {100 * (1 - mc / gw['clean']):7.0f}%", flush=True)
                rows.append({"scene": scene, "water": water, "method": name, "de00_gain_J": mj,
                             "de00_gain_clean": mc})
            for ref in SIM_REFERENCES:
                s_r = statistics.mean(per[ref]["water model, stereo range"])
                t_r = statistics.mean(per[ref]["water model, true range"])
                print(f"stereo / true range (vs {ref}): {s_r / t_r:.2f}x")
    OUT["simdive"] = rows


def section_stereo(args: argparse.Namespace) -> None:
    cases = _render_cases(args.size, ("lake",))
    max_d = 63 if args.size[0] <= 700 else 127
    rows = []
    for c in cases:
        p, rig = c["pair"], c["rig"]
        pin = rig.left
        with np.errstate(divide="ignore", invalid="ignore"):
            gt = (pin.fx * rig.baseline_m / p.gt.depth_m).astype(np.float32)
        case = f"{c['water']}/lamp {c['lamp']}"
        print(f"\n== stereo: lake {case}")
        print(f"{'method':16s} {'sea3d bad-2':>11s} {'density':>8s} {'OpenCV bad-2':>12s} "
              f"{'density':>8s}")
        ours_all = stereo_with_enhancement(p.left, p.right, gt, SgmConfig(max_disparity_px=max_d))
        ocv_all = stereo_with_enhancement(p.left, p.right, gt,
                                          OpenCVSgbmConfig(max_disparity_px=max_d))
        for m, ours in ours_all.items():
            ocv = ocv_all[m]
            print(f"{m:16s} {ours.bad_2:11.2f} {ours.density:8.1f} {ocv.bad_2:12.2f} "
                  f"{ocv.density:8.1f}", flush=True)
            rows.append({"case": case, "method": m, "sea3d": ours.as_dict(),
                         "opencv": ocv.as_dict()})
    OUT["stereo"] = rows


def section_features(args: argparse.Namespace) -> None:
    size = args.size
    rig = paper_rig("none", size_px=size)
    cam = rig.left
    r = Renderer(builtin_scene("lake"), supersample=2)
    rows = []
    for water in ("clear", "coastal"):
        im = dataclasses.replace(Imaging.underwater(water), caustics=CAUSTICS, vignetting=0.0)
        clean_im = dataclasses.replace(im, caustics=0.0)
        frames, poses, depth, cleans = [], [], [], []
        for k in range(7):
            T = look_at((0.35 + 0.04 * k, -1.6, 0.9), (0.04 * k, 0.0, 0.1))
            v = r.render(cam, T, im, time_s=1.5 * k, rng=np.random.default_rng(k))
            c = r.render(cam, T, clean_im, time_s=1.5 * k, rng=np.random.default_rng(k))
            frames.append(v.image)
            poses.append(T)
            depth.append(v.gt.depth_m)
            cleans.append(c.image)
        # Caustic removal of frames 2 and 4 with their four nearest neighbours each.
        removed = {}
        for k in (2, 4):
            idx = list(range(max(0, k - 2), min(7, k + 3)))
            res = remove_caustics([frames[j] for j in idx], idx.index(k), depth[k], cam,
                                  [poses[j] for j in idx])
            removed[k] = res.image
            seen = res.frames_seen >= 3

            def y(a: np.ndarray) -> np.ndarray:
                return luminance(srgb_to_linear(a.astype(np.float32) / 255.0))

            before = float(np.abs(y(frames[k]) - y(cleans[k]))[seen].mean())
            after = float(np.abs(y(res.image) - y(cleans[k]))[seen].mean())
            print(f"caustic removal {water} frame {k}: luminance error {before:.4f} -> "
                  f"{after:.4f} ({100 * (1 - after / before):.0f} % less) on "
                  f"{100 * seen.mean():.0f} % of the image")
            rows.append({"water": water, "frame": k, "caustic_error_before": before,
                         "caustic_error_after": after})
            if args.pictures and water == "clear" and k == 2:
                cmap = np.clip((res.caustic_map - 0.5) * 255, 0, 255).astype(np.uint8)
                _picture(args.pictures / "enhance_caustics.jpg",
                         [frames[k], res.image, np.repeat(cmap[..., None], 3, axis=2),
                          cleans[k]])
        T_b_a = np.linalg.inv(poses[4]) @ poses[2]
        variants = {
            "raw": (frames[2], frames[4]),
            "clahe": (clahe(frames[2]), clahe(frames[4])),
            "caustics removed": (removed[2], removed[4]),
            "caustics removed + clahe": (clahe(removed[2]), clahe(removed[4])),
            "caustic-free render (ceiling)": (cleans[2], cleans[4]),
        }
        print(f"\n== features: lake {water}, caustics {CAUSTICS}, views 8 cm and 3 s apart")
        for name, (a, b) in variants.items():
            fm = correct_feature_matches(a, b, depth[2], cam, T_b_a, tol_px=3.0)
            print(f"{name:32s} correct {fm.correct:5d} of {fm.matches:5d} ratio-test matches "
                  f"({100 * fm.precision:.0f} % of the {fm.judged} with true depth)", flush=True)
            rows.append({"water": water, "variant": name, "correct": fm.correct,
                         "matches": fm.matches, "judged": fm.judged})
    OUT["features"] = rows


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.glob("*") if p.suffix.lower() in (".jpg", ".jpeg", ".png"))


def _read(p: Path) -> np.ndarray:
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None:
        raise SystemExit(f"cannot read {p}")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _ssim_l(a: np.ndarray, b: np.ndarray) -> float:
    from skimage.metrics import structural_similarity

    la = cv2.cvtColor(a.astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)[..., 0]
    lb = cv2.cvtColor(b.astype(np.float32) / 255.0, cv2.COLOR_RGB2Lab)[..., 0]
    return float(structural_similarity(la, lb, data_range=100.0))


def section_real(args: argparse.Namespace) -> None:
    methods = ("grey-world", "shades-of-grey", "red-comp", "clahe", "udcp")
    uw = args.data / "underwater"
    rows: dict[str, Any] = {}
    euvp = uw / "euvp_pairs"
    if euvp.is_dir():
        acc: dict[str, list[list[float]]] = {m: [] for m in ("input", *methods)}
        for raw_p in _images(euvp / "raw"):
            raw, ref = _read(raw_p), _read(euvp / "reference" / raw_p.name)
            for m in acc:
                out = raw if m == "input" else enhance_image(raw, m).images[0]
                r = compare_to_reference(out, ref)
                acc[m].append([r.psnr_db, r.ssim, r.ciede2000, r.ciede2000_gain])
        print(f"\n== EUVP ({len(acc['input'])} pairs, reference = EUVP's enhanced image), means")
        print(f"{'method':16s} {'PSNR dB':>8s} {'SSIM':>6s} {'dE00':>6s} {'dE00 gain':>9s}")
        for m, vals in acc.items():
            v = np.mean(np.asarray(vals), axis=0)
            print(f"{m:16s} {v[0]:8.2f} {v[1]:6.3f} {v[2]:6.2f} {v[3]:9.2f}")
        rows["euvp"] = {m: np.mean(np.asarray(v), axis=0).tolist() for m, v in acc.items()}
    ruie = uw / "ruie_uccs"
    if ruie.is_dir():
        print("\n== RUIE UCCS (no reference): colour cast (CIELAB chroma of the mean), SSIM of "
              "L* to the input, UCIQE; means per folder")
        rows["ruie"] = {}
        for sub in ("blue", "green", "blue-green"):
            paths = _images(ruie / sub)[:: max(1, args.ruie_stride)]
            stats: dict[str, list[list[float]]] = {m: [] for m in ("input", *methods)}
            for pth in paths:
                img = _read(pth)
                for m in stats:
                    out = img if m == "input" else enhance_image(img, m).images[0]
                    stats[m].append([colour_cast(out), _ssim_l(out, img), uciqe(out).uciqe])
            print(f"-- {sub} ({len(paths)} images)")
            for m, vals in stats.items():
                v = np.mean(np.asarray(vals), axis=0)
                shrink = sum(1 for a, b in zip(stats["input"], vals, strict=True) if b[0] < a[0])
                print(f"{m:16s} cast {v[0]:6.2f} (smaller in {shrink}/{len(vals)})  "
                      f"SSIM L* {v[1]:.3f}  UCIQE {v[2]:.3f}")
            rows["ruie"][sub] = {m: np.mean(np.asarray(v), axis=0).tolist()
                                 for m, v in stats.items()}
    singles = uw / "singles"
    if singles.is_dir():
        print("\n== real singles (no reference): UIQM / UCIQE / colour cast")
        rows["singles"] = {}
        for pth in _images(singles):
            img = _read(pth)
            if max(img.shape[:2]) > 1280:
                s = 1280 / max(img.shape[:2])
                img = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
            line = f"{pth.stem[:22]:22s}"
            outs = {"input": img}
            for m in methods:
                outs[m] = enhance_image(img, m).images[0]
            for m, out in outs.items():
                q = uiqm(out)
                line += f" | {m} {q.uiqm:.2f}/{uciqe(out).uciqe:.3f}/{colour_cast(out):.1f}"
            print(line, flush=True)
            if args.pictures and pth.stem.startswith("galdran1"):
                _picture(args.pictures / "enhance_real_single.jpg",
                         [outs["input"], outs["grey-world"], outs["red-comp"], outs["clahe"],
                          outs["udcp"]], height=180)
    field = uw / "sea3d_field_left"
    if field.is_dir() and args.pictures:
        img = _read(sorted(field.glob("*.jpg"))[0])
        _picture(args.pictures / "enhance_field.jpg",
                 [img, enhance_image(img, "red-comp").images[0],
                  enhance_image(img, "clahe").images[0]],
                 height=200)
    OUT["real"] = rows


BOARD_SETS = ("stereopi_panama_sea", "stereopi_bermuda1_sea")
BOARD_INNER = (9, 6)
"""The StereoPi sets' chessboard: 9 x 6 inner corners (10 x 7 squares), square size not
documented, so board range is in units of squares (the water model's ``beta_D z`` is
unit-free when it is fitted and applied in the same units)."""


def _board_frames(folder: Path) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Left halves (RGB) of the side-by-side frames and their detected inner corners."""
    imgs, corners = [], []
    for f in sorted(folder.glob("*.png")):
        bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
        left = bgr[:, : bgr.shape[1] // 2]
        grey = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
        ok, c = cv2.findChessboardCorners(
            grey, BOARD_INNER, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            c = cv2.cornerSubPix(grey, c, (5, 5), (-1, -1),
                                 (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3))
            imgs.append(cv2.cvtColor(left, cv2.COLOR_BGR2RGB))
            corners.append(c)
    return imgs, corners


def _board_geometry(imgs: list[np.ndarray], corners: list[np.ndarray]
                    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per frame: range to the board (squares; NaN off the board) and the masks of its white
    and black square interiors, from the left camera calibrated on these frames (OpenCV,
    ``CALIB_FIX_K3``) and each frame's board pose (its PnP solution)."""
    nx, ny = BOARD_INNER
    obj = np.zeros((nx * ny, 3), np.float32)
    obj[:, :2] = np.mgrid[0:nx, 0:ny].T.reshape(-1, 2)
    h, w = imgs[0].shape[:2]
    _rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
        [obj] * len(corners), corners, (w, h), None, None, flags=cv2.CALIB_FIX_K3)
    uv = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(uv.astype(np.float64), K, dist).reshape(-1, 2)
    rays = np.column_stack([rays, np.ones(len(rays))])
    out = []
    for img, rvec, tvec in zip(imgs, rvecs, tvecs, strict=True):
        R, _ = cv2.Rodrigues(rvec)
        t = tvec.ravel()
        n = R[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (n @ t) / (rays @ n)
        P = rays * lam[:, None]
        Q = (P - t) @ R  # board coordinates, squares
        X, Y = Q[:, 0].reshape(h, w), Q[:, 1].reshape(h, w)
        on = (lam.reshape(h, w) > 0) & (X > -1) & (X < nx) & (Y > -1) & (Y < ny)
        rng_sq = np.where(on, lam.reshape(h, w) * np.linalg.norm(rays, axis=1).reshape(h, w),
                          np.nan).astype(np.float32)
        fx, fy = X - np.floor(X), Y - np.floor(Y)
        inner = on & (fx > 0.25) & (fx < 0.75) & (fy > 0.25) & (fy < 0.75)
        parity = ((np.floor(X) + np.floor(Y)) % 2 == 0)
        lum = img.astype(np.float32).mean(axis=2)
        a, b = inner & parity, inner & ~parity
        white, black = (a, b) if lum[a].mean() > lum[b].mean() else (b, a)
        out.append((rng_sq, white, black))
    return out


def _lab_of_mean(img: np.ndarray, mask: np.ndarray) -> tuple[float, float, float]:
    """CIELAB L*, a*, b* of the mean linear colour of ``img`` over ``mask``."""
    lin = srgb_to_linear(img.astype(np.float32) / np.float32(255.0))[mask].mean(axis=0)
    enc = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * np.power(lin, 1 / 2.4) - 0.055)
    lab = cv2.cvtColor(np.clip(enc, 0, 1).astype(np.float32)[None, None], cv2.COLOR_RGB2Lab)
    return float(lab[0, 0, 0]), float(lab[0, 0, 1]), float(lab[0, 0, 2])


def section_board(args: argparse.Namespace) -> None:
    """Real open-sea frames with a neutral target: the cast of the board's white squares
    (and black) before and after each method, same run; the water model fitted over the
    dive's frames with the board's range (PnP), per-image Sea-thru with the same range."""
    rows = []
    for name in BOARD_SETS:
        folder = args.data / "underwater_stereo" / name / "sbs"
        if not folder.is_dir():
            print(f"\n== board: {folder} missing, skipped")
            continue
        imgs, corners = _board_frames(folder)
        geo = _board_geometry(imgs, corners)
        t0 = time.perf_counter()
        # Range in squares, not metres: only the unit-free plausibility limits apply.
        sq = WaterFitConfig(metric_range=False)
        model = fit_water_model([(im, g[0]) for im, g in zip(imgs, geo, strict=True)], sq)
        keep_j = WaterFitConfig(white_balance="none", metric_range=False)
        model_j = fit_water_model([(im, g[0]) for im, g in zip(imgs, geo, strict=True)],
                                  keep_j)
        locus = WaterFitConfig(white_balance="locus", metric_range=False)
        model_l = fit_water_model([(im, g[0]) for im, g in zip(imgs, geo, strict=True)],
                                  locus)
        fit_s = time.perf_counter() - t0
        span = [float(np.nanpercentile(g[0], q)) for g in geo for q in (5, 95)]
        per: dict[str, list[tuple[float, float, float, float]]] = {}
        for k, (img, (rng_sq, white, black)) in enumerate(zip(imgs, geo, strict=True)):
            outs = {
                "input": img,
                "grey-world": enhance_image(img, "grey-world").images[0],
                "xphoto-grey (OpenCV)": _xphoto_grey(img),
                "water model of each image alone, board range": restore(
                    img, rng_sq, fit_water_model([(img, rng_sq)], sq), sq).image,
                "water model, board range": restore(img, rng_sq, model, sq).image,
                "water model, no balance (J), board range": restore(img, rng_sq, model_j,
                                                                    keep_j).image,
                "water model, locus balance, board range": restore(img, rng_sq, model_l,
                                                                   locus).image,
            }
            for m, out in outs.items():
                _L, a, b = _lab_of_mean(out, white)
                _Lb, ab, bb = _lab_of_mean(out, black)
                per.setdefault(m, []).append((a, b, float(np.hypot(a, b)),
                                              float(np.hypot(ab, bb))))
            if args.pictures and k == 0:
                _picture(args.pictures / f"enhance_board_{name}.jpg",
                         [outs["input"], outs["grey-world"], outs["xphoto-grey (OpenCV)"],
                          outs["water model, board range"]], height=160)
        print(f"\n== board: {name} ({len(imgs)} frames with the board; range "
              f"{min(span):.1f}-{max(span):.1f} squares; water model [{model.status}] beta_D "
              f"{np.round(model.beta_D_per_m, 3).tolist()} per square, fit {fit_s:.1f} s)")
        print(f"{'method':40s} {'white a*':>8s} {'b*':>6s} {'C*':>6s} {'black C*':>8s}  "
              "(means over the frames)")
        for m, v in per.items():
            a, b, c, cb = (statistics.mean(x[i] for x in v) for i in range(4))
            print(f"{m:40s} {a:8.1f} {b:6.1f} {c:6.1f} {cb:8.1f}", flush=True)
            rows.append({"set": name, "method": m, "white_a": a, "white_b": b, "white_C": c,
                         "black_C": cb, "frames": len(imgs), "status": model.status})
    OUT["board"] = rows


def section_cast(args: argparse.Namespace) -> None:
    """Real frames without a reference: the colour cast (CIELAB chroma of the mean colour)
    before and after grey world, OpenCV xphoto's grey world and red compensation, same run,
    on the Sea3D field dive's left frames and the RUIE UCCS folders (every
    ``--ruie-stride``-th image). A grey world drives this cast to about zero by construction,
    so it says how much cast there was, not which colours are right (the board says that)."""
    uw = args.data / "underwater"
    sets = [("sea3d_field_left", uw / "sea3d_field_left")]
    sets += [(f"ruie {sub}", uw / "ruie_uccs" / sub) for sub in ("blue", "green", "blue-green")]
    rows: dict[str, Any] = {}
    print("\n== cast without a reference: mean CIELAB chroma of the mean colour (median), "
          "images whose cast shrank")
    for name, folder in sets:
        if not folder.is_dir():
            continue
        paths = _images(folder)[:: max(1, args.ruie_stride)]
        got: dict[str, list[float]] = {}
        for pth in paths:
            img = _read(pth)
            if max(img.shape[:2]) > 1280:
                s = 1280 / max(img.shape[:2])
                img = cv2.resize(img, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
            outs = {"input": img, "grey-world": enhance_image(img, "grey-world").images[0],
                    "xphoto-grey (OpenCV)": _xphoto_grey(img),
                    "red-comp": enhance_image(img, "red-comp").images[0]}
            for m, out in outs.items():
                got.setdefault(m, []).append(colour_cast(out))
            if args.pictures and pth == paths[0] and name == "sea3d_field_left":
                _picture(args.pictures / "enhance_cast_field.jpg", list(outs.values()))
        line = f"{name:18s} ({len(paths)} images)"
        for m, v in got.items():
            shrank = sum(1 for a, b in zip(got["input"], v, strict=True) if b < a)
            line += f" | {m} {statistics.mean(v):.1f} / {statistics.median(v):.1f}" + (
                f" ({shrank}/{len(v)})" if m != "input" else "")
        print(line, flush=True)
        rows[name] = {m: statistics.mean(v) for m, v in got.items()}
    OUT["cast"] = rows


def _time(fn: Any, repeats: int) -> tuple[float, float]:
    walls, cpus = [], []
    fn()  # warm-up (imports, caches)
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return statistics.median(walls), statistics.median(cpus)


def section_speed(args: argparse.Namespace) -> None:
    field = args.data / "underwater" / "sea3d_field_left"
    imgs = sorted(field.glob("*.jpg")) if field.is_dir() else []
    if imgs:
        img = cv2.resize(_read(imgs[0]), (1920, 1080))
    else:
        img = (np.random.default_rng(0).random((1080, 1920, 3)) * 255).astype(np.uint8)
    yy = np.linspace(6.0, 1.0, 1080, dtype=np.float32)[:, None]
    rng_map = np.repeat(yy, 1920, axis=1)
    rng_map[:200] = np.nan  # open water without range
    print(f"\n== speed per 1920x1080 image, medians of {args.repeats} runs (wall s, CPU s)")

    def ref_clahe() -> None:
        lab = cv2.cvtColor(img, cv2.COLOR_RGB2Lab)
        lab[..., 0] = cv2.createCLAHE(2.0, (8, 8)).apply(lab[..., 0])
        cv2.cvtColor(lab, cv2.COLOR_Lab2RGB)

    refs = {"grey-world": ("OpenCV xphoto grey world", lambda: _xphoto_grey(img)),
            "clahe": ("OpenCV CLAHE on 8-bit L", ref_clahe)}
    rows = []
    for m in METHODS:
        kw: dict[str, Any] = {"range_m": rng_map} if m == "seathru" else {}
        wall, cpu = _time(lambda m=m, kw=kw: enhance_image(img, m, **kw), args.repeats)
        line = f"{m:16s} {wall:7.3f} {cpu:7.3f}"
        row: dict[str, Any] = {"method": m, "wall_s": wall, "cpu_s": cpu}
        if m in refs:
            name, fn = refs[m]
            rw, rc = _time(fn, args.repeats)
            line += f"   {name}: {rw:.3f} {rc:.3f}  (ours / reference: {wall / rw:.1f}x wall)"
            row.update(reference=name, reference_wall_s=rw, reference_cpu_s=rc)
        print(line, flush=True)
        rows.append(row)
    # The dive's water model is fitted once; each frame is then one inversion.
    model = fit_water_model([(img, rng_map)])
    for name, fn in (("water model fit (once per dive)",
                      lambda: fit_water_model([(img, rng_map)])),
                     ("seathru with the dive's model", lambda: restore(img, rng_map, model))):
        wall, cpu = _time(fn, args.repeats)
        print(f"{name:32s} {wall:7.3f} {cpu:7.3f}", flush=True)
        rows.append({"method": name, "wall_s": wall, "cpu_s": cpu})
    OUT["speed"] = rows


def _log_chroma(pixels: np.ndarray) -> np.ndarray:
    m = pixels.reshape(-1, 3).astype(np.float64).mean(axis=0)
    return np.log(np.array([m[0] / m[1], m[2] / m[1]]))


def section_process(args: argparse.Namespace) -> None:
    """``sea3d process --restore-colours`` on a simulated coastal dive of the lake with clean
    references: per-image Sea-thru (``seathru-per-image``), the dive's one water model
    (``seathru``, the default) and grey world of each frame, in the same run. Per frame: CIEDE2000
    after one exposure gain and the colour cast against the clean view (rectified the same
    way), over the pixels with depth, and the spread of the cast over the frames (frame-to-
    frame stability); per run: the cast of the fused cloud and mesh against the clean views'
    mean colour, and the per-frame cost of restoring against matching (summary.json)."""
    import tempfile

    from sea3d.enhance.colour import grey_world
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.io.session import SessionWriter, open_session
    from sea3d.pipeline.colour_stage import DiveColourConfig, DiveColours
    from sea3d.pipeline.frame_stage import FrameStageConfig, process_frame, stage_depth
    from sea3d.pipeline.process import (
        ColourConfig,
        ExecutorConfig,
        PoseConfig,
        ProcessConfig,
        run_process,
    )
    from sea3d.sim.survey import SurveyConfig, simulate_survey
    from sea3d.stereo.recipe import DepthConfig

    size = (192, 108)  # as tests/enhance/test_process_colours.py
    n_frames = args.process_frames
    rig = paper_rig("none", size_px=size)
    depth_cfg = DepthConfig(max_depth_m=8.0)
    with tempfile.TemporaryDirectory() as tmp:
        src, gt = Path(tmp) / "lake", Path(tmp) / "lake_gt"
        cfg = SurveyConfig(frames=n_frames, water="coastal", supersample=1,
                           clean_reference=True)
        with SessionWriter(src, format="folder", rig_yaml=rig_to_yaml(rig)) as w:
            simulate_survey(builtin_scene("lake"), rig, cfg, w, gt)
        plain_cfg = FrameStageConfig(rig=rig, depth=depth_cfg)
        per_image_cfg = FrameStageConfig(rig=rig, depth=depth_cfg, restore_colours="seathru")
        maps = stage_depth(plain_cfg).maps
        frames, cleans = [], []
        with open_session(src) as s:
            for t in s.stamps("left"):
                left, right = s.image("left", int(t)), s.image("right", int(t))
                frames.append((process_frame(plain_cfg, int(t), left, right),
                               process_frame(per_image_cfg, int(t), left, right)))
                clean = _read(gt / "clean" / "left" / f"{int(t)}.png")
                cleans.append(cv2.remap(clean, maps.map_left_x, maps.map_left_y,
                                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))
        dive = DiveColours(maps)
        dived = [r for plain, _ in frames for r in dive.push(plain)] + dive.flush()
        other_wb = {}
        for wb in ("locus", "grey-world"):
            d = DiveColours(maps, DiveColourConfig(water=WaterFitConfig(white_balance=wb)))
            other_wb[wb] = [r.colors() for plain, _ in frames for r in d.push(plain)] + [
                r.colors() for r in d.flush()]
        runs = {}
        for mode in ("seathru-per-image", "seathru"):
            runs[mode] = run_process(src, ProcessConfig(
                out_dir=Path(tmp) / mode, executor=ExecutorConfig(workers=0),
                poses=PoseConfig(poses_path=gt / "poses_left.tum"),
                colours=ColourConfig(restore_colours=mode), depth=DepthConfig(max_depth_m=8.0),
                report=False, evaluate=False))
    variants = {
        "input": [plain.rect_left for plain, _ in frames],
        "grey world (per frame)": [grey_world(plain.rect_left) for plain, _ in frames],
        "sea-thru per image (seathru-per-image)": [rest.colors() for _, rest in frames],
        "dive water model (seathru)": [r.colors() for r in dived],
        "dive water model, wb locus": other_wb["locus"],
        "dive water model, wb grey world": other_wb["grey-world"],
    }
    masks = [np.isfinite(plain.depth_m) & (c.max(axis=2) > 0)
             for (plain, _), c in zip(frames, cleans, strict=True)]
    ref_all = np.concatenate([c[m] for c, m in zip(cleans, masks, strict=True)])
    print(f"\n== process --restore-colours: lake, coastal, {size[0]}x{size[1]}, {n_frames} "
          f"frames (depth on {100 * np.mean([m.mean() for m in masks]):.0f} %)")
    print(f"{'method':34s} {'dE00 gain':>9s} {'cast':>6s} {'cast sd':>7s}")
    rows: dict[str, Any] = {}
    for name, imgs in variants.items():
        de = [ciede2000_after_gain(img, c, m)[0]
              for img, c, m in zip(imgs, cleans, masks, strict=True)]
        casts = [np.abs(_log_chroma(img[m]) - _log_chroma(c[m])).sum()
                 for img, c, m in zip(imgs, cleans, masks, strict=True)]
        chroma = np.stack([_log_chroma(img[m]) - _log_chroma(c[m])
                           for img, c, m in zip(imgs, cleans, masks, strict=True)])
        sd = float(np.max(np.std(chroma, axis=0)))
        rows[name] = {"dE00_gain_median": float(np.median(de)),
                      "cast_median": float(np.median(casts)), "cast_sd_over_frames": sd}
        print(f"{name:34s} {np.median(de):9.2f} {np.median(casts):6.3f} {sd:7.3f}")
    ref = _log_chroma(ref_all)
    print("fused outputs, colour cast |log R/G| + |log B/G| against the clean views' mean:")
    for mode, res in runs.items():
        per = res.summary["colours"].get("per_frame_s", {})
        casts = {name: float(np.abs(_log_chroma(np.asarray(c)) - ref).sum())
                 for name, c in (("cloud", res.cloud_colors), ("mesh", res.mesh.colors_rgb))}
        print(f"  {mode:17s} cloud {casts['cloud']:.3f}  mesh {casts['mesh']:.3f}  status "
              f"{res.summary['colours']['restore_status']}  per frame: restore "
              f"{per.get('restore_colours_s', 0):.4f} s, match {per.get('match_s', 0):.4f} s")
        rows[f"process {mode}"] = {**casts, "per_frame_s": per}
    wm = dive.summary()["water_model"] or {}
    print(f"dive water model: status {wm.get('status')}, beta_D {wm.get('beta_D_per_m')}, "
          f"B_inf {wm.get('B_inf_rgb')}, fit {dive.fit_s:.2f} s over "
          f"{len(dive.fit_stamps)} frames; checks: {wm.get('checks')}")
    OUT["process"] = rows


def _picture(path: Path, panels: list[np.ndarray], height: int = 160) -> None:
    """Panels side by side, scaled to ``height``, as a small JPEG (kept under 200 KB)."""
    scaled = []
    for p in panels:
        s = height / p.shape[0]
        scaled.append(cv2.resize(p, (round(p.shape[1] * s), height),
                                 interpolation=cv2.INTER_AREA))
    strip = np.concatenate(scaled, axis=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    for q in (85, 75, 65, 50):
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(strip, cv2.COLOR_RGB2BGR),
                               [cv2.IMWRITE_JPEG_QUALITY, q])
        if ok and len(buf) < 200_000:
            path.write_bytes(buf.tobytes())
            print(f"wrote {path} ({len(buf) // 1024} KB)")
            return
    raise SystemExit(f"{path}: could not get under 200 KB")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--section", action="append",
                    choices=("formation", "simdive", "board", "cast", "colour", "stereo",
                             "features", "real", "speed", "process"))
    ap.add_argument("--size", default="480x270", help="simulated image size WxH")
    ap.add_argument("--data", type=Path, default=DATA, help="the shared data folder")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per method")
    ap.add_argument("--process-frames", type=int, default=12,
                    help="frames of the simulated dive of --section process")
    ap.add_argument("--ruie-stride", type=int, default=5, help="use every n-th RUIE image")
    ap.add_argument("--pictures", type=Path, help="write the docs' pictures to this folder")
    ap.add_argument("--json", type=Path, help="also write the figures as JSON")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    args.size = (w, h)
    sections = args.section or ["formation", "simdive", "board", "cast", "colour", "stereo",
                                "features", "real", "speed", "process"]
    funcs = {"formation": section_formation, "simdive": section_simdive, "board": section_board,
             "cast": section_cast,
             "colour": section_colour,
             "stereo": section_stereo, "features": section_features, "real": section_real,
             "speed": section_speed, "process": section_process}
    for s in sections:
        t0 = time.perf_counter()
        funcs[s](args)
        print(f"[{s}: {time.perf_counter() - t0:.0f} s]", file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps(OUT, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
