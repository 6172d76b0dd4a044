"""Mie spheres: the theory, the sphere as a scatterer, and the layer of spheres (one home)."""
