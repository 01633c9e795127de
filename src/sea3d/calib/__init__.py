"""sea3d.calib."""
