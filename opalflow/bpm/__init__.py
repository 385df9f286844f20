"""Bonded-particle compression pipeline, scene-agnostic: shared spec sections, bonds, deck, time step, run and analysis."""
