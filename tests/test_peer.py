"""What the static solver is measured against and what keeps it fast: the damped-relaxation peer deck run
by LAMMPS (opalflow/bpm/relaxation.py), the structure cache (opalflow/bpm/scene.py), the threads each
solver runs with and the wall time a run records (bench/bench_peer.py, bench_threads.py and
bench_overhead.py time them; no timing is asserted here)."""
import json
import time

import numpy as np
import pytest

from opalflow.bpm.deck import compression_deck
from opalflow.bpm.loading import LOADINGS
from opalflow.bpm.relaxation import relaxation_deck
from opalflow.bpm.scene import build_key, scene_of
from opalflow.bpm.static import block_matrix, solve_compression
from opalflow.linalg.direct import Factor, solver_threads, thread_budget
from opalflow.bpm.stiffness import stiffness_network
from opalflow.cli import main
from opalflow.lammps.datafile import write_data
from opalflow.lammps.engine import script_commands, session
from opalflow.registry import load_spec
from opalflow.resources import WORKFLOWS

SMALL_OPAL = ["pores.arrangement=none", "pores.spacing_nm=300.0", "pores.diameter_nm=250.0", "pores.layers=1",
              "packing.seed=3"]


@pytest.mark.parametrize("workflow, sets", [("lattice_sc", []), ("opal_quick", SMALL_OPAL),
                                            ("lattice_sc", ["compression.loading=tension"])])
def test_damped_relaxation_in_lammps_reaches_the_static_modulus(tmp_path, workflow, sets):
    """The peer deck (the run's own system, groups, bonds and time step; bonds unbreakable; the top layer
    displaced and held) relaxed by LAMMPS to rest gives the static solver's E: the run stops (fix halt) within
    0.1 % of it, and E stays there when the run goes on (no transient crossing)."""
    spec = load_spec(WORKFLOWS / f"{workflow}.toml", sets)
    deck = compression_deck(spec, scene_of(spec).structure(spec))
    s = deck.structure
    static = solve_compression(stiffness_network(s, deck.coefficients), s.positions,
                               LOADINGS[deck.loading].supports(deck), say=lambda m: None)
    script = relaxation_deck(deck, steps=200_000, damping=1.0, every=50, target_MPa=static.modulus_MPa,
                             tolerance=1e-3)
    assert "break no" in script and "smooth no" in script and "pair_style" not in script
    assert "fix             stop all halt" in script
    write_data(tmp_path / "data.lmp", s)
    with session(tmp_path) as lmp:
        for cmd in script_commands(script):
            lmp.command(cmd)
        steps = lmp.get_thermo("step")
        lmp.command("run 2000 post no")          # on past the stop: E stays within 0.1 %
    E = np.loadtxt(tmp_path / "relax.txt", ndmin=2)
    assert 0 < steps < 200_000
    assert abs(E[E[:, 0] == steps, 1][0] / static.modulus_MPa - 1) < 1e-3
    assert np.all(np.abs(E[E[:, 0] >= steps, 1] / static.modulus_MPa - 1) < 1e-3)


def test_the_tuned_peer_starts_affine_and_computes_each_bond_once(tmp_path):
    """What a skilled LAMMPS user tunes (bench/bench_peer.py): the affine start (``displace_atoms ramp`` from the
    substrate's highest centre to the top layer) is the simple-cubic lattice's exact uniaxial response, so its
    first sample is the static E (the top layer alone starts 10x off), and ``newton on on`` gives the same E
    sample for sample as ``on off``."""
    spec = load_spec(WORKFLOWS / "lattice_sc.toml", [])
    deck = compression_deck(spec, scene_of(spec).structure(spec))
    s = deck.structure
    E = solve_compression(stiffness_network(s, deck.coefficients), s.positions,
                          LOADINGS[deck.loading].supports(deck), say=lambda m: None).modulus_MPa
    samples, steps = {}, {}
    for name, options in (("top", {}), ("affine", {"start": "affine"}),
                          ("affine_newton", {"start": "affine", "newton_bond": True})):
        folder = tmp_path / name
        folder.mkdir()
        write_data(folder / "data.lmp", s)
        script = relaxation_deck(deck, steps=100_000, damping=1.0, every=20, target_MPa=E, tolerance=1e-3, **options)
        assert ("ramp z" in script) == (name != "top") and ("newton          on on" in script) == name.endswith("newton")
        with session(folder) as lmp:
            for cmd in script_commands(script):
                lmp.command(cmd)
            steps[name] = lmp.get_thermo("step")
        samples[name] = np.loadtxt(folder / "relax.txt", ndmin=2)
    assert abs(samples["affine"][0, 1] / E - 1) < 1e-4 and samples["top"][0, 1] / E > 2
    assert steps["affine"] <= steps["top"] < 100_000
    assert steps["affine_newton"] == steps["affine"]
    assert np.allclose(samples["affine_newton"][:, 1], samples["affine"][:, 1], rtol=1e-9)


