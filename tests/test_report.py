"""Tests for harness.report (report directory contract) and harness.provenance."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from harness import provenance, report  # noqa: E402
from harness.checks.base import CheckResult, Gate  # noqa: E402

PROV = {
    "git_sha": "abc123def4567890",
    "dirty": False,
    "compiler": "GNU Fortran 12.2.0",
    "fflags": "-O2 -g",
    "numpy": "2.3.5",
    "date": "2025-01-01T00:00:00Z",
}
CONTRACT_KEYS = {"git_sha", "dirty", "compiler", "fflags", "numpy", "date"}


def _make_results(out_dir: Path) -> list[CheckResult]:
    fig_dir = out_dir / "figures"
    fig_dir.mkdir(parents=True)
    fig, ax = plt.subplots(figsize=(3, 2))
    ax.loglog([0.1, 0.05, 0.025], [1e-2, 2.6e-3, 7e-4], "o-")
    fig.savefig(fig_dir / "conv.png", dpi=50)
    plt.close(fig)
    good = CheckResult(
        name="convergence",
        requirement="CPDI converges at second order in L2 for the <manufactured> solution",
        metrics={"l2_order": 1.98, "l2_error_fine": 7.0e-4},
        gates=[Gate.at_least("l2_order", 1.98, 1.8)],
        tables=["| h | L2 error | rate |\n| ---: | ---: | ---: |\n| 0.1 | 1e-2 |  |\n| 0.05 | 2.6e-3 | 1.94 |"],
        notes=["Uses `cpdi` shape with **MUSL** update."],
        wall_s=3.25,
    )
    bad = CheckResult(
        name="locking",
        requirement="No volumetric locking: tip deflection within 5 % of analytic",
        metrics={"tip_rel_error": 0.12, "nan_metric": float("nan")},
        gates=[Gate.at_most("tip_rel_error", 0.12, 0.05), Gate.at_least("nan_metric", float("nan"), 0.0)],
        figures=["conv.png"],
        notes=["<script>alert(1)</script> must be escaped"],
        wall_s=10.0,
    )
    return [good, bad]


@pytest.fixture()
def written(tmp_path: Path) -> tuple[Path, dict, list[CheckResult]]:
    out = tmp_path / "report"
    results = _make_results(out)
    gate_summary = [
        {
            "check": "convergence",
            "metric": "l2_order",
            "value": 1.98,
            "gold": 1.97,
            "abs_tol": 0.05,
            "rel_tol": 0.0,
            "status": "ok",
            "reason": "",
        },
        {
            "check": "locking",
            "metric": "tip_rel_error",
            "value": 0.12,
            "gold": 0.03,
            "abs_tol": 0.01,
            "rel_tol": 0.1,
            "status": "regressed",
            "reason": "0.12 > 0.03 + tol",
        },
        {
            "check": "convergence",
            "metric": "l2_error_fine",
            "value": 7e-4,
            "gold": 9e-4,
            "abs_tol": 1e-5,
            "rel_tol": 0.05,
            "status": "improved",
            "reason": "better than gold",
        },
    ]
    metrics = report.write_report(out, results, PROV, quick=True, gate_summary=gate_summary)
    return out, metrics, results


def test_metrics_json_schema(written: tuple[Path, dict, list[CheckResult]]) -> None:
    out, returned, _ = written
    data = json.loads((out / "metrics.json").read_text())
    assert data == returned
    assert set(data) == {"schema", "passed", "quick", "provenance", "checks"}
    assert data["schema"] == 1 and data["passed"] is False and data["quick"] is True
    assert CONTRACT_KEYS <= set(data["provenance"])
    assert set(data["checks"]) == {"convergence", "locking"}
    conv, lock = data["checks"]["convergence"], data["checks"]["locking"]
    assert conv["passed"] is True and lock["passed"] is False
    for check in data["checks"].values():
        assert {"passed", "requirement", "metrics", "gates"} <= set(check)
        assert isinstance(check["requirement"], str) and isinstance(check["metrics"], dict)
        for gate in check["gates"]:
            assert set(gate) == {"metric", "value", "bound", "kind", "passed"}
            assert gate["kind"] in {"max", "min", "gold"} and isinstance(gate["passed"], bool)
    assert conv["gates"][0] == {"metric": "l2_order", "value": 1.98, "bound": 1.8, "kind": "min", "passed": True}
    assert lock["gates"][1]["value"] is None  # nan stored as null: strict JSON
    assert "NaN" not in (out / "metrics.json").read_text()


def test_all_passing_is_passed(tmp_path: Path) -> None:
    good = _make_results(tmp_path / "r")[0]
    assert report.write_report(tmp_path / "r", [good], PROV, quick=False)["passed"] is True
    # a regression against gold fails the report even when every check passes
    regressed = [
        {
            "check": "convergence",
            "metric": "l2_order",
            "value": 1.0,
            "gold": 2.0,
            "abs_tol": 0.1,
            "rel_tol": 0.0,
            "status": "regressed",
            "reason": "x",
        }
    ]
    assert report.write_report(tmp_path / "r", [good], PROV, quick=False, gate_summary=regressed)["passed"] is False


def test_index_html_self_contained(written: tuple[Path, dict, list[CheckResult]]) -> None:
    out, _, _ = written
    page = (out / "index.html").read_text()
    assert "<title>cpdi-verify report</title>" in page
    assert "QUICK TIER (CI resolution)" in page
    assert 'src="data:image/png;base64,' in page
    assert 'src="figures/' not in page
    assert not re.search(r'(src|href)="(https?:|//|figures/)', page)
    assert "<script" not in page and "&lt;script&gt;" in page
    assert "&lt;manufactured&gt;" in page
    assert "<code>cpdi</code>" in page and "<strong>MUSL</strong>" in page
    assert '<th style="text-align:right">rate</th>' in page and '<td style="text-align:right">1.94</td>' in page
    assert "Regression gate vs gold" in page and 'class="regressed"' in page
    assert "improved: regenerate gold" in page
    assert "abc123def456" in page


def test_report_md(written: tuple[Path, dict, list[CheckResult]]) -> None:
    out, _, _ = written
    md = (out / "report.md").read_text()
    assert md.startswith("# cpdi-verify report")
    assert "| check | result | verdict | wall time |" in md
    assert "| convergence | PASS | passed (1 gates) | 3.2 s |" in md
    assert re.search(r"\| locking \| \*\*FAIL\*\* \| FAILED: tip_rel_error=0.12 \(max 0.05\)", md)
    assert "![conv.png](figures/conv.png)" in md
    assert "## Regression gate vs gold" in md and "improved: regenerate gold" in md


def test_results_json_and_rerender_identical(written: tuple[Path, dict, list[CheckResult]]) -> None:
    out, _, results = written
    stored = json.loads((out / "results.json").read_text())
    assert stored["quick"] is True and stored["provenance"] == PROV and len(stored["gate_summary"]) == 3
    assert [r["name"] for r in stored["results"]] == [r.name for r in results]
    assert json.loads((out / "provenance.json").read_text()) == PROV
    before = {f: (out / f).read_bytes() for f in ("index.html", "report.md", "metrics.json")}
    for f in before:
        (out / f).unlink()
    report.rerender(out)
    for f, content in before.items():
        assert (out / f).read_bytes() == content, f


def test_error_result_rendered_as_failed(tmp_path: Path) -> None:
    r = CheckResult(name="dam_break", requirement="front position", error="CpdiError: <NaN> in stress", wall_s=1.0)
    metrics = report.write_report(tmp_path, [r], PROV, quick=False)
    assert metrics["passed"] is False and metrics["checks"]["dam_break"]["passed"] is False
    page = (tmp_path / "index.html").read_text()
    assert "FAILED to run" in page and "CpdiError: &lt;NaN&gt; in stress" in page
    assert "QUICK TIER" not in page
    assert "FAILED to run" in (tmp_path / "report.md").read_text()


def test_missing_figure_is_reported(tmp_path: Path) -> None:
    r = CheckResult(name="fsi", requirement="r", figures=["nope.png"])
    report.write_report(tmp_path, [r], PROV, quick=False)
    assert "Missing figure" in (tmp_path / "index.html").read_text()


def test_markdown_tables_lists_and_inline_render_as_html() -> None:
    """Check text (tables, notes) goes through markdown-it-py: a pipe table becomes a <table> with its
    alignment, an escaped pipe stays a literal pipe, raw HTML is shown as text, lists and inline code work."""
    out = report.markdown_html("Caption with `a|b`\n\n| x | y |\n|---|:-:|\n| 1 \\| 2 | <b> |\n\n- one\n- **two**")
    assert "<p>Caption with <code>a|b</code></p>" in out
    assert "<table>" in out and "</table>" in out and "<th>x</th>" in out
    assert "<td>1 | 2</td>" in out and '<td style="text-align:center">&lt;b&gt;</td>' in out
    assert "<ul>\n<li>one</li>\n<li><strong>two</strong></li>\n</ul>" in out
    # a caption line directly above a table (as the checks write them) still gives a table
    assert "<table>" in report.markdown_html("**CPDI** (rates)\n| h | e |\n| ---: | ---: |\n| 0.1 | 1e-2 |")


def test_no_hand_written_converter_left() -> None:
    """The HTML comes from Jinja2 templates and markdown-it-py, not from string-built tags."""
    import inspect

    from markdown_it import MarkdownIt

    for name in ("md_to_html", "_md_inline", "_table_to_html", "_split_row", "_html_rows", "_html_check"):
        assert not hasattr(report, name), name
    assert isinstance(report._MD, MarkdownIt)
    source = inspect.getsource(report)
    assert not re.search(r"<(table|tr|td|th|ul|li|section|h[1-6])\b", source)
    assert (report.TEMPLATES / "index.html.j2").is_file() and (report.TEMPLATES / "report.md.j2").is_file()


class _Anchors:
    """ids, in-page links, images and the table of contents of an HTML page (stdlib parser)."""

    def __init__(self, page: str) -> None:
        from html.parser import HTMLParser

        self.ids: list[str] = []
        self.links: list[str] = []
        self.toc_links: list[str] = []
        self.images: list[dict] = []
        outer = self

        class P(HTMLParser):
            in_toc = 0

            def handle_starttag(self, tag, attrs):
                a = dict(attrs)
                if "id" in a:
                    outer.ids.append(a["id"])
                if tag == "nav":
                    self.in_toc += 1
                if tag == "a" and a.get("href", "").startswith("#"):
                    outer.links.append(a["href"][1:])
                    if self.in_toc:
                        outer.toc_links.append(a["href"][1:])
                if tag == "img":
                    outer.images.append(a)

            def handle_endtag(self, tag):
                if tag == "nav":
                    self.in_toc -= 1

        P().feed(page)


def test_html_toc_and_check_anchors(written: tuple[Path, dict, list[CheckResult]]) -> None:
    """The table of contents lists every section and every check; every in-page link lands on an
    existing id; each check's section has its name as id; ids are unique."""
    out, _, results = written
    page = _Anchors((out / "index.html").read_text())
    assert len(page.ids) == len(set(page.ids))
    assert page.links and set(page.links) <= set(page.ids)
    assert {r.name for r in results} <= set(page.toc_links)
    assert {"summary", "provenance", "regression-gate", "checks"} <= set(page.toc_links)
    html_text = (out / "index.html").read_text()
    for r in results:
        assert f'<section id="{r.name}">' in html_text


