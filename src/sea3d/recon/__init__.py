"""sea3d.recon: point clouds, TSDF fusion, submaps and meshes."""

from sea3d.geometry.mesh import Mesh

__all__ = ["Mesh"]
