"""Results on disk: every file is written under a temporary name, then renamed.

A finished result is therefore never replaced by a half-written one, and a run folder is
held by one process at a time (:func:`folder_lock`).  Every JSON file opalflow reads back (run.json,
states, references, progress) is read by :func:`read_json`: damage is one line naming the file
and what to do (:class:`DamagedFile`, exit 2: never a regression's 1, never a traceback).
"""
from __future__ import annotations

import dataclasses
import json
import os
import signal
import socket
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from opalflow.spec import InputError

LOCK_FILE = ".opalflow.lock"
#: a run folder's files that opalflow reads back: its record, its summary (the mark of a finished run), its data
RECORD, SUMMARY, RESULTS = "run.json", "summary.json", "results.h5"

#: fault injection (tests/test_rundir.py): ``OPALFLOW_FAILPOINT=N`` kills the process that imported opalflow with
#: it set (SIGKILL: no handler, no cleanup) at its N-th write point, a temporary file written and not yet renamed;
#: the variable is taken out of the environment, so processes started by this one (LAMMPS, jobs) do not count
_FAILPOINT = {"at": os.environ.pop("OPALFLOW_FAILPOINT", ""), "pid": os.getpid(), "seen": 0}


def failpoint() -> None:
    """A write point (see :data:`_FAILPOINT`); nothing unless ``OPALFLOW_FAILPOINT`` was set."""
    if _FAILPOINT["at"] and os.getpid() == _FAILPOINT["pid"]:
        _FAILPOINT["seen"] += 1
        if _FAILPOINT["seen"] == int(_FAILPOINT["at"]):
            os.kill(os.getpid(), signal.SIGKILL)


class DamagedFile(InputError):
    """A file opalflow wrote and reads back that is missing, cut short or without what it must hold (one line:
    the file, what it is, what is wrong, what to do)."""

    def __init__(self, path, what: str, wrong: str, remedy: str):
        self.path, self.wrong = Path(path), wrong
        super().__init__(f"{path} ({what}): {wrong}; {remedy}")


def read_json(path: str | os.PathLike, what: str, remedy: str, *, keys: tuple[str, ...] = ()) -> dict:
    """The JSON object in ``path`` holding ``keys``; :class:`DamagedFile` when it is missing, unreadable, cut
    short, not an object or without one of ``keys`` (``what``: what the file is, ``remedy``: what to do)."""
    try:
        data = json.loads(Path(path).read_bytes())
    except FileNotFoundError:
        raise DamagedFile(path, what, "missing", remedy) from None
    except OSError as exc:
        raise DamagedFile(path, what, f"cannot be read ({exc.strerror})", remedy) from None
    except ValueError as exc:            # JSONDecodeError, UnicodeDecodeError
        raise DamagedFile(path, what, f"damaged, not JSON ({exc})", remedy) from None
    if not isinstance(data, dict):
        raise DamagedFile(path, what, f"damaged: holds a JSON {type(data).__name__}, not an object", remedy)
    missing = [k for k in keys if k not in data]
    if missing:
        raise DamagedFile(path, what, f"damaged: has no {', '.join(repr(k) for k in missing)}", remedy)
    return data


def _default(obj):
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):      # a typed result: its fields as a table
        return dataclasses.asdict(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot store {type(obj).__name__} in JSON")


@contextmanager
def atomic_path(path: str | os.PathLike, tmp_name: str | None = None):
    """A temporary path to write ``path`` to; renamed to ``path`` when the block ends without error,
    removed when it fails (a full disk, say), so the earlier file stays as it was."""
    path = Path(path)
    tmp = path.with_name(tmp_name or path.name + ".tmp")
    try:
        yield tmp
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError) and not exc.filename:
            raise OSError(exc.errno, exc.strerror, str(path)) from None
        raise
    failpoint()
    os.replace(tmp, path)


@contextmanager
def staged_files(folder: str | os.PathLike):
    """Write a set of files all or none: ``stage(name)`` gives the temporary path ``.staged.NAME`` to
    write ``folder/NAME`` to; when the block ends without error they are renamed in the order staged
    (stage the file that marks a finished result last), when it fails they are removed, so a full
    disk never leaves new results beside old ones."""
    folder = Path(folder)
    staged: list[str] = []

    def stage(name: str) -> Path:
        staged.append(name)
        return folder / f".staged.{name}"

    try:
        yield stage
    except BaseException as exc:
        for name in staged:
            (folder / f".staged.{name}").unlink(missing_ok=True)
        if isinstance(exc, OSError) and (exc.filename or staged):
            # a write that fails at close names no file: it is the one staged last
            name = Path(exc.filename).name.removeprefix(".staged.") if exc.filename else staged[-1]
            raise OSError(exc.errno, exc.strerror, str(folder / name)) from None
        raise
    for name in staged:
        failpoint()
        os.replace(folder / f".staged.{name}", folder / name)


def json_text(data: dict) -> str:
    """``data`` as indented JSON (numpy arrays and scalars as lists and numbers, dataclasses as tables)."""
    return json.dumps(data, indent=2, default=_default) + "\n"


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json_atomic(path: str | os.PathLike, data: dict) -> None:
    write_text_atomic(path, json_text(data))


