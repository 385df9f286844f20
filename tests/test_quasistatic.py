"""Loadings as objects and the quasi-static fracture method (opalflow/bpm/loading.py,
opalflow/bpm/quasistatic.py): analytic strengths of the simple-cubic lattice pulled along its bonds, eq.
10.4 of the calibration in tension, the first branch against the static solver, both re-solve designs, a
run stopped by a scheduler's signal resumed to the same numbers, and the refusals."""
import dataclasses
import json
import math
import types
from pathlib import Path

import numpy as np
import pytest

import opalflow
from opalflow.bpm.loading import LOADINGS, Loading
from opalflow.cli import main
from opalflow.lammps import engine
from opalflow.spec import SpecError

TENSION = ["compression.loading=tension", "bonds.breakable=true", "compression.strain_max=0.02",
           "compression.snapshot_strains=[]"]
QUICK = ["compression.method=quasistatic", "compression.snapshot_strains=[]", "compression.strain_max=0.03"]


def sc_strength(sigma_b=94.3, f=1.0):
    """sigma_b pi r_b^2 / a^2 with r_b = f a / 2 (silica bonds, Dosta et al. Table 1)."""
    return sigma_b * math.pi * f**2 / 4


def test_sc_lattice_in_tension_breaks_at_the_bond_strength_quasistatic(tmp_path):
    s = opalflow.run("lattice_sc", tmp_path / "q", set=[*TENSION, "compression.method=quasistatic"], quiet=True)
    assert s["strength_MPa"] == pytest.approx(sc_strength(), rel=1e-3)
    assert s["youngs_modulus_GPa"] == pytest.approx(s["reference"]["youngs_modulus_specimen_GPa"]["value"], rel=1e-6)
    assert s["strain_at_peak"] == pytest.approx(94.3 / 6530, rel=1e-3)       # sigma_b / E_b
    assert s["broken_bonds_by_material"] == {"silica": s["broken_bonds"]} and s["broken_bonds"] >= 1
    for name in ("fracture.png", "stress_strain.png", "fracture.peak.dump", "fracture.end.dump", "results.h5"):
        assert (tmp_path / "q" / name).exists(), name
    dump = (tmp_path / "q" / "fracture.end.dump").read_text().splitlines()
    assert dump[8] == "ITEM: ATOMS id type x y z radius broken_bonds" and len(dump) == 9 + s["n_particles"]


def test_sc_lattice_in_tension_dynamic_run_of_the_tension_loading(tmp_path):
    """The new tension loading through LAMMPS (bonds break at full load: smooth no) within 2 %; with LAMMPS's
    smoothing (1 - B^4) the same lattice peaks near B = 5^(-1/4), at 0.535 of it."""
    sets = [*TENSION, "bonds.smooth=false", "compression.plate_speed_m_s=0.5", "compression.output_every_strain=5e-5"]
    s = opalflow.run("lattice_sc", tmp_path / "d", set=sets, quiet=True)
    assert s["strength_MPa"] == pytest.approx(sc_strength(), rel=0.02)
    assert s["strain_at_peak"] > 0 and s["broken_bonds"] >= 16          # the 4 x 4 columns all broke
    deck = (tmp_path / "d" / "in.lmp").read_text()
    assert "uniaxial tension" in deck and "move linear 0.0 0.0 0.5 units box" in deck and "smooth no" in deck
    smooth = opalflow.run("lattice_sc", tmp_path / "s", set=[*sets[:-2], "bonds.smooth=true",
                                                              "compression.plate_speed_m_s=0.5"], quiet=True)
    assert smooth["strength_MPa"] / s["strength_MPa"] == pytest.approx(0.8 * 5 ** -0.25, rel=0.05)


@pytest.mark.parametrize("rule", ["dosta", "musen", "musen_2020", "musen_crit2"])
def test_sc_lattice_in_tension_breaks_at_the_bond_strength_by_the_papers_rules(tmp_path, rule):
    """Pulled along its bonds a bond carries its normal force alone: the paper's rules (eqs. 16-17) and MUSEN's
    (2020's, whose terms cancel, and its second criterion, each term alone) break it where LAMMPS's does, at
    sigma_b pi r_b^2 / a^2, by the rule's normal check."""
    from opalflow.bpm.quasistatic import CHECKS
    from opalflow.bpm.spec import BREAKING_RULES

    s = opalflow.run("lattice_sc", tmp_path / rule, set=[*TENSION, "compression.method=quasistatic",
                                                          f'bonds.breaking="{rule}"'], quiet=True)
    assert s["strength_MPa"] == pytest.approx(sc_strength(), rel=1e-3)
    report = (tmp_path / rule / "report.md").read_text()
    assert BREAKING_RULES[rule] in report and "| length bin | " + " | ".join(CHECKS[rule]) + " |" in report
    # pulled along their axis, the bonds break by the normal check, each in its length bin
    normal, *others = CHECKS[rule]
    assert s["broken_bonds_by_check"] == {normal: {"silica 1.000-1.000": s["broken_bonds"]},
                                          **{name: {} for name in others}}


