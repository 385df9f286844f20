"""Progress of a long loop: step, rate and time left, said every few seconds and kept in the run folder's
``progress.json`` for ``python -m opalflow status`` (:mod:`opalflow.runs.status`).

The one writer of ``progress.json``: a counted loop (a LAMMPS run's steps, a polycrystal's macro steps, an MD
check) through :class:`Progress`, a job's last message through :func:`note`; both write a :class:`ProgressNote`,
and status reads one back (:meth:`ProgressNote.read`).
"""
from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from opalflow.spec import is_number
from opalflow.store import read_json, write_json_atomic

PROGRESS_FILE = "progress.json"


def _number(x) -> float | None:
    """``x`` as a float where it is a number (:func:`opalflow.spec.is_number`), else None."""
    return float(x) if is_number(x) else None


@dataclass
class ProgressNote:
    """What progress.json holds: a counted loop's step of ``total`` (in ``unit``s), its rate (per second), the
    seconds left and the strain reached, or a job's last ``message``; and when (``time``, epoch seconds)."""

    time: float | None = None
    message: str | None = None
    step: float | None = None
    total: float | None = None
    rate_steps_s: float | None = None
    left_s: float | None = None
    strain: float | None = None
    unit: str = "step"

    def write(self, folder: Path) -> None:
        write_json_atomic(Path(folder) / PROGRESS_FILE,
                          {k: v for k, v in dataclasses.asdict(self).items() if v is not None})

    @classmethod
    def read(cls, folder: Path) -> ProgressNote:
        """The note in ``folder`` with the values of the wrong type left out (status judges what is left);
        :class:`opalflow.store.DamagedFile` where the file cannot be read as a table."""
        raw = read_json(Path(folder) / PROGRESS_FILE, "the run's progress", "")
        message, unit = raw.get("message"), raw.get("unit")
        return cls(time=_number(raw.get("time")), message=message if isinstance(message, str) else None,
                   step=_number(raw.get("step")), total=_number(raw.get("total")),
                   rate_steps_s=_number(raw.get("rate_steps_s")), left_s=_number(raw.get("left_s")),
                   strain=_number(raw.get("strain")), unit=unit if isinstance(unit, str) else "step")


class Progress:
    """Says ``{label}{unit} step/total (%)[, strain e], rate, time left[ extra]`` at most every ``interval`` seconds
    (and at the last step) through ``say`` (default: stderr); with a ``folder``, the same numbers in
    ``folder/progress.json``.  ``start``: the step the loop starts from (a resumed run), not counted in the
    rate."""

    def __init__(self, total: int, start: int = 0, label: str = "", *, interval: float = 5.0, say=None,
                 folder: Path | None = None, unit: str = "step"):
        self.total, self.start, self.label, self.interval, self.unit = max(total, 1), start, label, interval, unit
        self.t0 = self.last = time.perf_counter()
        self.say = say or (lambda line: print(line, file=sys.stderr, flush=True))
        self.folder = folder

    def update(self, step: int, strain: float | None = None, force: bool = False, extra: str = "") -> None:
        now = time.perf_counter()
        if not force and step < self.total and now - self.last < self.interval:
            return
        self.last = now
        rate = max(step - self.start, 0) / max(now - self.t0, 1e-9)
        left = (self.total - step) / rate if rate > 0 else float("inf")
        strain_txt = f", strain {strain:.4f}" if strain is not None else ""
        rate_txt = f"{rate:.0f}" if rate >= 10 else f"{rate:.2g}"
        self.say(f"{self.label}{self.unit} {step}/{self.total} ({100 * step / self.total:.0f} %){strain_txt}, "
                 f"{rate_txt} {self.unit}s/s, {left:.0f} s left{extra}")
        if self.folder is not None:
            ProgressNote(time.time(), step=step, total=self.total, rate_steps_s=rate,
                         left_s=left if rate > 0 else None, strain=strain, unit=self.unit).write(self.folder)


def note(folder: Path, message: str) -> None:
    """A job's last message (it counts no steps of its own) into ``folder/progress.json``."""
    ProgressNote(time.time(), message).write(folder)
