"""Homogenization of periodic microstructures: tensor utilities, FFT and FEM RVE solvers, foam tables."""
