"""Spec fuzzing: every field of every workflow kind mutated, seeded.

Each case is refused with one line that names a field (exit 2, nothing written), or it is valid;
never another exception, and no string from a spec reaches a LAMMPS deck unless it is a name
([A-Za-z0-9_]+).
"""
import dataclasses
import json
import math
import random
import re
import zlib
from collections import Counter
from pathlib import Path

import pytest

from opalflow import registry
from opalflow.bpm.pipeline import build_structure
from opalflow.bpm.deck import compression_deck
from opalflow.cli import main
from opalflow.resources import WORKFLOWS
from opalflow.spec import InputError, read_toml
from opalflow.store import SUMMARY, write_json_atomic

#: the base workflow of each kind
BASES = {"opal": "opal_quick", "lattice": "lattice_sc", "datafile": "lattice_sc",
         "tersoff_properties": "tersoff_properties", "tersoff_fit": "tersoff_fit",
         "tersoff_stability": "tersoff_stability", "study": "calibrate_silica",
         "stability_matrix": "stability_matrix", "aerogel": "aerogel_compression", "aggregation": "aerogel_dlca",
         "polycrystal_tension": "polycrystal_tension", "polycrystal_waves": "polycrystal_waves"}
METACHARACTERS = ["a$b", "${x}", "a&b", "a#b", "a;b", "{x}", 'a"b', "a'b", "a\nshell rm -rf /",
                  "silica; shell ls", "x\tpair_style zero", ""]
VALUES = [None, "x", "random", 0, 1, -1, 2, 7, 2**62, -(2**62), 0.0, 0.5, -0.5, 1e-300, 1e308, -1e308,
          math.nan, math.inf, -math.inf, True, False, [], [0.01], [1, 2], ["a"], [[1]], {}, {"a": 1}]
NAME = re.compile(r"[A-Za-z0-9_]+")


def fields(cls, prefix=()):
    """Dotted paths of every leaf field of a spec class."""
    out = []
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if dataclasses.is_dataclass(default):
            out += fields(type(default), prefix + (f.name,))
        else:
            out.append(prefix + (f.name,))
    return out


def base_raw(kind: str, datafile: str) -> dict:
    raw = read_toml(WORKFLOWS / f"{BASES[kind]}.toml")
    raw["kind"] = kind
    if kind == "datafile":
        raw["datafile"] = {"path": datafile, "materials": ["silica", "substrate"]}
    return raw


def put(raw: dict, path: tuple, value) -> dict:
    node = raw
    for key in path[:-1]:
        nxt = node.get(key)
        if not isinstance(nxt, dict):
            nxt = node[key] = {}
        node = nxt
    if value is None:
        node.pop(path[-1], None)
    else:
        node[path[-1]] = value
    return raw


def mutations(rng: random.Random, kind: str, n: int, datafile: str):
    """n mutated raw specs of ``kind``: (the paths changed, the raw table)."""
    paths = fields(registry.get(kind).spec_class())
    for _ in range(n):
        raw = base_raw(kind, datafile)
        what = rng.random()
        if what < 0.08 and ("materials",) in paths:        # a material property out of range or of a wrong type
            key = rng.choice(["density_kg_m3", "bond_youngs_modulus_GPa", "bond_poisson_ratio", "bond_strength_MPa"])
            raw.setdefault("materials", {})["silica"] = {key: rng.choice(VALUES[1:] + METACHARACTERS)}
            yield [("materials", "silica", key)], raw
        elif what < 0.16:                                 # unknown key in a section or at the top
            path = rng.choice(paths)[:-1] + ("colour",)
            yield [path], put(raw, path, 1)
        elif what < 0.2:                                  # a section that is no section, or an unknown one
            key = rng.choice(["nonsense", paths[-1][0]])
            raw[key] = rng.choice([1, "x", [1]])
            yield [(key,)], raw
        else:                                             # one to three fields get odd values
            changed = rng.sample(paths, rng.choice([1, 1, 1, 2, 3]))
            for path in changed:
                raw = put(raw, path, rng.choice(VALUES + METACHARACTERS) if rng.random() < 0.8
                          else rng.choice(METACHARACTERS))
            yield changed, raw


