"""Rule 1: nothing Python can reach may STOP. No `stop` / `error stop` in fortran/."""

import re
from pathlib import Path

FORTRAN = Path(__file__).resolve().parent.parent / "fortran"
STOP = re.compile(r"^\s*(\d+\s+)?(error\s+)?stop\b|\bthen\s+(error\s+)?stop\b|\)\s*(error\s+)?stop\b", re.I)


def test_no_stop_statement_in_fortran():
    files = [p for p in FORTRAN.rglob("*") if p.suffix.lower() in (".f90", ".f", ".pyf", ".f03", ".f08")]
    assert len(files) >= 9
    hits = []
    for p in files:
        for n, line in enumerate(p.read_text().splitlines(), 1):
            code = line.split("!", 1)[0]
            if STOP.search(code):
                hits.append(f"{p.relative_to(FORTRAN)}:{n}: {line.strip()}")
    assert not hits, "STOP kills the Python interpreter under f2py; return a status instead:\n" + "\n".join(hits)


def test_detector_catches_stop():
    assert STOP.search("  error stop 1")
    assert STOP.search("if (x) stop")
    assert STOP.search("  stop")
    assert not STOP.search("  call stopwatch()")
