"""sea3d.sim."""
