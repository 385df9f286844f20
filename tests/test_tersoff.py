"""Tersoff track (seed 003): files, LAMMPS properties against Table 1, AD gradients, fit, stability."""
import json
import math

import jax
import numpy as np
import pytest

from opalflow.cli import main
from opalflow.spec import SpecError
from opalflow.tersoff import fit as fitting
from opalflow.tersoff.model import DiamondModel
from opalflow.tersoff.parameters import COLUMNS, TersoffParameters, format_tersoff, read_tersoff, write_tersoff
from opalflow.tersoff.properties import evaluate
from opalflow.tersoff.stability import Criteria, check
from opalflow.tersoff.parameters import REFERENCE_POTENTIAL

from conftest import assert_refused

REF = fitting.zhuravlev2021()
TABLE2 = read_tersoff(REFERENCE_POTENTIAL)


@pytest.fixture(scope="module")
def table2_lammps(tmp_path_factory):
    return evaluate(TABLE2, tmp_path_factory.mktemp("table2"), strain=1e-4)


# ----------------------------------------------------------------------------- files
def test_table2_file_holds_the_paper_values():
    assert (TABLE2.A, TABLE2.B, TABLE2.lambda1, TABLE2.lambda2, TABLE2.lambda3) == (
        3821.34, 113.17, 3.36252, 1.27279, 1.19417)
    assert (TABLE2.beta, TABLE2.n, TABLE2.gamma, TABLE2.c, TABLE2.d, TABLE2.costheta0) == (
        0.132272, 4.16334, 5.71477, 9.69902, 2.35646, -0.40882)
    assert (TABLE2.R, TABLE2.D, TABLE2.m) == (2.85, 0.15, 3.0)
    assert "Symmetry 2021, 13, 219" in REFERENCE_POTENTIAL.read_text()


def test_round_trip_is_exact(tmp_path):
    p = TABLE2.replace(A=3821.3400000000001 * (1 + 1e-13), gamma=1 / 3)
    back = read_tersoff(write_tersoff(tmp_path / "x.tersoff", p, "two\nline comment"))
    assert back == p


def test_multi_element_file_selects_the_entry(tmp_path):
    """Comments, an entry over several lines, other entries; the Si entry is picked."""
    si = [repr(float(v)) for v in TABLE2.values()]
    c = " ".join(repr(float(v)) for v in TABLE2.replace(A=1393.6, B=346.7).values())
    text = (f"# header\nC C C {c}  # carbon\n\nSi Si Si {' '.join(si[:6])}\n   {' '.join(si[6:])}\n"
            f"Si C C {c}\nC Si Si {c}\n")
    path = tmp_path / "SiC.tersoff"
    path.write_text(text)
    assert read_tersoff(path, "Si") == TABLE2
    assert read_tersoff(path, "C").A == 1393.6
    with pytest.raises(SpecError, match="no 'Ge Ge Ge' entry"):
        read_tersoff(path, "Ge")


@pytest.mark.parametrize("change,field", [({"m": 2.0}, "m"), ({"B": -1.0}, "B"), ({"D": 3.0}, "D"),
                                          ({"n": 0.0}, "n"), ({"A": math.nan}, "A")])
def test_validation_names_the_parameter(change, field):
    with pytest.raises(SpecError) as exc:
        TABLE2.replace(**change).validate()
    assert exc.value.field == f"tersoff.{field}"
    assert len(str(exc.value).splitlines()) == 1


def test_costheta0_outside_range_warns():
    with pytest.warns(UserWarning, match="costheta0"):
        TABLE2.replace(costheta0=-1.2).validate()


def test_truncated_file_is_refused(tmp_path):
    path = tmp_path / "bad.tersoff"
    path.write_text(format_tersoff(TABLE2).rsplit(" ", 1)[0] + "\n")
    with pytest.raises(SpecError, match="17 words"):
        read_tersoff(path)


