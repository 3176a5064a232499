"""The equivalence marks of the mutation tool (tools/mutation/equivalent.toml) follow the code.

A mark names a mutant by content (tools.mutation.marks): file, enclosing routine, the statement
and its mutation, normalised (comment stripped, case folded, blanks collapsed), and for a
statement found more than once in its routine which copy. Moving code keeps the mark; editing
the marked statement orphans it, and the mutant it was meant for would be counted as a survivor
without anyone noticing: this suite fails naming the mark, `make mutate` warns and the report
lists such marks.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tools.mutation import execute, generate, marks, summary

REPO = Path(__file__).resolve().parent.parent


def _keys(repo: Path, rel: str) -> set[str]:
    return {m.key for m in generate.file_mutants(repo, rel)}


def _copy(tmp_path: Path, rel: str) -> Path:
    dest = tmp_path / rel
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(REPO / rel, dest)
    return dest


def test_the_committed_marks_are_read():
    ms = marks.load()
    assert len(ms) >= 1 and all(m.reason and m.statement != m.mutation for m in ms)
    assert len({m.key for m in ms}) == len(ms), "two marks name the same mutant"
    assert all(m.statement == marks.normalise(m.statement) and m.mutation == marks.normalise(m.mutation) for m in ms)
    assert summary.equivalent_keys() == {m.key: m.reason for m in ms}


def test_every_committed_mark_names_a_mutant_of_the_current_sources():
    # Judged in a git checkout only: the mutation tool's scratch copies (git archive, no .git) hold
    # a mutated source, whose own statement would orphan its mark there and "kill" the mutant for
    # no physical reason.
    if not (REPO / ".git").exists():
        pytest.skip("not a git checkout (a mutation scratch copy): marks are judged in the repository")
    files = generate.sources(REPO)
    keys = {k for f in files for k in _keys(REPO, f)}
    bad = marks.orphans(REPO, files, keys)
    assert not bad, f"{len(bad)} mark(s) of tools/mutation/equivalent.toml do not resolve:\n" + "\n".join(bad.values())


def _a_committed_mark() -> marks.Mark:
    """A committed mark of a statement found once in its routine, in the smallest such file."""
    return min((m for m in marks.load() if m.occurrences == 1), key=lambda m: (REPO / m.file).stat().st_size)


def test_a_mark_resolves_after_lines_and_a_routine_are_inserted_above_it(tmp_path):
    m = _a_committed_mark()
    src = _copy(tmp_path, m.file)
    line, why = marks.resolve(tmp_path, m)
    assert why == "" and m.key in _keys(tmp_path, m.file)
    lines = src.read_text().splitlines()
    assert marks.normalise(lines[line - 1]) == m.statement
    head = generate.routines(lines).index(m.routine)   # the marked routine's first line
    new_routine = ["", "", "  subroutine inserted_above(x)", "    real, intent(inout) :: x",
                   "    if (x > 1.0) x = 2.0*x   ! a statement that is itself mutated",
                   "  end subroutine inserted_above", ""]
    moved = lines[:head] + new_routine + lines[head:line - 1] + ["", "", ""] + lines[line - 1:]
    src.write_text("\n".join(moved) + "\n")
    now, why = marks.resolve(tmp_path, m)
    assert why == "" and now == line + len(new_routine) + 3
    assert m.key in _keys(tmp_path, m.file)          # and its mutant has the same key
    assert marks.orphans(tmp_path, [m.file], _keys(tmp_path, m.file), [m]) == {}
    # neither a comment nor case nor blanks are the statement
    moved[now - 1] = moved[now - 1].upper().replace(" ", "  ") + "   ! a comment added"
    src.write_text("\n".join(moved) + "\n")
    assert marks.resolve(tmp_path, m) == (now, "") and m.key in _keys(tmp_path, m.file)


def test_a_mark_whose_statement_changed_or_left_its_routine_fails_naming_it(tmp_path):
    m = _a_committed_mark()
    src = _copy(tmp_path, m.file)
    line, _ = marks.resolve(tmp_path, m)
    lines = src.read_text().splitlines()
    edited = lines.copy()
    edited[line - 1] = edited[line - 1].split("!")[0].rstrip() + " + 0*1"  # a different statement
    src.write_text("\n".join(edited) + "\n")
    bad = marks.orphans(tmp_path, [m.file], _keys(tmp_path, m.file), [m])
    assert list(bad) == [m.key]
    assert m.key in bad[m.key] and m.routine in bad[m.key] and m.statement in bad[m.key]
    assert "not in" in bad[m.key] and f"python -m tools.mutation.marks {m.file}:LINE" in bad[m.key]
    # the same statement moved into another routine (appended at the end of the file's last one)
    moved = lines[:line - 1] + lines[line:]
    last_end = max(i for i, t in enumerate(moved) if generate.END_ROUTINE.match(t))
    moved.insert(last_end, lines[line - 1])
    src.write_text("\n".join(moved) + "\n")
    assert generate.routines(moved)[last_end] != m.routine
    assert list(marks.orphans(tmp_path, [m.file], None, [m])) == [m.key]
    # a mark of a file outside the run is not judged
    assert marks.orphans(tmp_path, ["fortran/src/other.f90"], set(), [m]) == {}


def test_a_statement_twice_in_a_routine_is_told_apart_by_its_occurrence(tmp_path):
    rel = "fortran/src/cpdi_x.f90"
    (tmp_path / "fortran" / "src").mkdir(parents=True)
    body = ["module m_x", "contains", "  subroutine step(a, b)", "    real, intent(inout) :: a", "    real :: b",
            "    if (a > b) a = b", "    b = 2.0*b", "    if (a > b) a = b   ! the second copy",
            "  end subroutine step",
            "  subroutine other(a, b)", "    real, intent(inout) :: a", "    real :: b", "    if (a > b) a = b",
            "  end subroutine other", "end module m_x"]

    def write(lines):
        (tmp_path / rel).write_text("\n".join(lines) + "\n")

    write(body)
    printed = marks.describe(tmp_path, rel, 8)   # the second copy in step
    assert "occurrence = 2" in printed and "occurrences = 2" in printed and 'routine = "step"' in printed
    m = marks.Mark(rel, "step", "if (a > b) a = b", "if (a >= b) a = b", "r", occurrence=2, occurrences=2)
    assert m.key.endswith(":2") and m.key in _keys(tmp_path, rel)
    assert marks.resolve(tmp_path, m) == (8, "")
    assert marks.resolve(tmp_path, marks.Mark(rel, "other", m.statement, m.mutation, "r")) == (13, "")
    write(body[:2] + ["", "  ! moved down"] + body[2:])        # moved: still the second copy
    assert marks.resolve(tmp_path, m) == (10, "")
    write(body[:6] + ["    if (a > b) a = b"] + body[6:])      # a third copy: which one is meant?
    line, why = marks.resolve(tmp_path, m)
    assert line is None and "occurs 3 times" in why and m.key in why
    write(body[:7] + body[8:])                                # the second copy removed
    assert marks.resolve(tmp_path, m)[0] is None


def test_generated_keys_follow_the_statement_not_the_line(tmp_path):
    rel = "fortran/src/cpdi_x.f90"
    (tmp_path / "fortran" / "src").mkdir(parents=True)
    body = ["module m_x", "contains", "  subroutine step(a, b)", "    real, intent(inout) :: a", "    real :: b",
            "    if (a > b) a = b", "  end subroutine step", "  subroutine other(a, b)",
            "    real, intent(inout) :: a", "    real :: b", "    if (a > b) a = b", "  end subroutine other",
            "end module m_x"]

    def keys(lines, stmt="if (a > b) a = b"):
        (tmp_path / rel).write_text("\n".join(lines) + "\n")
        return {(m.key, marks.normalise(m.after)) for m in generate.file_mutants(tmp_path, rel)
                if m.before.split("!")[0].strip() == stmt}

    before = keys(body)
    assert before and {k.split(":")[1] for k, _ in before} == {"step", "other"}
    assert keys(body[:2] + ["", "  ! three lines", "  ! of comment", "  ! added above"] + body[2:]) == before
    assert keys(body[:5] + ["    b = b"] + body[5:]) == before   # same statement one line further down
    edited = keys([t.replace("if (a > b) a = b", "if (a > 2*b) a = b") for t in body], "if (a > 2*b) a = b")
    assert edited and not {k for k, _ in edited} & {k for k, _ in before}


def test_a_change_inside_a_comment_is_no_mutant(tmp_path):
    rel = "fortran/src/cpdi_x.f90"
    (tmp_path / "fortran" / "src").mkdir(parents=True)
    (tmp_path / rel).write_text("module m_x\ncontains\n  subroutine s(a)\n    real, intent(inout) :: a\n"
                                "    a = (b(1) - b(2))*a   ! multiplies N(x1) - N(x3)\n"
                                "  end subroutine s\nend module m_x\n")
    ms = generate.file_mutants(tmp_path, rel)
    assert ms and all(marks.normalise(m.before) != marks.normalise(m.after) for m in ms)
    assert all(m.to_dict()["key"] == m.key for m in ms)   # a report row carries the content key


def test_report_rows_get_the_content_key_of_this_tree(tmp_path):
    """A journal written before the keys existed (rows with only the line-based id) still meets
    its marks: the rows take the key of the mutant as the tree computes it."""
    m = generate.Mutant("cpdi_x:6:abcdef12", "fortran/src/cpdi_x.f90", 6, "r", "if (a > b) a = b",
                        "if (a >= b) a = b", "cpdi_x:step:0000aaaa")
    old = {k: v for k, v in m.to_dict().items() if k != "key"} | {"verdict": "survived", "killed_by": "",
                                                                   "tier": "full", "seconds": 1.0}
    (tmp_path / "journal.jsonl").write_text(json.dumps(old) + "\n")
    assert execute.journal_rows(tmp_path / "journal.jsonl", [m])[0]["key"] == m.key


def test_the_notes_list_every_mark_with_its_reason():
    """docs/notes/mutation_equivalents.md lists every marked mutant with its reason (the issue's
    bar: the notes say what was marked and why)."""
    notes = (REPO / "docs" / "notes" / "mutation_equivalents.md").read_text()
    rows = {line.split("`")[1]: line for line in notes.splitlines() if line.startswith("| `cpdi_")}
    for mark, reason in summary.equivalent_keys().items():
        assert mark in rows, f"{mark} is marked but not listed in docs/notes/mutation_equivalents.md"
        assert reason.replace("|", "\\|")[:60] in rows[mark], f"{mark}: the notes give another reason"
    assert set(rows) <= set(summary.equivalent_keys()), "the notes list a mark that equivalent.toml does not hold"


def test_the_report_counts_a_marked_mutant_as_equivalent_and_lists_orphaned_marks(tmp_path):
    m = marks.load()[0]
    row = {"id": f"{Path(m.file).stem}:{m.line_hint}:00000000", "file": m.file, "line": m.line_hint, "rule": "r",
           "before": m.statement, "after": m.mutation, "key": m.key, "verdict": "survived", "killed_by": "",
           "tier": "fast", "seconds": 1.0}
    other = row | {"id": "cpdi_x:1:11111111", "key": "cpdi_x:s:22222222", "verdict": "killed", "killed_by": "t"}
    meta = {"rev": "0" * 40, "date": "2026-11-28", "sampling": "s", "tiers": "t", "stale_marks": ["cpdi_y:r:33333333"]}
    sc = summary.write(tmp_path, [row, other], meta)["overall"]
    assert (sc["equivalent"], sc["counted"], sc["killed"]) == (1, 1, 1)
    md = (tmp_path / "summary.md").read_text()
    assert f"| `{m.file}:{m.line_hint}` | `r` | equivalent |" in md and "`cpdi_y:r:33333333`" in md
    assert json.loads((tmp_path / "mutants.json").read_text())["mutants"][0]["key"] == m.key
