"""The equivalence marks of the mutation tool (tools/mutation/equivalent.toml) follow the code.

A mark names a mutant by file, line and a hash of the mutated line. When that line moves or
changes, the mark names nothing, and the mutant it was meant for would be counted as a
survivor without anyone noticing: `make mutate` warns and the report lists such marks.
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
    marks = summary.equivalent_ids()
    assert len(marks) >= 1 and all(i.count(":") == 2 and r for i, r in marks.items())


def test_every_committed_mark_names_a_mutant_of_the_current_sources():
    # A Fortran edit that moves a marked line orphans its mark (fc9c115 moved the schedule
    # mark's statement by three lines; only the next `make mutate` said so). Here the suite
    # says so at once: move the mark to the same mutation of the same statement
    # (tools/rekey_mutation_marks.py does it) and re-read its reason against the code around
    # it. Judged in a git checkout only: the mutation tool's scratch copies (git archive, no
    # .git) hold a mutated source, whose own line would orphan its mark there and "kill" the
    # mutant for no physical reason.
    from pathlib import Path

    import pytest

    from tools.mutation import generate

    repo = Path(__file__).resolve().parent.parent
    if not (repo / ".git").exists():
        pytest.skip("not a git checkout (a mutation scratch copy): marks are judged in the repository")
    files = generate.sources(repo)
    ids = {m.id for f in files for m in generate.file_mutants(repo, f)}
    assert summary.stale_marks(ids, files) == []


def test_the_notes_list_every_mark_with_its_reason():
    """docs/notes/mutation_equivalents.md lists every marked mutant with its reason (the issue's
    bar: the notes say what was marked and why)."""
    from pathlib import Path

    notes = (Path(__file__).resolve().parents[1] / "docs" / "notes" / "mutation_equivalents.md").read_text()
    rows = {line.split("`")[1]: line for line in notes.splitlines() if line.startswith("| `cpdi_")}
    for mark, reason in summary.equivalent_ids().items():
        assert mark in rows, f"{mark} is marked but not listed in docs/notes/mutation_equivalents.md"
        assert reason.replace("|", "\\|")[:60] in rows[mark], f"{mark}: the notes give another reason"
