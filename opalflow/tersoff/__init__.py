"""Atomistic track (seed 003): Tersoff potentials for silicon - parameters, properties, fit, stability."""