def test_each_broken_bond_names_its_check_and_length_bin(quick):
    """results.h5 stores, for every broken bond in order, the check that broke it and its length; the summary's
    counts by check and bin add up to the bonds broken, in all and before the peak; the report tables them."""
    import h5py

    root, q = quick
    counts = {name: sum(by_bin.values()) for name, by_bin in q["broken_bonds_by_check"].items()}
    assert sum(counts.values()) == q["broken_bonds"] and set(counts) == {"normal + bending", "shear + twist"}
    assert sum(sum(b.values()) for b in q["broken_bonds_by_check_at_peak"].values()) == q["broken_bonds_at_peak"]
    with h5py.File(root / "direct" / "results.h5") as h:
        g = h["quasistatic"]
        check, length = g["broken_bond_check"][:], g["broken_bond_length_nm"][:]
        assert len(check) == len(length) == len(g["broken_bond_index"]) == q["broken_bonds"]
    assert np.bincount(check, minlength=2).tolist() == [counts["normal + bending"], counts["shear + twist"]]
    assert np.all((length > 0.99 * 60) & (length < 1.75 * 60))
    assert "| length bin | normal + bending | shear + twist |" in (root / "direct" / "report.md").read_text()


def test_a_network_that_holds_to_strain_max_says_so(tmp_path):
    """The simple-cubic lattice compressed along its bonds: pressed bonds never break by LAMMPS's rule, so no
    event happens; the strength is NaN and the headline says why instead of printing it."""
    s = opalflow.run("lattice_sc", tmp_path / "c", set=["compression.method=quasistatic", "bonds.breakable=true"],
                     quiet=True)
    assert s["quasistatic"]["events"] == 0 and math.isnan(s["strength_MPa"])
    assert "no bond reached its limit before the run stopped (the network holds to strain_max = " in s["headline"]
    assert "nan" not in s["headline"]


def test_breaking_rules_weigh_the_bond_loads_as_written():
    """breaking_index by rule against the four load ratios computed here (quickstart's network, random
    displacements and rotations): LAMMPS's one sum with the signed normal force; the paper's eqs. 16-17 as
    the larger of the normal (|Fr| and bending) and the shear (shear force and twisting) ratio; MUSEN's with
    Fr signed.  LAMMPS's index is the sum of MUSEN's two, so never below MUSEN's where both are positive."""
    from opalflow.bpm.quasistatic import Strengths, bond_checks, breaking_index
    from tests.test_static import scene

    _, _, net = scene("quickstart")
    rng = np.random.default_rng(3)
    x = rng.normal(scale=1e-2, size=(net.n_particles, 6))
    m = len(net.L)
    c = [rng.uniform(0.5, 2.0, m) * k for k in (1e3, 1e3, 1e4, 1e4)]
    F = net.bond_forces(x[:, :3], x[:, 3:])
    fr = np.einsum("ij,ij->i", net.n, F)
    fs = np.linalg.norm(F - fr[:, None] * net.n, axis=1)
    d = x[net.i, 3:] - x[net.j, 3:]
    tw = np.einsum("ij,ij->i", net.n, d)
    bt = np.linalg.norm(d - tw[:, None] * net.n, axis=1)
    shear = fs / c[1] + net.twist * np.abs(tw) / c[3]
    normal = net.bend * bt / c[2]
    got = {rule: breaking_index(net, x, Strengths(*c, rule))
           for rule in ("lammps", "dosta", "musen", "musen_2020", "musen_crit2")}
    checks = bond_checks(net, x, Strengths(*c, "musen"))
    assert np.allclose(checks[0], fr / c[0] + normal, rtol=1e-12) and np.allclose(checks[1], shear, rtol=1e-12)
    assert np.allclose(bond_checks(net, x, Strengths(*c, "dosta"))[0], np.abs(fr) / c[0] + normal, rtol=1e-12)
    assert np.allclose(got["lammps"], fr / c[0] + normal + shear, rtol=1e-12)
    assert np.allclose(got["dosta"], np.maximum(np.abs(fr) / c[0] + normal, shear), rtol=1e-12)
    assert np.allclose(got["musen"], np.maximum(fr / c[0] + normal, shear), rtol=1e-12)
    stretched = fr > 0
    assert 0 < stretched.sum() < m
    assert np.array_equal(got["dosta"][stretched], got["musen"][stretched])
    assert np.all(got["dosta"] >= got["musen"]) and np.any(got["dosta"] > got["musen"])
    both = fr / c[0] + normal > 0
    assert np.all(got["lammps"][both] >= got["musen"][both]) and np.any(got["lammps"] < got["musen"])
    # MUSEN's code of 2020 (655e066): |M_b| R / I - |F_n| / A over sigma in tension, |M_t| R / J - |F_t| / A over
    # tau; MUSEN's second criterion: each term alone, bending in tension only
    twist = net.twist * np.abs(tw) / c[3]
    r_n, r_b, r_s = fr / c[0], normal, fs / c[1]
    assert np.allclose(got["musen_2020"], np.maximum(np.where(stretched, np.abs(r_b - np.abs(r_n)), 0.0),
                                                     np.abs(twist - r_s)), rtol=1e-12)
    assert np.allclose(got["musen_crit2"], np.max([r_n, np.where(stretched, r_b, 0.0), r_s, twist], axis=0),
                       rtol=1e-12)
    # |a - b| <= max(a, b) <= a + b for a, b >= 0: the 2020 rule's index never above the second criterion's, that
    # never above the additive one's (so the strengths come in the reverse order)
    assert np.all(got["musen_2020"] <= got["musen_crit2"] + 1e-12) and np.any(got["musen_2020"] < got["musen_crit2"])
    assert np.all(got["musen_crit2"] <= got["musen"] + 1e-12) and np.any(got["musen_crit2"] < got["musen"])
    # positively homogeneous (the events' e = 1 / max B_1): twice the field, twice every index; the sign of Fr kept
    for rule in ("musen_2020", "musen_crit2"):
        assert np.allclose(breaking_index(net, 2 * x, Strengths(*c, rule)), 2 * got[rule], rtol=1e-12)
    assert bond_checks(net, x, Strengths(*c, "musen_crit2")).shape == (4, m)


