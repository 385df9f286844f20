"""The spec core: TOML -> typed dataclasses, ``--set`` overrides, the checks every track uses.

It knows no track.  A track declares its workflow spec as a dataclass subclass of
:class:`WorkflowSpec` (one field per TOML section or top-level key, each section a
dataclass) with a ``validate`` method; :mod:`opalflow.registry` picks the class by the
workflow's ``kind`` and calls :func:`convert` and ``validate``.

Every error is a :class:`SpecError` whose message is one line naming the field, the
value and what is allowed, raised before anything is written.  Names that reach a
LAMMPS script must match ``[A-Za-z0-9_]+`` and numbers must be numbers, so a
workflow file cannot smuggle LAMMPS commands (LAMMPS has ``shell``) into a deck.
"""
from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_type_hints

NAME_RE = re.compile(r"[A-Za-z0-9_]+")
#: the longest name opalflow takes (workflow, material, partition ...): it goes into file headers and folder names
NAME_MAX = 64
#: the longest description (one line, shown in reports)
DESCRIPTION_MAX = 500
#: the longest value a refusal echoes
SHOWN_MAX = 120


class InputError(ValueError):
    """Bad input, found before anything is written: the CLI prints the one-line message, exit 2."""


class SpecError(InputError):
    """A spec field holds a value that is not allowed (one-line message)."""

    def __init__(self, field_name: str, value: Any, allowed: str):
        self.field = field_name
        self.value = value
        self.allowed = allowed
        shown = repr(value)
        if len(shown) > SHOWN_MAX:          # (one line a terminal can show: a 1 MB name is not echoed)
            shown = f"{shown[:SHOWN_MAX - 20]}... ({len(shown)} characters)"
        super().__init__(f"{field_name} = {shown}: {allowed}")


@dataclass
class WorkflowSpec:
    """What every workflow file has: its name, a one-line description and its kind."""

    name: str = "opal"               # the run's name ([A-Za-z0-9_]+; a file's stem where not given)
    description: str = ""            # one line, shown by `list` and in the report
    kind: str = "opal"               # what is built and run: a kind of opalflow/registry.py (`python -m opalflow list`)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def validate(self) -> None:
        """Check every field; raise SpecError naming the first bad one (tracks extend this)."""
        check_name("name", self.name)
        check(len(self.description) <= DESCRIPTION_MAX and "\n" not in self.description, "description",
              self.description, f"one line of at most {DESCRIPTION_MAX} characters")


# ----------------------------------------------------------------------------- loading
def read_toml(path: str | Path) -> dict:
    """The raw table of a workflow file (without a ``name``: the file's stem, where that is a name)."""
    path = Path(path)
    if path.is_dir():
        raise SpecError("workflow", str(path), "is a folder, not a workflow file (.toml)")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SpecError("workflow", str(path), "file not found") from None
    except OSError as exc:
        raise SpecError("workflow", str(path), f"cannot be read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise SpecError("workflow", str(path), "is not a text file (a workflow is TOML in UTF-8)") from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError("workflow", str(path), f"not valid TOML ({exc})") from None
    if "name" not in raw and NAME_RE.fullmatch(path.stem) and len(path.stem) <= NAME_MAX:
        raw["name"] = path.stem
    return raw


def parse_value(text: str) -> Any:
    """A ``--set`` value: TOML syntax (numbers, booleans, quoted strings, arrays), else a bare string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_overrides(raw: dict, overrides: list[str]) -> None:
    """Apply ``section.key=value`` overrides to the raw TOML dict, in place (before validation)."""
    for item in overrides:
        if "=" not in item:
            raise SpecError("--set", item, "expected section.key=value")
        path, text = item.split("=", 1)
        set_value(raw, path.strip(), parse_value(text.strip()), item)


def set_value(raw: dict, path: str, value: Any, item: Any = None) -> None:
    """Set ``section.key`` of the raw TOML dict to ``value``, in place (a Python value: the API's ``set={...}``)."""
    keys = path.split(".")
    if not all(NAME_RE.fullmatch(k) for k in keys):
        raise SpecError("--set", item if item is not None else path, "keys must match [A-Za-z0-9_]+ separated by dots")
    node = raw
    for k in keys[:-1]:
        node = node.setdefault(k, {})
        if not isinstance(node, dict):
            raise SpecError(path, item if item is not None else value, f"'{k}' is not a section")
    node[keys[-1]] = value


def convert(cls, raw: dict, prefix: str = ""):
    """The dataclass ``cls`` from a raw table: unknown keys refused, every value type-checked."""
    hints = get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    for key in raw:
        if key not in names:
            where = f"{prefix}{key}"
            raise SpecError(where, raw[key], f"unknown key; allowed in "
                            f"{prefix.rstrip('.') or 'the top level'}: {', '.join(names)}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in raw:
            continue
        value, hint, where = raw[f.name], hints[f.name], f"{prefix}{f.name}"
        if dataclasses.is_dataclass(hint):
            if not isinstance(value, dict):
                raise SpecError(where, value, "must be a table (section)")
            kwargs[f.name] = convert(hint, value, f"{where}.")
        else:
            kwargs[f.name] = _coerce(value, hint, where)
    return cls(**kwargs)


def _coerce(value, hint, where):
    """Check a TOML value against a field's type (``X | None`` allows a missing value)."""
    if typing.get_origin(hint) is list:
        if not isinstance(value, list):
            raise SpecError(where, value, "must be a list")
        item = typing.get_args(hint)[0]
        return [_coerce(v, item, f"{where}[{k}]") for k, v in enumerate(value)]
    args = typing.get_args(hint)
    if args:
        if value is None:
            return None
        hint = next(a for a in args if a is not type(None))
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SpecError(where, value, "must be a finite number")
        return float(value)
    if hint is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise SpecError(where, value, "must be an integer")
    if hint is str and not isinstance(value, str):
        raise SpecError(where, value, "must be a string")
    if hint is dict and not isinstance(value, dict):
        raise SpecError(where, value, "must be a table")
    if hint is bool and not isinstance(value, bool):
        raise SpecError(where, value, "must be true or false")
    return value


# ----------------------------------------------------------------------------- checks
def check(cond: bool, where: str, value, allowed: str) -> None:
    """Raise SpecError(where, value, allowed) unless ``cond``."""
    if not cond:
        raise SpecError(where, value, allowed)


def check_name(where: str, value: str) -> None:
    check(bool(NAME_RE.fullmatch(value)), where, value,
          "names may only contain letters, digits and '_' ([A-Za-z0-9_]+)")
    check(len(value) <= NAME_MAX, where, value, f"names may be at most {NAME_MAX} characters long")


def is_number(value) -> bool:
    """A finite int or float that is not a bool (raw TOML values of free-form tables)."""
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