def field_exists(spec_cls, where: str) -> bool:
    """Does a refusal's field ('packing.seed', 'study.cells[1]', 'materials.silica.x', 'kind') name a
    field of the spec (a check across fields names the one it holds against the other)?"""
    name = re.sub(r"\[\d+\]", "", where).split(".")
    top = {f.name for f in dataclasses.fields(spec_cls)}
    return name[0] in top or where in ("kind", "workflow")


@pytest.fixture(scope="module")
def datafile(tmp_path_factory):
    from opalflow.lammps.datafile import write_data

    path = tmp_path_factory.mktemp("fuzz") / "lattice.lmp"
    write_data(path, build_structure(registry.load_spec(WORKFLOWS / "lattice_sc.toml")))
    return str(path)


def test_fuzzed_specs_are_refused_in_one_line_or_valid(datafile):
    rng = random.Random(20261123)
    outcomes, examples = Counter(), []
    for kind in BASES:
        cls = registry.get(kind).spec_class()
        base = read_toml(WORKFLOWS / f"{BASES[kind]}.toml")      # (the file, before its kind is switched)
        for changed, raw in mutations(rng, kind, 500, datafile):
            try:
                spec = registry.spec_from_dict(json.loads(json.dumps(raw, allow_nan=True)), base)
            except InputError as exc:
                msg = str(exc)
                assert "\n" not in msg, (kind, changed, msg)
                where = msg.split(" = ", 1)[0]
                mutated = re.sub(r"\[\d+\]", "", where) in {".".join(path) for path in changed}
                # (a mutated kind that does not read a section of the file: the refusal names the section)
                mutated = mutated or (("kind",) in changed and "does not read it" in msg)
                assert mutated or field_exists(cls, where), (kind, changed, msg)
                outcomes["refused, names a mutated field" if mutated else "refused, names another field"] += 1
                if not mutated and len(examples) < 6:
                    examples.append((changed, msg[:160]))
                continue
            outcomes["valid"] += 1
            if kind in ("lattice", "datafile"):
                outcomes["valid, deck built" if check_deck(spec, raw) else "valid, deck refused in one line"] += 1
    print(dict(outcomes), *examples, sep="\n")
    assert sum(v for k, v in outcomes.items() if k.startswith("refused")) > 1000
    assert outcomes["valid, deck built"] > 30


def strings(value):
    if isinstance(value, str):
        yield value
    elif isinstance(value, dict):
        for v in value.values():
            yield from strings(v)
    elif isinstance(value, list):
        for v in value:
            yield from strings(v)


def check_deck(spec, raw) -> bool:
    """A valid lattice or data-file spec builds a deck (or is refused in one line), and no string of the
    spec that is not a name is in it."""
    try:
        deck = compression_deck(spec, build_structure(spec))
    except InputError as exc:
        assert "\n" not in str(exc)
        return False
    text = deck.in_lmp + deck.resume_lmp
    for s in strings(raw):
        if s and not NAME.fullmatch(s):
            assert s not in text, (s, raw)
    return True


def toml_literal(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value == math.inf else "-inf" if value == -math.inf
                                                else repr(value))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_literal(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {toml_literal(v)}" for k, v in value.items()) + "}"
    return str(value)


