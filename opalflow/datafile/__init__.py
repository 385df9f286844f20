"""Data-file scene (kind = "datafile"): a user's own ``atom_style bpm/sphere`` data file, compressed."""
