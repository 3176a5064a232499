"""Equivalence marks (tools/mutation/equivalent.toml), keyed by content, not by line.

A mark names a mutant by what it changes: the source file, the enclosing routine (the innermost
subroutine or function, "module" outside any), the statement (the mutated source line) and the
mutated statement, both normalised: the comment stripped, case folded (Fortran is case
insensitive) and blanks collapsed to one; they are compared, and hashed into the key, with no
blanks at all. Moving code (lines inserted above, a routine added before) leaves a mark
resolving; editing the statement, or moving it to another routine, orphans it, and `check`
says which mark and what to do. A line number in a mark (`line_hint`) is for readers only.

A statement that occurs more than once in its routine is told apart by `occurrence` (1-based,
in source order) and `occurrences` (how many there were when it was marked): a mark resolves
only while the routine holds exactly `occurrences` copies (default 1), so a copy added or
removed makes the mark fail rather than silently name another line.

``python -m tools.mutation.marks fortran/src/x.f90:LINE`` prints the fields of a new mark for
every mutant of that line.
"""

from __future__ import annotations

import hashlib
import re
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

EQUIVALENT = Path(__file__).with_name("equivalent.toml")
_STRING_OR_COMMENT = re.compile(r"'[^']*'|\"[^\"]*\"|!")


def strip_comment(text: str) -> str:
    """The code of a source line: a `!` outside quotes starts a comment."""
    for m in _STRING_OR_COMMENT.finditer(text):
        if m.group() == "!":
            return text[:m.start()]
    return text


def normalise(text: str) -> str:
    """A statement as a mark stores it: no comment, lower case, blanks collapsed to one."""
    return " ".join(strip_comment(text).lower().split())


def compact(text: str) -> str:
    """What is compared and hashed: the normalised text without blanks (`a+b` is `a + b`)."""
    return "".join(normalise(text).split())


def content_key(stem: str, routine: str, before: str, after: str, occurrence: int = 1) -> str:
    """stem:routine:hash of the normalised statement and its mutation, ":n" for the n-th copy of
    the statement in its routine (n >= 2). What mutants.json's `key` and the notes' table name."""
    digest = hashlib.sha1(f"{compact(before)}\n{compact(after)}".encode()).hexdigest()[:8]
    return f"{stem}:{routine.lower()}:{digest}" + (f":{occurrence}" if occurrence > 1 else "")


@dataclass(frozen=True)
class Mark:
    file: str            # fortran/src/x.f90
    routine: str
    statement: str       # normalised, as normalise() gives it
    mutation: str        # the mutated statement, normalised
    reason: str
    diff: str = ""       # the mutant described for readers (may abbreviate)
    occurrence: int = 1
    occurrences: int = 1
    line_hint: int = 0   # where it was when marked: for readers, never matched

    @property
    def key(self) -> str:
        return content_key(Path(self.file).stem, self.routine, self.statement, self.mutation, self.occurrence)

    @property
    def description(self) -> str:
        return self.diff or f"{self.statement} -> {self.mutation}"

    @property
    def where(self) -> str:
        return f"{self.file} ({self.routine}, near line {self.line_hint})"


def load(path: Path = EQUIVALENT) -> list[Mark]:
    if not path.is_file():
        return []
    fields = set(Mark.__dataclass_fields__)
    out = []
    for e in tomllib.loads(path.read_text()).get("mutant", []):
        unknown = set(e) - fields
        if unknown:
            raise ValueError(f"{path}: a mark has unknown fields {sorted(unknown)} (a line-keyed mark of before "
                             f"issue 39? give file, routine, statement, mutation): {e}")
        out.append(Mark(**e))
    return out


def statements(repo: Path, rel: str) -> dict[str, list[tuple[int, str]]]:
    """routine -> its source lines (1-based number, text), in order."""
    from tools.mutation.generate import routines

    lines = (repo / rel).read_text(encoding="utf-8").splitlines()
    out: dict[str, list[tuple[int, str]]] = {}
    for n, (text, routine) in enumerate(zip(lines, routines(lines), strict=True), 1):
        out.setdefault(routine, []).append((n, text))
    return out


