"""Verification report writer: metrics.json, provenance.json, results.json, report.md, index.html.

Layout of a report directory (docs/design.md, "Interface contract")::

    <out_dir>/metrics.json     machine-readable verdicts (schema 1)
    <out_dir>/provenance.json  code/toolchain/machine provenance
    <out_dir>/results.json     full CheckResult dicts + quick + provenance + gate_summary
    <out_dir>/report.md        Markdown report, figures referenced as figures/x.png
    <out_dir>/index.html       self-contained HTML report (figures embedded as base64)
    <out_dir>/junit.xml        JUnit XML: a testsuite per check, a testcase per gate (harness.junit)
    <out_dir>/figures/*.png    written by the checks

report.md and index.html are Jinja2 templates (``harness/templates/``); the Markdown that checks
write (tables, notes, requirements) becomes HTML through markdown-it-py (CommonMark + pipe tables,
raw HTML shown as text). The HTML page has a table of contents and an anchor per check (its
``id`` is the check's name).

Everything rendered is derived from ``results.json`` alone, so :func:`rerender`
reproduces byte-identical output without re-running any check. Non-finite floats are
stored as ``null`` (strict JSON) and restored to nan on reading.
"""

from __future__ import annotations

import base64
import json
import math
import shutil
from pathlib import Path
from typing import Any

from jinja2 import Environment, FileSystemLoader, StrictUndefined
from markdown_it import MarkdownIt
from markupsafe import Markup

from harness import junit, parallel
from harness.checks.base import CheckResult

SCHEMA = 1
TITLE = "cpdi-verify report"
QUICK_BANNER = "QUICK TIER (CI resolution)"
GATE_FIELDS = ("metric", "value", "bound", "kind", "passed")
GATE_SUMMARY_FIELDS = ("check", "metric", "value", "gold", "abs_tol", "rel_tol", "status", "reason")
PROVENANCE_ORDER = (
    "git_sha", "dirty", "branch", "compiler", "fflags", "python", "numpy", "h5py", "matplotlib",
    "meson", "lapack", "hostname", "cpu", "nproc", "omp_num_threads", "date",
)  # fmt: skip
_MIME = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".svg": "image/svg+xml"}

__all__ = ["write_report", "rerender", "build_metrics", "markdown_html"]


# --------------------------------------------------------------------------- JSON helpers


