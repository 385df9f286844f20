"""Every time the README quotes beside a command, measured: -> bench/results/readme.json.

Each command of the README's code blocks that carries a time in its comment is either run here and timed
(the whole command, as a user waits for it: Python start, build, run, analysis), or, where it takes longer
than ``--budget`` seconds, priced by ``python -m opalflow plan`` from the cost laws measured by
bench_cost.py (then said as predicted); a kind that plan cannot price is run.  tests/test_readme.py checks the README's quotes against this file.

    python bench/bench_readme.py [--budget 200]
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
sys.path.insert(0, str(ROOT / "tests"))
from test_readme import BLOCKS, commands, quoted_times  # noqa: E402  (the README's own parser)

OUT = ROOT / "bench" / "results" / "readme.json"


def planned_seconds(cmd: list[str], cwd: Path) -> float | None:
    """The wall time ``plan`` predicts for ``run WORKFLOW [--set ...]`` on one worker (its core-hours), None
    where the kind has no cost model."""
    args = cmd[4:]
    if cmd[3] != "run" or not args:
        return None
    plan = [sys.executable, "-m", "opalflow", "plan", args[0], "--sample", "2"]
    plan += [a for k, a in enumerate(args[1:], 1) if a == "--set" or (k > 1 and args[k - 1] == "--set")]
    got = subprocess.run(plan, cwd=cwd, capture_output=True, text=True)
    m = re.search(r"total: ([0-9.e+-]+) core-hours", got.stdout)
    return float(m.group(1)) * 3600 if m else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--budget", type=float, default=200.0,
                    help="commands quoted longer than this are priced by plan where it can (else run)")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for line, text, marker in BLOCKS:
            for quoted, command in quoted_times(text):
                cmd = commands(command)[0]
                row = {"readme_line": line, "command": command.split("#")[0].strip(), "quoted": quoted}
                s = planned_seconds(cmd, Path(tmp)) if quoted["seconds"] > args.budget else None
                if s is not None:
                    row.update(how="predicted by python -m opalflow plan (cost laws of bench/results/cost_laws.json)",
                               seconds=s)
                else:
                    t = time.perf_counter()
                    proc = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True)
                    row.update(how="measured: the whole command", seconds=time.perf_counter() - t,
                               exit=proc.returncode)
                print(f"{row['command'][:90]:<90} quoted {quoted['text']:>8}  {row['how'].split(':')[0]} "
                      f"{row['seconds'] if row['seconds'] is None else round(row['seconds'], 1)} s", flush=True)
                rows.append(row)
    machine = {"host": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
               "load_1min": os.getloadavg()[0], "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M")}
    OUT.write_text(json.dumps({"machine": machine, "rows": rows}, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
