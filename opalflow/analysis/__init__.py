"""Analysis of structures and LAMMPS output."""