def test_html_figures_embedded(written: tuple[Path, dict, list[CheckResult]]) -> None:
    """Every figure is embedded as a base64 data: URI holding the file's bytes (self-contained page)."""
    import base64

    out, _, results = written
    page = _Anchors((out / "index.html").read_text())
    listed = [f for r in results for f in r.figures]
    assert listed and len(page.images) == len(listed)
    for img, name in zip(page.images, listed, strict=True):
        head, data = img["src"].split(",", 1)
        assert head == "data:image/png;base64"
        assert base64.b64decode(data) == (out / "figures" / name).read_bytes()


def test_rerender_without_results_json_raises(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        report.rerender(tmp_path)


# --------------------------------------------------------------------------- provenance


def test_provenance_non_git_dir(tmp_path: Path) -> None:
    info = provenance.collect(tmp_path, build_dir=tmp_path / "does-not-exist")
    assert CONTRACT_KEYS <= set(info)
    assert info["git_sha"] == "unknown" and info["dirty"] == "unknown" and info["fflags"] == "unknown"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", info["date"])
    import numpy

    assert info["numpy"] == numpy.__version__
    json.dumps(info)  # serialisable


def test_provenance_missing_dir_never_raises(tmp_path: Path) -> None:
    info = provenance.collect(tmp_path / "no" / "such" / "dir")
    assert info["git_sha"] == "unknown"


def test_provenance_reads_fflags(tmp_path: Path) -> None:
    (tmp_path / "fflags.txt").write_text("-O3 -march=native -fopenmp\n")
    assert provenance.collect(tmp_path, build_dir=tmp_path)["fflags"] == "-O3 -march=native -fopenmp"


def _git(cwd: Path, *args: str) -> None:
    subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True)


