"""sea3d.odometry."""
