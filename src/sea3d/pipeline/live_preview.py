"""The depth preview of the live view (``sea3d record/monitor --foxglove``).

Capture hands frames on and runs no stage: :class:`~sea3d.capture.foxglove_live.FoxgloveBridge`
calls the depth provider its caller gives it. :class:`DepthPreview` is that provider: a
low-resolution depth image through :class:`~sea3d.stereo.recipe.StereoDepth` (refraction
corrected with the rig), or a raw OpenCV SGBM disparity when there is no rig.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["DepthPreview"]


class DepthPreview:
    """Low-resolution depth (with a rig) or raw disparity (without) of a stereo pair.

    Args:
        rig: the stereo rig (:class:`~sea3d.geometry.rig.StereoRig`), or None for disparity.
        width_px: width of the preview image (the rig is scaled to it; >= 32).
    """

    def __init__(self, rig: Any, width_px: int) -> None:
        self.rig = rig
        self.width_px = int(width_px)
        self._stereo: Any = None

    def compute(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, bool]:
        """Depth of a pair.

        Args:
            left, right: (H, W) or (H, W, 3) uint8/uint16 camera frames.

        Returns:
            ``(image, is_disparity)``: (h, width_px) float32 depth in metres (NaN where
            unknown), or, without a rig, the disparity in pixels and True.
        """
        import cv2

        if self.rig is None:
            return self._disparity(left, right), True
        if self._stereo is None:
            from sea3d.stereo.recipe import DepthConfig, StereoDepth

            scale = self.width_px / self.rig.width
            small = self.rig.scaled(self.width_px, max(1, round(self.rig.height * scale)))
            # OpenCV's engine is the fastest on a CPU; ranges from the (small) rig
            self._stereo = StereoDepth(small, DepthConfig(engine="opencv"))
        size = (self._stereo.rig.width, self._stereo.rig.height)
        ls = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
        rs = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
        return self._stereo.compute(ls, rs).depth_m, False

    __call__ = compute

    def _disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        import cv2

        def grey(img: np.ndarray) -> np.ndarray:
            g = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
            if g.dtype == np.uint16:
                g = (g.astype(np.uint16) >> 8).astype(np.uint8)
            h, w = g.shape
            return cv2.resize(g, (self.width_px, max(1, round(h * self.width_px / w))))

        gl, gr = grey(left), grey(right)
        n = max(16, (gl.shape[1] // 6) // 16 * 16)
        sgbm = cv2.StereoSGBM.create(0, n, 5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10)
        disp = sgbm.compute(gl, gr).astype(np.float32) / 16.0  # SGBM's fixed point, x16
        disp[disp <= 0] = np.nan
        return disp
