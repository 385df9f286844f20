"""The paper's porosity study at the paper's resolution (d = 15 nm, issue 56 item 2), job by job, and at coarser
resolutions (``study.diameter_nm``, item 3): which is the coarsest that gives the paper's exponents.

    python -m opalflow run porosity_strength --out DIR --set study.paper_scale=true [--set 'study.seeds=[1]']
        [--set study.diameter_nm=30] --set executor.workers=1 --set executor.cpus_per_rank=2
                                                    # one job at a time: the densest at 15 nm need ~18 GiB
    python bench/bench_porosity_paper.py DIR [--paused LABEL=SECONDS ...]
                                                    # -> bench/results/porosity_paper_dD.json (D: the jobs' d)
    python bench/bench_porosity_paper.py --resolution   # -> bench/results/porosity_resolution.json

The study resumes job by job (a rerun keeps the finished jobs and continues a stopped one from its saved
events), so it may run over several sittings; this records what its folder holds: each finished job's porosity,
density, E, strength, events, bonds broken, particles and bonds, its last session's wall time and the peak
memory of its process, and the study's fits once the study has written them (all its jobs finished).  The jobs
already recorded stay (a folder on another machine, a study of other seeds: ``--set 'study.seeds=[2]'``); a job
of the same label is replaced by the folder's.  ``--paused LABEL=SECONDS``: the job's process was stopped
(SIGSTOP) that long during its session (the machine lent to something else): kept as ``paused_s``, its wall
time stays as measured; ``--note LABEL=TEXT``: what else ran on the machine during the job.  ``peak_rss_of``
(seed 1 of the d = 15 nm study): whose peak memory a job's ``peak_rss_GiB`` is where it is not the job's own.

``--resolution``: each recorded resolution's fits of eqs. 22 and 23 (b_E and m with their 95 % intervals, every
recorded job) against the finest resolution's intervals, and its cost (the mean wall time of a job, less the time
it was stopped, over the finest's): the coarsest d whose b_E and m both fall inside is the cheapest resolution for
the paper's study.
"""
from __future__ import annotations

import datetime
import json
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
RESOLUTION = RESULTS / "porosity_resolution.json"


def out_of(diameter_nm: float) -> Path:
    """The record of the study at particle diameter ``diameter_nm``."""
    return RESULTS / f"porosity_paper_d{diameter_nm:g}.json"


def record(folder: Path) -> dict:
    jobs, diameters, settings = [], set(), set()
    for job in sorted(folder.glob("jobs/*/summary.json")):
        s = json.loads(job.read_text())
        if s.get("state") != "finished":
            continue
        rec = json.loads((job.parent / "run.json").read_text())
        diameters.add(rec["spec"]["packing"]["diameter_nm"])
        settings.add((rec["spec"]["bonds"]["breaking"], rec["spec"]["compression"]["event_tolerance"]))
        last = rec["sessions"][-1]
        jobs.append({"label": rec["label"], "porosity": s["porosity"], "density_kg_m3": s["density_kg_m3"],
                     "youngs_modulus_GPa": s["youngs_modulus_GPa"], "strength_MPa": s["strength_MPa"],
                     "strain_at_peak": s["strain_at_peak"], "events": last["last_step"],
                     "broken_bonds": s["broken_bonds"], "particles": s["n_particles"], "bonds": s["n_bonds"],
                     "last_session_wall_s": last["wall_s"], "last_session_resumed": bool(last["restart"]),
                     "sessions": len(rec["sessions"]), "peak_rss_GiB": rec["peak_rss_MiB"] / 1024})
    if len(diameters) != 1:
        raise SystemExit(f"{folder}: {len(diameters)} particle diameters among its finished jobs (one study's jobs "
                         "share one)")
    d = diameters.pop()
    (breaking, tolerance), = settings
    study = folder / "summary.json"
    fits = json.loads(study.read_text()).get("fits") if study.exists() else None
    size = "" if d == 15 else f" --set study.diameter_nm={d:g}"
    return {"command": "python -m opalflow run porosity_strength --out DIR --set study.paper_scale=true" + size +
                       " --set executor.workers=1 --set executor.cpus_per_rank=2; python bench/bench_porosity_paper.py "
                       "DIR", "diameter_nm": d, "breaking": breaking, "event_tolerance": tolerance,
            "machine": {"cpus": os.cpu_count(), "date": datetime.date.today().isoformat()},
            "jobs_finished": len(jobs), "jobs": jobs, "fits": fits}


def merged(result: dict) -> dict:
    """``result`` with the jobs recorded before that its folder does not hold (their sitting's date kept)."""
    out = out_of(result["diameter_nm"])
    if not out.exists():
        return result
    before = json.loads(out.read_text())
    mine = {j["label"] for j in result["jobs"]}
    date = before.get("machine", {}).get("date", "")
    kept = [{**j, "date": j.get("date", date)} for j in before["jobs"] if j["label"] not in mine]
    today = result["machine"]["date"]
    jobs = sorted(kept + [{**j, "date": today} for j in result["jobs"]], key=lambda j: j["label"])
    return {**result, "jobs_finished": len(jobs), "jobs": jobs, "fits": result["fits"] or before.get("fits")}


