"""Contact-only scenes: an unbonded granular packing compressed by a plate, on LAMMPS or LIGGGHTS."""
