"""Every file in tests/malformed/ is a case with one defect; its first line names the expected
message (`# expect: ...`). Each must be refused with that message, naming the key."""

from pathlib import Path

import pytest

from harness import cases
from harness.cases import CaseError

FILES = sorted((Path(__file__).parent / "malformed").glob("*.toml"))


def test_there_are_at_least_25_kinds_of_rejection():
    assert len(FILES) >= 25


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_malformed_case_is_refused_with_its_message(path):
    expect = path.read_text().splitlines()[0].removeprefix("# expect:").strip()
    with pytest.raises(CaseError) as ei:
        cases.load(path)
    assert expect in str(ei.value), f"message was: {ei.value}"
    assert str(path) in str(ei.value), "the message names the file"
