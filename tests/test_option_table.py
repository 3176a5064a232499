"""The solver's option table (fortran/src/cpdi_options.f90) is the one source of the options:
every name the core reads exists in it, and the harness's copies are derived from it."""

import re
from pathlib import Path

from harness import cases
from harness.solver import CASE_NO, OPTIONS

SRC = Path(__file__).resolve().parent.parent / "fortran" / "src"


def test_every_option_the_core_reads_by_name_is_a_row_of_the_table():
    """opt_value / opt_code / opt_is of a name not in the table give a meaningless value (huge),
    not an error: a misspelt name in the core would pass the build."""
    used = {}
    for f in SRC.glob("*.f90"):
        code = re.sub(r"!.*", "", f.read_text())   # comments may name 'name'
        for name in re.findall(r"opt_(?:value|code|is)\(\s*[\w%]+\s*,\s*'(\w+)'", code):
            used.setdefault(name, f.name)
    assert len(used) >= 20, sorted(used)
    missing = {n: f for n, f in used.items() if n not in OPTIONS}
    assert not missing, f"options read by name but not in the table: {missing}"


def test_the_case_schema_has_one_solver_key_per_case_option_with_the_table_s_range():
    solver = cases.SCHEMA["solver"].sub
    for name, opt in OPTIONS.items():
        if opt.in_case == CASE_NO:
            assert name not in solver
            continue
        key = solver[name]
        assert key.doc == opt.help and key.unit == opt.unit
        if opt.kind == "enum":
            assert key.kind == "choice" and key.choices == opt.choices