def test_breaking_indices_on_threads_are_the_same(monkeypatch):
    """breaking_index with its bonds in two threads' shares (the paper's 17.5 M bonds), per-bond strengths and
    strengths by type, each rule folded and unfolded: the same digits as on one thread."""
    from opalflow.bpm import quasistatic, stiffness
    from opalflow.bpm.quasistatic import CHECKS, Strengths, bond_checks, breaking_index
    from tests.test_static import scene

    _, _, net = scene("quickstart")
    rng = np.random.default_rng(4)
    x = rng.normal(scale=1e-2, size=(net.n_particles, 6))
    m = len(net.L)
    per_bond = [rng.uniform(0.5, 2.0, m) * k for k in (1e3, 1e3, 1e4, 1e4)]
    index = rng.integers(0, 3, m).astype(np.int32)
    tables = [rng.uniform(0.5, 2.0, 3) * k for k in (1e3, 1e3, 1e4, 1e4)]
    cases = [Strengths(*per_bond, rule) for rule in CHECKS] + [Strengths(*tables, rule, index) for rule in CHECKS]
    one = [(breaking_index(net, x, c), bond_checks(net, x, c)) for c in cases]
    for module in (quasistatic, stiffness):
        monkeypatch.setattr(module, "PARTS_MIN_BONDS", 1)
    monkeypatch.setattr(stiffness, "NUMPY_MAX_BONDS", 1)
    monkeypatch.setattr(quasistatic, "kernel_threads", lambda: 2)
    for c, (index_one, checks_one) in zip(cases, one):
        assert np.array_equal(breaking_index(net, x, c), index_one) and np.array_equal(bond_checks(net, x, c),
                                                                                       checks_one), c.rule


