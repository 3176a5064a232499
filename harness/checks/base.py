"""Shared result types for verification checks.

Every check module in ``harness.checks`` exposes ``NAME``, ``REQUIREMENT`` and
``run(ctx) -> CheckResult``. The report writer and the gate only ever see these types.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class Gate:
    """One acceptance bound on one metric.

    kind: ``"max"`` (value <= bound), ``"min"`` (value >= bound) or ``"gold"``
    (value within tolerance of the gold baseline; ``bound`` holds the gold value).

    known_limitation: where set, the reason the model is known not to meet this bound (a
    documented limitation of the physics it solves, not of the code). Such a gate is still
    evaluated and shown: a miss reads XFAIL and does not fail the check, a pass reads XPASS
    (the limitation is no longer seen: remove the mark). Like pytest's xfail.
    """

    metric: str
    value: float
    bound: float
    kind: str
    passed: bool
    note: str = ""
    known_limitation: str = ""

    @classmethod
    def at_most(cls, metric: str, value: float, bound: float, note: str = "", known_limitation: str = "") -> Gate:
        return cls(metric, float(value), float(bound), "max", bool(value <= bound), note, known_limitation)

    @classmethod
    def at_least(cls, metric: str, value: float, bound: float, note: str = "", known_limitation: str = "") -> Gate:
        return cls(metric, float(value), float(bound), "min", bool(value >= bound), note, known_limitation)

    @property
    def outcome(self) -> str:
        """PASS, FAIL, XFAIL (a known limitation, not met) or XPASS (a known limitation, met)."""
        if self.known_limitation:
            return "XPASS" if self.passed else "XFAIL"
        return "PASS" if self.passed else "FAIL"

    @property
    def counts(self) -> bool:
        """Whether this gate decides the check's verdict (a known limitation does not)."""
        return not self.known_limitation


@dataclass
class CheckResult:
    """Outcome of one check: metrics, gates, figures, tables and a verdict."""

    name: str
    requirement: str
    metrics: dict[str, float] = field(default_factory=dict)
    gates: list[Gate] = field(default_factory=list)
    figures: list[str] = field(default_factory=list)  # file names under <report>/figures/
    tables: list[str] = field(default_factory=list)  # Markdown tables
    notes: list[str] = field(default_factory=list)  # free Markdown paragraphs
    error: str | None = None  # set when the check could not run to the end
    wall_s: float = 0.0

    @property
    def passed(self) -> bool:
        return self.error is None and all(g.passed for g in self.gates if g.counts)

    @property
    def verdict(self) -> str:
        if self.error is not None:
            return f"FAILED to run: {self.error}"
        def listed(gates):
            return ", ".join(f"{g.metric}={g.value:.4g} ({g.kind} {g.bound:.4g})" for g in gates)

        failed = [g for g in self.gates if g.counts and not g.passed]
        known = [g for g in self.gates if not g.counts and not g.passed]
        lim = f"; known limitations not met (XFAIL): {listed(known)}" if known else ""
        if not failed:
            return f"passed ({sum(g.counts for g in self.gates)} gates{lim})"
        return f"FAILED: {listed(failed)}{lim}"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["passed"] = self.passed
        d["verdict"] = self.verdict
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CheckResult:
        keys = ("metric", "value", "bound", "kind", "passed", "note", "known_limitation")
        gates = [Gate(**{k: g[k] for k in keys if k in g}) for g in d.get("gates", [])]
        return cls(
            name=d["name"],
            requirement=d.get("requirement", ""),
            metrics=dict(d.get("metrics", {})),
            gates=gates,
            figures=list(d.get("figures", [])),
            tables=list(d.get("tables", [])),
            notes=list(d.get("notes", [])),
            error=d.get("error"),
            wall_s=float(d.get("wall_s", 0.0)),
        )


@dataclass
class CheckContext:
    """What a check gets to run: where to write figures, whether this is the quick tier."""

    out_dir: Path  # the report directory; figures go to out_dir / "figures"
    quick: bool
    runs_dir: Path  # scratch directory for the check's simulation runs
    progress: bool = True
    # runs started before the first check by the check's start_early(ctx) (parallel.submit), by name
    early: dict[str, Any] = field(default_factory=dict)

    @property
    def fig_dir(self) -> Path:
        p = self.out_dir / "figures"
        p.mkdir(parents=True, exist_ok=True)
        return p


def runs_by_h(fn, hs) -> list:
    """[fn(h) for h in hs] side by side (harness.parallel.pmap); a failed run raises, named by its h."""
    from harness import parallel

    outs = parallel.pmap(fn, [(h,) for h in hs])
    for h, o in zip(hs, outs, strict=True):
        if isinstance(o, Exception):
            raise RuntimeError(f"the h = {h:g} run failed: {o}")
    return outs


def put_level_metrics(res: CheckResult, h: float, metrics: dict, steps: int) -> None:
    """A resolution level's metrics into res, each named h<h>_<key> (h0005_cp_max), and its steps."""
    tag = f"h{h:g}".replace(".", "")
    for k, v in metrics.items():
        res.metrics[f"{tag}_{k}"] = v
    res.metrics[f"{tag}_steps"] = float(steps)


def run_completed(res: CheckResult, suffix: str, label: str, out: Any) -> bool:
    """Gate `completed<suffix>` that the run `label` reached t_end (out is its result, or the
    exception it raised, which the gate's text and a note then name); True if it did."""
    completed = not isinstance(out, Exception)
    res.metrics[f"completed{suffix}"] = float(completed)
    res.gates.append(Gate.at_least(f"completed{suffix}", float(completed), 1.0,
                                   f"{label} reached t_end" + ("" if completed else f": {out}")))
    if not completed:
        res.notes.append(f"{label}: did not complete: {out}")
    return completed