def _jsonable(obj: Any) -> Any:
    """Recursively convert to strict-JSON types (non-finite floats -> None, numpy -> python)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if hasattr(obj, "item") and callable(obj.item):  # numpy scalar
        obj = obj.item()
    if isinstance(obj, bool):
        return obj
    if isinstance(obj, int):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    return str(obj)


def _dump(path: Path, data: Any) -> None:
    path.write_text(json.dumps(_jsonable(data), indent=2, allow_nan=False) + "\n", encoding="utf-8")


def _as_float(v: Any) -> float:
    """JSON null (a stored nan) back to nan."""
    return float("nan") if v is None else float(v)


def _result_from_json(d: dict[str, Any]) -> CheckResult:
    d = dict(d)
    d["gates"] = [
        {**g, "value": _as_float(g.get("value")), "bound": _as_float(g.get("bound"))} for g in d.get("gates", [])
    ]
    d["metrics"] = {k: (float("nan") if v is None else v) for k, v in d.get("metrics", {}).items()}
    return CheckResult.from_dict(d)


# --------------------------------------------------------------------------- metrics.json


def _overall_passed(results: list[CheckResult], gate_summary: list[dict] | None) -> bool:
    """All checks passed and no gold-regression row has status ``regressed``."""
    regressed = any(row.get("status") == "regressed" for row in gate_summary or [])
    return bool(results) and all(r.passed for r in results) and not regressed


def build_metrics(
    results: list[CheckResult], provenance: dict, quick: bool, gate_summary: list[dict] | None = None,
    execution: dict | None = None,
) -> dict[str, Any]:
    """The ``metrics.json`` document (schema 1). Extra per-check keys: verdict, wall_s, error. With
    ``execution`` (harness.parallel.Cluster.summary: where the runs ran, the tasks re-run after their
    worker died) it is added as the top-level key ``execution``."""
    checks: dict[str, Any] = {}
    for r in results:
        checks[r.name] = {
            "passed": r.passed,
            "requirement": r.requirement,
            "metrics": dict(r.metrics),
            "gates": [
                {
                    "metric": g.metric,
                    "value": float(g.value),
                    "bound": float(g.bound),
                    "kind": g.kind,
                    "passed": bool(g.passed),
                    **({"note": g.note} if g.note else {}),
                    **({"known_limitation": g.known_limitation, "outcome": g.outcome} if g.known_limitation else {}),
                }
                for g in r.gates
            ],
            "verdict": r.verdict,
            "wall_s": float(r.wall_s),
            "error": r.error,
        }
    return _jsonable(
        {
            "schema": SCHEMA,
            "passed": _overall_passed(results, gate_summary),
            "quick": bool(quick),
            "provenance": dict(provenance),
            "checks": checks,
            **({"execution": execution} if execution is not None else {}),
        }
    )


# --------------------------------------------------------------------------- formatting


def _fmt(v: Any) -> str:
    """Compact human-readable value: 4 significant digits for floats."""
    if v is None:
        return "nan"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _figure_path(out_dir: Path, name: str) -> Path:
    """Figures are listed relative to <report>/figures/ (a leading ``figures/`` is tolerated)."""
    name = name.removeprefix("figures/")
    return out_dir / "figures" / name


def _provenance_rows(provenance: dict, quick: bool) -> list[tuple[str, str]]:
    keys = [k for k in PROVENANCE_ORDER if k in provenance]
    keys += sorted(k for k in provenance if k not in PROVENANCE_ORDER)
    rows = [(k, _fmt(provenance[k])) for k in keys]
    rows.append(("tier", "quick" if quick else "full"))
    return rows


def _gate_status_label(status: str) -> str:
    return "improved: regenerate gold" if status == "improved" else status


# --------------------------------------------------------------------------- rendering (Jinja2 + markdown-it-py)

TEMPLATES = Path(__file__).resolve().parent / "templates"
# CommonMark with GFM pipe tables; raw HTML in check text is shown as text, never passed through.
_MD = MarkdownIt("commonmark", {"html": False}).enable("table")

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, Helvetica, Arial, sans-serif;
       color: #1f2328; background: #fff; line-height: 1.5; margin: 0; }
main { max-width: 1100px; margin: 0 auto; padding: 1.5rem 2rem 4rem; }
h1 { margin-bottom: .3rem; } h2 { border-bottom: 1px solid #d0d7de; padding-bottom: .3rem; margin-top: 2.2rem; }
h3 { margin-top: 1.6rem; }
section, h2 { scroll-margin-top: 1rem; }
a.anchor { color: #8c959f; text-decoration: none; font-weight: 400; margin-left: .3rem; }
a.anchor:hover { color: #0969da; }
nav.toc { font-size: .9rem; background: #f6f8fa; border-bottom: 1px solid #d0d7de; padding: .6rem 2rem; }
nav.toc .toc-title { font-weight: 700; margin: 0 0 .3rem; }
nav.toc ol { margin: 0; padding-left: 1.2rem; } nav.toc ol ol { columns: 2; }
nav.toc a { color: #0969da; text-decoration: none; } nav.toc a:hover { text-decoration: underline; }
.dot { display: inline-block; width: .6rem; height: .6rem; border-radius: 50%; margin-right: .35rem; }
.dot.pass { background: #1a7f37; } .dot.fail { background: #cf222e; }
@media (min-width: 1400px) {
  nav.toc { position: fixed; top: 0; left: 0; bottom: 0; width: 230px; overflow-y: auto; border-bottom: 0;
            border-right: 1px solid #d0d7de; padding: 1rem; }
  nav.toc ol ol { columns: 1; }
  main { margin-left: calc(230px + max(0px, (100vw - 230px - 1100px) / 2)); }
}
table { border-collapse: collapse; margin: .8rem 0; font-size: .92rem; }
th, td { border: 1px solid #d0d7de; padding: .3rem .6rem; vertical-align: top; }
th { background: #f6f8fa; text-align: left; }
code, pre { font-family: ui-monospace, SFMono-Regular, Menlo, Consolas, monospace; font-size: .88em; }
code { background: #f6f8fa; padding: .1em .3em; border-radius: 4px; }
pre { white-space: pre-wrap; margin: .3rem 0 0; }
blockquote { margin: .8rem 0; padding: .4rem 1rem; border-left: 4px solid #8c959f; background: #f6f8fa; }
.badge { display: inline-block; padding: .08rem .55rem; border-radius: 1rem; font-weight: 600;
         font-size: .82rem; color: #fff; }
.badge.pass { background: #1a7f37; } .badge.fail { background: #cf222e; }
.badge.info { background: #9a6700; } .badge.muted { background: #6e7781; }
.badge.known { background: #8250df; }
.banner { background: #fff8c5; border: 1px solid #d4a72c; padding: .6rem 1rem; font-weight: 700;
          border-radius: 6px; margin: .8rem 0; }
.error { background: #ffebe9; border: 1px solid #cf222e; padding: .6rem 1rem; border-radius: 6px; margin: .8rem 0; }
tr.regressed td { background: #ffebe9; } tr.improved td { background: #fff8c5; }
tr.failgate td { background: #ffebe9; }
figure { margin: 1rem 0; } figure img { max-width: 100%; border: 1px solid #d0d7de; }
figcaption { font-size: .85rem; color: #57606a; }
.verdict { font-weight: 600; } .verdict .wall { font-weight: 400; color: #57606a; }
"""


