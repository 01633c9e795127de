"""sea3d.pipeline."""
