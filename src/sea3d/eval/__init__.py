"""Metrics: disparity (Middlebury-style bad-pixel rates, EPE, density) and depth."""

from sea3d.eval.disparity import DisparityMetrics, disparity_metrics

__all__ = ["DisparityMetrics", "disparity_metrics"]
