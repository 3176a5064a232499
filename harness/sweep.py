"""``cpdi sweep``: a parameter study over case overrides.

``cpdi sweep CASE --set grid.cell=0.0146,0.0073 --set solver.cfl=0.3,0.5`` runs the cartesian
product of the values (numbered in the order given, the last ``--set`` varying fastest), each
run into ``OUT/run_NNN/`` as ``cpdi run`` would, and writes one table of the results
(``OUT/sweep.csv`` and ``OUT/sweep.md``) and one plot of a chosen summary metric
(``OUT/sweep.png``: the metric against the first swept key, one line per combination of the others).

The table has, per run: the swept values, status, particles, steps, simulated time, wall time,
particle updates per second and, for every probe series, its final value (``final.<series>``).
``--metric`` names any of these columns (default ``wall_s``). A failed run is a row with status
``failed`` and its error; the sweep goes on and exits 1 at the end.

The runs go side by side to a Dask cluster (harness.parallel): a local one of ``--jobs``
single-threaded workers (default: one per core), or the existing cluster at ``--scheduler``;
``--jobs 1`` runs them one after another in this process, with progress bars. A run whose worker
was lost is run again and named in the closing lines.
"""

from __future__ import annotations

import csv
import itertools
import math
from pathlib import Path

from harness.cases import CaseError

BASE_COLUMNS = ["status", "particles", "steps", "simulated_time", "wall_s", "particle_updates_per_s"]


def split_values(text: str) -> list[str]:
    """Split ``a,b,[1,2]`` on the commas outside brackets and quotes."""
    out, depth, quote, cur = [], 0, None, ""
    for ch in text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(cur.strip())
            cur = ""
            continue
        cur += ch
    out.append(cur.strip())
    return out


def parse_axes(assignments: list[str]) -> list[tuple[str, list[str]]]:
    """``["a.b=1,2", "c.d=x"]`` -> ``[("a.b", ["1", "2"]), ("c.d", ["x"])]``; raises CaseError."""
    axes: list[tuple[str, list[str]]] = []
    for a in assignments:
        key, sep, values = a.partition("=")
        key = key.strip()
        if not sep or not key:
            raise CaseError(f"--set {a!r}: expected SECTION.KEY=V1,V2,..., e.g. --set solver.cfl=0.3,0.5")
        vals = split_values(values)
        if any(v == "" for v in vals):
            raise CaseError(f"--set {a!r}: an empty value; give comma-separated values, e.g. {key}=0.3,0.5")
        if key in (k for k, _ in axes):
            raise CaseError(f"--set {key} is given twice; list all its values in one --set {key}=V1,V2")
        axes.append((key, vals))
    return axes


def combinations(axes: list[tuple[str, list[str]]]) -> list[dict[str, str]]:
    keys = [k for k, _ in axes]
    return [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*(v for _, v in axes))]


def _number(v):
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return "" if v is None else str(v)


def write_table(rows: list[dict], columns: list[str], out: Path) -> None:
    with open(out / "sweep.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({c: _fmt(r.get(c)) for c in columns})
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_fmt(r.get(c)).replace("|", "\\|") for c in columns) + " |" for r in rows]
    (out / "sweep.md").write_text("\n".join(lines) + "\n")