def markdown_html(text: str) -> str:
    """A block of check Markdown (tables, lists, paragraphs) as HTML, by markdown-it-py."""
    return _MD.render(text.strip("\n")).rstrip("\n")


def _inline_markup(text: str) -> Markup:
    return Markup(_MD.renderInline(text))


def _block_markup(text: str) -> Markup:
    return Markup(markdown_html(text))


def _md_cell(v: Any) -> str:
    s = v if isinstance(v, str) else _fmt(v)
    return s.replace("|", "\\|").replace("\n", " ")


def _pass_word(passed: bool) -> str:
    return "PASS" if passed else "**FAIL**"


def _md_outcome(g) -> str:
    """pass / **FAIL**, or XFAIL / XPASS with the known limitation."""
    if g.counts:
        return "pass" if g.passed else "**FAIL**"
    return f"{g.outcome} (known limitation: {g.known_limitation})"


def _other_metrics(r: CheckResult) -> list[list[Any]]:
    gated = {g.metric for g in r.gates}
    return [[k, v] for k, v in r.metrics.items() if k not in gated]


_ENV: Environment | None = None


def _env() -> Environment:
    global _ENV
    if _ENV is None:
        env = Environment(loader=FileSystemLoader(TEMPLATES), autoescape=lambda name: bool(name) and
                          name.endswith(".html.j2"), undefined=StrictUndefined, trim_blocks=True,
                          lstrip_blocks=True, keep_trailing_newline=True)
        env.filters.update(fmt=_fmt, md_cell=_md_cell, md=_block_markup, md_inline=_inline_markup)
        env.globals.update(title=TITLE, quick_banner=QUICK_BANNER, gate_fields=list(GATE_SUMMARY_FIELDS),
                           pass_word=_pass_word, other_metrics=_other_metrics, status_label=_gate_status_label,
                           basename=lambda f: Path(f).name,
                           gate_table=lambda r: [[g.metric, g.value, g.bound, g.kind, _md_outcome(g)] for g in r.gates])
        _ENV = env
    return _ENV


BENCH_PHASES = ("shape", "p2g", "grid", "g2p", "deformation", "stress", "projection")
BENCH_HEADER = ["shape", "particles", "threads", "M updates/s (median)", "bytes/particle"] + \
    [f"{p} ns" for p in BENCH_PHASES]
BENCH_FIGURES = ("bench.png", "bench_phases.png")


