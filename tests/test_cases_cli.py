"""Case loading/validation and the `run` command's outputs (summary, series, HDF5 + XDMF)."""

import json
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest

from harness import cases
from harness.cases import CaseError

REPO = Path(__file__).resolve().parent.parent
WATER = REPO / "cases" / "water_column.toml"


def raw_case():
    import tomllib

    return tomllib.loads(WATER.read_text())


def test_every_committed_case_validates():
    files = sorted((REPO / "cases").glob("*.toml"))
    assert files
    for f in files:
        case = cases.load(f)
        assert case.data["case"]["requirement"].strip(), f"{f.name} needs a one-line requirement"


@pytest.mark.parametrize("mutate, message", [
    (lambda r: r["solver"].__setitem__("cfll", 0.3), "unknown key 'solver.cfll'; did you mean 'cfl'"),
    (lambda r: r["solver"].__setitem__("cfl", "fast"), "solver.cfl = 'fast' must be a number"),
    (lambda r: r["solver"].__setitem__("shape", "cpd"), "did you mean 'cpdi'"),
    (lambda r: r["materials"][0].__setitem__("density", -1.0), "materials[0].density = -1.0 must be positive"),
    (lambda r: (r["materials"][0].pop("bulk_modulus"), r["solver"].__setitem__("fluid", "weakly_compressible")),
     "needs 'bulk_modulus'"),  # (incompressible water has no use for it)
    (lambda r: r["grid"].__setitem__("cell", 0.01), "not a whole number of cells"),
    (lambda r: r["bodies"][0].__setitem__("material", "watr"), "did you mean 'water'"),
    (lambda r: r["bodies"][0]["geometry"].__setitem__("max", [0.146, 9.0]), "outside the grid"),
    (lambda r: r.pop("case"), "missing required key 'case'"),
    (lambda r: r["grid"]["walls"].__setitem__("left", "sticky"), "is not one of slip, noslip, open"),
])
def test_malformed_cases_are_refused_with_the_key_named(mutate, message):
    raw = raw_case()
    mutate(raw)
    with pytest.raises(CaseError) as ei:
        cases.validate(raw)
    assert message in str(ei.value)


