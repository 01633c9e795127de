"""sea3d.io."""