def _bench_intro(bench: dict) -> str:
    prov = bench.get("provenance") or {}
    sha = str(prov.get("git_sha", "unknown"))[:12] + (" (dirty)" if prov.get("git_dirty") else "")
    return (f"From reports/bench/bench.json (make bench): git {sha}, {prov.get('date', '')}, "
            f"{bench.get('repeats', 1)} repeats per row, projection {bench.get('projection', '?')}"
            f"{', quick' if bench.get('quick') else ''}. It is the last benchmark run on this machine, "
            f"not part of this verify run; compare its git SHA with the report's.")


def _bench_rows(bench: dict) -> list[list[str]]:
    rows = []
    for r in bench.get("cases", []):
        ph = r.get("phase_ns_per_update") or {}
        rows.append([r.get("shape", ""), str(r.get("particles", "")), str(r.get("threads", "")),
                     f"{r.get('particle_updates_per_s', 0.0) / 1e6:.2f}", f"{r.get('bytes_per_particle', 0.0):.0f}"]
                    + [f"{ph.get(p, 0.0):.0f}" for p in BENCH_PHASES])
    return rows


def _bench_summary_rows(bench: dict) -> list[list[str]]:
    return [[k, _fmt(v)] for k, v in (bench.get("summary") or {}).items() if v is not None]


def _figure(out_dir: Path, name: str) -> dict[str, str]:
    """A figure for the HTML page: its bytes as base64 (``data`` empty if the file is missing)."""
    path = _figure_path(out_dir, name)
    if not path.is_file():
        return {"listed": name, "name": path.name, "mime": "", "data": ""}
    return {"listed": name, "name": path.name, "mime": _MIME.get(path.suffix.lower(), "application/octet-stream"),
            "data": base64.b64encode(path.read_bytes()).decode("ascii")}


def _context(results: list[CheckResult], provenance: dict, quick: bool, gate_summary: list[dict] | None,
             passed: bool, bench: dict | None, execution: dict | None = None) -> dict[str, Any]:
    """What both templates see."""
    rows = [{**row, "status": str(row.get("status", ""))} for row in gate_summary or []]
    gate_rows = []
    for row in rows:
        status = "**regressed**" if row["status"] == "regressed" else _gate_status_label(row["status"])
        gate_rows.append([row.get(k) for k in GATE_SUMMARY_FIELDS[:6]] + [status, row.get("reason", "")])
    return {
        "results": results, "provenance": provenance, "quick": quick, "passed": passed, "bench": bench,
        "n_passed": sum(r.passed for r in results),
        "git_short": str(provenance.get("git_sha", "unknown"))[:12], "date": str(provenance.get("date", "")),
        "summary_rows": [[r.name, _pass_word(r.passed), r.verdict, f"{r.wall_s:.1f} s"] for r in results],
        "provenance_rows": _provenance_rows(provenance, quick),
        "gate_summary": rows, "gate_rows": gate_rows,
        "gate_attention": [r for r in rows if r["status"] != "ok"],
        "gate_counts": {k: sum(r["status"] == k for r in rows) for k in ("ok", "regressed", "improved")},
        "gate_reasons": sorted({str(r.get("reason", "")) for r in rows if r["status"] == "ok" and r.get("reason")}),
        "bench_intro": _bench_intro(bench) if bench else "",
        "bench_summary_rows": _bench_summary_rows(bench) if bench else [],
        "bench_header": BENCH_HEADER, "bench_rows": _bench_rows(bench) if bench else [],
        "execution": parallel.execution_text(execution) if execution else "",
    }


def render_html(
    out_dir: Path,
    results: list[CheckResult],
    provenance: dict,
    quick: bool,
    gate_summary: list[dict] | None,
    passed: bool,
    bench: dict | None = None,
    execution: dict | None = None,
) -> str:
    """index.html (templates/index.html.j2): a table of contents, an anchor per check (id = its
    name), every figure embedded as a data: URI."""
    ctx = _context(results, provenance, quick, gate_summary, passed, bench, execution)
    ctx["css"] = Markup(_CSS)
    ctx["figures"] = {r.name: [_figure(out_dir, f) for f in r.figures] for r in results}
    ctx["bench_figures"] = [_figure(out_dir, f) for f in BENCH_FIGURES if bench and _figure_path(out_dir, f).is_file()]
    return _env().get_template("index.html.j2").render(ctx)


