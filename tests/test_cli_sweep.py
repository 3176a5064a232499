"""The ``cpdi`` console script's argument handling (through harness.cli.main, which the script calls)
and ``cpdi sweep`` on a tiny case."""

from __future__ import annotations

import csv
import sys
import tomllib
from pathlib import Path

import pytest

from harness import cli, paths, sweep

REPO = Path(__file__).resolve().parent.parent
CASE = str(REPO / "cases" / "water_column.toml")
TINY = ["--set", "solver.t_end=0.02", "--set", "solver.output_every=0.01"]


def test_console_script_entry_point() -> None:
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert meta["project"]["scripts"]["cpdi"] == "harness.cli:main"
    assert meta["build-system"]["build-backend"] == "mesonpy"
    assert all("==" in r for r in meta["build-system"]["requires"]), "build requirements are pinned exactly"


@pytest.mark.parametrize("sub", ["run", "verify", "report", "sweep"])
def test_subcommands_have_help(sub: str, capsys, monkeypatch) -> None:
    monkeypatch.setattr(sys, "argv", ["cpdi"])
    with pytest.raises(SystemExit) as exc:
        cli.main([sub, "--help"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: cpdi {sub}")


@pytest.mark.parametrize("argv", [[], ["sweep"], ["sweep", CASE], ["run"], ["nonsense"], ["verify", "--bogus"]])
def test_bad_arguments_exit_2(argv: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    assert "error:" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["sweep", "no/such/case.toml", "--set", "solver.cfl=0.3,0.5"], "does not exist"),
    (["sweep", CASE, "--set", "solver.cfl"], "expected SECTION.KEY=V1,V2"),
    (["sweep", CASE, "--set", "solver.cfl=0.3,,0.5"], "an empty value"),
    (["sweep", CASE, "--set", "solver.cfl=0.3", "--set", "solver.cfl=0.5"], "given twice"),
    (["sweep", CASE, "--set", "solver.cfll=0.3,0.5"], "solver.cfll"),
    (["sweep", CASE, "--set", "solver.cfl=0.3,-1"], "cfl"),
    (["report", "/nonexistent/report"], "no results.json"),
])
def test_bad_input_is_one_line_and_exit_2(argv: list[str], message: str, capsys, tmp_path: Path) -> None:
    assert cli.main([*argv, *(["--out", str(tmp_path / "o")] if argv[0] == "sweep" else [])]) == 2
    err = capsys.readouterr().err
    assert "error:" in err and message in err
    assert not (tmp_path / "o").exists(), "nothing runs before every combination validates"


def test_split_values() -> None:
    assert sweep.split_values("0.1,0.2") == ["0.1", "0.2"]
    assert sweep.split_values("[0.0, -9.81],[0.0,-1.0]") == ["[0.0, -9.81]", "[0.0,-1.0]"]
    assert sweep.split_values('"a,b",c') == ['"a,b"', "c"]
    assert sweep.combinations([("a", ["1", "2"]), ("b", ["x", "y", "z"])])[:2] == [{"a": "1", "b": "x"},
                                                                                   {"a": "1", "b": "y"}]


def test_sweep_tiny_case(tmp_path: Path, capsys) -> None:
    out = tmp_path / "sweep"
    code = cli.main(["sweep", CASE, "--set", "grid.cell=0.0146,0.0073", "--set", "solver.cfl=0.3,0.5", *TINY,
                     "--metric", "final.front_x", "--out", str(out), "--no-progress"])
    assert code == 0, capsys.readouterr()
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert [(r["grid.cell"], r["solver.cfl"]) for r in rows] == [("0.0146", "0.3"), ("0.0146", "0.5"),
                                                                 ("0.0073", "0.3"), ("0.0073", "0.5")]
    assert all(r["status"] == "completed" and float(r["simulated_time"]) == pytest.approx(0.02) for r in rows)
    assert int(rows[2]["particles"]) == 4 * int(rows[0]["particles"])  # half the cell, 4x the particles
    assert all(0.146 < float(r["final.front_x"]) < 0.2 for r in rows)
    md = (out / "sweep.md").read_text().splitlines()
    assert len(md) == 2 + 4 and "final.front_x" in md[0]
    assert (out / "sweep.png").stat().st_size > 5000
    assert all((out / f"run_{i:03d}" / "summary.json").is_file() for i in range(4))


def test_sweep_unknown_metric(tmp_path: Path, capsys) -> None:
    code = cli.main(["sweep", CASE, "--set", "solver.cfl=0.3,0.5", "--set", "grid.cell=0.0146", *TINY,
                     "--metric", "nope", "--out", str(tmp_path), "--no-progress"])
    assert code == 2
    assert "--metric 'nope' is not a column" in capsys.readouterr().out
    assert (tmp_path / "sweep.csv").is_file(), "the table is still written"


def test_data_directory(monkeypatch, tmp_path: Path) -> None:
    assert paths.in_source_tree() and paths.data_root() == REPO and paths.work_root() == REPO
    monkeypatch.setenv("CPDI_DATA_DIR", str(tmp_path))
    assert paths.data_root() == tmp_path
