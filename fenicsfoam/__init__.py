"""Simulation of soft robots made of homogenized 3D-printed foams with FEniCSx (dolfinx 0.5)."""

__version__ = "0.1.0"