def render_markdown(
    results: list[CheckResult], provenance: dict, quick: bool, gate_summary: list[dict] | None, passed: bool,
    bench: dict | None = None, execution: dict | None = None,
) -> str:
    """report.md (templates/report.md.j2); figures referenced as figures/NAME."""
    ctx = _context(results, provenance, quick, gate_summary, passed, bench, execution)
    text = _env().get_template("report.md.j2").render(ctx)
    return text.rstrip("\n") + "\n"


# --------------------------------------------------------------------------- entry points


def _render(out_dir: Path, payload: dict[str, Any]) -> dict[str, Any]:
    """Write metrics.json, report.md and index.html from a results.json payload."""
    results = [_result_from_json(d) for d in payload.get("results", [])]
    provenance = dict(payload.get("provenance") or {})
    quick = bool(payload.get("quick", False))
    gate_summary = payload.get("gate_summary") or None
    bench = payload.get("bench") or None
    execution = payload.get("execution")
    metrics = build_metrics(results, provenance, quick, gate_summary, execution)
    _dump(out_dir / "metrics.json", metrics)
    junit.write(out_dir / "junit.xml", metrics, gate_summary)
    passed = bool(metrics["passed"])
    md = render_markdown(results, provenance, quick, gate_summary, passed, bench, execution)
    (out_dir / "report.md").write_text(md, encoding="utf-8")
    page = render_html(out_dir, results, provenance, quick, gate_summary, passed, bench, execution)
    (out_dir / "index.html").write_text(page, encoding="utf-8")
    return metrics


def write_report(
    out_dir: Path,
    results: list[CheckResult],
    provenance: dict,
    quick: bool,
    gate_summary: list[dict] | None = None,
    bench_dir: Path | None = None,
    execution: dict | None = None,
) -> dict[str, Any]:
    """Write the full report into ``out_dir`` and return the metrics.json dict. With
    ``bench_dir`` holding a bench.json (make bench), its numbers and plots are included; with
    ``execution`` (harness.parallel.Cluster.summary), where the runs ran and which ran again.

    Overall ``passed`` is true iff there is at least one check, every check passed and
    no ``gate_summary`` row has status ``"regressed"``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    _dump(out_dir / "provenance.json", provenance)
    payload = {
        "schema": SCHEMA,
        "quick": bool(quick),
        "provenance": provenance,
        "gate_summary": gate_summary,
        "results": [r.to_dict() for r in results],
        "bench": _load_bench(out_dir, bench_dir),
        **({"execution": execution} if execution is not None else {}),
    }
    _dump(out_dir / "results.json", payload)
    # Render from the stored JSON so that rerender() gives byte-identical output.
    return _render(out_dir, json.loads((out_dir / "results.json").read_text(encoding="utf-8")))


def _load_bench(out_dir: Path, bench_dir: Path | None) -> dict | None:
    """bench.json of bench_dir (None if absent or unreadable); its plots are copied into
    the report's figures/ so the report stays self-contained."""
    if bench_dir is None or not (Path(bench_dir) / "bench.json").is_file():
        return None
    try:
        bench = json.loads((Path(bench_dir) / "bench.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    (out_dir / "figures").mkdir(parents=True, exist_ok=True)
    for src, dst in (("bench.png", "bench.png"), ("phases.png", "bench_phases.png")):
        if (Path(bench_dir) / src).is_file():
            shutil.copyfile(Path(bench_dir) / src, out_dir / "figures" / dst)
    return bench


def rerender(report_dir: Path) -> None:
    """Rebuild metrics.json, report.md and index.html from ``report_dir/results.json``."""
    report_dir = Path(report_dir)
    src = report_dir / "results.json"
    if not src.is_file():
        raise FileNotFoundError(f"{src} not found: not a verify report directory (run `python -m harness verify`)")
    _render(report_dir, json.loads(src.read_text(encoding="utf-8")))
