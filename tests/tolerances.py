"""Test tolerances in one place, with units in their names."""

PIXEL_EXACT_PX = 1e-6  # pinhole project/unproject against OpenCV
REFRACTIVE_ROUNDTRIP_PX = 1e-4  # project(unproject(uv)) through a port
PINHOLE_REDUCTION_PX = 1e-9  # port camera that must reduce to the pinhole exactly
METRE_EXACT_M = 1e-9
