"""The equivalence marks of the mutation tool (tools/mutation/equivalent.toml) follow the code.

A mark names a mutant by content: file, enclosing routine, and a hash of the statement and its
mutation (tools.mutation.generate.content_key). Moving code keeps the mark; editing the marked
statement orphans it, and the mutant it was meant for would be counted as a survivor without
anyone noticing: this suite fails, `make mutate` warns and the report lists such marks.
"""

from __future__ import annotations

from tools.mutation import summary


def test_a_mark_whose_line_moved_is_reported_and_others_are_not():
    marks = {"cpdi_step:350:aaaa": "r", "cpdi_step:118:bbbb": "r", "cpdi_shape:120:cccc": "r"}
    generated = {"cpdi_step:118:bbbb", "cpdi_step:119:dddd", "cpdi_shape:120:cccc"}
    assert summary.stale_marks(generated, ["fortran/src/cpdi_step.f90", "fortran/src/cpdi_shape.f90"],
                               marks) == ["cpdi_step:350:aaaa"]


def test_marks_of_files_outside_the_run_are_not_judged():
    marks = {"cpdi_step:350:aaaa": "r"}
    assert summary.stale_marks(set(), ["fortran/src/cpdi_shape.f90"], marks) == []


def test_the_committed_marks_are_read():
    marks = summary.equivalent_keys()
    assert len(marks) >= 1 and all(i.count(":") in (2, 3) and r for i, r in marks.items())


def test_every_committed_mark_names_a_mutant_of_the_current_sources():
    # An edit of a marked statement orphans its mark: review the mark against the new statement
    # and write its new key (from tools.mutation.generate.file_mutants). Judged in a git checkout
    # only: the mutation tool's scratch copies (git archive, no .git) hold a mutated source, whose
    # own statement would orphan its mark there and "kill" the mutant for no physical reason.
    from pathlib import Path

    import pytest

    from tools.mutation import generate

    repo = Path(__file__).resolve().parent.parent
    if not (repo / ".git").exists():
        pytest.skip("not a git checkout (a mutation scratch copy): marks are judged in the repository")
    files = generate.sources(repo)
    keys = {m.key for f in files for m in generate.file_mutants(repo, f)}
    assert summary.stale_marks(keys, files) == []


def test_a_mark_follows_its_statement_when_code_moves_and_not_when_it_changes(tmp_path):
    from tools.mutation import generate

    src = tmp_path / "fortran" / "src"
    src.mkdir(parents=True)
    body = ["module m_x", "contains", "  subroutine step(a, b)", "    real, intent(inout) :: a", "    real :: b",
            "    if (a > b) a = b", "  end subroutine step", "  subroutine other(a, b)",
            "    real, intent(inout) :: a", "    real :: b", "    if (a > b) a = b", "  end subroutine other",
            "end module m_x"]
    f = src / "cpdi_x.f90"

    def keys(lines, stmt="if (a > b) a = b"):
        f.write_text("\n".join(lines) + "\n")
        return {(m.key, m.after.strip()) for m in generate.file_mutants(tmp_path, "fortran/src/cpdi_x.f90")
                if m.before.strip() == stmt}

    before = keys(body)
    assert before and all(k.split(":")[1] in ("step", "other") for k, _ in before)
    assert keys(body[:2] + ["  ! three lines", "  ! of comment", "  ! added above"] + body[2:]) == before
    edited = keys([t.replace("if (a > b) a = b", "if (a > 2*b) a = b") for t in body], "if (a > 2*b) a = b")
    assert edited and not {k for k, _ in edited} & {k for k, _ in before}
    moved = keys(body[:5] + ["    b = b"] + body[5:])   # same statement one line further down
    assert moved == before


def test_the_notes_list_every_mark_with_its_reason():
    """docs/notes/mutation_equivalents.md lists every marked mutant with its reason (the issue's
    bar: the notes say what was marked and why)."""
    from pathlib import Path

    notes = (Path(__file__).resolve().parents[1] / "docs" / "notes" / "mutation_equivalents.md").read_text()
    rows = {line.split("`")[1]: line for line in notes.splitlines() if line.startswith("| `cpdi_")}
    for mark, reason in summary.equivalent_keys().items():
        assert mark in rows, f"{mark} is marked but not listed in docs/notes/mutation_equivalents.md"
        assert reason.replace("|", "\\|")[:60] in rows[mark], f"{mark}: the notes give another reason"
