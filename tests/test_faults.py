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
    assert stdout.startswith("E = ") and not (out / LOCK_FILE).exists()
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