# ----------------------------------------------------------------------------- properties
def test_table2_reproduces_table1_calculated_column(table2_lammps):
    """Acceptance 1: LAMMPS on Table 2's set gives Table 1's calculated column (1.5 GPa, 0.01 eV)."""
    ev = table2_lammps
    assert ev.Ec_eV == pytest.approx(REF.calculated["Ec_eV"], abs=REF.tolerance_energy_eV)
    for key, value in ev.values.items():
        assert value == pytest.approx(REF.calculated[key], abs=REF.tolerance_modulus_GPa), key
    assert ev.a0_A == pytest.approx(5.429, abs=0.002)


def test_lammps_finite_differences_match_exact_derivatives(table2_lammps):
    """LAMMPS (energies, minimised C44) and the AD model are independent: they agree to 1e-3 GPa."""
    exact = DiamondModel().evaluate(TABLE2, a=table2_lammps.a0_A)
    assert table2_lammps.Ec_eV == pytest.approx(exact["Ec_eV"], abs=1e-9)
    for key, value in table2_lammps.values.items():
        assert value == pytest.approx(exact[key], abs=1e-3), key
    assert DiamondModel().lattice_constant(TABLE2.values()) == pytest.approx(table2_lammps.a0_A, abs=1e-7)


def test_model_energy_does_not_depend_on_the_neighbour_list():
    """Candidates beyond the cutoff carry f_C = 0: first shell alone or three shells, same numbers."""
    near = DiamondModel(neighbor_radius_over_a=0.5).evaluate(TABLE2)
    far = DiamondModel(neighbor_radius_over_a=1.05).evaluate(TABLE2)
    for key in near:
        assert near[key] == pytest.approx(far[key], rel=1e-12, abs=1e-12), key


# ----------------------------------------------------------------------------- gradients and fit
def _loss():
    return fitting.Loss(targets=REF.targets, weights=fitting.default_weights(),
                        bounds=fitting.DEFAULT_BOUNDS, fixed=fitting.DEFAULT_FIXED)


def test_ad_gradient_matches_central_differences():
    """Acceptance 3: at random points, AD and central differences agree to 1e-6 (relative)."""
    loss = _loss()
    f = jax.jit(loss.scaled)
    rng = np.random.default_rng(11)
    h = 1e-5
    for _ in range(4):
        z = rng.uniform(0.05, 0.95, len(loss.free))
        _, g = loss.value_and_grad(z)
        g = np.asarray(g)
        fd = np.array([(float(f(z + h * e)) - float(f(z - h * e))) / (2 * h) for e in np.eye(len(z))])
        assert np.linalg.norm(fd - g) / np.linalg.norm(g) < 1e-6
        big = np.abs(g) > 1e-6 * np.linalg.norm(g)
        assert np.all(np.abs(fd - g)[big] / np.abs(g)[big] < 1e-6)
    # lambda3 (m = 3) cannot enter any target: r_ij - r_ik is first order in strain, its cube third
    assert g[loss.free.index("lambda3")] == 0.0


def test_loss_of_table2_and_of_its_own_properties():
    loss = _loss()
    props = loss.model.evaluate(TABLE2)
    by_hand = math.sqrt((props["dE_da_eV_per_A"] ** 2 + sum(
        ((props[k] - t) / t) ** 2 for k, t in REF.targets.items())) / 8)
    assert loss(TABLE2) == pytest.approx(by_hand, rel=1e-12)
    assert loss(TABLE2) == pytest.approx(0.031146, abs=2e-6)


def test_fit_from_random_starts_beats_table2():
    """Acceptance 2 (small): 4 seeded random starts reach a loss no larger than Table 2's."""
    loss = fitting.Loss(REF.targets, fitting.default_weights(), fitting.DEFAULT_BOUNDS, fitting.DEFAULT_FIXED)
    results = fitting.multistart(loss, starts=4, seed=1)
    assert results[0].loss <= loss(TABLE2)
    assert [r.loss for r in results] == sorted(r.loss for r in results)
    assert all(len(r.history) == r.iterations for r in results)
    best = TersoffParameters.from_values(results[0].params)
    assert {k: getattr(best, k) for k in ("m", "R", "D")} == {"m": 3.0, "R": 2.85, "D": 0.15}