def test_structure_cache_reuses_a_build_and_only_for_the_same_inputs(tmp_path, monkeypatch):
    """The second build of a spec comes from the cache (the same arrays, a line saying so); a new compression
    setting reuses it, a new packing seed does not; a damaged cache file is rebuilt; OPALFLOW_CACHE=off
    builds every time."""
    monkeypatch.setenv("OPALFLOW_CACHE", str(tmp_path / "cache"))
    spec = load_spec(WORKFLOWS / "opal_quick.toml", SMALL_OPAL)
    scene = scene_of(spec)
    said = []
    first = scene.structure(spec, said.append)
    assert not any("from the cache" in m for m in said)
    again = scene.structure(spec, said.append)
    assert "from the cache" in said[-1]
    assert np.array_equal(first.positions, again.positions) and np.array_equal(first.bonds, again.bonds)
    # the structure's statistics come with it (a neighbour search a rerun does not repeat), the same numbers;
    # a part of it (select) does not carry the whole's
    assert again.meta["statistics"] == scene.statistics(again) == scene.statistics_of(again)
    assert "statistics" not in again.select(np.arange(again.n_particles) % 2 == 0).meta
    other_run = load_spec(WORKFLOWS / "opal_quick.toml", SMALL_OPAL + ["compression.method=static",
                                                                       "compression.plate_speed_m_s=0.5"])
    assert build_key(other_run) == build_key(spec)
    other_sample = load_spec(WORKFLOWS / "opal_quick.toml", SMALL_OPAL[:-1] + ["packing.seed=4"])
    assert build_key(other_sample) != build_key(spec)
    files = list((tmp_path / "cache").glob("*.pkl"))
    assert len(files) == 1
    files[0].write_bytes(b"damaged")
    said.clear()
    rebuilt = scene.structure(spec, said.append)
    assert not any("from the cache" in m for m in said) and np.array_equal(rebuilt.positions, first.positions)
    monkeypatch.setenv("OPALFLOW_CACHE", "off")
    said.clear()
    scene.structure(spec, said.append)
    assert not any("from the cache" in m for m in said)


def test_threads_follow_the_budget_a_job_sets():
    """The iterative solvers run one BLAS thread; the factor takes the budget, which a job's threadpool limit
    lowers (jobs side by side do not oversubscribe the cores)."""
    from threadpoolctl import threadpool_limits

    assert solver_threads("amg") == solver_threads("cg") == 1
    assert solver_threads("direct") == thread_budget() >= 1
    with threadpool_limits(limits=1):
        assert thread_budget() == 1
        spec = load_spec(WORKFLOWS / "lattice_sc.toml")
        deck = compression_deck(spec, scene_of(spec).structure(spec))
        net = stiffness_network(deck.structure, deck.coefficients)
        free = np.ones((net.n_particles, 6), bool)
        free[deck.structure.groups["substrate"]] = False
        assert Factor(block_matrix(net, free)[0]).threads == 1


def test_kernel_threads_survive_lammps_setting_openmp_to_one_thread(tmp_path):
    """LAMMPS sets OpenMP's threads to 1 when it starts without OMP_NUM_THREADS: the factor's budget follows
    (MKL's PARDISO stalled on more), opalflow's own kernels keep the BLAS libraries' count (they fell to one
    thread when they counted OpenMP's: a quasi-static run that built its structure through LAMMPS)."""
    import os

    from threadpoolctl import threadpool_info, threadpool_limits

    from opalflow.linalg.direct import kernel_threads

    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip(f"needs 2 CPUs ({len(os.sched_getaffinity(0))} here)")
    with session(tmp_path) as lmp:
        lmp.command("units si")
    openmp = [lib["num_threads"] for lib in threadpool_info() if lib.get("user_api") == "openmp"]
    if not openmp or min(openmp) > 1:
        pytest.skip(f"this LAMMPS left OpenMP's threads at {openmp}: nothing to tell apart")
    with threadpool_limits(limits=2, user_api="blas"):
        assert kernel_threads() == 2 and thread_budget() == 1


def test_recorded_wall_time_covers_the_analysis_and_the_files(tmp_path):
    """summary.json's wall_s of a command-line run counts from the process start to the last result file:
    at least the time from before the call to summary.json's own write."""
    out = tmp_path / "s"
    t = time.time()
    assert main(["run", "lattice_sc", "--out", str(out), "--set", "compression.method=static"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    written = max(p.stat().st_mtime for p in out.iterdir() if p.suffix in (".png", ".h5", ".md"))
    assert summary["wall_s"] >= written - t - 0.02
    assert summary["wall_s"] > summary["static_s"] + summary["build_s"]