def plot(rows: list[dict], keys: list[str], metric: str, out: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # the first key with more than one value is the x axis, the other varying keys make the lines;
    # single-valued keys are constants of the study (in the title)
    varying = [k for k in keys if len({r[k] for r in rows}) > 1] or keys[:1]
    x_key, others = varying[0], varying[1:]
    fixed = [f"{k} = {rows[0][k]}" for k in keys if k not in varying]
    if fixed:
        title += "\n" + ", ".join(fixed)
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in others), []).append(r)
    numeric_x = all(_number(r[x_key]) is not None for r in rows)
    labels_x = list(dict.fromkeys(r[x_key] for r in rows))
    for g, members in groups.items():
        pts = [(_number(r[x_key]) if numeric_x else labels_x.index(r[x_key]), _number(r.get(metric)))
               for r in members]
        pts = [(x, y) for x, y in pts if y is not None]
        label = ", ".join(f"{k} = {v}" for k, v in zip(others, g, strict=True)) or None
        if pts:
            ax.plot(*zip(*sorted(pts), strict=True), "o-", label=label)
    if not numeric_x:
        ax.set_xticks(range(len(labels_x)), labels_x)
    ax.set_xlabel(x_key)
    ax.set_ylabel(metric)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if others:
        ax.legend(fontsize="small")
    fig.tight_layout()
    path = out / "sweep.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _run(case_path: str, overrides: list[str], run_dir: Path, progress: bool):
    """One run of the sweep (on a cluster worker): (summary, final value of each probe series, error)."""
    from harness import cases, runner

    try:
        res = runner.run(cases.load(case_path, overrides), run_dir, progress=progress)
    except runner.RunFailed as exc:
        return exc.summary, {}, str(exc)
    return res.summary, {k: float(v[-1]) for k, v in res.series.items() if k != "t" and len(v)}, None


def main(case_path: str, assignments: list[str], out: Path, metric: str = "wall_s", progress: bool = True,
         jobs: int | None = None, scheduler: str | None = None) -> int:
    from harness import cases, parallel

    axes = parse_axes(assignments)
    if not axes:
        raise CaseError("nothing to sweep: give at least one --set SECTION.KEY=V1,V2,...")
    combos = combinations(axes)
    for combo in combos:  # every combination validates before anything runs
        cases.load(case_path, [f"{k}={v}" for k, v in combo.items()])
    keys = [k for k, _ in axes]
    out = out.resolve()  # the workers may not share this process's working directory
    out.mkdir(parents=True, exist_ok=True)
    with parallel.cluster(jobs, scheduler) as pool:
        print(f"[sweep] {len(combos)} runs: {pool.describe()}", flush=True)
        for i, combo in enumerate(combos):
            print(f"[sweep] run_{i:03d}: " + ", ".join(f"{k}={v}" for k, v in combo.items()), flush=True)
        outs = parallel.pmap(_run, [(str(Path(case_path).resolve()), [f"{k}={v}" for k, v in combo.items()],
                                     out / f"run_{i:03d}", progress and pool.serial)
                                    for i, combo in enumerate(combos)])
        reruns, uncounted = pool.reruns, pool.uncounted
    rows: list[dict] = []
    series_cols: list[str] = []
    for i, (combo, res) in enumerate(zip(combos, outs, strict=True)):
        row: dict = {"run": f"run_{i:03d}", **combo}
        if isinstance(res, Exception):  # not a solver failure: the run could not be made
            res = ({"status": "failed"}, {}, f"{type(res).__name__}: {res}")
        summary, finals, error = res
        if error is not None:
            row["error"] = error
            print(f"[sweep] {row['run']} failed: {error}", flush=True)
        row.update({c: summary.get(c) for c in BASE_COLUMNS})
        for name, value in finals.items():
            row[f"final.{name}"] = value
            if f"final.{name}" not in series_cols:
                series_cols.append(f"final.{name}")
        rows.append(row)
    for r in reruns:
        print(f"[sweep] run_{r.index:03d} was run {r.runs} times: its worker was lost; the row is the last run's",
              flush=True)
    if uncounted:
        print("[sweep] the scheduler's event log could not be read: runs re-run after a lost worker are not known",
              flush=True)
    columns = ["run", *keys, *BASE_COLUMNS, *series_cols] + (["error"] if any("error" in r for r in rows) else [])
    if metric not in columns:
        print(f"error: --metric {metric!r} is not a column of the table; choose one of: "
              f"{', '.join(c for c in columns if c not in ('run', 'status', 'error', *keys))}")
        write_table(rows, columns, out)
        return 2
    write_table(rows, columns, out)
    png = plot(rows, keys, metric, out, f"{Path(case_path).stem}: {metric}")
    print(f"sweep: {len(rows)} runs, {sum(r['status'] == 'completed' for r in rows)} completed -> "
          f"{out / 'sweep.csv'}, {out / 'sweep.md'}, {png}")
    return 0 if all(r["status"] == "completed" for r in rows) else 1
