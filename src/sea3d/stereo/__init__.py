"""sea3d.stereo."""
