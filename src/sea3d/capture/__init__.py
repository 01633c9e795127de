"""sea3d.capture."""