def test_contacts_press_in_compression_and_open_in_tension(tmp_path):
    """The simple-cubic lattice with its nearest-neighbour bonds left out (bonds.min_length_factor; the sqrt(2) a
    and sqrt(3) a bonds hold it) has touching unbonded neighbours.  Compressed under periodic sides (uniaxial
    strain, affine), each column of contacts is a chain of springs k_n one spacing a apart: E grows by k_n / a,
    whatever the friction (nothing slips); pulled, the contacts open and E is the bonds' alone."""
    from opalflow.bpm.contacts import hertz_mindlin_springs
    from opalflow.materials import contact_properties

    base = ["compression.method=quasistatic", "bonds.breakable=true", "bonds.cutoff_factor=1.75",
            "bonds.min_length_factor=1.1", "contacts.enabled=true", "compression.strain_max=0.004"]
    E = {}
    for loading in ("plate", "tension"):
        for mode in ("off", "frictionless", "sticking"):
            s = opalflow.run("lattice_sc", tmp_path / f"{loading}-{mode}", quiet=True,
                             set=[*base, f"compression.loading={loading}", f'contacts.quasistatic="{mode}"'])
            E[loading, mode] = s["youngs_modulus_GPa"]
    silica = contact_properties("silica")
    k_n = hertz_mindlin_springs(silica, silica, np.array([10.0]), np.array([10.0]), 0.01)[0][0]    # a = d = 20 nm
    assert E["plate", "frictionless"] - E["plate", "off"] == pytest.approx(k_n / 20.0 / 1e3, rel=1e-6)
    assert E["plate", "sticking"] == pytest.approx(E["plate", "frictionless"], rel=1e-9)
    assert E["tension", "frictionless"] == pytest.approx(E["tension", "off"], rel=1e-9)
    assert E["tension", "sticking"] == pytest.approx(E["tension", "off"], rel=1e-9)
    report = (tmp_path / "plate-sticking" / "report.md").read_text()
    assert 'Contacts (`contacts.quasistatic = "sticking"`' in report


def test_contacts_give_the_same_fracture_by_every_resolver(tmp_path):
    """quickstart with sticking contacts, its first 30 events: the factor with Woodbury updates (contacts closing as
    well as bonds breaking) and CG on the damaged network find the same peak; broken pressed bonds leave contacts
    pressing."""
    sets = [*QUICK, "bonds.smooth=false", 'bonds.breaking="musen"', 'contacts.quasistatic="sticking"',
            "compression.events_max=30"]
    got = {r: opalflow.run("quickstart", tmp_path / r, set=[*sets, f"compression.resolver={r}"], quiet=True)
           for r in ("direct", "amg")}
    assert got["amg"]["strength_MPa"] == pytest.approx(got["direct"]["strength_MPa"], rel=1e-3)
    q = got["direct"]["quasistatic"]
    assert q["contacts"] == "sticking" and q["contact_pairs"] > 0 and q["contacts_pressing_at_end"] > 0


def test_eq_10_4_calibration_measured_in_tension(tmp_path):
    """Roy and Hossain eqs. 10.3-10.4 (opalflow.bpm.spec.first_estimate): a simple-cubic array calibrated to
    E = 3 GPa and sigma_t = 40 MPa has that E and that tensile strength."""
    s = opalflow.run("lattice_sc", tmp_path / "c", set=[*TENSION, "compression.method=quasistatic",
                                                         "calibration.target_E_GPa=3",
                                                         "calibration.target_tensile_strength_MPa=40"], quiet=True)
    assert s["youngs_modulus_GPa"] == pytest.approx(3.0, rel=1e-6)
    assert s["strength_MPa"] == pytest.approx(40.0, rel=1e-3)


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    root = tmp_path_factory.mktemp("quasistatic")
    return root, opalflow.run("quickstart", root / "direct", set=QUICK, quiet=True)


def test_first_branch_is_the_static_modulus(quick, tmp_path):
    _, q = quick
    st = opalflow.run("quickstart", tmp_path / "static", set=["compression.method=static",
                                                                  "compression.snapshot_strains=[]"], quiet=True)
    assert q["youngs_modulus_GPa"] == pytest.approx(st["youngs_modulus_GPa"], rel=1e-6)
    assert q["strength_MPa"] > 0 and 0 < q["strain_at_peak"] < 0.03
    assert q["broken_bonds_at_peak"] < q["broken_bonds"] and q["quasistatic"]["resolver"] == "direct"


@pytest.mark.parametrize("resolver", ["amg", "block-amg"])
def test_every_resolver_breaks_the_same_bonds(quick, tmp_path, resolver):
    """The iterative re-solves (warm-started CG to 1e-6 |b|) against the factor: the same bonds in the same
    order, strength and strain at peak within 5e-5, E within 1e-6."""
    root, direct = quick
    other = opalflow.run("quickstart", tmp_path / resolver, set=[*QUICK, f"compression.resolver={resolver}"],
                         quiet=True)
    assert other["quasistatic"]["resolver"] == resolver and other["quasistatic"]["cg_iterations"] > 0
    for key, rel in (("strength_MPa", 5e-5), ("strain_at_peak", 5e-5), ("youngs_modulus_GPa", 1e-6)):
        assert other[key] == pytest.approx(direct[key], rel=rel), key
    import h5py

    with h5py.File(root / "direct" / "results.h5") as a, h5py.File(tmp_path / resolver / "results.h5") as b:
        assert np.array_equal(a["quasistatic/broken_bond_index"][()], b["quasistatic/broken_bond_index"][()])


