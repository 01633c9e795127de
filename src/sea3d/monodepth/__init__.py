"""Learned monocular depth as a plug-in: a user-supplied ONNX network (onnxruntime), made
metric by robust alignment to sparse metric depth (stereo, a depth map with holes, SfM points).

See ``docs/monodepth.md``.
"""

from sea3d.monodepth.align import Alignment, align_depth, fill_holes, sparse_depth_from_points
from sea3d.monodepth.model import MonoDepthConfig, OnnxDepthModel, select_providers

__all__ = [
    "Alignment",
    "MonoDepthConfig",
    "OnnxDepthModel",
    "align_depth",
    "fill_holes",
    "select_providers",
    "sparse_depth_from_points",
]
