"""The mutation report: reports/mutation/<date>-<sha>/ summary.md, mutants.json, index.html."""

from __future__ import annotations

import html
import json
from collections import defaultdict
from pathlib import Path

from tools.mutation import marks

KILLED = ("killed", "killed (time limit)")


def stale_marks(repo: Path, files: list[str], generated: set[str] | None = None) -> dict[str, str]:
    """Marks of equivalent.toml for the given source files that name no mutant of the sources now:
    key -> what is wrong and how to fix it (tools.mutation.marks.orphans). A mark names its mutant
    by file, routine, statement and mutation (not the line), so moving code keeps it; editing the
    marked statement orphans it, and the mutant would then count as a survivor unnoticed: the mark
    must be reviewed again."""
    return marks.orphans(repo, files, generated)


def equivalent_keys() -> dict[str, str]:
    """Mutants marked equivalent by hand (reviewed), content key -> reason."""
    return {m.key: m.reason for m in marks.load()}


def mark(row: dict) -> str:
    """What a mark names for a report row or mutant: its content key (rows of reports made before
    the keys existed have only their line-based id, which no mark names)."""
    return row.get("key") or row["id"]


def score(rows: list[dict]) -> dict:
    """Kill rates over the mutants that count (compiled, not marked equivalent), overall and per
    file: by `make test` (kill_rate: the fast and full tiers), and by make test and `make verify`
    (the verify tier, run on make test's survivors with --verify); the share of the killed ones
    that the fast tier killed."""
    eq = equivalent_keys()

    def counts(rs):
        live = [r for r in rs if r["verdict"] in (*KILLED, "survived") and mark(r) not in eq]
        every_kill = [r for r in live if r["verdict"] in KILLED]
        killed = [r for r in every_kill if r.get("tier") != "verify"]
        fast = [r for r in killed if r.get("tier") == "fast"]
        verified = [r for r in live if r.get("tier") == "verify"]
        return {"mutants": len(rs), "counted": len(live), "killed": len(killed),
                "kill_rate": len(killed) / len(live) if live else float("nan"),
                "verify_runs": len(verified), "killed_with_verify": len(every_kill),
                "kill_rate_with_verify": len(every_kill) / len(live) if live else float("nan"),
                "killed_by_fast_tier": len(fast) / len(killed) if killed else float("nan"),
                "no_compile": sum(r["verdict"] == "no-compile" for r in rs),
                "equivalent": sum(mark(r) in eq for r in rs),
                "time_limit": sum(r["verdict"] == "killed (time limit)" for r in rs)}

    by_file = defaultdict(list)
    for r in rows:
        by_file[r["file"]].append(r)
    return {"overall": counts(rows), "files": {f: counts(rs) for f, rs in sorted(by_file.items())}}


def _pct(x: float) -> str:
    return "n/a" if x != x else f"{100 * x:.1f} %"


def write(out: Path, rows: list[dict], meta: dict) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    sc = score(rows)
    eq = equivalent_keys()
    (out / "mutants.json").write_text(json.dumps({"meta": meta, "score": sc, "mutants": rows}, indent=1) + "\n")
    o = sc["overall"]
    md = [f"# Mutation testing of the Fortran core ({meta['rev'][:12]}, {meta['date']})", "",
          f"Sample: {o['mutants']} mutants ({meta['sampling']}); tiers: {meta['tiers']}.", "",
          f"**Kill rate: {_pct(o['kill_rate'])}** of {o['counted']} counted mutants "
          f"({o['killed']} killed; {o['no_compile']} did not compile and {o['equivalent']} are marked "
          f"equivalent: neither counts). Killed by the fast tier: {_pct(o['killed_by_fast_tier'])} of the killed. "
          f"{o['time_limit']} were killed by the time limit (a hang counts as killed).", "",
          *_verify_lines(o),
          *_run_lines(meta),
          "| file | mutants | counted | killed | kill rate | fast tier share |", "|---|---|---|---|---|---|"]
    md += [f"| {f} | {c['mutants']} | {c['counted']} | {c['killed']} | {_pct(c['kill_rate'])} | "
           f"{_pct(c['killed_by_fast_tier'])} |" for f, c in sc["files"].items()]
    surv = [r for r in rows if (r["verdict"] == "survived" or r.get("tier") == "verify") and mark(r) not in eq]
    wrong = [r for r in rows if mark(r) in eq and r["verdict"] in KILLED]
    if wrong:   # a test told them apart: the mark is wrong (they are run through the fast tier only)
        md += ["", f"**{len(wrong)} mutants marked equivalent were killed** (check their marks in "
               "tools/mutation/equivalent.toml): " + ", ".join(f"`{r['id']}` by {r['killed_by']}" for r in wrong)]
    if meta.get("stale_marks"):
        md += ["", f"**{len(meta['stale_marks'])} marks in tools/mutation/equivalent.toml name no mutant of "
               "this revision** (their statement changed or left its routine; re-check and update them): "
               + ", ".join(f"`{i}`" for i in meta["stale_marks"])]
    md += ["", f"## Survivors of make test ({len(surv)})", ""]
    md += [f"- `{r['file']}:{r['line']}` `{r['before'].strip()}` -> `{r['after'].strip()}`"
           + (f" (killed by {r['killed_by']})" if r["verdict"] in KILLED else
              " (survived make verify too)" if r.get("tier") == "verify" else "") for r in surv]
    md += ["", "## Every mutant", "", "| mutant | rule | verdict | killed by | s |", "|---|---|---|---|---|"]
    md += [f"| `{r['file']}:{r['line']}` | `{r['rule'].replace('|', '/')}` | "
           f"{'equivalent' if mark(r) in eq else r['verdict']} | {r['killed_by']} | {r['seconds']:.0f} |"
           for r in rows]
    (out / "summary.md").write_text("\n".join(md) + "\n")
    _html(out, sc, rows, eq, meta)
    return sc