def test_auto_takes_what_fits_the_size(quick, tmp_path, monkeypatch):
    """compression.resolver = auto: the factor up to DIRECT_MAX_DOFS free dofs (the quickstart), amg up to
    RESOLVE_AMG_MAX_BONDS bonds, block-amg above (the paper's 17.5 M bonds; here the bounds lowered to the
    quickstart)."""
    from opalflow.bpm import quasistatic

    _, direct = quick
    assert direct["quasistatic"]["resolver"] == "direct"
    monkeypatch.setattr(quasistatic, "DIRECT_MAX_DOFS", 100)
    for bound, expected in ((10**9, "amg"), (1000, "block-amg")):
        monkeypatch.setattr(quasistatic, "RESOLVE_AMG_MAX_BONDS", bound)
        got = opalflow.run("quickstart", tmp_path / expected, set=[*QUICK, "compression.events_max=2"], quiet=True)
        assert got["quasistatic"]["resolver"] == expected


def test_a_looser_resolve_costs_fewer_iterations_within_a_percent(quick, tmp_path):
    """compression.resolve_rtol = 1e-4 (the fast setting of the README's d = 30 nm rows): amg's re-solves take
    under half the CG iterations of 1e-6, the strength and strain at peak within 1 % of the factor's."""
    _, direct = quick
    runs = {rtol: opalflow.run("quickstart", tmp_path / f"rtol{rtol:g}", quiet=True,
                               set=[*QUICK, "compression.resolver=amg", f"compression.resolve_rtol={rtol}"])
            for rtol in (1e-6, 1e-4)}
    assert runs[1e-4]["quasistatic"]["cg_iterations"] < 0.5 * runs[1e-6]["quasistatic"]["cg_iterations"]
    for key in ("strength_MPa", "strain_at_peak"):
        assert runs[1e-4][key] == pytest.approx(direct[key], rel=0.01), key


def test_local_steps_settle_events_between_global_resolves(quick, tmp_path):
    """compression.local_rtol: events settle by the local step until the residual passes the bound, with fewer
    CG iterations; on a sample this coarse one bond carries a large part of the load and the local steps'
    error shows (3e-4: strength +3.7 % against the factor's; 1e-4: no event settles). At d = 45 nm, 3e-5: -0.15 %
    against every event re-solved (bench/results/quasistatic_scale.json)."""
    _, direct = quick
    runs = {lr: opalflow.run("quickstart", tmp_path / f"local{lr:g}", quiet=True,
                             set=[*QUICK, "compression.resolver=amg", "compression.resolve_rtol=1e-5",
                                  f"compression.local_rtol={lr}"]) for lr in (1e-4, 3e-4)}
    assert runs[1e-4]["quasistatic"]["settled_locally"] == 0
    assert runs[1e-4]["strength_MPa"] == pytest.approx(direct["strength_MPa"], rel=1e-3)
    q = runs[3e-4]["quasistatic"]
    assert 0 < q["settled_locally"] < q["events"]
    assert q["cg_iterations"] < runs[1e-4]["quasistatic"]["cg_iterations"]
    assert runs[3e-4]["strength_MPa"] == pytest.approx(direct["strength_MPa"], rel=0.05)


def test_a_signal_stops_the_events_and_resume_gives_the_same_numbers(quick, tmp_path):
    _, whole = quick
    out = tmp_path / "stopped"
    engine.request_stop("SIGUSR1")           # as the job's handler does when SLURM signals: stop at the next event
    with pytest.raises(engine.Preempted):
        opalflow.run("quickstart", out, set=QUICK, quiet=True)
    state = json.loads((out / "quasistatic_state.json").read_text())
    assert len(state["events"]) == 1 and not (out / "summary.json").exists()
    again = opalflow.run(None, out, resume=True, quiet=True)
    for key in ("strength_MPa", "strain_at_peak", "youngs_modulus_GPa", "broken_bonds"):
        assert again[key] == pytest.approx(whole[key], rel=1e-9), key
    record = json.loads((out / "run.json").read_text())
    assert len(record["sessions"]) == 2 and record["sessions"][1]["restart"] == "quasistatic_state.json"
    assert not (out / "quasistatic_state.json").exists()


def _dump_numbers(path):
    lines = path.read_text().splitlines()
    return lines[:5] + lines[8:9], np.loadtxt(lines[5:8]), np.loadtxt(lines[9:])


