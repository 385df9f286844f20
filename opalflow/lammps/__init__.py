"""LAMMPS side: data files, decks from templates, the engine that runs them."""