def _verify_lines(o: dict) -> list[str]:
    """The kill rate with `make verify` as well, where the verify tier ran (markdown lines)."""
    if not o["verify_runs"]:
        return []
    return [f"**With make verify: {_pct(o['kill_rate_with_verify'])}** ({o['killed_with_verify']} killed; "
            f"make verify ran on {o['verify_runs']} survivors of make test).", ""]


def _run_lines(meta: dict) -> list[str]:
    """How long the run took and on what (markdown lines), from meta's run and provenance."""
    out = []
    r = meta.get("run")
    if r:
        resumed = f" (resumed: {r['resumed_with']} were tested before)" if r["resumed_with"] else ""
        verified = f", make verify on {r['verified']} survivors" if r.get("verified") else ""
        out.append(f"Run: {r['seconds'] / 60:.1f} min wall time for {r['tested']} mutants{verified} with "
                   f"{r['jobs']} parallel scratch builds{resumed}.")
    for e in meta.get("earlier", []):   # the runs before a resumed one, oldest first
        line = _run_lines({"run": e["run"]})[0].removeprefix("Run: ")
        out.append(f"Earlier run of this report ({e['rev'][:12]}, {e['date']}): {line}")
    p = meta.get("provenance")
    if p:
        out.append(f"Provenance: {p.get('git_sha', '?')[:12]} (dirty: {p.get('dirty')}), {p.get('compiler')}, "
                   f"flags `{p.get('fflags')}`, Python {p.get('python')}, numpy {p.get('numpy', '?')}, "
                   f"LAPACK {p.get('lapack')}; {p.get('cpu')} ({p.get('nproc')} cores); {p.get('date')}.")
    return [*out, ""] if out else []


def _html(out: Path, sc: dict, rows: list[dict], eq: dict, meta: dict) -> None:
    o = sc["overall"]
    e = html.escape
    colour = {"killed": "#dafbe1", "killed (time limit)": "#dafbe1", "survived": "#ffebe9"}
    body = [f"<h1>Mutation testing of the Fortran core</h1><p>{e(meta['rev'][:12])}, {e(meta['date'])}; "
            f"{e(meta['sampling'])}; tiers: {e(meta['tiers'])}.</p>",
            f"<p><b>Kill rate {_pct(o['kill_rate'])}</b> of {o['counted']} counted mutants; fast tier "
            f"{_pct(o['killed_by_fast_tier'])} of the killed; {o['no_compile']} did not compile; "
            f"{o['equivalent']} marked equivalent; {o['time_limit']} killed by the time limit.</p>",
            *(f"<p>{e(line)}</p>" for line in _run_lines(meta) if line),
            "<table><tr><th>file</th><th>mutants</th><th>counted</th><th>killed</th><th>kill rate</th></tr>"]
    body += [f"<tr><td>{e(f)}</td><td>{c['mutants']}</td><td>{c['counted']}</td><td>{c['killed']}</td>"
             f"<td>{_pct(c['kill_rate'])}</td></tr>" for f, c in sc["files"].items()]
    body.append("</table><h2>Every mutant</h2><table><tr><th>mutant</th><th>diff</th><th>verdict</th>"
                "<th>killed by</th><th>s</th></tr>")
    for r in rows:
        v = "equivalent: " + eq[mark(r)] if mark(r) in eq else r["verdict"]
        body.append(f"<tr style='background:{colour.get(r['verdict'], '#f6f8fa')}'><td>{e(r['file'])}:{r['line']}</td>"
                    f"<td><pre>- {e(r['before'].strip())}\n+ {e(r['after'].strip())}</pre></td><td>{e(v)}</td>"
                    f"<td>{e(r['killed_by'])}</td><td>{r['seconds']:.0f}</td></tr>")
    body.append("</table>")
    style = ("body{font-family:sans-serif;margin:2rem;max-width:1200px} table{border-collapse:collapse} "
             "td,th{border:1px solid #d0d7de;padding:.2rem .4rem;font-size:.85rem;vertical-align:top} "
             "pre{margin:0;white-space:pre-wrap}")
    (out / "index.html").write_text(f"<!doctype html><html><head><meta charset='utf-8'><title>mutation "
                                    f"{e(meta['rev'][:12])}</title><style>{style}</style></head><body>"
                                    + "\n".join(body) + "</body></html>\n")