def fits_of_recorded(jobs: list[dict]) -> dict | None:
    """Eqs. 22, 23 and 26 fitted to every recorded job (the study's own fits: opalflow.studies.run.porosity_fits, 95 %
    intervals), beside the paper's values (opalflow.studies.run.paper()): the table while the study is partly run."""
    from opalflow.runs.result import table_of
    from opalflow.studies.run import paper, porosity_fits

    if len(jobs) < 3:
        return None
    fits = porosity_fits([j["porosity"] for j in jobs], [j["youngs_modulus_GPa"] for j in jobs],
                         [j["strength_MPa"] for j in jobs])
    return {"jobs": sorted(j["label"] for j in jobs), "fits": {k: table_of(f) for k, f in fits.items()},
            "paper": table_of(paper().porosity)}


def resolution() -> dict:
    """The resolution table (module docstring) of every recorded study (porosity_paper_d*.json)."""
    studies = sorted((r for p in RESULTS.glob("porosity_paper_d*.json")
                      if (r := json.loads(p.read_text())).get("fits_of_recorded_jobs")),     # (3 jobs at least)
                     key=lambda r: r["diameter_nm"])
    finest = studies[0]
    ref = finest["fits_of_recorded_jobs"]["fits"]

    def mean_wall(r):
        return sum(j["last_session_wall_s"] - j.get("paused_s", 0.0) for j in r["jobs"]) / len(r["jobs"])

    rows = []
    for r in studies:
        fits = r["fits_of_recorded_jobs"]["fits"]
        row = {"diameter_nm": r["diameter_nm"], "jobs": r["jobs_finished"],
               "mean_job_wall_s": round(mean_wall(r), 1), "cost_ratio": round(mean_wall(r) / mean_wall(finest), 4),
               "mean_particles": round(sum(j["particles"] for j in r["jobs"]) / len(r["jobs"]))}
        for key, law in (("b_E", "E_exponential"), ("m", "E_power"), ("b_sigma", "strength_exponential")):
            row[key], row[f"{key}_ci"] = fits[law]["exponent"], fits[law]["exponent_ci"]
        row["inside"] = all(ref[law]["exponent_ci"][0] <= fits[law]["exponent"] <= ref[law]["exponent_ci"][1]
                            for law in ("E_exponential", "E_power"))
        rows.append(row)
    inside = [row for row in rows[1:] if row["inside"]]
    cheapest = max(inside, key=lambda row: row["diameter_nm"]) if inside else None
    return {"command": "python bench/bench_porosity_paper.py --resolution", "reference_diameter_nm":
            rows[0]["diameter_nm"], "rows": rows,
            "cheapest_diameter_nm": cheapest["diameter_nm"] if cheapest else None,
            "cheapest_cost_ratio": cheapest["cost_ratio"] if cheapest else None}


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, nargs="?")
    ap.add_argument("--paused", action="append", default=[], metavar="LABEL=SECONDS")
    ap.add_argument("--note", action="append", default=[], metavar="LABEL=TEXT",
                    help="what else ran on the machine during the job (its wall time stays as measured)")
    ap.add_argument("--resolution", action="store_true", help="the resolution table of the recorded studies")
    args = ap.parse_args()
    if args.resolution:
        table = resolution()
        RESOLUTION.write_text(json.dumps(table, indent=1) + "\n")
        for row in table["rows"]:
            ci = {k: "[{:.2f}, {:.2f}]".format(*row[f"{k}_ci"]) for k in ("b_E", "m")}
            print(f"d = {row['diameter_nm']:g} nm: {row['jobs']} jobs, b_E {row['b_E']:.2f} {ci['b_E']}, m "
                  f"{row['m']:.2f} {ci['m']}, cost {row['cost_ratio']:.3g} x; inside: {row['inside']}")
        print(f"cheapest: d = {table['cheapest_diameter_nm']} nm -> {RESOLUTION}")
        raise SystemExit(0)
    result = record(args.folder)
    paused = {k: float(v) for k, v in (p.split("=", 1) for p in args.paused)}
    notes = dict(n.split("=", 1) for n in args.note)
    for job in result["jobs"]:
        if job["label"] in paused:
            job["paused_s"] = paused[job["label"]]
        if job["label"] in notes:
            job["note"] = notes[job["label"]]
    result = merged(result)
    result["fits_of_recorded_jobs"] = fits_of_recorded(result["jobs"])
    # the porosities the paper quotes its results at (0.49 to 0.63, Dosta et al. section 4): the laws over them alone
    result["fits_from_porosity_0.48"] = fits_of_recorded([j for j in result["jobs"] if j["porosity"] >= 0.48])
    out = out_of(result["diameter_nm"])
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"{result['jobs_finished']} jobs finished -> {out}")