def _fix(m: Mark) -> str:
    return (f"Review the mark against the code now: if the mutant still cannot change a result, write "
            f"its new fields from `python -m tools.mutation.marks {m.file}:LINE` into tools/mutation/equivalent.toml "
            "(and its row in docs/notes/mutation_equivalents.md); otherwise delete the mark.")


def resolve(repo: Path, m: Mark, generated: set[str] | None = None) -> tuple[int | None, str]:
    """Where the mark's statement is now (its line) and '' when it resolves, or (None, why not).
    `generated`: the content keys of the mutants the sources give now; when given, the mutation
    itself must still be made (a changed rule in fortran.rules could drop it)."""
    head = f"mark {m.key} ({m.description}) in {m.where}"
    if not (repo / m.file).is_file():
        return None, f"{head}: {m.file} does not exist any more. {_fix(m)}"
    body = statements(repo, m.file)
    if m.routine.lower() not in body:
        return None, f"{head}: there is no routine {m.routine} in {m.file} (renamed or moved?). {_fix(m)}"
    want = compact(m.statement)
    found = [n for n, text in body[m.routine.lower()] if compact(text) == want]
    if not found:
        return None, (f"{head}: its statement `{m.statement}` is not in {m.routine} any more (edited, or moved to "
                      f"another routine). {_fix(m)}")
    if len(found) != m.occurrences:
        return None, (f"{head}: its statement `{m.statement}` occurs {len(found)} times in {m.routine} (lines "
                      f"{', '.join(map(str, found))}), and {m.occurrences} when it was marked: a copy was added or "
                      f"removed, so which one the mark means is no longer known. Check which line the reason is "
                      f"about and set occurrence (its place among them, in source order) and occurrences = "
                      f"{len(found)}. {_fix(m)}")
    if m.occurrence > len(found):
        return None, f"{head}: occurrence {m.occurrence} of {len(found)}. {_fix(m)}"
    if generated is not None and m.key not in generated:
        return None, (f"{head}: the statement is there (line {found[m.occurrence - 1]}) but no mutant turns it into "
                      f"`{m.mutation}` any more (a rule in tools/mutation/fortran.rules changed?). {_fix(m)}")
    return found[m.occurrence - 1], ""


def orphans(repo: Path, files: list[str], generated: set[str] | None = None,
            marks: list[Mark] | None = None) -> dict[str, str]:
    """Marks of the given source files that do not resolve: key -> what is wrong and how to fix it."""
    wanted = set(files)
    out = {}
    for m in load() if marks is None else marks:
        if m.file in wanted:
            line, why = resolve(repo, m, generated)
            if line is None:
                out[m.key] = why
    return out


def describe(repo: Path, rel: str, line: int) -> str:
    """The toml of a mark for each mutant of one source line (to paste, then write diff and reason)."""
    from tools.mutation.generate import file_mutants

    out = []
    for mu in file_mutants(repo, rel):
        if mu.line != line:
            continue
        routine = mu.key.split(":")[1]
        same = [n for n, text in statements(repo, rel)[routine] if compact(text) == compact(mu.before)]
        out += ["[[mutant]]", f'file = "{rel}"', f'routine = "{routine}"',
                f"statement = {_toml_str(normalise(mu.before))}", f"mutation = {_toml_str(normalise(mu.after))}"]
        if len(same) > 1:
            out += [f"occurrence = {same.index(line) + 1}", f"occurrences = {len(same)}"]
        out += [f"line_hint = {line}", 'reason = ""', f"# key {mu.key}, rule {mu.rule}; a `diff` (the "
                "mutant for readers) is needed only where statement -> mutation does not read well", ""]
    return "\n".join(out) if out else f"no mutant of {rel}:{line}"


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


if __name__ == "__main__":
    repo = Path(__file__).resolve().parents[2]
    for arg in sys.argv[1:] or ["-h"]:
        if ":" not in arg:
            raise SystemExit("usage: python -m tools.mutation.marks fortran/src/x.f90:LINE ...")
        rel, ln = arg.rsplit(":", 1)
        print(describe(repo, rel, int(ln)))
