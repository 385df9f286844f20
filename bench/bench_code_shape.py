"""The shape of opalflow's code, counted with ``ast`` (issue 54's acceptance 1): how much data is read
back as dicts and how long the functions are.

    python bench/bench_code_shape.py [--out bench/results/code_shape.json] [--top 12]

Counts, over every module of the package:
- ``string_subscripts``: ``x["key"]`` (an ``ast.Subscript`` whose index is a str constant), read or
  written: a dict, an HDF5 file or a TOML table indexed by name;
- ``dict_functions``: functions annotated ``-> dict...`` or with a ``return`` of a dict display,
  dict comprehension or ``dict(...)`` call; of them ``mapping_functions``: those annotated ``dict[K, V]``
  (a mapping keyed by data: label -> result, material -> stress) or returning only comprehensions, the rest
  record-shaped (a bare ``dict`` or a display with string keys: a record that could be a class);
- ``file_literals``: the modules that spell ``results.h5``, ``summary.json``, ``run.json`` in code (docstrings,
  which name the files to the reader, are not counted);
- ``long_functions``: functions (methods included) over 80 lines;
- ``string_imports``: ``resolve("opalflow...")`` / ``import_module("opalflow...")`` with a constant.
"""
from __future__ import annotations

import argparse
import ast
import json
from collections import Counter
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "opalflow"
FILES = ("results.h5", "summary.json", "run.json")
LONG = 80


def _own_returns(fn: ast.AST):
    """The return statements of ``fn`` itself (not of the functions and lambdas defined inside it)."""
    todo = list(ast.iter_child_nodes(fn))
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        if isinstance(node, ast.Return):
            yield node
        todo.extend(ast.iter_child_nodes(node))


def _returns_dict(fn: ast.AST) -> bool:
    ann = getattr(fn, "returns", None)
    if ann is not None and ast.unparse(ann).split("[")[0].strip() in ("dict", "Dict"):
        return True
    for node in _own_returns(fn):
        if node.value is not None:
            v = node.value
            if isinstance(v, (ast.Dict, ast.DictComp)):
                return True
            if isinstance(v, ast.Call) and isinstance(v.func, ast.Name) and v.func.id == "dict":
                return True
    return False


def _mapping(fn: ast.AST) -> bool:
    """A dict-returning function whose dict is a mapping keyed by data, not a record."""
    ann = getattr(fn, "returns", None)
    if ann is not None and isinstance(ann, ast.Subscript) and ast.unparse(ann.value) in ("dict", "Dict"):
        return True
    values = [n.value for n in _own_returns(fn) if n.value is not None]
    return bool(values) and all(isinstance(v, ast.DictComp) for v in values)


def _string_import(node: ast.Call) -> bool:
    name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
    return (name in ("resolve", "import_module") and node.args and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str) and node.args[0].value.startswith("opalflow"))


def shape(package: Path = PACKAGE) -> dict:
    subs, dict_fns, mapping_fns, long_fns, string_imports = Counter(), [], [], [], []
    literals = {f: set() for f in FILES}
    for path in sorted(package.rglob("*.py")):
        rel = str(path.relative_to(package.parent))
        tree = ast.parse(path.read_text())
        docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                      if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                      and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant) \
                    and isinstance(node.slice.value, str):
                subs[rel] += 1
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if _returns_dict(node):
                    dict_fns.append(f"{rel}:{node.name}")
                    if _mapping(node):
                        mapping_fns.append(f"{rel}:{node.name}")
                length = node.end_lineno - node.lineno + 1
                if length > LONG:
                    long_fns.append(f"{rel}:{node.name} ({length} lines)")
            elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
                for f in FILES:
                    if f in node.value:
                        literals[f].add(rel)
            elif isinstance(node, ast.Call) and _string_import(node):
                string_imports.append(f"{rel}:{node.lineno} {node.args[0].value}")
    return {"string_subscripts": sum(subs.values()),
            "string_subscripts_by_module": dict(subs.most_common()),
            "dict_functions": len(dict_fns), "dict_function_names": dict_fns,
            "mapping_functions": len(mapping_fns), "mapping_function_names": mapping_fns,
            "file_literals": {f: sorted(m) for f, m in literals.items()},
            "long_functions": long_fns,
            "string_imports": string_imports}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, help="write the counts as JSON here")
    p.add_argument("--top", type=int, default=12, help="modules listed by string subscripts")
    a = p.parse_args(argv)
    s = shape()
    print(f"string subscripts: {s['string_subscripts']}")
    for mod, n in list(s["string_subscripts_by_module"].items())[:a.top]:
        print(f"  {n:5d} {mod}")
    print(f"functions returning dict: {s['dict_functions']} ({s['mapping_functions']} of them mappings keyed by data, "
          f"{s['dict_functions'] - s['mapping_functions']} record-shaped)")
    for f, mods in s["file_literals"].items():
        print(f"{f!r} spelled in {len(mods)} modules: {', '.join(mods)}")
    print(f"functions over {LONG} lines: {len(s['long_functions'])}: {', '.join(s['long_functions'])}")
    print(f"imports by string: {len(s['string_imports'])}")
    for line in s["string_imports"]:
        print(f"  {line}")
    if a.out:
        a.out.write_text(json.dumps(s, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