# ----------------------------------------------------------------------------- stability
def test_table2_is_stable_and_a_bad_set_fails(tmp_path):
    """Acceptance 4 (short runs, 2 ps): Table 2 passes every boundary at 300 K; cos(theta0) = +0.5
    (60-degree bonds; its relaxed C44 is negative) breaks up with a reason."""
    good = check(TABLE2, tmp_path / "good", time_ps=2.0, workers=1)
    assert [r.boundary for r in good] == ["ppp", "ppf", "pff", "fff"]
    assert all(r.passed for r in good), [r.reason for r in good]
    assert all(r.fourfold_interior == 1.0 and r.atoms_lost == 0 for r in good)
    bad_set = TABLE2.replace(costheta0=0.5)
    assert DiamondModel().evaluate(bad_set, DiamondModel().lattice_constant(bad_set.values()))["C44_GPa"] < 0
    bad = check(bad_set, tmp_path / "bad", boundaries=("ppp", "fff"), time_ps=2.0, workers=1)
    assert not any(r.passed for r in bad)
    assert all("4-coordinated" in r.reason or "lost" in r.reason for r in bad)


def test_stability_criteria_are_applied(tmp_path):
    """The same run fails when the RMS limit is set below its thermal vibration."""
    strict = check(TABLE2, tmp_path, boundaries=("ppp",), time_ps=0.5, workers=1,
                   criteria=Criteria(max_rms_A=0.01))
    assert not strict[0].passed and "RMS" in strict[0].reason


# ----------------------------------------------------------------------------- workflows
def test_properties_workflow_with_set_potential(tmp_path, capsys):
    """--set points the workflow at any file; the summary carries the issue's keys."""
    other = write_tersoff(tmp_path / "mine.tersoff", TABLE2.replace(A=3900.0))
    out = tmp_path / "run"
    assert main(["run", "tersoff_properties", "--out", str(out), "--set", f'tersoff.potential="{other}"',
                 "--set", "tersoff.strain_scan=[1e-3]"]) == 0
    s = json.loads((out / "summary.json").read_text())
    for key in ("a0_A", "Ec_eV", "B_GPa", "Cprime_GPa", "C11_GPa", "C12_GPa", "C44_GPa", "C44_0_GPa",
                "loss", "reference_loss", "fit_s", "stability"):
        assert key in s
    assert s["mode"] == "properties" and "parameters" not in s        # TersoffResult: no key of the fit's
    # a stronger repulsion A: less binding and a longer bond than Table 2's set
    assert s["Ec_eV"] > REF.calculated["Ec_eV"] + 0.01 and s["a0_A"] > 5.44
    assert s["reference_loss"] == pytest.approx(0.031146, abs=2e-6)
    assert (out / "report.md").exists() and (out / "strain_scan.png").exists()
    assert read_tersoff(out / "potential.tersoff") == TABLE2.replace(A=3900.0)


@pytest.mark.parametrize("sets,field", [
    (['tersoff.potential="no_such.tersoff"'], "tersoff.potential"),
    (['tersoff.element="Si; shell touch x"'], "tersoff.element"),
    (["tersoff.targets={ G = 1.0 }"], "tersoff.targets.G"),
    (["tersoff.bounds={ A = [5.0, 1.0] }"], "tersoff.bounds.A"),
    (['stability.boundaries=["ppx"]'], "stability.boundaries[0]"),
    (["tersoff.fixed=[\"R\"]"], "tersoff.fixed"),
])
def test_bad_tersoff_spec_is_one_line(tmp_path, capsys, sets, field):
    out = tmp_path / "run"
    assert_refused(capsys, ["run", "tersoff_fit", "--out", str(out)], sets, field, out)


def test_columns_are_lammps_order():
    assert COLUMNS == ("m", "gamma", "lambda3", "c", "d", "costheta0", "n", "beta", "lambda2", "B", "R", "D",
                       "lambda1", "A")


def test_mpi_options_are_refused_for_atomistic_runs(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "tersoff_properties", "--out", str(out), "--np", "2"]) == 2
    assert capsys.readouterr().err.startswith("error: --np/--suffix/--resume = 'tersoff_properties'")
    assert not out.exists()
