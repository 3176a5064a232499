"""Move the equivalence marks of tools/mutation/equivalent.toml (and their rows in
docs/notes/mutation_equivalents.md) to the lines their mutants are on now.

A mark's id is file:line:hash, the hash that of the mutated line's text. An edit above a marked
line moves it and orphans the mark (tests/test_mutation_marks.py fails). This finds, for every
orphaned mark, the mutant of the same file with the same hash (the same mutation of the same
statement) and rewrites the id. Where the same text is mutated on several lines, the mutant whose
diff equals the mark's and whose line is nearest to the old one is taken, and listed for a human
to check (a large shift can make the nearest the wrong one). A mark that matches none is listed
too. Exit status 1 when anything is listed. Run from the repository root: .venv/bin/python tools/rekey_mutation_marks.py
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import tomllib  # noqa: E402

from tools.mutation import generate, summary  # noqa: E402

FILES = (REPO / "tools/mutation/equivalent.toml", REPO / "docs/notes/mutation_equivalents.md")


def main() -> int:
    files = generate.sources(REPO)
    mutants = {m.id: m for f in files for m in generate.file_mutants(REPO, f)}
    diffs = {e["id"]: e.get("diff", "") for e in tomllib.loads(FILES[0].read_text()).get("mutant", [])}
    by_key: dict[tuple[str, str], list] = {}
    for m in mutants.values():
        stem, _, digest = m.id.split(":")
        by_key.setdefault((stem, digest), []).append(m)
    moves, unresolved = {}, []
    for old in summary.stale_marks(set(mutants), files):
        stem, line, digest = old.split(":")
        same = by_key.get((stem, digest), [])
        diff = diffs.get(old, "").strip()
        found = [m for m in same if len(same) == 1 or f"{m.before.strip()} -> {m.after.strip()}" == diff]
        if len(found) == 1:
            moves[old] = found[0].id
        elif found:   # the same statement on several lines: the nearest is a guess, to be checked
            moves[old] = min(found, key=lambda m: abs(m.line - int(line))).id
            unresolved.append(f"{old}: moved to the nearest of lines {sorted(m.line for m in found)}, "
                              f"{moves[old]}; check its reason names that statement's routine")
        else:
            unresolved.append(f"{old}: no mutant with its hash and diff")
    lines = {tuple(old.split(":")[:2]): new.split(":")[1] for old, new in moves.items()}

    def move(match: re.Match) -> str:   # ids, and bare file:line references in the reasons, at once
        stem, line, rest = match.group(1), match.group(2), match.group(3) or ""
        return f"{stem}:{lines.get((stem, line), line)}{rest}"

    for path in FILES:
        path.write_text(re.sub(r"\b(cpdi_[a-z_]+):(\d+)(:[0-9a-f]{8})?\b", move, path.read_text()))
    for old, new in sorted(moves.items()):
        print(f"moved {old} -> {new}")
    for line in unresolved:
        print(f"CHECK {line}")
    return 1 if unresolved else 0


if __name__ == "__main__":
    raise SystemExit(main())
