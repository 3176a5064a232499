"""cases/dam_break.toml defaults to the incompressible water (issue 38); dam_break_front runs the
weakly compressible water beside it through explicit overrides (harness.problems.dam_break)."""

import pytest

from harness import cases
from harness.checks import dam_break_front as dbf
from harness.problems import dam_break as db


def test_the_case_default_is_the_incompressible_water():
    s = cases.load(db.CASE)["solver"]
    assert (s["fluid"], s["transfer"], s["projection"]) == ("incompressible", "apic", "none")


def test_the_check_runs_both_waters():
    gated = dbf.snap_case(20, "cell", "log", 0.5, "weakly_compressible")
    s = gated["solver"]
    assert (s["fluid"], s["transfer"], s["projection"], s["kinematics"]) == ("weakly_compressible", "flip", "cell",
                                                                             "log")
    assert gated["materials"][0]["bulk_modulus"] == 2.13e9 and gated["grid"]["cell"] == db.L / 20
    s = dbf.snap_case(40, "none", "log", 0.5, "incompressible")["solver"]
    assert (s["fluid"], s["transfer"], s["projection"]) == ("incompressible", "apic", "none")
    with pytest.raises(ValueError, match="fluid"):
        db.load(db.L / 20, fluid="compressible")
