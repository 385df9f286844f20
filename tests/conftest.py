import atexit
import os
import shutil
import tempfile
import textwrap

# a worker of pytest-xdist (-n, pyproject.toml) shares the cores with the others: its BLAS, OpenMP and MKL
# threads (the factor's PARDISO, numpy) get its share, set before numpy loads them; oversubscribed, OpenMP's
# waiting threads spin, and a solve took 5-7x as long (measured in CI)
if os.environ.get("PYTEST_XDIST_WORKER"):
    _share = max(1, len(os.sched_getaffinity(0)) // int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")))
    for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(_var, str(_share))

import numpy as np  # noqa: E402
import pytest

from opalflow import registry

from opalflow.opal.scene import build_opal
from opalflow.resources import WORKFLOWS
from opalflow.registry import load_spec


# the structure cache of the whole session in a folder of its own (not the user's ~/.cache): tests that build
# one scene twice reuse it, as a user's reruns do; subprocesses (the CLI, jobs) inherit it; removed at exit
os.environ["OPALFLOW_CACHE"] = tempfile.mkdtemp(prefix="opalflow-cache-")
atexit.register(shutil.rmtree, os.environ["OPALFLOW_CACHE"], True)


@pytest.fixture(scope="session")
def quick_spec():
    return load_spec(WORKFLOWS / "opal_quick.toml")


@pytest.fixture(scope="session")
def quick_structure(quick_spec):
    structure, _ = build_opal(quick_spec)
    return structure


@pytest.fixture(scope="session")
def coated_quick():
    """Quick scene coated with 60 nm (one particle diameter) of titania."""
    spec = load_spec(WORKFLOWS / "opal_quick.toml", ["coating.thickness_nm=60.0"])
    structure, _ = build_opal(spec)
    return spec, structure


def brute_force_pairs(x, r, box, periodic):
    """All pairs closer than r by direct O(N^2) minimum-image distances."""
    d = x[None, :, :] - x[:, None, :]
    for k in range(3):
        if periodic[k]:
            d[..., k] -= box[k] * np.round(d[..., k] / box[k])
    dist = np.sqrt((d**2).sum(-1))
    i, j = np.nonzero(np.triu(dist < r, 1))
    return np.column_stack([i, j])


def signalled_run(out, sig) -> tuple[int, str]:
    """A real dynamic run of the lattice into ``out`` in a child process, sent ``sig`` once LAMMPS has written its
    first restart file: (exit code, stderr).  Python keeps SIGINT ignored where its parent ignored it
    (background shells): the child restores Ctrl-C itself (a preexec_fn would fork this JAX-threaded process)."""
    import subprocess
    import sys
    import time

    args = ["run", "lattice_sc", "--out", str(out), "--set", "compression.strain_max=0.02",
            "--set", "compression.restart_every_strain=0.001"]
    child = ("import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
             f"sys.argv = ['opalflow'] + {args!r}; runpy.run_module('opalflow', run_name='__main__')")
    p = subprocess.Popen([sys.executable, "-c", child], stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not list(out.glob("restart.*.bin")):
        time.sleep(0.2)
    p.send_signal(sig)
    err = p.stderr.read()
    return p.wait(), err


def assert_refused(capsys, argv: list[str], sets: list[str], field: str, out) -> None:
    """The CLI refuses the --set values with one line naming ``field``, exit 2, ``out`` not created."""
    from opalflow.cli import main

    for s in sets:
        argv = argv + ["--set", s]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert err.startswith(f"error: {field} = ")
    assert not out.exists()


# ----------------------------------------------------------------------------- a new track (a plugin)
TOY = '''
"""A throwaway track: counts to ``toy.n`` and reports the sum."""
import json
import time
from dataclasses import dataclass, field

from opalflow.registry import Kind
from opalflow.runs.record import finish
from opalflow.spec import WorkflowSpec, check


@dataclass
class ToySpec:
    n: int = 3


@dataclass
class ToyWorkflow(WorkflowSpec):
    toy: ToySpec = field(default_factory=ToySpec)

    def validate(self):
        super().validate()
        check(1 <= self.toy.n <= 100, "toy.n", self.toy.n, "must be in [1, 100]")


def run(spec, out, say=print):
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    total = sum(range(1, spec.toy.n + 1))
    say(f"toy: summed 1..{spec.toy.n}")
    summary = {"sum": total, "headline": f"sum = {total}", "wall_s": time.perf_counter() - t0}
    return finish(out, summary, summary["headline"])


KIND = Kind("toy", spec="toytrack:ToyWorkflow", run="toytrack:run", summary="sum of 1..n (a test track)")
'''


@pytest.fixture
def toytrack(tmp_path, monkeypatch):
    """A package ``toytrack`` outside opalflow, on the path, with an entry point in opalflow.kinds."""
    site = tmp_path / "site"
    (site / "toytrack").mkdir(parents=True)
    (site / "toytrack" / "__init__.py").write_text(textwrap.dedent(TOY))
    dist = site / "toytrack-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: toytrack\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(f"[{registry.ENTRY_POINT_GROUP}]\ntoy = toytrack:KIND\n")
    (tmp_path / "toy.toml").write_text('name = "toy_sum"\nkind = "toy"\n[toy]\nn = 10\n')
    monkeypatch.syspath_prepend(str(site))
    return tmp_path


def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (pyproject.toml): one worker per core this process may use, at most 4 (each worker runs LAMMPS
    and the solvers on one core; more would need more memory than a laptop has for the paper-scale build)."""
    return max(1, min(4, len(os.sched_getaffinity(0))))


def pytest_collection_modifyitems(config, items):
    """The SLURM tests share one controller (one of them restarts it): one worker runs them all, in order, and
    first (they are the longest group: the other workers take the rest meanwhile)."""
    for item in items:
        if item.nodeid.startswith("tests/test_slurm.py"):
            item.add_marker(pytest.mark.xdist_group("slurm"))
    items.sort(key=lambda item: not item.nodeid.startswith("tests/test_slurm.py"))
