"""The quick verification tier inside `make test`: every check passes its own gates and
every gold metric of the quick tier holds. A failure names the check and the metric."""

import pytest

from harness import gate, verify

QUICK = gate.load_gold().get("tiers", {}).get("quick", {})
PAIRS = [(c, m) for c in QUICK for m in QUICK[c]]


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("verify_quick")
    metrics, rows = verify.verify(True, verify.CHECKS, out, progress=False)
    return metrics, {(r["check"], r["metric"]): r for r in rows}


@pytest.mark.parametrize("check", verify.CHECKS)
def test_quick_check_passes_its_gates(quick_run, check):
    c = quick_run[0]["checks"][check]
    assert c["passed"], f"{check}: {c['verdict']}"


@pytest.mark.parametrize("check, metric", PAIRS, ids=[f"{c}.{m}" for c, m in PAIRS])
def test_quick_metric_holds_against_gold(quick_run, check, metric):
    row = quick_run[1][(check, metric)]
    assert row["status"] != "regressed", gate.summary_lines([row])[0]


def test_every_check_has_quick_gold():
    assert set(QUICK) == set(verify.CHECKS), "run make regen-gold after adding a check"