def lock_owner(folder: str | os.PathLike) -> tuple[int, str] | None:
    """(pid, host) of the process holding ``folder`` (its lock file), None where none holds it."""
    try:
        words = (Path(folder) / LOCK_FILE).read_text().split()
        return int(words[0]), words[1] if len(words) > 1 else socket.gethostname()
    except (OSError, ValueError, IndexError):
        return None


def process_alive(pid: int, host: str) -> bool | None:
    """Whether process ``pid`` of ``host`` lives: None where ``host`` is another machine (not checkable here)."""
    return _alive(pid) if host == socket.gethostname() else None


def _alive(pid: int) -> bool:
    """Whether process ``pid`` of this machine lives (a zombie, killed and not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def usable_folder(folder: str | os.PathLike, field: str = "--out") -> Path:
    """``folder`` as a Path where it can be one (InputError, one line, where it is empty or an existing file)."""
    if not str(folder).strip():
        raise InputError(f"{field} = {str(folder)!r}: give a folder name (an empty one would be the current folder)")
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{field} = {str(folder)!r}: exists and is not a folder; choose a folder")
    return folder


@contextmanager
def folder_lock(folder: str | os.PathLike, field: str = "--out"):
    """Hold ``folder`` for this process: ``.opalflow.lock`` holds the owner's pid and host.

    Every verb that writes into a run folder takes it (run, resume, build, check, analyze, regress, a study's
    jobs); ``status`` only reads.  A folder held by a live process, or by a process on another host (not
    checkable from here), is refused in one line naming the owner (InputError, ``field``: the option that named
    the folder); the lock of a process of this host that died (killed, machine restarted) is taken over.  A
    folder this call created is removed again if nothing else was written into it (a run refused on its input).
    """
    folder = usable_folder(folder, field)
    created = not folder.exists()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{field} = {str(folder)!r}: cannot be made ({exc.strerror}); choose a folder you can "
                         "write to") from None
    lock = folder / LOCK_FILE
    mine = folder / f"{LOCK_FILE}.{socket.gethostname()}.{os.getpid()}"
    try:
        # the lock appears with its owner written (a hard link of a finished file): never empty to a reader
        mine.write_text(f"{os.getpid()} {socket.gethostname()}\n")
        while True:
            try:
                os.link(mine, lock)
                break
            except FileExistsError:
                owner = lock_owner(folder)
                if owner is not None and owner[0] and process_alive(*owner) is not False:
                    pid, host = owner
                    raise InputError(f"{field} = {str(folder)!r}: in use by a running opalflow (pid {pid} on {host}, "
                                     f"{lock}); wait for it or choose another folder"
                                     + ("" if host == socket.gethostname() else
                                        f" (if that process is gone, remove {lock})")) from None
                lock.unlink(missing_ok=True)                    # stale: its owner is gone
    except OSError as exc:
        raise InputError(f"{field} = {str(folder)!r}: cannot be written ({exc.strerror}); choose a folder you "
                         "can write to") from None
    finally:
        mine.unlink(missing_ok=True)
    if (folder / RECORD).exists():          # a run folder (never a user's own folder given as --out)
        for left in (*folder.glob(".staged.*"), *folder.glob("*.tmp"), *folder.glob("*.tmp.*")):
            left.unlink(missing_ok=True)        # a killed writer's temporary files: the lock says it is gone
    try:
        yield folder
    finally:
        lock.unlink(missing_ok=True)
        if created and not any(folder.iterdir()):
            folder.rmdir()


def new_figure(*args, figsize=None, layout=None, **kwargs):
    """A matplotlib figure and its axes (``Figure.subplots(*args, **kwargs)``) made without pyplot: nothing
    shown, no backend chosen, so a Jupyter user's own figures keep theirs (matplotlib, "Embedding in a web
    application server": ``Figure`` is saved by its own canvas)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout=layout)
    return fig, fig.subplots(*args, **kwargs)


def save_figure(fig, path: str | os.PathLike, tight: bool = True) -> None:
    """Write a figure of :func:`new_figure` under a temporary name, then rename it.  ``tight``: lay it out
    with tight_layout first (figures with colour bars spanning several axes lay themselves out)."""
    path = Path(path)
    if tight:
        fig.tight_layout()
    with atomic_path(path, path.stem + ".tmp.png") as tmp:
        fig.savefig(tmp, dpi=120)


def put(h5, path: str, data, units: str, columns: list[str] | None = None, **attrs):
    """Dataset ``path`` of an open HDF5 file with its ``units`` ("1": a count or a ratio) and, for a table,
    the name of each column (``columns``); every dataset of results.h5 is written through here."""
    d = h5.create_dataset(path, data=data)
    d.attrs["units"] = units
    if columns is not None:
        d.attrs["columns"] = list(columns)
    for k, v in attrs.items():
        d.attrs[k] = v
    return d


def h5_bytes(fill, **attrs) -> bytes:
    """An HDF5 file made in memory by ``fill(h5)`` (file attributes ``attrs``), as bytes.

    Written by Python afterwards, a full disk is a plain OSError before the rename (HDF5 writing to a
    full disk itself reports it only at close, or not at all)."""
    import io

    import h5py

    from opalflow.version import __version__

    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as h:
        h.attrs["opalflow_version"] = __version__
        for k, v in attrs.items():
            h.attrs[k] = v
        fill(h)
    return buffer.getvalue()
