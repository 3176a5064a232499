"""harness.refdata: the `#` citation header and the columns of a reference CSV, on a hand-made
file and on the datasets in reference/data/."""

from __future__ import annotations

import re

import numpy as np
import pytest

from harness import refdata

TEXT = """# Author, A. (1952) Some Journal 1:2, table 3.
#   T = t sqrt(g/a), indented continuation
name,T,Z

a,0.5,1.25
# a remark between rows
b,1.0,nan
c,2,3e-1
"""


@pytest.fixture
def csv_file(tmp_path):
    p = tmp_path / "ref.csv"
    p.write_text(TEXT)
    return p


def test_header_is_the_comment_lines_without_the_hash(csv_file):
    assert refdata.header(csv_file) == ["Author, A. (1952) Some Journal 1:2, table 3.",
                                        "T = t sqrt(g/a), indented continuation",
                                        "a remark between rows"]
    assert refdata.header(str(csv_file))[0].startswith("Author")


def test_read_gives_the_named_columns_numeric_as_float_and_text_as_str(csv_file):
    cols = refdata.read(csv_file)
    assert set(cols) == {"name", "T", "Z"}
    assert list(cols["name"]) == ["a", "b", "c"] and cols["name"].dtype.kind == "U"
    assert cols["T"].dtype == np.float64
    np.testing.assert_array_equal(cols["T"], [0.5, 1.0, 2.0])
    assert cols["Z"][0] == 1.25 and np.isnan(cols["Z"][1]) and cols["Z"][2] == 0.3


def test_a_relative_name_is_read_from_the_data_directory(csv_file, monkeypatch):
    monkeypatch.setattr(refdata, "DATA", csv_file.parent)
    np.testing.assert_array_equal(refdata.read("ref.csv")["T"], [0.5, 1.0, 2.0])


def test_a_header_only_file_has_empty_columns(tmp_path):
    p = tmp_path / "empty.csv"
    p.write_text("# Someone (2000)\nt,p\n")
    cols = refdata.read(p)
    assert set(cols) == {"t", "p"} and all(len(v) == 0 for v in cols.values())


DATASETS = sorted(refdata.DATA.rglob("*.csv"))


@pytest.mark.parametrize("path", DATASETS, ids=[str(p.relative_to(refdata.DATA)) for p in DATASETS])
def test_every_reference_dataset_cites_its_source_and_reads_whole(path):
    head = refdata.header(path)
    assert any(re.search(r"\b(19|20)\d\d\b", ln) for ln in head), "no citation (a year) in the header"
    names = next(ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")).split(",")
    cols = refdata.read(path.relative_to(refdata.DATA))
    assert list(cols) == names
    lengths = {len(v) for v in cols.values()}
    assert len(lengths) == 1 and lengths.pop() > 0


def test_martin_moyce_height_table_by_hand():
    assert len(DATASETS) >= 5  # the datasets were found (an empty list would skip the test above)
    cols = refdata.read("martin_moyce_1952_height_n2eq2_a2.25in_table6.csv")
    assert set(cols) == {"tau", "H"}
    assert (cols["tau"][0], cols["H"][0]) == (0.56, 0.94) and (cols["tau"][1], cols["H"][1]) == (0.77, 0.89)
    assert "Martin" in " ".join(refdata.header(refdata.DATA / "martin_moyce_1952_height_n2eq2_a2.25in_table6.csv"))