def test_provenance_git_repo_dirty_flag(tmp_path: Path) -> None:
    try:
        _git(tmp_path, "init", "-q")
        _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "--allow-empty", "-m", "x")
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("git not usable")
    info = provenance.collect(tmp_path)
    assert re.fullmatch(r"[0-9a-f]{40}", info["git_sha"])
    assert info["dirty"] is False
    (tmp_path / "runs" / "case").mkdir(parents=True)
    (tmp_path / "runs" / "case" / "summary.json").write_text("{}")
    (tmp_path / "reports").mkdir()
    (tmp_path / "reports" / "index.html").write_text("x")
    assert provenance.collect(tmp_path)["dirty"] is False  # generated output ignored
    (tmp_path / "code.f90").write_text("x")
    assert provenance.collect(tmp_path)["dirty"] is True


def test_bench_numbers_in_the_report(tmp_path: Path) -> None:
    """The last `make bench` run (bench.json and its plots) is carried into the verify report,
    with its own git SHA, and survives a re-render byte for byte."""
    bench_dir = tmp_path / "bench"
    bench_dir.mkdir()
    row = {"name": "dam_break_32k", "shape": "cpdi", "particles": 32768, "threads": 2,
           "particle_updates_per_s": 7.9e6, "bytes_per_particle": 812.0,
           "phase_ns_per_update": {"shape": 36.0, "p2g": 22.0, "projection": 27.0}}
    (bench_dir / "bench.json").write_text(json.dumps({
        "cases": [row], "summary": {"cpdi_32k_speedup_2threads": 1.93}, "repeats": 3, "projection": "cell",
        "provenance": {"git_sha": "abc123def4567890", "date": "2026-11-21"}}))
    fig, ax = plt.subplots()
    ax.plot([0, 1])
    fig.savefig(bench_dir / "bench.png")
    plt.close(fig)
    good = CheckResult(name="a", requirement="r", gates=[Gate.at_most("m", 1.0, 2.0)])
    out = tmp_path / "r"
    report.write_report(out, [good], PROV, quick=False, bench_dir=bench_dir)
    md = (out / "report.md").read_text()
    assert "## Performance" in md and "abc123def456" in md
    assert "| cpdi | 32768 | 2 | 7.90 | 812 |" in md
    assert "cpdi_32k_speedup_2threads" in md
    page = (out / "index.html").read_text()
    assert "bench.png" in page and 'id="performance"' in page
    before = (page, md)
    report.rerender(out)
    assert ((out / "index.html").read_text(), (out / "report.md").read_text()) == before
    report.write_report(tmp_path / "plain", [good], PROV, quick=False)
    assert "Performance" not in (tmp_path / "plain" / "report.md").read_text()


