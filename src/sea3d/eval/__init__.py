"""sea3d.eval."""
