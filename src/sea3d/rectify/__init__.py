"""sea3d.rectify."""