def test_known_limitation_gates_are_reported_but_do_not_decide(tmp_path: Path) -> None:
    """A gate marked as a known limitation reads XFAIL when missed (the check still passes) and
    XPASS when met; an unmarked failing gate still fails the check; the mark and the outcome
    reach metrics.json, the Markdown and the HTML report, and survive a re-render."""
    why = "2D model against a 3D experiment"
    r = CheckResult(name="lobovsky", requirement="wall pressure", gates=[
        Gate.at_most("rise_dt", 0.05, 0.1),
        Gate.at_most("mean_rel", 0.34, 0.15, known_limitation=why),
        Gate.at_most("window_rms", 0.13, 0.15, known_limitation=why)])
    assert r.passed and [g.outcome for g in r.gates] == ["PASS", "XFAIL", "XPASS"]
    assert "XFAIL" in r.verdict and "mean_rel=0.34" in r.verdict and "window_rms" not in r.verdict
    metrics = report.write_report(tmp_path, [r], PROV, quick=False)
    assert metrics["passed"] is True
    gates = metrics["checks"]["lobovsky"]["gates"]
    assert "known_limitation" not in gates[0]
    assert gates[1]["known_limitation"] == why and gates[1]["outcome"] == "XFAIL" and gates[1]["passed"] is False
    assert gates[2]["outcome"] == "XPASS"
    md = (tmp_path / "report.md").read_text()
    assert f"XFAIL (known limitation: {why})" in md and f"XPASS (known limitation: {why})" in md
    assert ">XFAIL</span>" in (tmp_path / "index.html").read_text()
    before = (tmp_path / "metrics.json").read_bytes()
    report.rerender(tmp_path)
    assert (tmp_path / "metrics.json").read_bytes() == before
    # the mark does not excuse the other gates
    r.gates[0] = Gate.at_most("rise_dt", 0.2, 0.1)
    assert not r.passed and r.verdict.startswith("FAILED: rise_dt=0.2")


