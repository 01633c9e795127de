"""sea3d.geometry."""
