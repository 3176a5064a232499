"""Verification report writer: metrics.json, provenance.json, results.json, report.md, index.html.

Layout of a report directory (DESIGN.md, "metrics.json" contract)::

    <out_dir>/metrics.json     machine-readable verdicts (schema 1)
    <out_dir>/provenance.json  code/toolchain/machine provenance
    <out_dir>/results.json     full CheckResult dicts + quick + provenance + gate_summary
    <out_dir>/report.md        Markdown report, figures referenced as figures/x.png
    <out_dir>/index.html       self-contained HTML report (figures embedded as base64)
    <out_dir>/junit.xml        JUnit XML: a testsuite per check, a testcase per gate (harness.junit)
    <out_dir>/figures/*.png    written by the checks

Everything rendered is derived from ``results.json`` alone, so :func:`rerender`
reproduces byte-identical output without re-running any check. Non-finite floats are
stored as ``null`` (strict JSON) and restored to nan on reading.
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
import shutil
from pathlib import Path
from typing import Any

from harness import junit
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

__all__ = ["write_report", "rerender", "build_metrics", "md_to_html"]


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
    results: list[CheckResult], provenance: dict, quick: bool, gate_summary: list[dict] | None = None
) -> dict[str, Any]:
    """The ``metrics.json`` document (schema 1). Extra per-check keys: verdict, wall_s, error."""
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


def _slug(name: str) -> str:
    return "check-" + (re.sub(r"[^A-Za-z0-9_-]+", "-", name).strip("-") or "unnamed")


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


# --------------------------------------------------------------------------- tiny Markdown -> HTML


def _md_inline(text: str) -> str:
    """Escape HTML and render `code` and **bold** (nothing else)."""
    parts = re.split(r"(`[^`]*`)", text)
    out = []
    for part in parts:
        if len(part) >= 2 and part.startswith("`") and part.endswith("`"):
            out.append(f"<code>{html.escape(part[1:-1])}</code>")
        else:
            esc = html.escape(part)
            out.append(re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", esc))
    return "".join(out)


def _split_row(line: str) -> list[str]:
    """Cells of a pipe-table row; ``\\|`` is a literal pipe."""
    line = line.strip()
    if line.startswith("|"):
        line = line[1:]
    if line.endswith("|") and not line.endswith("\\|"):
        line = line[:-1]
    cells = re.split(r"(?<!\\)\|", line)
    return [c.strip().replace("\\|", "|") for c in cells]


_SEPARATOR = re.compile(r"^\s*\|?\s*:?-{1,}:?\s*(\|\s*:?-{1,}:?\s*)*\|?\s*$")


def _align(spec: str) -> str:
    spec = spec.strip()
    if spec.startswith(":") and spec.endswith(":"):
        return "center"
    if spec.endswith(":"):
        return "right"
    return "left" if spec.startswith(":") else ""


def _table_to_html(lines: list[str]) -> str:
    """A Markdown pipe table (header, separator, rows) as an HTML table."""
    header = _split_row(lines[0])
    aligns: list[str] = []
    body = lines[1:]
    if body and _SEPARATOR.match(body[0]):
        aligns = [_align(s) for s in _split_row(body[0])]
        body = body[1:]

    def cell(tag: str, text: str, i: int) -> str:
        a = aligns[i] if i < len(aligns) else ""
        style = f' style="text-align:{a}"' if a else ""
        return f"<{tag}{style}>{_md_inline(text)}</{tag}>"

    out = [
        "<table>",
        "<thead><tr>" + "".join(cell("th", h, i) for i, h in enumerate(header)) + "</tr></thead>",
        "<tbody>",
    ]
    for line in body:
        cells = _split_row(line)
        out.append("<tr>" + "".join(cell("td", c, i) for i, c in enumerate(cells)) + "</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def md_to_html(text: str) -> str:
    """Minimal Markdown: pipe tables, ``- `` bullet lists, paragraphs with `code`/**bold**."""
    blocks: list[str] = []
    lines = text.strip("\n").splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        kind = "table" if line.lstrip().startswith("|") else "list" if line.lstrip().startswith(("- ", "* ")) else "p"
        group = []
        while i < len(lines) and lines[i].strip():
            cur = lines[i].lstrip()
            cur_kind = "table" if cur.startswith("|") else "list" if cur.startswith(("- ", "* ")) else "p"
            if cur_kind != kind and not (kind == "list" and cur_kind == "p"):
                break
            group.append(lines[i])
            i += 1
        if kind == "table":
            blocks.append(_table_to_html(group))
        elif kind == "list":
            items: list[str] = []
            for g in group:
                s = g.lstrip()
                if s.startswith(("- ", "* ")):
                    items.append(s[2:])
                elif items:  # continuation line
                    items[-1] += " " + s
            blocks.append("<ul>" + "".join(f"<li>{_md_inline(it)}</li>" for it in items) + "</ul>")
        else:
            blocks.append("<p>" + _md_inline(" ".join(s.strip() for s in group)) + "</p>")
    return "\n".join(blocks)


# --------------------------------------------------------------------------- HTML

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, Helvetica, Arial, sans-serif;
       color: #1f2328; background: #fff; line-height: 1.5; margin: 0; }
main { max-width: 1100px; margin: 0 auto; padding: 1.5rem 2rem 4rem; }
h1 { margin-bottom: .3rem; } h2 { border-bottom: 1px solid #d0d7de; padding-bottom: .3rem; margin-top: 2.2rem; }
h3 { margin-top: 1.6rem; }
table { border-collapse: collapse; margin: .8rem 0; font-size: .92rem; }
th, td { border: 1px solid #d0d7de; padding: .3rem .6rem; vertical-align: top; }
th { background: #f6f8fa; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
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
.verdict { font-weight: 600; }
"""


def _e(v: Any) -> str:
    return html.escape(_fmt(v) if not isinstance(v, str) else v)


def _badge(passed: bool) -> str:
    return '<span class="badge pass">PASS</span>' if passed else '<span class="badge fail">FAIL</span>'


def _md_outcome(g) -> str:
    """pass / **FAIL**, or XFAIL / XPASS with the known limitation."""
    if g.counts:
        return "pass" if g.passed else "**FAIL**"
    return f"{g.outcome} (known limitation: {g.known_limitation})"


def _gate_badge(g) -> str:
    """PASS / FAIL, or XFAIL / XPASS for a gate marked as a known limitation."""
    if g.counts:
        return _badge(g.passed)
    return f'<span class="badge known" title="{html.escape(g.known_limitation)}">{g.outcome}</span>'


def _html_rows(header: list[str], rows: list[list[str]], row_classes: list[str] | None = None) -> str:
    """Table from already-escaped cell HTML."""
    out = ["<table>", "<thead><tr>" + "".join(f"<th>{h}</th>" for h in header) + "</tr></thead>", "<tbody>"]
    for i, row in enumerate(rows):
        cls = row_classes[i] if row_classes and row_classes[i] else ""
        attr = f' class="{cls}"' if cls else ""
        out.append(f"<tr{attr}>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def _html_figure(out_dir: Path, name: str) -> str:
    path = _figure_path(out_dir, name)
    if not path.is_file():
        return f'<p class="error">Missing figure: <code>{html.escape(name)}</code></p>'
    mime = _MIME.get(path.suffix.lower(), "application/octet-stream")
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    alt = html.escape(path.name)
    return f'<figure><img alt="{alt}" src="data:{mime};base64,{data}"><figcaption>{alt}</figcaption></figure>'


def _html_check(out_dir: Path, r: CheckResult) -> str:
    parts = [f'<section id="{_slug(r.name)}">', f"<h3>{html.escape(r.name)} {_badge(r.passed)}</h3>"]
    if r.error is not None:
        parts.append(f'<div class="error"><strong>FAILED to run</strong><pre>{html.escape(r.error)}</pre></div>')
    if r.requirement:
        parts.append(f"<blockquote>{_md_inline(r.requirement)}</blockquote>")
    parts.append(
        f'<p class="verdict">Verdict: {html.escape(r.verdict)} '
        f'<span style="font-weight:400;color:#57606a">({r.wall_s:.1f} s)</span></p>'
    )
    if r.gates:
        rows = [
            [
                html.escape(g.metric),
                _e(g.value),
                _e(g.bound),
                html.escape(g.kind),
                _gate_badge(g) + (f" {_md_inline(g.note)}" if g.note else "")
                + (f"<br><em>known limitation:</em> {_md_inline(g.known_limitation)}" if g.known_limitation else ""),
            ]
            for g in r.gates
        ]
        classes = ["" if g.passed or not g.counts else "failgate" for g in r.gates]
        parts.append(_html_rows(["metric", "value", "bound", "kind", "pass"], rows, classes))
    gated = {g.metric for g in r.gates}
    extra = {k: v for k, v in r.metrics.items() if k not in gated}
    if extra:
        parts.append(_html_rows(["other metric", "value"], [[html.escape(k), _e(v)] for k, v in extra.items()]))
    parts.extend(md_to_html(t) for t in r.tables)
    parts.extend(md_to_html(n) for n in r.notes)
    parts.extend(_html_figure(out_dir, f) for f in r.figures)
    parts.append("</section>")
    return "\n".join(parts)


def _gate_table(rows: list[dict], with_reason: bool) -> str:
    body, classes = [], []
    for row in rows:
        status = str(row.get("status", ""))
        badge_cls = {"ok": "pass", "regressed": "fail", "improved": "info"}.get(status, "muted")
        label = f'<span class="badge {badge_cls}">{html.escape(_gate_status_label(status))}</span>'
        cells = [_e(row.get(k)) for k in GATE_SUMMARY_FIELDS[:6]] + [label]
        body.append(cells + ([_e(row.get("reason", ""))] if with_reason else []))
        classes.append(status if status in ("regressed", "improved") else "")
    head = list(GATE_SUMMARY_FIELDS) if with_reason else list(GATE_SUMMARY_FIELDS[:7])
    return _html_rows(head, body, classes)


def _html_gate_summary(rows: list[dict]) -> str:
    """Counts, the rows that need attention (with their reasons), and the full table folded."""
    counts = {k: sum(r.get("status") == k for r in rows) for k in ("ok", "regressed", "improved")}
    out = ["<h2>Regression gate vs gold</h2>",
           f"<p>{len(rows)} metrics compared with <code>reference/gold/metrics.json</code>: "
           f"{counts['ok']} within tolerance, {counts['regressed']} regressed, {counts['improved']} improved.</p>"]
    attention = [r for r in rows if r.get("status") != "ok"]
    if attention:
        out.append(_gate_table(attention, with_reason=True))
    reasons = sorted({str(r.get("reason", "")) for r in rows if r.get("status") == "ok" and r.get("reason")})
    out.append("<details><summary>All compared metrics</summary>" + _gate_table(rows, with_reason=False)
               + "<p>Tolerance reasons:</p><ul>" + "".join(f"<li>{html.escape(x)}</li>" for x in reasons)
               + "</ul></details>")
    return "\n".join(out)


BENCH_PHASES = ("shape", "p2g", "grid", "g2p", "deformation", "stress", "projection")
BENCH_HEADER = ["shape", "particles", "threads", "M updates/s (median)", "bytes/particle"] + \
    [f"{p} ns" for p in BENCH_PHASES]


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


def _html_bench(out_dir: Path, bench: dict | None) -> str:
    if not bench:
        return ""
    parts = ['<h2 id="performance">Performance</h2>', f"<p>{html.escape(_bench_intro(bench))}</p>"]
    if bench.get("summary"):
        parts.append(_html_rows(["target", "value"], [[html.escape(a), html.escape(b)]
                                                     for a, b in _bench_summary_rows(bench)]))
    parts.append(_html_rows(BENCH_HEADER, [[html.escape(c) for c in row] for row in _bench_rows(bench)]))
    for fig in ("bench.png", "bench_phases.png"):
        if _figure_path(out_dir, fig).is_file():
            parts.append(_html_figure(out_dir, fig))
    return "\n".join(parts)


def _md_bench(bench: dict | None) -> str:
    if not bench:
        return ""
    parts = ["## Performance", _bench_intro(bench)]
    if bench.get("summary"):
        parts.append(_md_table(["target", "value"], _bench_summary_rows(bench)))
    parts.append(_md_table(BENCH_HEADER, _bench_rows(bench)))
    return "\n\n".join(parts)


def render_html(
    out_dir: Path,
    results: list[CheckResult],
    provenance: dict,
    quick: bool,
    gate_summary: list[dict] | None,
    passed: bool,
    bench: dict | None = None,
) -> str:
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en">',
        "<head>",
        '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{TITLE}</title>",
        f"<style>{_CSS}</style>",
        "</head>",
        "<body>",
        "<main>",
        f"<h1>{TITLE}</h1>",
    ]
    if quick:
        parts.append(f'<div class="banner">{QUICK_BANNER}</div>')
    parts.append(
        f"<p>Overall: {_badge(passed)} &nbsp; {sum(r.passed for r in results)}/{len(results)} checks "
        f"passed &middot; git {html.escape(str(provenance.get('git_sha', 'unknown'))[:12])} &middot; "
        f"{html.escape(str(provenance.get('date', '')))}</p>"
    )
    parts.append("<h2>Summary</h2>")
    rows = [
        [
            f'<a href="#{_slug(r.name)}">{html.escape(r.name)}</a>',
            _badge(r.passed),
            html.escape(r.verdict),
            f"{r.wall_s:.1f} s",
        ]
        for r in results
    ]
    parts.append(_html_rows(["check", "result", "verdict", "wall time"], rows))
    parts.append("<h2>Provenance</h2>")
    parts.append(
        _html_rows(["key", "value"], [[html.escape(k), html.escape(v)] for k, v in _provenance_rows(provenance, quick)])
    )
    if gate_summary:
        parts.append(_html_gate_summary(gate_summary))
    parts.append("<h2>Checks</h2>")
    parts.extend(_html_check(out_dir, r) for r in results)
    if bench:
        parts.append(_html_bench(out_dir, bench))
    parts += ["</main>", "</body>", "</html>"]
    return "\n".join(parts) + "\n"


# --------------------------------------------------------------------------- Markdown


def _md_cell(v: Any) -> str:
    s = v if isinstance(v, str) else _fmt(v)
    return s.replace("|", "\\|").replace("\n", " ")


def _md_table(header: list[str], rows: list[list[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _pass_word(passed: bool) -> str:
    return "PASS" if passed else "**FAIL**"


def _md_check(r: CheckResult) -> str:
    parts = [f"### {r.name} — {_pass_word(r.passed)}"]
    if r.error is not None:
        parts.append(
            f"> **FAILED to run:** `{r.error}`"
            if "\n" not in r.error and "`" not in r.error
            else "**FAILED to run:**\n\n```\n" + r.error + "\n```"
        )
    if r.requirement:
        parts.append("> " + r.requirement.replace("\n", "\n> "))
    parts.append(f"**Verdict:** {r.verdict} ({r.wall_s:.1f} s)")
    if r.gates:
        parts.append(
            _md_table(
                ["metric", "value", "bound", "kind", "pass"],
                [[g.metric, g.value, g.bound, g.kind, _md_outcome(g)] for g in r.gates],
            )
        )
    gated = {g.metric for g in r.gates}
    extra = [[k, v] for k, v in r.metrics.items() if k not in gated]
    if extra:
        parts.append(_md_table(["other metric", "value"], extra))
    parts.extend(t.strip("\n") for t in r.tables)
    parts.extend(n.strip("\n") for n in r.notes)
    parts.extend(f"![{Path(f).name}](figures/{f.removeprefix('figures/')})" for f in r.figures)
    return "\n\n".join(parts)


def render_markdown(
    results: list[CheckResult], provenance: dict, quick: bool, gate_summary: list[dict] | None, passed: bool,
    bench: dict | None = None,
) -> str:
    parts = [f"# {TITLE}"]
    if quick:
        parts.append(f"> **{QUICK_BANNER}**")
    parts.append(
        f"**Overall: {'PASS' if passed else 'FAIL'}** — {sum(r.passed for r in results)}/{len(results)} checks passed"
    )
    parts.append("## Summary")
    parts.append(
        _md_table(
            ["check", "result", "verdict", "wall time"],
            [[r.name, _pass_word(r.passed), r.verdict, f"{r.wall_s:.1f} s"] for r in results],
        )
    )
    parts.append("## Provenance")
    parts.append(_md_table(["key", "value"], [list(row) for row in _provenance_rows(provenance, quick)]))
    if gate_summary:
        parts.append("## Regression gate vs gold")
        rows = []
        for row in gate_summary:
            status = _gate_status_label(str(row.get("status", "")))
            if row.get("status") == "regressed":
                status = "**regressed**"
            rows.append([row.get(k) for k in GATE_SUMMARY_FIELDS[:6]] + [status, row.get("reason", "")])
        parts.append(_md_table(list(GATE_SUMMARY_FIELDS), rows))
    parts.append("## Checks")
    parts.extend(_md_check(r) for r in results)
    if bench:
        parts.append(_md_bench(bench))
    return "\n\n".join(parts) + "\n"


# --------------------------------------------------------------------------- entry points


def _render(out_dir: Path, payload: dict[str, Any]) -> dict[str, Any]:
    """Write metrics.json, report.md and index.html from a results.json payload."""
    results = [_result_from_json(d) for d in payload.get("results", [])]
    provenance = dict(payload.get("provenance") or {})
    quick = bool(payload.get("quick", False))
    gate_summary = payload.get("gate_summary") or None
    bench = payload.get("bench") or None
    metrics = build_metrics(results, provenance, quick, gate_summary)
    _dump(out_dir / "metrics.json", metrics)
    junit.write(out_dir / "junit.xml", metrics, gate_summary)
    passed = bool(metrics["passed"])
    md = render_markdown(results, provenance, quick, gate_summary, passed, bench)
    (out_dir / "report.md").write_text(md, encoding="utf-8")
    page = render_html(out_dir, results, provenance, quick, gate_summary, passed, bench)
    (out_dir / "index.html").write_text(page, encoding="utf-8")
    return metrics


def write_report(
    out_dir: Path,
    results: list[CheckResult],
    provenance: dict,
    quick: bool,
    gate_summary: list[dict] | None = None,
    bench_dir: Path | None = None,
) -> dict[str, Any]:
    """Write the full report into ``out_dir`` and return the metrics.json dict. With
    ``bench_dir`` holding a bench.json (make bench), its numbers and plots are included.

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
