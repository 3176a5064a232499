"""`make memcheck`: the Fortran-only API driver under AddressSanitizer and the debug flags
(-fcheck=all -ffpe-trap=invalid -finit-real=snan) must run clean: no invalid access, no leak,
no runtime check fired, every API call and error path as expected; on one thread and on two
(the OpenMP phases, the thread teams' calibration and probes)."""

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.skipif(shutil.which("gfortran") is None, reason="needs gfortran")
def test_memcheck_is_clean():
    p = subprocess.run(["make", "--no-print-directory", "memcheck"], cwd=REPO, capture_output=True, text=True,
                       timeout=600)
    out = p.stdout + p.stderr
    assert p.returncode == 0, out[-4000:]
    # once as a small run steps (one thread), once on two threads with teams chosen per step
    assert out.count("memcheck driver: 0 failures") == 2
    assert "ERROR: AddressSanitizer" not in out and "LeakSanitizer" not in out
