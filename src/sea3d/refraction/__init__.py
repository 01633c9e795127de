"""sea3d.refraction."""