def test_a_run_stopped_after_its_peak_resumes_to_the_same_fracture_dumps(quick, tmp_path, monkeypatch):
    """Stopped one event before the end (after the peak), the resumed run's fracture dumps are the
    uninterrupted run's: the peak's displacements come back from the state (quasistatic_peak.npy)."""
    root, whole = quick
    n = whole["quasistatic"]["events"]
    assert n >= 3 and whole["broken_bonds_at_peak"] < whole["broken_bonds"]     # the peak comes before the end
    calls = []
    monkeypatch.setattr("opalflow.bpm.quasistatic_run.stop_requested", lambda: calls.append(1) or len(calls) == n - 1)
    out = tmp_path / "stopped"
    with pytest.raises(engine.Preempted):
        opalflow.run("quickstart", out, set=QUICK, quiet=True)
    state = json.loads((out / "quasistatic_state.json").read_text())
    assert len(state["events"]) == n - 1 and state["peak_event"] >= 0 and (out / "quasistatic_peak.npy").exists()
    monkeypatch.setattr("opalflow.bpm.quasistatic_run.stop_requested", lambda: False)
    again = opalflow.run(None, out, resume=True, quiet=True)
    assert again["strength_MPa"] == pytest.approx(whole["strength_MPa"], rel=1e-9)
    for tag in ("peak", "end"):
        head, box, rows = _dump_numbers(out / f"fracture.{tag}.dump")
        head0, box0, rows0 = _dump_numbers(root / "direct" / f"fracture.{tag}.dump")
        assert head == head0 and np.array_equal(box, box0)
        assert np.allclose(rows, rows0, atol=2e-6), tag
    from opalflow.lammps.datafile import read_data

    peak = np.loadtxt((out / "fracture.peak.dump").read_text().splitlines()[9:])
    built = read_data(out / "data.lmp")
    assert np.abs(peak[np.argsort(peak[:, 0]), 2:5] - built.positions).max() > 1e-3    # deformed, not data.lmp's
    assert not (out / "quasistatic_peak.npy").exists()


