"""The equivalence marks of the mutation tool (harness/mutation/equivalent.toml) follow the code.

A mark names a mutant by file, line and a hash of the mutated line. When that line moves or
changes, the mark names nothing, and the mutant it was meant for would be counted as a
survivor without anyone noticing: `make mutate` warns and the report lists such marks.
"""

from __future__ import annotations

from harness.mutation import summary


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
