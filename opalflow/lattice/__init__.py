"""Lattice scene (kind = "lattice"): regular arrays of bonded spheres for analytic checks."""