@pytest.mark.parametrize("kind", ["opal", "lattice", "tersoff_properties", "study"])
def test_fuzzed_set_through_the_cli(kind, tmp_path, capsys):
    """Through 'python -m opalflow build' with --set: refused -> exit 2, one line, nothing written."""
    rng = random.Random(zlib.crc32(kind.encode()))
    cls = registry.get(kind).spec_class()
    paths = fields(cls)
    refused = 0
    for n in range(25):
        path = rng.choice(paths)
        value = rng.choice([v for v in VALUES + METACHARACTERS if v is not None])
        out = tmp_path / f"case{n}"
        code = main(["build", BASES[kind], "--out", str(out), "--set", f"kind={kind}",
                     "--set", f"{'.'.join(path)}={toml_literal(value)}"])
        err = capsys.readouterr().err.strip().splitlines()
        if code == 2:
            refused += 1
            assert [line for line in err if line.startswith("error:")] == err[-1:], (path, value, err)
            assert not out.exists(), (path, value)
        else:
            assert code == 0 and kind in ("opal", "lattice") and (out / "in.lmp").exists(), (path, value, code)
    assert refused >= 10


def _toml_value(v) -> str:
    """A --set value as TOML writes it (a few odd forms a shell user types, too)."""
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if v is None:
        return ""
    return json.dumps(v)


def test_the_command_line_refuses_in_one_line_or_accepts_and_writes_nothing_on_refusal(tmp_path, monkeypatch,
                                                                                        capsys):
    """``run WORKFLOW --set ...`` with random sections, keys, values and kinds (every workflow file, every field
    of every kind, unknown ones, malformed items): exit 0 (the spec is valid: the run itself is stubbed out, it
    is not what this checks) or one line ``error: ...`` with exit 2 and no folder; never a traceback."""
    import opalflow.runs.record as record
    from opalflow.runs.result import Result

    accepted = []
    def stub(kind, spec, out, **kw):          # the run: its spec kept, a summary written and returned as finish()
        accepted.append(spec)
        Path(out).mkdir(parents=True, exist_ok=True)
        summary = {"headline": "stub", "wall_s": 0.0, "state": "finished"}
        write_json_atomic(Path(out) / SUMMARY, summary)
        return Result.from_summary(summary)

    monkeypatch.setattr(record, "run_kind", stub)
    rng = random.Random(20261203)
    workflows = sorted(p.stem for p in WORKFLOWS.glob("*.toml"))
    paths = sorted({".".join(p) for kind in registry.kinds().values() for p in fields(kind.spec_class())})
    kinds = sorted(registry.kinds())
    outcomes = Counter()
    for case in range(400):
        sets = []
        for _ in range(rng.choice([1, 1, 2, 3])):
            what = rng.random()
            if what < 0.55:
                sets.append(f"{rng.choice(paths)}={_toml_value(rng.choice(VALUES + METACHARACTERS))}")
            elif what < 0.65:
                sets.append(f"kind={json.dumps(rng.choice(kinds + ['nope', 'opal;shell ls']))}")
            elif what < 0.8:
                section = rng.choice([p.split('.')[0] for p in paths] + ["nonsense"])
                sets.append(f"{section}.{rng.choice(['colour', 'x', 'seed'])}={_toml_value(rng.choice(VALUES))}")
            else:
                sets.append(rng.choice(["no_equals", "a..b=1", "=1", "packing.=1", ".x=1", "packing.seed",
                                        "packing seed=1", "packing.seed==1", "packing.seed=[1,", "x=\"unclosed"]))
        out = tmp_path / f"case{case}"
        argv = ["run", rng.choice(workflows), "--out", str(out)] + [a for s in sets for a in ("--set", s)]
        before = len(accepted)
        code = main(argv)
        err = capsys.readouterr().err.strip()
        assert code in (0, 2), (argv, code, err[-500:])
        if code == 2:
            assert len(err.splitlines()) == 1 and err.startswith("error: ") and len(err) < 1000, (argv, err[:500])
            assert not out.exists(), argv
            outcomes["refused"] += 1
        else:
            assert len(accepted) == before + 1, argv
            outcomes["accepted"] += 1
    assert outcomes["refused"] > 200 and outcomes["accepted"] >= 5, outcomes       # (seeded: 387 and 13)
