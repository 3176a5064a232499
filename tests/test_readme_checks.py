"""One source for the checks (issue 39 item 2): they register themselves, their requirement is
their case file's, and the README's table and `verify --only` are generated from that."""

from __future__ import annotations

import importlib
import re

import pytest

from harness import cases, paths, verify
from harness.checks import registry
from tools import readme_checks


def test_every_check_module_registers_itself():
    mods = sorted(p.stem for p in (paths.SOURCE_ROOT / "harness" / "checks").glob("*.py")
                  if p.stem not in ("__init__", "base", "registry"))
    assert sorted(r.name for r in registry.all_checks()) == mods
    assert verify.CHECKS == registry.gated() and verify.EXPERIMENTAL == registry.experimental()
    assert not set(verify.CHECKS) & set(verify.EXPERIMENTAL)


@pytest.mark.parametrize("check", [r.name for r in registry.all_checks()])
def test_requirement_is_the_case_files(check):
    """A check that runs a case file of its own shows that file's requirement, not a copy."""
    mod = importlib.import_module(f"harness.checks.{check}")
    src = (paths.SOURCE_ROOT / "harness" / "checks" / f"{check}.py").read_text()
    assert "REQUIREMENT = registry.requirement(" in src or not re.search(r'CASES / "[a-z_]+\.toml"', src), (
        f"{check} runs a case file but types its own requirement")
    if "REQUIREMENT = registry.requirement(" in src:
        named = re.search(r'REQUIREMENT = registry\.requirement\("([a-z_]+\.toml)"\)', src)
        case = paths.CASES / named.group(1) if named else mod.CASE
        assert mod.REQUIREMENT == cases.load(case)["case"]["requirement"]


def test_experimental_checks_name_existing_notes():
    for r in registry.all_checks():
        if not r.gated:
            assert (paths.SOURCE_ROOT / r.notes).is_file(), r


def test_readme_table_is_generated():
    assert readme_checks.main(["--check"]) == 0, "run python -m tools.readme_checks"


def test_readme_table_follows_a_changed_requirement(monkeypatch):
    """The generator reads the registry, so a changed requirement changes the table (not a frozen copy)."""
    mod = importlib.import_module("harness.checks.sinking_block")
    monkeypatch.setattr(mod, "REQUIREMENT", "A block sinks | and stays.")
    assert "| `sinking_block` | A block sinks \\| and stays. |" in readme_checks.table()


def test_registering_twice_is_refused():
    def run(ctx):
        return None

    run.__module__ = "elsewhere.sinking_block"
    with pytest.raises(ValueError, match="registered twice"):
        registry.check(order=1)(run)
    with pytest.raises(ValueError, match="notes"):
        registry.check(order=1, experimental="fails")


def test_verify_only_with_no_name_lists_the_checks(capsys):
    assert verify.main(only=[]) == 0
    out = capsys.readouterr().out
    for r in registry.all_checks():
        assert r.name in out
    assert "not gated:" in out
