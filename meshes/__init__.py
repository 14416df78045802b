"""Geometry and meshes: stochastic Voronoi foams (voxels, gmsh RVE), beams and the Tripod plate."""
