"""Faults: two runs into one folder, stale locks, killed runs, broken inputs -> one clear line, and
finished results untouched."""
import json
import os
import subprocess
import sys
import tempfile
import time

import pytest

from opalflow.cli import main
from opalflow.store import LOCK_FILE


def test_a_second_run_into_a_running_folder_is_refused(tmp_path, capsys):
    """Two real runs into one --out: the second is refused in one line while the first runs; the first
    finishes and leaves no lock."""
    out = tmp_path / "run"
    first = subprocess.Popen([sys.executable, "-m", "opalflow", "run", "lattice_sc", "--out", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while time.time() < deadline and not (out / LOCK_FILE).exists():
        time.sleep(0.01)
    assert main(["run", "lattice_sc", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: --out = '{out}': in use by a running opalflow (pid "
                                               f"{first.pid}")
    stdout, stderr = first.communicate(timeout=300)
    assert first.returncode == 0, stderr[-2000:]
    assert stdout.startswith("E (top-layer strain) = ") and not (out / LOCK_FILE).exists()
    assert json.loads((out / "summary.json").read_text())["complete"]


def test_the_lock_of_a_dead_run_is_taken_over(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    dead = subprocess.Popen(["true"])
    dead.wait()
    (out / LOCK_FILE).write_text(f"{dead.pid}\n")
    assert main(["build", "lattice_sc", "--out", str(out)]) == 0
    assert (out / "in.lmp").exists() and not (out / LOCK_FILE).exists()


def test_a_refused_run_leaves_no_folder_behind(tmp_path, capsys):
    """The lock does not leave an empty folder when the input is refused after it was taken."""
    out = tmp_path / "run"
    assert main(["build", "opal_quick", "--out", str(out), "--set", "pores.arrangement=random",
                 "--set", "pores.porosity=0.6", "--set", "pores.porosity_tolerance=0.001"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith("error: pores.porosity = 0.6")
    assert not out.exists()


def test_own_live_pid_is_not_mistaken_for_a_stale_lock(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / LOCK_FILE).write_text(f"{os.getpid()}\n")
    assert main(["build", "lattice_sc", "--out", str(out)]) == 2
    assert "in use by a running opalflow" in capsys.readouterr().err


def test_damaged_run_folder_files_are_one_line(tmp_path, capsys):
    """A damaged run.json or curve.txt: analyze and --resume say so in one line, exit 2."""
    out = tmp_path / "run"
    assert main(["build", "lattice_sc", "--out", str(out)]) == 0
    (out / "curve.txt").write_text("# averages\n# step ...\n12 0.1 nonsense\n")
    capsys.readouterr()
    assert main(["analyze", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "curve.txt is damaged" in err[0]
    (out / "run.json").write_text('{"workflow": "lattice_sc", "spec": ')      # cut off mid-write
    for argv in (["analyze", str(out)], ["run", "--out", str(out), "--resume"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "run.json is damaged" in err[0], err


def test_damaged_results_are_made_again_by_analyze(tmp_path, capsys):
    """A results.h5 cut short and a summary.json of garbage (a crash while copying, say): analyze reads
    neither, writes both whole again, the same numbers as before."""
    import h5py

    out = tmp_path / "run"
    assert main(["run", "lattice_sc", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    h5 = (out / "results.h5").read_bytes()
    (out / "results.h5").write_bytes(h5[: len(h5) // 3])
    (out / "summary.json").write_bytes(b"\x00\xff{garbage")
    capsys.readouterr()
    assert main(["analyze", str(out)]) == 0
    again = json.loads((out / "summary.json").read_text())
    assert again["youngs_modulus_GPa"] == summary["youngs_modulus_GPa"]
    with h5py.File(out / "results.h5") as h:
        assert len(h["curve/stress_MPa"]) == len(h["curve/strain"]) > 10
    assert not list(out.glob(".staged.*"))


def _can_mount_tmpfs() -> bool:
    """Root and allowed to mount a tmpfs (a small disk to fill)."""
    if os.geteuid() != 0:
        return False
    probe = tempfile.mkdtemp()
    try:
        if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", probe], capture_output=True).returncode:
            return False
        subprocess.run(["umount", probe], check=False)
        return True
    except OSError:
        return False
    finally:
        os.rmdir(probe)


@pytest.mark.skipif(not _can_mount_tmpfs(), reason="filling a small disk needs root and a mountable tmpfs")
def test_a_full_disk_while_writing_results_keeps_the_earlier_ones(tmp_path, capsys):
    """analyze on a disk with room for the run folder but not for new results: one error line, exit 1,
    the earlier results byte for byte, no temporary file left."""
    import shutil

    src = tmp_path / "run"
    assert main(["run", "lattice_sc", "--out", str(src)]) == 0
    pages = sum(-(-f.stat().st_size // 4096) for f in src.rglob("*") if f.is_file())   # tmpfs counts pages
    disk = tmp_path / "disk"
    disk.mkdir()
    # a tmpfs with room for the folder and 24 KiB more: less than a new results.h5 (~40 KiB)
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={4 * (pages + 6)}k", "tmpfs", str(disk)], check=True)
    try:
        out = disk / "run"
        shutil.copytree(src, out)
        before = {f.name: f.read_bytes() for f in out.iterdir() if f.is_file()}
        capsys.readouterr()
        assert main(["analyze", str(out)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len([line for line in err if line.startswith("error:")]) == 1, err
        assert err[-1].startswith(f"error: cannot write {out}/") and "files written before are intact" in err[-1]
        after = {f.name: f.read_bytes() for f in out.iterdir() if f.is_file()}
        assert after == before
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def _cli_child(args: list[str], **popen) -> subprocess.Popen:
    """``python -m opalflow ARGS`` in a child that takes Ctrl-C and SIGTERM as a terminal would send them
    (Python keeps SIGINT ignored where its parent ignored it: the child restores it itself)."""
    child = ("import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
             f"sys.argv = ['opalflow'] + {args!r}; runpy.run_module('opalflow', run_name='__main__')")
    return subprocess.Popen([sys.executable, "-c", child], stderr=subprocess.PIPE, text=True, **popen)


def _wait_for(cond, seconds=120.0):
    deadline = time.time() + seconds
    while time.time() < deadline and not cond():
        time.sleep(0.1)
    assert cond(), "timed out"


def test_sigterm_stops_with_one_line_releases_the_lock_and_resumes(tmp_path):
    """Was: SIGTERM ended a run with no message and left .opalflow.lock behind."""
    import signal

    out = tmp_path / "sc"
    p = _cli_child(["run", "lattice_sc", "--out", str(out), "--set", "compression.strain_max=0.03",
                    "--set", "compression.restart_every_strain=0.001"])
    _wait_for(lambda: list(out.glob("restart.*.bin")))
    p.send_signal(signal.SIGTERM)
    err = p.stderr.read()
    assert p.wait() == 143
    last = err.strip().splitlines()[-1]
    assert last.startswith("terminated (SIGTERM) at step ") and f"--out {out} --resume" in last, last
    assert "Traceback" not in err and not (out / LOCK_FILE).exists()
    assert json.loads((out / "run.json").read_text())["state"] == "interrupted"
    assert main(["run", "--out", str(out), "--resume"]) == 0


def test_ctrl_c_before_the_first_restart_says_run_again_not_resume(tmp_path):
    """Was: Ctrl-C before the first restart file printed a --resume line that then failed ('no readable
    restart file in the folder')."""
    import signal

    out = tmp_path / "sc"
    p = _cli_child(["run", "lattice_sc", "--out", str(out), "--set", "compression.strain_max=0.05",
                    "--set", "compression.restart_every_strain=0.05"])
    _wait_for(lambda: (out / "log.lammps").exists())
    p.send_signal(signal.SIGINT)
    err = p.stderr.read()
    assert p.wait() == 130
    assert not list(out.glob("restart.*.bin"))
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted") and "--resume" not in last and "run the same command again" in last, last
    assert not (out / LOCK_FILE).exists()


def test_a_pipe_closed_early_exits_quietly():
    """Was: ``list | head`` and ``info | head`` ended with BrokenPipeError (exit 1) in some tries."""
    for verb in ("list", "info"):
        p = subprocess.Popen([sys.executable, "-m", "opalflow", verb], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
        p.stdout.close()              # the reader is gone before the first line is written
        err = p.stderr.read()
        assert p.wait() == 0 and err == "", (verb, err)


@pytest.mark.parametrize("text", ["", "# nothing yet\n", 'kind = "opal"\nmaterial = "silica"\n'])
def test_an_empty_or_sectionless_workflow_file_is_one_line(tmp_path, capsys, text):
    """Was: an empty workflow file built the paper's full sample (1.6 M particles, 587 MB) without a word."""
    path = tmp_path / "w.toml"
    path.write_text(text)
    out = tmp_path / "out"
    assert main(["build", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: workflow = '{path}': has no [section]")
    assert not out.exists()


def test_a_run_longer_than_an_hour_says_its_estimate():
    """Was: nothing said how long a run would take (the empty file's sample: ~3.9 days)."""
    from opalflow.api import load_workflow
    from opalflow.bpm.deck import compression_deck
    from opalflow.bpm.dynamic_run import long_run_estimate
    from opalflow.bpm.pipeline import build_structure

    quick = load_workflow("lattice_sc")
    assert long_run_estimate(quick, compression_deck(quick, build_structure(quick))) == ""
    slow = load_workflow("lattice_sc", {"compression.plate_speed_m_s": 1e-5})     # 10 000x the steps
    line = long_run_estimate(slow, compression_deck(slow, build_structure(slow)))
    assert line.startswith("estimate: this run takes about ") and "compression.method" in line, line


def test_a_process_that_ran_lammps_leaves_no_mpi_shared_memory_behind():
    """MPICH's singleton keeps ``/dev/shm/mpich_shm_<pid in hex>_0`` while LAMMPS runs; opalflow ends MPI at
    exit, so the segment goes with the process (left behind, it stops another user's process whose pid maps
    to the same name from starting MPI)."""
    code = ("from opalflow.lammps.engine import mpich_segment, new_lammps\n"
            "lmp = new_lammps()\n"
            "lmp.command('units lj')\n"
            "print(mpich_segment(), mpich_segment().exists())\n"
            "open_at_exit = new_lammps()\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    segment, existed = done.stdout.split()
    if existed != "True":
        pytest.skip(f"this MPI keeps no {segment} while it runs")
    assert not os.path.exists(segment)


def test_a_stale_mpi_segment_under_this_pid_is_cleared_or_named(tmp_path):
    """A segment a killed process left under the pid this one now has: removed before MPI starts where this process
    may remove it, this user's (left, MPICH's start hangs) or another user's as root (left, MPICH stops with "Out of
    memory": CI's failure of 4f83419, a segment of user id 1001); one it may not remove (another user's, this
    process not root) is one line naming the file, not MPICH's abort."""
    code = ("import os, sys\n"
            "from opalflow.lammps.engine import EngineError, clear_stale_segment, mpich_segment, new_lammps\n"
            "stale = mpich_segment()\n"
            "stale.write_bytes(bytes(1061440))\n"
            "if sys.argv[1] != 'mine':\n"
            "    os.chown(stale, 65534, -1)\n"
            "try:\n"
            "    if sys.argv[1] == 'not-root':\n"
            "        os.seteuid(65533)\n"
            "        clear_stale_segment()\n"     # (what new_lammps calls first; the stdlib is not this uid's to read)
            "    new_lammps().command('units lj')\n"
            "except EngineError as exc:\n"
            "    os.seteuid(0)\n"
            "    stale.unlink()\n"
            "    print('refused:', exc)\n"
            "    sys.exit(0)\n"
            "print('ran', stale.exists() and stale.stat().st_uid == os.getuid())\n")     # MPICH's own now
    mine = subprocess.run([sys.executable, "-c", code, "mine"], capture_output=True, text=True, timeout=60)
    assert mine.returncode == 0 and mine.stdout.strip() == "ran True", mine.stderr[-2000:]
    if os.geteuid() != 0:
        pytest.skip("another user's segment is made here only as root (chown)")
    other = subprocess.run([sys.executable, "-c", code, "other"], capture_output=True, text=True, timeout=60)
    assert other.returncode == 0 and other.stdout.strip() == "ran True", other.stderr[-2000:]
    refused = subprocess.run([sys.executable, "-c", code, "not-root"], capture_output=True, text=True, timeout=60)
    assert refused.returncode == 0, refused.stderr[-2000:]
    assert refused.stdout.startswith("refused: /dev/shm/mpich_shm_") and "of user id 65534" in refused.stdout


def test_python_m_opalflow_keeps_freed_memory_for_the_next_arrays():
    """opalflow.heap: in a process started as ``python -m opalflow`` glibc keeps what it frees, so a 78 MB
    array made again and again faults its pages in once (without it each is mapped anew and faults again:
    0.6 s per 78 MB on this VM, opalflow/heap.py)."""
    import subprocess
    import sys

    probe = ("import resource, numpy as np\n"
             "from opalflow.heap import keep_freed_memory\n"
             "{setup}\n"
             "def faults():\n"
             "    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
             "x = np.ones(9_700_000)\n"
             "y = x * 2; del y\n"
             "before = faults()\n"
             "for _ in range(5):\n"
             "    y = x * 2; del y\n"
             "print(faults() - before)\n")
    kept = int(subprocess.run([sys.executable, "-c", probe.format(setup="assert keep_freed_memory()")],
                              capture_output=True, text=True, check=True).stdout)
    fresh = int(subprocess.run([sys.executable, "-c", probe.format(setup="")],
                               capture_output=True, text=True, check=True).stdout)
    assert kept < 100 < fresh, (kept, fresh)


def test_python_m_opalflow_keeps_numpy_arrays_out_of_huge_pages_where_faults_compact():
    """opalflow.heap: where a fault in memory advised into huge pages waits for the kernel to compact memory
    (THP ``defrag`` madvise, this machine's), a ``python -m opalflow`` process switches numpy's huge-page
    advice off: a 240 MB array lies in small pages, where numpy's advice puts it in huge pages (first touch
    1.35 s against 0.13 s here, opalflow/heap.py)."""
    import subprocess
    import sys
    from pathlib import Path

    from opalflow.heap import faults_compact

    enabled = Path("/sys/kernel/mm/transparent_hugepage/enabled")
    if not faults_compact() or "[madvise]" not in enabled.read_text():
        pytest.skip("transparent huge pages here are not given on advice with compaction (THP enabled "
                    "'madvise', defrag one of always, madvise, defer+madvise): numpy's advice is kept")
    probe = ("import numpy as np\n"
             "from opalflow.heap import no_huge_page_advice\n"
             "{setup}\n"
             "x = np.ones(30_000_000)\n"
             "rollup = open('/proc/self/smaps_rollup').read().splitlines()\n"
             "print(next(int(line.split()[1]) for line in rollup if line.startswith('AnonHugePages')))\n")
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    huge = {setup: int(subprocess.run([sys.executable, "-c", probe.format(setup=setup)], capture_output=True,
                                      text=True, check=True, env=env).stdout)
            for setup in ("assert no_huge_page_advice()", "pass")}
    if huge["pass"] == 0:
        pytest.skip("the kernel gave numpy's advised array no huge page (memory too fragmented to compact): "
                    "the probe cannot tell the two apart")
    assert huge["assert no_huge_page_advice()"] == 0, huge