@pytest.mark.parametrize("damage", ["truncated", "no events", "bad event"])
def test_a_damaged_state_is_one_line_and_changes_nothing(quick, tmp_path, capsys, damage):
    """A quasistatic_state.json cut short or without its events: `run --resume` says so in one line, exit 2
    (not a regression's 1), and leaves run.json as it was."""
    out = tmp_path / "stopped"
    engine.request_stop("SIGUSR1")
    with pytest.raises(engine.Preempted):
        opalflow.run("quickstart", out, set=QUICK, quiet=True)
    path = out / "quasistatic_state.json"
    text = path.read_text()
    path.write_text({"truncated": text[:len(text) // 2], "no events": '{"modulus_MPa": 1.0}',
                     "bad event": '{"events": [{"strain": 1}], "modulus_MPa": 1.0}'}[damage])
    record = (out / "run.json").read_text()
    capsys.readouterr()
    assert main(["run", "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and "without --resume" in err, err
    assert (out / "run.json").read_text() == record


def test_event_tolerance_breaks_more_bonds_per_event(quick, tmp_path):
    _, exact = quick
    loose = opalflow.run("quickstart", tmp_path / "tol", set=[*QUICK, "compression.event_tolerance=0.05"], quiet=True)
    assert loose["quasistatic"]["events"] <= exact["quasistatic"]["events"]
    assert loose["strength_MPa"] == pytest.approx(exact["strength_MPa"], rel=0.1)


def test_a_new_loading_is_one_class_and_one_registry_line():
    """The loadings the deck and the solvers know come from the registry; each one's blocks render."""
    assert set(LOADINGS) == {"plate", "glued", "tension", "bending"}
    assert all(isinstance(v, Loading) and v.name == k for k, v in LOADINGS.items())
    sample = types.SimpleNamespace(plate_z0_nm=100.0, base_nm=5.0)
    blocks = LOADINGS["tension"].blocks(sample, 1.0, 2, 90.0, "")
    assert "move linear 0.0 0.0 1.0" in blocks["plate"] and "ramp vz 0.0 1.0" in blocks["affine_start"]


def test_methods_are_objects_that_check_their_spec_and_have_a_runner_each():
    """compression.method -> opalflow.bpm.methods.METHODS: each has its runner side by side in
    opalflow.bpm.run.RUNNERS, its options are the runner's keywords, and the refusals of what it cannot compute
    come from it, before anything is written."""
    import inspect

    from opalflow.bpm.methods import METHODS
    from opalflow.bpm.run import RUNNERS, run_workflow

    assert set(METHODS) == set(RUNNERS) == {"dynamic", "static", "quasistatic"}
    for name, method in METHODS.items():
        params = inspect.signature(RUNNERS[name].run).parameters
        assert method.name == name and set(method.options) <= set(params), name
        assert ("resume" in method.options) == (RUNNERS[name].resumable is not None), name
    assert [m.linear for m in METHODS.values()] == [False, True, True]
    from opalflow.registry import load_spec
    from opalflow.resources import WORKFLOWS

    spec = load_spec(WORKFLOWS / "lattice_sc.toml", ["compression.method=static"])
    with pytest.raises(SpecError, match="compression.method = 'static': a static solve has no --resume"):
        run_workflow(spec, Path("/nonexistent"), resume=True)


@pytest.mark.parametrize("sets, field", [
    (["compression.method=quasistatic", "bonds.breakable=false"], "bonds.breakable"),
    (["compression.method=quasistatic", 'bonds.model="contact"'], "bonds.model"),
    (["compression.loading=pull"], "compression.loading"),
    (["compression.method=quasistatic", "bonds.breakable=true", "compression.resolver=lu"], "compression.resolver"),
    (["compression.method=quasistatic", "bonds.breakable=true", "compression.local_rtol=1e-7"],
     "compression.local_rtol"),
    (['bonds.breaking="dosta"'], "bonds.breaking"),
    (["compression.method=quasistatic", "bonds.breakable=true", 'bonds.breaking="potyondy"'], "bonds.breaking"),
    (["bonds.min_length_factor=1.75"], "bonds.min_length_factor"),
    (['contacts.quasistatic="sticking"'], "contacts.quasistatic"),
    (["compression.method=quasistatic", "bonds.breakable=true", "contacts.enabled=true",
      'contacts.quasistatic="coulomb"'], "contacts.quasistatic"),
    (["compression.method=quasistatic", "bonds.breakable=true", "contacts.enabled=true",
      'contacts.quasistatic="sticking"', "compression.local_rtol=1e-4"], "compression.local_rtol"),
    (["bonds.min_length_factor=-0.1"], "bonds.min_length_factor"),
])
def test_refusals_are_one_line_and_write_nothing(tmp_path, capsys, sets, field):
    out = tmp_path / "no"
    args = ["run", "lattice_sc", "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and field in err[0]
    assert not out.exists()


def test_tension_on_a_packing_without_bonds_is_refused(tmp_path, capsys):
    """A data file with no bonds pulled in tension: one line naming the field, nothing written (every
    bonded-particle scene refuses a structure without bonds before its loading is looked at)."""
    from opalflow.bpm.pipeline import build_structure
    from opalflow.lammps.datafile import write_data
    from opalflow.registry import load_spec
    from opalflow.resources import WORKFLOWS

    s = build_structure(load_spec(WORKFLOWS / "lattice_sc.toml", []))
    s = dataclasses.replace(s, bonds=np.zeros((0, 2), int), bond_types=np.zeros(0, int), bond_type_names=[])
    write_data(tmp_path / "loose.lmp", s)
    out = tmp_path / "no"
    code = main(["run", "lattice_sc", "--out", str(out), "--set", "kind=datafile", "--set", "compression.loading=tension",
                 "--set", f'datafile.path="{tmp_path / "loose.lmp"}"', "--set", 'datafile.materials=["silica","substrate"]'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "datafile.path" in err[0] and "no bonds" in err[0], err
    assert not out.exists()


def test_local_step_keeps_the_internal_force_and_relaxes_its_patch():
    """LocalSettle (compression.local_rtol): a broken bond's force leaves f = K x, the particles within
    LOCAL_HOPS intact bonds of it move so that their free dofs are in equilibrium (residual at round-off), no
    other particle moves, f stays K x of the damaged network (kept up to date, not recomputed), and every bond
    with an end that moved is among those it returns (whose B the event loop renews)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import shortest_path

    from opalflow.bpm.quasistatic import LOCAL_HOPS, Adjacency, LocalSettle
    from tests.test_static import scene

    _, sample, net = scene("quickstart")
    n, m = net.n_particles, len(net.L)
    x = np.random.default_rng(7).normal(scale=1e-2, size=6 * n)
    free = np.repeat(~sample.structure.groups["substrate"], 6)
    x[~free] = 0.0
    force = net.matvec(x)
    broken = np.array([int(np.argmax(net.L))])          # (any bond: the longest)
    settle = LocalSettle(net, Adjacency(net))
    settle.release(x, force, broken)
    alive = np.ones(m, bool)
    alive[broken] = False
    damaged = dataclasses.replace(net, a_r=net.a_r * alive, a_s=net.a_s * alive, bend=net.bend * alive,
                                  twist=net.twist * alive)
    assert np.allclose(force, damaged.matvec(x), rtol=0, atol=1e-12 * np.abs(force).max())
    before = x.copy()
    touched = settle(x, force, broken, alive, free)
    assert np.allclose(force, damaged.matvec(x), rtol=0, atol=1e-10 * np.abs(force).max())
    graph = sp.coo_matrix((np.ones(m - 1), (net.i[alive], net.j[alive])), shape=(n, n))
    ends = [net.i[broken[0]], net.j[broken[0]]]
    hops = shortest_path(graph, directed=False, unweighted=True, indices=ends).min(axis=0)
    patch = np.repeat(hops <= LOCAL_HOPS, 6)
    moved = np.repeat((x != before).reshape(n, 6).any(axis=1), 6)
    assert moved.any() and not np.any(moved & ~patch)
    ends_moved = moved.reshape(n, 6)[:, 0]
    assert set(np.flatnonzero(alive & (ends_moved[net.i] | ends_moved[net.j]))) <= set(touched)   # (B kept there)
    assert np.abs(force[patch & free]).max() < 1e-9 * np.abs(force).max()
    assert np.abs(force[~patch & free]).max() > 1e-3 * np.abs(force).max()      # (the rest untouched)



def test_the_loose_particles_are_those_of_the_connected_components():
    """Adjacency.reached (the event loop's loose particles: no copy of the network) against the definition by the
    connected components of the intact bonds (opalflow.bpm.static.loose_particles), with a cluster cut off."""
    from opalflow.bpm.loading import LOADINGS
    from opalflow.bpm.quasistatic import Adjacency
    from opalflow.bpm.static import loose_particles
    from tests.test_static import scene

    spec, sample, net = scene("quickstart")
    anchored = LOADINGS[spec.compression.loading].supports(sample).anchored
    alive = np.ones(len(net.L), bool)
    middle = np.median(sample.structure.positions[:, 2])
    z = sample.structure.positions[:, 2]
    alive[(z[net.i] < middle) != (z[net.j] < middle)] = False          # the upper half cut off
    loose = ~Adjacency(net).reached(alive, anchored)
    assert np.array_equal(loose, loose_particles(net.part(alive), anchored))
    assert 0 < loose.sum() < net.n_particles and not loose[anchored].any()


def test_a_search_round_the_broken_bonds_tells_whether_anything_came_loose():
    """Adjacency.still_joined, which spares the event loop the connected components of the whole network:
    true where every broken bond's ends still meet (the components unchanged), false where a particle lost its
    last bond."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    from opalflow.bpm.quasistatic import Adjacency
    from tests.test_static import scene

    _, _, net = scene("quickstart")
    n, m = net.n_particles, len(net.L)

    def components(alive):
        graph = sp.coo_matrix((np.ones(int(alive.sum())), (net.i[alive], net.j[alive])), shape=(n, n))
        return connected_components(graph, directed=False)[0]

    adjacency, alive = Adjacency(net), np.ones(m, bool)
    longest = np.array([int(np.argmax(net.L))])
    alive[longest] = False
    assert adjacency.still_joined(alive, net.i[longest], net.j[longest])
    assert components(alive) == components(np.ones(m, bool))
    own = np.flatnonzero((net.i == net.i[0]) | (net.j == net.i[0]))       # every bond of one particle
    alive[own] = False
    assert not adjacency.still_joined(alive, net.i[own], net.j[own])
    assert components(alive) == components(np.ones(m, bool)) + 1


def test_the_quasistatic_report_has_the_inputs_the_why_and_the_provenance(quick, tmp_path, monkeypatch):
    """The quasi-static report was thinner than the dynamic one: no inputs table, errors of -86 % with no
    "why the error", "structure built in 0.0 s" where the cache line said 1.8 s, results.h5 without the
    provenance group the README lists."""
    import h5py

    root, _ = quick
    text = (root / "direct" / "report.md").read_text()
    assert "## Inputs" in text and "| breaking rule |" in text and "| re-solves |" in text
    assert "| why the error |" in text and "resolution: d = 60 nm" in text          # the quickstart's -86 %
    with h5py.File(root / "direct" / "results.h5", "r") as h:
        assert {"spec", "lammps_version", "git_commit", "seeds", "run"} <= set(h["provenance"].attrs)
    monkeypatch.setenv("OPALFLOW_CACHE", str(tmp_path / "cache"))
    opalflow.run("quickstart", tmp_path / "first", set=QUICK, quiet=True)
    opalflow.run("quickstart", tmp_path / "again", set=QUICK, quiet=True)
    assert "; structure built in " in (tmp_path / "first" / "report.md").read_text()
    again = (tmp_path / "again" / "report.md").read_text()
    assert "structure read from the cache in " in again and "(first built in " in again
