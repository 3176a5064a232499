"""Bad input for the water models gets one clear error naming the problem and the fix."""

from pathlib import Path

import pytest

from harness import cases, runner
from harness.cases import CaseError
from harness.solver import CpdiError

REPO = Path(__file__).resolve().parents[1]
TANK = REPO / "cases" / "resting_tank.toml"
DAM_BREAK = REPO / "cases" / "dam_break.toml"
# the dam break's real water: its case file defaults to the incompressible water (issue 38)
REAL_WATER = ['solver.fluid="weakly_compressible"', 'solver.transfer="flip"', 'solver.projection="cell"']


def test_hopeless_time_step_is_refused_before_running(tmp_path):
    # real water (K = 2.13 GPa) on the dam break's grid forces dt = 2e-6 s: 1000 s would take 5e8 steps
    case = cases.load(DAM_BREAK, [*REAL_WATER, "solver.t_end=1000"])
    with pytest.raises(CaseError, match=r"sound speed 14\d\d m/s of material 'water'.*max_estimated_steps"):
        runner.run(case, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()  # refused before any output is touched


def test_hopeless_limit_can_be_raised():
    case = cases.load(DAM_BREAK, [*REAL_WATER, "solver.t_end=1000", "solver.max_estimated_steps=1e9"])
    sim, _ = runner.build(case)
    runner.check_feasible(case, sim)  # no error: the user asked for it
    sim.close()


def test_incompressible_with_a_solid_needs_contact_off_and_a_water():
    # solids couple to the incompressible water as one continuum (issue 21, cpdi_fsi): the
    # Bardenhagen contact of the weakly compressible model is refused; without it the run is accepted
    # (contact set here: the case file's own setting depends on its water model)
    case = cases.load(REPO / "cases" / "sinking_block.toml", ['solver.fluid="incompressible"',
                                                              'solver.projection="none"', "solver.t_end=0.001",
                                                              "solver.output_every=0.001", "solver.series_every=0.001",
                                                              "contact.enabled=true"])
    with pytest.raises(CpdiError, match="contact is not available") as ei:
        runner.run(case, None, progress=False)
    assert ei.value.kind == "input"
    case = cases.load(REPO / "cases" / "sinking_block.toml", ['solver.fluid="incompressible"',
                                                              'solver.projection="none"', "solver.t_end=0.001",
                                                              "solver.output_every=0.001", "solver.series_every=0.001",
                                                              "contact.enabled=false"])
    runner.run(case, None, progress=False)   # accepted now


def test_incompressible_refuses_damping_and_projection():
    for over, text in ((["solver.damping=0.1"], "damping"), (['solver.projection="cell"'], "projection")):
        case = cases.load(TANK, over)
        with pytest.raises(CpdiError, match=text):
            runner.run(case, None, progress=False)


def test_apic_needs_incompressible():
    """A rule between two options (cpdi_check_options) refuses the case as it loads, not at its run."""
    with pytest.raises(CaseError, match=r"\[solver\] transfer = 'apic' is available with fluid = 'incompressible'"):
        cases.load(TANK, ['solver.fluid="weakly_compressible"', 'solver.transfer="apic"'])
    case = cases.load(TANK, ['solver.fluid="weakly_compressible"'])
    sim, _ = runner.build(case)   # the same case with flip builds
    sim.close()


def test_non_converging_solve_names_residual_and_fix(tmp_path):
    case = cases.load(TANK, ["solver.cg_max_iterations=2", "solver.t_end=1.0", "solver.output_every=0.5"])
    with pytest.raises(runner.RunFailed, match=r"did not converge.*relative residual.*cg_max_iterations") as ei:
        runner.run(case, tmp_path, progress=False)
    assert ei.value.summary["status"] == "failed"
    assert "solve" in ei.value.summary["error"]


def test_zero_volume_water_body_is_refused():
    with pytest.raises(CaseError):
        cases.load(TANK, ["bodies.0.geometry.max=[2.5, 0.0]"])


def test_incompressible_water_needs_no_bulk_modulus():
    raw = cases.load(TANK).data
    mats = [{k: v for k, v in m.items() if k != "bulk_modulus"} for m in raw["materials"]]
    assert "bulk_modulus" not in mats[0]
    data = cases.validate({**raw, "materials": mats})
    assert data["solver"]["fluid"] == "incompressible"


@pytest.mark.parametrize("theta_min, theta", [(0.1, 0.5), (1.0, 1.0)])
def test_theta_min_is_where_the_surface_condition_sits(theta_min, theta):
    """[solver] theta_min (a row of the Fortran option table and nothing else, issue 39 item 1)
    reaches the ghost-fluid surface: the resting tank's surface lies on the top water cells' upper
    faces, half a cell above their centres (theta = 0.5); theta_min = 1 puts p = 0 a whole cell
    above them. The top cell's pressure is then rho g h theta, the hydrostatic step below it rho g h
    either way."""
    case = cases.load(TANK, [f"solver.theta_min={theta_min}", "solver.t_end=0.02", "solver.output_every=0.02"])
    sim, _ = runner.build(case)
    sim.advance(0.02)
    g = sim.grid_pressure()
    sim.close()
    p, water = g["pressure"], g["water"]
    col = p.shape[0] // 2
    top = max(j for j in range(p.shape[1]) if water[col, j] > 0)
    rho_g_h = 1000.0 * 9.81 * case["grid"]["cell"]
    assert p[col, top] == pytest.approx(theta * rho_g_h, rel=1e-6)
    assert p[col, top - 1] - p[col, top] == pytest.approx(rho_g_h, rel=1e-6)


def test_theta_min_out_of_range_is_refused_at_load():
    with pytest.raises(CaseError, match=r"solver.theta_min = 0.0 must lie in \(0.0, 1.0\]"):
        cases.load(TANK, ["solver.theta_min=0.0"])
