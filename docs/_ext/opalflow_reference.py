"""Sphinx extension: the command-line and workflow reference pages, generated at every build from
``opalflow.cli.parser()`` and the spec classes of ``opalflow.registry`` (a new option or spec field appears
without editing a page).  Written to ``docs/reference/generated/`` (git-ignored) when the builder starts."""
from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import typing
from pathlib import Path

HERE = Path(__file__).resolve().parents[1] / "reference" / "generated"


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def cli_page() -> str:
    """Every verb of ``python -m opalflow``: its help, usage and options."""
    from opalflow.cli import parser

    ap = parser()
    lines = ["# Command line", "", "Generated from `opalflow/cli.py`'s parser at every build of these pages.", "",
             f"`{ap.prog} [--version] VERB ...`", ""]
    sub = next(a for a in ap._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in sub._choices_actions}
    for verb, p in sub.choices.items():
        usage = " ".join(p.format_usage().split())[len("usage: "):]
        lines += [f"## {verb}", "", helps.get(verb, ""), "", f"`{usage}`", "",
                  "| argument | default | meaning |", "|---|---|---|"]
        for action in p._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            name = ", ".join(action.option_strings) or action.dest
            if action.choices:
                name += " {" + ",".join(map(str, action.choices)) + "}"
            default = "" if action.default in (None, False, [], argparse.SUPPRESS) else f"`{action.default}`"
            lines.append(f"| `{_cell(name)}` | {default} | {_cell(action.help or '')} |")
        lines.append("")
    return "\n".join(lines)


def _comments(cls) -> dict[str, str]:
    """Each field's description in a dataclass's source: the ``#:`` lines above it (Sphinx autodoc's attribute
    comments) and the comment after it (``name: type = default  # comment``)."""
    try:
        source = inspect.getsource(cls)
    except (OSError, TypeError):
        return {}
    found, above = {}, []
    for line in source.splitlines():
        if line.strip().startswith("#:"):
            above.append(line.strip()[2:].strip())
            continue
        m = re.match(r"^\s+(\w+)\s*:[^#]*?(?:#\s*(.*))?$", line)
        if m and not line.strip().startswith(("#", '"', "def ", "return")):
            text = " ".join(above + ([m.group(2).strip()] if m.group(2) else []))
            if text:
                found[m.group(1)] = text
        above = []
    return found


def _type_name(hint) -> str:
    text = getattr(hint, "__name__", None) if typing.get_origin(hint) is None else None
    return text or str(hint).replace("typing.", "")


def _section(cls, where: str) -> list[str]:
    """One table per dataclass: field, type, default, meaning; nested sections after it."""
    hints = typing.get_type_hints(cls)
    comments = {k: v for base in reversed(cls.__mro__) if dataclasses.is_dataclass(base)
                for k, v in _comments(base).items()}            # (a field inherited: its description where declared)
    doc = (inspect.getdoc(cls) or "").split("\n\n")[0].replace("\n", " ")
    lines = [f"### `[{where}]`" if where else "### top level", "", doc, "",
             "| key | type | default | meaning |", "|---|---|---|---|"]
    nested = []
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        if dataclasses.is_dataclass(hint):
            nested.append((hint, f"{where}.{f.name}" if where else f.name))
            lines.append(f"| `{f.name}` | section | | the section `[{f.name}]` below |")
            continue
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = ""
        lines.append(f"| `{f.name}` | {_cell(_type_name(hint))} | `{_cell(repr(default))}` | "
                     f"{_cell(comments.get(f.name, ''))} |")
    lines.append("")
    for hint, name in nested:
        lines += _section(hint, name)
    return lines


def workflows_page() -> str:
    """Every workflow kind: its spec class's sections and fields."""
    from opalflow import registry

    lines = ["# Workflow files", "", "Generated from the spec classes of `opalflow/registry.py` at every build of "
             "these pages: each kind, its sections and keys (type, default, and the comment beside the field "
             "in the source). A workflow file names its `kind`; `--set SECTION.KEY=VALUE` changes one key.", ""]
    by_class: dict[str, list[str]] = {}
    for kind in registry.kinds().values():
        by_class.setdefault(kind.spec, []).append(kind.name)
    for spec_path, kinds in by_class.items():
        cls = registry.resolve(spec_path)
        lines += [f"## {', '.join(kinds)}", "", ", ".join(f"`{k}`: {registry.get(k).summary}" for k in kinds) + ".",
                  "", f"Spec class `{spec_path.replace(':', '.')}`.", ""]
        lines += _section(cls, "")
    return "\n".join(lines)


def write_pages(app=None) -> None:
    HERE.mkdir(parents=True, exist_ok=True)
    for name, text in (("cli.md", cli_page()), ("workflows.md", workflows_page())):
        path = HERE / name
        if not path.exists() or path.read_text() != text + "\n":
            path.write_text(text + "\n")


def setup(app):
    app.connect("builder-inited", write_pages)
    return {"parallel_read_safe": True, "version": "1"}
