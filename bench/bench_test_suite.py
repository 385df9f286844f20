"""The test suite as CI runs it, timed, with each skip's reason: -> bench/results/test_suite.json.

Clones this repository's HEAD into a fresh folder and runs ``bash .ci/run`` there (LIGGGHTS and a one-node SLURM
where root can start them, a new virtual environment, the README's test command), as CI does after each
session: the whole run's wall time, the install's share, and the tests' (pytest's own summary: passed, skipped,
failed, seconds, workers).  The README's test command quotes these figures.

    python bench/bench_test_suite.py [--keep DIR]
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
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "test_suite.json"


def summary(log: str) -> dict:
    """pytest's last line (``404 passed, 5 skipped in 1456.38s``) and the workers xdist started."""
    line = [ln for ln in log.splitlines() if re.search(r"\d+ (passed|failed)", ln)][-1]
    counts = {k: int(v) for v, k in re.findall(r"(\d+) (passed|failed|skipped|errors?)", line)}
    workers = re.search(r"created: (\d+)/\d+ workers", log)
    # -ra's summary: "SKIPPED [2] tests/test_slurm.py:30: no SLURM running and not root: ..."
    skips = [{"tests": int(n), "where": where, "reason": why}
             for n, where, why in re.findall(r"^SKIPPED \[(\d+)\] (\S+?): (.*)$", log, re.M)]
    return {**counts, "pytest_s": float(re.search(r"in ([\d.]+)s", line).group(1)),
            "workers": int(workers.group(1)) if workers else 1, "line": line.strip("= "), "skips": skips}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", type=Path, help="clone into this folder and keep it (default: a temporary one)")
    args = ap.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="opalflow-ci-")) / "clone"
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    subprocess.run(["git", "clone", "-q", str(ROOT), str(folder)], check=True)
    t0 = time.perf_counter()
    done = subprocess.run(["bash", ".ci/run"], cwd=folder, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    log = done.stdout + done.stderr
    (folder / "ci.log").write_text(log)
    result = {"machine": {"host": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
                          "load_1min": os.getloadavg()[0],
                          "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M")},
              "commit": commit, "command": "bash .ci/run (in a fresh clone)", "exit": done.returncode,
              "whole_s": round(wall, 1), **summary(log)}
    result["install_and_setup_s"] = round(wall - result["pytest_s"], 1)
    OUT.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))
    print(f"log: {folder / 'ci.log'}", file=sys.stderr)
    return done.returncode


if __name__ == "__main__":
    sys.exit(main())
