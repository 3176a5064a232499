"""What the installed package is (issue 39, item 3): the runtime harness only, with runtime
dependencies only, and importing it changes nothing in the caller's environment.

The slow end-to-end check (pip install into a fresh venv, then cpdi verify --quick) is
tests/test_packaging.py; these read pyproject.toml and meson.build and import the checkout.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DEV_ONLY = ("pytest", "hypothesis", "ruff", "selenium", "universalmutator", "comby", "mutmut", "meson", "ninja",
            "tabulate", "python-levenshtein")


def _name(req: str) -> str:
    return req.split("==")[0].split("[")[0].strip().lower()


def test_runtime_dependencies_are_what_a_run_and_a_report_need() -> None:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    runtime = {_name(r) for r in project["dependencies"]}
    assert not runtime & set(DEV_ONLY), runtime & set(DEV_ONLY)
    assert {"numpy", "h5py", "matplotlib", "jinja2", "dask", "distributed"} <= runtime
    test = {_name(r) for r in project["optional-dependencies"]["test"]}
    assert {"pytest", "hypothesis", "meson", "ninja", "universalmutator"} <= test
    for extra in project["optional-dependencies"].values():  # every pin exact, so bootstraps repeat
        assert all("==" in r for r in extra), extra
    assert all("==" in r for r in project["dependencies"])


def test_developer_tools_are_not_in_the_installed_package() -> None:
    pkg = REPO / "harness"
    assert not (pkg / "mutation").exists() and not list(pkg.glob("bench*.py"))
    assert (REPO / "tools" / "mutation" / "equivalent.toml").is_file() and (REPO / "tools" / "bench.py").is_file()
    # meson installs the harness directory only (tools/ stays in the checkout)
    assert "install_subdir('tools'" not in (REPO / "meson.build").read_text()


def test_importing_the_harness_and_loading_the_solver_leave_the_environment_unchanged() -> None:
    """libgomp reads its settings as the extension loads: harness.solver sets its defaults for that
    import only. The solver still runs on the cores this process may use."""
    code = ("import os, json; before = dict(os.environ); import harness, harness.cli, harness.runner; "
            "from harness import solver; solver.api(); "
            "print(json.dumps([before == dict(os.environ), solver.threads(), harness.available_cores()]))")
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, check=True)
    unchanged, threads, cores = json.loads(out.stdout.strip().splitlines()[-1])
    assert unchanged is True
    assert threads == cores
    # a user's setting wins
    env["OMP_NUM_THREADS"] = "1"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, check=True)
    unchanged, threads, _ = json.loads(out.stdout.strip().splitlines()[-1])
    assert unchanged is True and threads == 1


def test_developer_tools_run_from_the_checkout() -> None:
    for mod in ("tools.bench", "tools.mutation"):
        p = subprocess.run([sys.executable, "-m", mod, "--help"], cwd=REPO, capture_output=True, text=True)
        assert p.returncode == 0 and "usage: python -m " + mod in p.stdout, p.stderr
