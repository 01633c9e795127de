"""sea3d.recon."""
