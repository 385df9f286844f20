"""A run's result as a class: every summary.json key is a field, and the field says which cases give it.

A track whose runs come in several cases (the bonded-particle methods: :class:`opalflow.bpm.result.
CompressionResult`; the Tersoff workflows: :class:`opalflow.tersoff.result.TersoffResult`) subclasses
:class:`Result` and names the case of each run (:attr:`Result.case`); :func:`key` declares a field with the
cases that give it, the label and format of its report row, and whether it is left out where a run has none.
Adding a key that every case gives is one field and the line that computes it.

Reading a folder's summary.json is here too (:func:`read_summary`, :func:`finished_summary`); writing it is
:func:`opalflow.runs.record.finish`'s, which returns what it wrote as the run's result class.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import os
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from opalflow.store import SUMMARY


def read_summary(folder: str | os.PathLike) -> dict | None:
    """The summary.json of ``folder`` (None where there is none or it is cut short)."""
    try:
        data = json.loads((Path(folder) / SUMMARY).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def finished_summary(folder: str | os.PathLike) -> dict | None:
    """The summary of a finished run in ``folder`` (not ``build``'s), else None."""
    s = read_summary(folder)
    return s if s is not None and s.get("state", "finished") != "built" else None


def is_finished(folder: str | os.PathLike) -> bool:
    return finished_summary(folder) is not None


@functools.cache
def _hints(cls: type) -> dict[str, type]:
    return typing.get_type_hints(cls)


def typed(hint, value):
    """``value`` as JSON gives it (tables, lists) read as the type ``hint`` says: a dataclass from its table (its
    fields typed the same way, down to the leaves), ``list[X]``, ``dict[str, X]`` and ``X | None`` of them;
    anything else as it is."""
    if value is None:
        return None
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return typed(inner[0], value) if len(inner) == 1 else value
    if dataclasses.is_dataclass(hint) and isinstance(value, dict):
        hints = _hints(hint)
        return hint(**{k: typed(hints[k], v) for k, v in value.items()})
    if origin is list and args and isinstance(value, list):
        return [typed(args[0], v) for v in value]
    if origin is dict and len(args) == 2 and isinstance(value, dict):
        return {k: typed(args[1], v) for k, v in value.items()}
    return value


def optional(default=None):
    """A field left out of its table (summary.json) where it is None (a number the run has no case for)."""
    return field(default=default, metadata={"optional": True})


def table_of(value):
    """A dataclass as summary.json holds it: nested dataclasses as tables, optional fields (:func:`optional`,
    ``key(optional=True)``) left out where None; lists and tables of them alike."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: table_of(getattr(value, f.name)) for f in dataclasses.fields(value)
                if not (f.metadata.get("optional") and getattr(value, f.name) is None)}
    if isinstance(value, dict):
        return {k: table_of(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [table_of(v) for v in value]
    return value


def key(*cases: str, label: str = "", fmt: str = "{:.4g}", optional: bool = False, default=None,
        default_factory=dataclasses.MISSING):
    """A result key: the cases that give it, its report row (``label``, ``fmt``; none without a label),
    ``optional``: left out where the run has none (None); its default (``default_factory`` for a list or table)."""
    meta = {"cases": cases, "label": label, "fmt": fmt, "optional": optional}
    if default_factory is not dataclasses.MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(eq=False)
class Result(Mapping):
    """A run's result; subclasses declare the keys (:func:`key`) and say the run's :attr:`case`.

    Read back from a run folder as the same object (:meth:`read`, :meth:`from_summary`: the pattern of atomate2's
    task documents).  ``extra``: summary.json's keys that no field declares (the run's ``state``; a kind without
    a result class of its own reads back as this class with every key here).

    The typed fields are the way to read it (``result.youngs_modulus_GPa``, ``result.quasistatic.events``); it is
    also a read-only mapping of summary.json's table (``result["youngs_modulus_GPa"]``, ``dict(result)``: nested
    parts as tables, as the file holds them), so code written against the file reads it unchanged.  Two results
    are equal when their tables are.
    """

    extra: dict = field(default_factory=dict)

    @classmethod
    def from_summary(cls, summary: dict) -> Result:
        """The result a summary.json holds: each key a field of this class (typed as the field says:
        :func:`typed`), the others :meth:`rest`."""
        names = {f.name for f in dataclasses.fields(cls) if f.init and f.name != "extra"}
        hints = _hints(cls)
        out = cls(**{k: typed(hints[k], v) for k, v in summary.items() if k in names})
        out.rest({k: v for k, v in summary.items() if k not in names})
        return out

    @classmethod
    def read(cls, folder) -> Result | None:
        """The result of the finished run in ``folder`` (None where it has not finished or its summary.json is
        cut short)."""
        summary = finished_summary(folder)
        return None if summary is None else cls.from_summary(summary)

    def rest(self, keys: dict) -> None:
        """Keep summary.json's keys that no field declares (in ``extra``; a subclass may keep them elsewhere)."""
        self.extra.update(keys)

    @property
    def case(self) -> str:
        """The run's case (a subclass names it; the generic class has none: its keys are all in ``extra``)."""
        return ""

    def case_keys(self) -> list[str]:
        """The declared keys this run's case gives, in the order declared."""
        return [f.name for f in dataclasses.fields(self) if self.case in f.metadata.get("cases", ())
                and not (f.metadata["optional"] and getattr(self, f.name) is None)]

    def summary(self) -> dict:
        """summary.json (before :func:`opalflow.runs.record.finish` adds the state); the values are this object's
        own (a dict filled later, such as a timings dict, is filled in both)."""
        own = {k: getattr(self, k) for k in self.case_keys()}
        return {**own, **{k: v for k, v in self.extra.items() if k not in own}}

    # summary.json's table, read only (the Mapping protocol: [], get, in, keys, items, len, dict(result))
    def __getitem__(self, name: str):
        return table_of(self.summary()[name])

    def __iter__(self):
        return iter(self.summary())

    def __len__(self) -> int:
        return len(self.summary())

    def __eq__(self, other) -> bool:
        return isinstance(other, Mapping) and dict(self.items()) == dict(other.items())

    __hash__ = None