def test_toml_syntax_error_names_the_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[case]\nname = "x"\nrequirement = "y"\n[grid\n')
    with pytest.raises(CaseError, match=r"TOML syntax error.*line 4"):
        cases.load(bad)


def test_overrides_apply_and_validate():
    case = cases.load(WATER, ["solver.cfl=0.2", "materials.0.density=1100", "grid.walls.top=\"slip\""])
    assert case["solver"]["cfl"] == 0.2
    assert case["materials"][0]["density"] == 1100.0
    assert case["grid"]["walls"]["top"] == "slip"
    with pytest.raises(CaseError, match="unknown section 'solvr'"):
        cases.load(WATER, ["solvr.cfl=0.2"])


def test_readme_documents_every_key():
    text = (REPO / "cases" / "README.md").read_text()
    assert cases.schema_markdown() in text, "cases/README.md is out of date: paste harness.cases.schema_markdown()"


def run_cli(*args, cwd=REPO):
    return subprocess.run([sys.executable, "-m", "harness", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def test_run_writes_the_contract_outputs(tmp_path):
    out = tmp_path / "wc"
    p = run_cli("run", str(WATER), "--out", str(out), "--no-progress", "--set", "grid.cell=0.0146",
                "--set", "solver.t_end=0.1", "--set", "solver.output_every=0.05")
    assert p.returncode == 0, p.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed"
    for key in ("case", "parameters", "steps", "simulated_time", "wall_s", "particles", "particle_updates_per_s"):
        assert key in summary
    assert summary["simulated_time"] == pytest.approx(0.1)
    # the summary line: wall time and particles x steps per second
    m = re.search(r"completed t = (\S+) s in (\d+) steps, (\S+) s wall, (\d+) particles, (\S+) M particle-updates/s",
                  p.stdout)
    assert m, p.stdout
    steps, wall, n, rate = int(m[2]), float(m[3]), int(m[4]), float(m[5])
    assert (steps, n) == (summary["steps"], summary["particles"])
    assert wall == pytest.approx(summary["wall_s"], abs=0.006)
    assert rate == pytest.approx(n * steps / summary["wall_s"] / 1e6, abs=0.006)
    header = (out / "series.csv").read_text().splitlines()[0].split(",")
    for col in ("t", "kinetic_energy", "strain_energy", "momentum_x", "momentum_y", "front_x", "column_height"):
        assert col in header
    with h5py.File(out / "snapshots.h5", "r") as f:
        groups = sorted(f["snapshots"])
        assert len(groups) == 3  # t = 0, 0.05, 0.1
        g = f["snapshots"][groups[-1]]
        n = summary["particles"]
        assert g["position"].shape == (n, 2) and g["corners"].shape == (n, 4, 2)
        assert g["stress"].shape == (n, 4) and g["pressure"].shape == (n,)
        assert g.attrs["time"] == pytest.approx(0.1)
        # XDMF: every DataItem names an existing dataset of the right size
        root = ET.parse(out / "snapshots.xdmf").getroot()
        items = root.findall(".//DataItem")
        assert len(items) >= 3 * 7
        for item in items:
            dims = tuple(int(d) for d in item.attrib["Dimensions"].split())
            if item.attrib["Format"] == "XML":  # inline values (the pressure grid's origin and spacing)
                assert len(item.text.split()) == int(np.prod(dims)), item.text
                continue
            fname, path = item.text.strip().split(":")
            assert fname == "snapshots.h5"
            assert f[path].shape == dims, path


def test_failed_run_keeps_outputs_and_exits_nonzero(tmp_path):
    out = tmp_path / "bad"
    # an absurd time step on purpose: the solver refuses it at the first step
    p = run_cli("run", str(WATER), "--out", str(out), "--no-progress", "--set", "grid.cell=0.0146",
                "--set", "solver.dt=1.0")
    assert p.returncode == 1
    assert "exceeds the stable limit" in p.stderr
    assert "Traceback" not in p.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "cfl" in summary["error"]
    assert (out / "series.csv").is_file() and (out / "snapshots.xdmf").is_file()


def test_bad_case_file_gives_one_line_error(tmp_path):
    bad = tmp_path / "x.toml"
    bad.write_text(WATER.read_text().replace("cfl = 0.4", "cfl = 4.0"))
    p = run_cli("run", str(bad), "--no-progress")
    assert p.returncode == 2
    assert "solver.cfl = 4.0 must lie in (0.0, 1.0]" in p.stderr
    assert "Traceback" not in p.stderr


def test_front_probe_ignores_isolated_droplets():
    from harness.probes import front_x

    x = np.array([[0.1, 0.001], [0.11, 0.001], [0.12, 0.001], [0.13, 0.001], [0.5, 0.001]])
    assert front_x(x, 0.01, 0.011, 3) == pytest.approx(0.13)  # 3 particles within 2 spacings
    assert front_x(x, 0.01, 0.011, 1) == pytest.approx(0.5)  # min_count = 1 takes the droplet


def test_verify_shows_per_check_progress_and_wall_times(tmp_path, monkeypatch, capsys):
    """verify's live bar counts the checks done out of the total and names the running check; each
    check's result line gives its wall time."""
    import io
    import types

    from harness import verify
    from harness.checks.base import CheckResult, Gate

    def fake(name):
        mod = types.SimpleNamespace(REQUIREMENT=f"{name} holds")
        mod.run = lambda ctx: CheckResult(name=name, requirement=mod.REQUIREMENT,
                                          gates=[Gate.at_most("err", 0.1, 1.0)])
        return mod

    monkeypatch.setattr(verify.importlib, "import_module", lambda path: fake(path.rsplit(".", 1)[1]))
    monkeypatch.setattr(verify.paths, "work_root", lambda: tmp_path)  # runs/ under tmp_path
    bar_out = io.StringIO()
    real_bar = verify._check_bar
    monkeypatch.setattr(verify, "_check_bar", lambda total, progress: real_bar(total, progress, file=bar_out))
    results = verify.run_checks(["alpha", "beta"], tmp_path / "report", quick=True, progress=True)
    assert [r.name for r in results] == ["alpha", "beta"] and all(r.passed for r in results)
    bar = bar_out.getvalue()
    assert "verify: 0/2 checks done, running alpha" in bar and "1/2 checks done, running beta" in bar
    assert "2/2 checks done |" in bar
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "[verify] alpha: alpha holds"
    assert re.fullmatch(r"\[verify\] alpha: PASS - passed \(1 gates\) \(\d+\.\d s\)", lines[1])
    # --no-progress: no bar at all, the same lines
    bar_out.truncate(0)
    verify.run_checks(["alpha"], tmp_path / "report", quick=True, progress=False)
    assert bar_out.getvalue() == ""


def test_verify_only_takes_names_after_one_flag_or_several(monkeypatch):
    """``--only a b`` and ``--only a --only b`` both run a and b (a repeated flag used to keep only
    its last names)."""
    from harness import cli, verify

    seen = []
    monkeypatch.setattr(verify, "main", lambda **kw: seen.append(kw["only"]) or 0)
    assert cli.main(["verify", "--only", "wedge_entry", "cylinder_entry"]) == 0
    assert cli.main(["verify", "--only", "wedge_entry", "--only", "cylinder_entry"]) == 0
    assert seen == [["wedge_entry", "cylinder_entry"]] * 2
