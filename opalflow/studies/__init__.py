"""Studies of Dosta et al. (kind = "study"): sweeps of compression jobs, cached by spec hash, with reports."""