def test_junit_xml_counts_match_metrics_json(tmp_path: Path) -> None:
    """junit.xml: a testsuite per check and a testcase per gate (counts equal to metrics.json);
    a missed gate is a failure naming metric, value, bound and reference; an XFAIL is skipped;
    a check that could not run is an error; gold regressions are failures of their own suite."""
    import xml.etree.ElementTree as ET

    why = "2D model"
    ok = CheckResult(name="lobovsky", requirement="wall pressure (Lobovsky 2014)", gates=[
        Gate.at_most("rise_dt", 0.05, 0.1, "first rise [t*]"),
        Gate.at_most("mean_rel", 0.34, 0.15, known_limitation=why),
        Gate.at_most("volume", 0.02, 0.01)])
    broken = CheckResult(name="bar", requirement="x", error="CpdiError: NaN at step 3")
    rows = [{"check": "lobovsky", "metric": "rise_dt", "value": 0.05, "gold": 0.01, "abs_tol": 0.0,
             "rel_tol": 0.05, "status": "regressed", "reason": "errors: 5 %"},
            {"check": "lobovsky", "metric": "volume", "value": 0.02, "gold": 0.02, "abs_tol": 0.0,
             "rel_tol": 0.05, "status": "ok", "reason": ""}]
    metrics = report.write_report(tmp_path, [ok, broken], PROV, quick=True, gate_summary=rows)
    root = ET.parse(tmp_path / "junit.xml").getroot()
    suites = {s.get("name"): s for s in root.iter("testsuite")}
    assert set(suites) == {"lobovsky", "bar", "regression_vs_gold"}
    for name, c in metrics["checks"].items():
        if not c["error"]:
            assert int(suites[name].get("tests")) == len(c["gates"]) == len(suites[name].findall("testcase"))
    lob = suites["lobovsky"]
    assert (lob.get("failures"), lob.get("skipped"), lob.get("errors")) == ("1", "1", "0")
    fail = lob.find("testcase[@name='volume']/failure").get("message")
    assert "volume = 0.02" in fail and "<= 0.01" in fail and "Lobovsky 2014" in fail
    assert why in lob.find("testcase[@name='mean_rel']/skipped").get("message")
    assert lob.find("testcase[@name='rise_dt']/failure") is None
    assert "NaN at step 3" in suites["bar"].find("testcase/error").get("message")
    gold = suites["regression_vs_gold"]
    assert (gold.get("tests"), gold.get("failures")) == ("2", "1")
    assert root.get("tests") == str(3 + 1 + 2) and root.get("failures") == "2" and root.get("errors") == "1"
    before = (tmp_path / "junit.xml").read_bytes()
    report.rerender(tmp_path)
    assert (tmp_path / "junit.xml").read_bytes() == before
