"""Mutants of the Fortran sources: universalmutator's engine and rules, a stratified sample."""

from __future__ import annotations

import contextlib
import hashlib
import io
import math
import random
import re
from dataclasses import asdict, dataclass
from pathlib import Path

from tools.mutation import marks

RULES = [str(Path(__file__).with_name("fortran.rules")), "fortran.rules"]  # ours, universalmutator's builtin
# Lines never mutated: comments, blank, directives, declarations and module structure, and the
# error messages (their text is not physics; a changed message is caught by no physics test).
IGNORE = [
    r"^\s*(!|$)",
    r"^\s*#",
    r"::",
    r"^\s*(use|implicit|public|private|module|contains|end|subroutine|function|pure|elemental|"
    r"recursive|type|interface|integer|real|logical|character|procedure|program|include)\b",
    r"^\s*(if\s*\(.*\)\s*)?(call\s+st%set|write\s*\(\s*buf)",
    r"^\s*&\s*['\"]",
    r"^\s*['\"]",
    r"^\s*(case|select)\b",
]


@dataclass(frozen=True)
class Mutant:
    id: str        # this commit's name: file, line and a hash of the mutated line
    file: str      # path relative to the repository
    line: int      # 1-based
    rule: str      # the rule that made it (LHS ==> RHS)
    before: str
    after: str
    key: str = ""  # by content, what equivalence marks name: file, routine, statement and mutation

    def to_dict(self) -> dict:
        return asdict(self)


ROUTINE = re.compile(r"^\s*(?:(?:pure|elemental|recursive|impure|module|integer|real|logical|complex|"
                     r"type\s*\([^)]*\)|(?:integer|real|logical)\s*\([^)]*\))\s+)*"
                     r"(?:subroutine|function)\s+(\w+)", re.IGNORECASE)
END_ROUTINE = re.compile(r"^\s*end\s*(?:subroutine|function)\b", re.IGNORECASE)


def routines(lines: list[str]) -> list[str]:
    """The innermost subroutine or function each line is in ("module" outside any)."""
    out, stack = [], []
    for text in lines:
        code = text.split("!")[0]
        if END_ROUTINE.match(code):
            out.append(stack[-1] if stack else "module")
            if stack:
                stack.pop()
            continue
        m = ROUTINE.match(code)
        if m and not code.strip().lower().startswith("end"):
            stack.append(m.group(1).lower())
        out.append(stack[-1] if stack else "module")
    return out


def _engine():
    try:
        from universalmutator import mutator
    except ImportError as exc:  # make mutate installs it; a plain python -m tools.mutation may not have it
        raise SystemExit("error: universalmutator is not installed; run `make mutate` (it installs the "
                         "pinned mutation-testing packages into .venv)") from exc
    return mutator


def file_mutants(repo: Path, rel: str) -> list[Mutant]:
    """Every mutant of one source file (deduplicated by line and text)."""
    mutator = _engine()
    lines = (repo / rel).read_text(encoding="utf-8").splitlines(keepends=True)
    with contextlib.redirect_stdout(io.StringIO()):
        raw = mutator.mutants_regexp(lines, ruleFiles=RULES, ignorePatterns=IGNORE)
    where = routines(lines)
    out, seen, count = [], set(), {}
    for lineno, text, rule, _ in sorted(raw, key=lambda r: r[0]):
        before = lines[lineno - 1]
        if text.strip() == before.strip() or (lineno, text) in seen or text.count("\n") > 1:
            continue
        if _unbalanced(text):
            continue
        seen.add((lineno, text))
        same = (where[lineno - 1], marks.compact(before), marks.compact(text))
        if same[1] == same[2]:   # only a comment (or blanks, or case) changed: no mutant
            continue
        digest = hashlib.sha1(text.encode()).hexdigest()[:8]
        stem, routine = Path(rel).stem, where[lineno - 1]
        count[same] = count.get(same, 0) + 1   # the n-th copy of this statement in its routine
        out.append(Mutant(f"{stem}:{lineno}:{digest}", rel, lineno, rule[0], before.rstrip("\n"),
                          text.rstrip("\n"), marks.content_key(stem, routine, before, text, count[same])))
    return out


def _unbalanced(text: str) -> bool:
    """A mutant whose parentheses no longer balance cannot compile: not worth a build."""
    code = re.sub(r"'[^']*'|\"[^\"]*\"", "", text.split("!")[0])
    return code.count("(") != code.count(")")


def sources(repo: Path) -> list[str]:
    return sorted(str(p.relative_to(repo)) for p in (repo / "fortran" / "src").glob("*.f90"))


def sample(all_mutants: dict[str, list[Mutant]], n: int, seed: int) -> list[Mutant]:
    """A stratified random sample of about n mutants: every file gets a share proportional to the
    square root of its mutant count (small files are not drowned by large ones), at least
    min(3, its count); drawn with a fixed seed, so the same commit gives the same sample."""
    rng = random.Random(seed)
    weights = {f: math.sqrt(len(m)) for f, m in all_mutants.items() if m}
    total = sum(weights.values())
    picked = []
    for f in sorted(weights):
        pool = sorted(all_mutants[f], key=lambda m: m.id)
        k = min(len(pool), max(3, round(n * weights[f] / total)))
        picked += rng.sample(pool, k)
    return picked
