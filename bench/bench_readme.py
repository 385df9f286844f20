"""Every time the README quotes beside a command, measured: -> bench/results/readme.json.

Each command of the README's code blocks that carries a time in its comment is run here and timed: the
whole command, as a user waits for it (Python start, build, run, analysis), starting from an empty
structure cache (a new user's).  Commands of hours carry no time
in the README (``python -m opalflow plan`` prices them before they are submitted).  tests/test_readme.py
checks the README's quotes against this file.

    python bench/bench_readme.py [--only TEXT ...]

``--only``: run just the commands that contain one of these texts and keep the other rows of the file.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_readme import BLOCKS, commands, quoted_times  # noqa: E402  (the README's own parser)

OUT = ROOT / "bench" / "results" / "readme.json"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--only", nargs="*", default=[], help="run the commands containing one of these texts")
    a = ap.parse_args()
    before = json.loads(OUT.read_text()) if a.only and OUT.exists() else {"rows": [], "machine": {}}
    old = before["rows"]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        # a structure cache of this run's own, empty at the start: the times are a new user's, who has built
        # nothing yet (a command that reuses a structure an earlier README command built says so, as for them)
        env = {**os.environ, "OPALFLOW_CACHE": os.path.join(tmp, "cache")}
        for line, text, marker in BLOCKS:
            for quoted, command in quoted_times(text):
                cmd = commands(command)[0]
                row = {"readme_line": line, "command": command.split("#")[0].strip(), "quoted": quoted}
                if a.only and not any(t in row["command"] for t in a.only):
                    kept = [r for r in old if r["command"] == row["command"]]
                    rows += [{**kept[0], "readme_line": line, "quoted": quoted}] if kept else []
                    continue
                t = time.perf_counter()
                proc = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, env=env)
                row.update(how="measured: the whole command", seconds=time.perf_counter() - t, exit=proc.returncode)
                print(f"{row['command'][:90]:<90} quoted {quoted['text']:>8}  {row['how'].split(':')[0]} "
                      f"{row['seconds'] if row['seconds'] is None else round(row['seconds'], 1)} s", flush=True)
                rows.append(row)
    machine = {"host": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
               "load_1min": os.getloadavg()[0], "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M")}
    if a.only:                 # the rows kept from the earlier run: its machine line
        machine.update(only=a.only, kept_rows_machine=before["machine"])
    OUT.write_text(json.dumps({"machine": machine, "rows": rows}, indent=1) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
