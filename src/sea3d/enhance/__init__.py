"""sea3d.enhance."""
