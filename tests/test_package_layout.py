"""What the installed package is (issue 39, item 3): the runtime harness only, with runtime
dependencies only, and importing it changes nothing in the caller's environment.

The slow end-to-end check (pip install into a fresh venv, then cpdi verify --quick) is
tests/test_packaging.py; these read pyproject.toml and meson.build and import the checkout.
"""

from __future__ import annotations

import json
import os
import re
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


def test_the_test_and_bench_extensions_are_built_but_never_installed() -> None:
    """One meson project builds three extensions from the one core: the solver's _cpdi (installed),
    the tests' _cpdi_test and the bench's _cpdi_bench (install : false; make build copies them into
    tests/ and tools/). meson-python installs what the build's install plan lists, and that is the
    solver's extension, its flags file and the three data trees, nothing of tests/ or tools/."""
    build = REPO / "build"
    plan = json.loads((build / "meson-info" / "intro-install_plan.json").read_text())
    suffix = next((build / "fortran").glob("_cpdi.*.so")).name.removeprefix("_cpdi")
    assert [t["destination"] for t in plan["targets"].values()] == ["{py_platlib}/harness/_cpdi" + suffix]
    assert {Path(src).name for src in plan["install_subdirs"]} == {"harness", "cases", "reference"}
    every = [d["destination"] for part in plan.values() for d in part.values()]
    assert not [d for d in every if "_cpdi_test" in d or "_cpdi_bench" in d or "/tests" in d or "/tools" in d]
    # built by the same project and in place for the tests and the bench
    for name, home in (("_cpdi_test", "tests"), ("_cpdi_bench", "tools")):
        assert (build / "fortran" / (name + suffix)).is_file(), name
        assert (REPO / home / (name + suffix)).is_file(), f"make build copies {name} into {home}/"
    assert not list((REPO / "harness").glob("_cpdi_*.so")), "only the solver's extension belongs in harness/"


# every module of the package imported, then the extension loaded as the harness loads it; prints
# whether os.environ was the same after each, the solver's threads and the cores this process may use
_IMPORT_ALL = """
import importlib, json, os, pkgutil
before = dict(os.environ)
import harness
for m in pkgutil.walk_packages(harness.__path__, "harness."):
    if m.name not in ("harness.__main__", "harness._cpdi"):  # the CLI's start; the extension, loaded below
        importlib.import_module(m.name)
imported = dict(os.environ)
from harness import solver
solver.api()
print(json.dumps([before == imported, before == dict(os.environ), solver.threads(), harness.available_cores()]))
"""


def _libgomp_settings(stderr: str) -> dict[str, str]:
    """What libgomp read from the environment as it initialised (OMP_DISPLAY_ENV=VERBOSE)."""
    return dict(re.findall(r"^\s*(OMP_NUM_THREADS|GOMP_SPINCOUNT) = '([^']*)'", stderr, re.M))


def test_importing_the_harness_and_loading_the_solver_leave_the_environment_unchanged() -> None:
    """No module of the package changes an environment variable as it is imported. libgomp reads its
    settings once, as the extension loads: harness.solver puts its defaults in the environment for that
    import only, and libgomp's own report (OMP_DISPLAY_ENV) shows it read them. A user's setting wins."""
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    env["OMP_DISPLAY_ENV"] = "VERBOSE"
    out = subprocess.run([sys.executable, "-c", _IMPORT_ALL], cwd=REPO, env=env, capture_output=True, text=True,
                         check=True)
    unchanged_by_imports, unchanged, threads, cores = json.loads(out.stdout.strip().splitlines()[-1])
    assert unchanged_by_imports is True and unchanged is True
    assert threads == cores
    assert _libgomp_settings(out.stderr) == {"OMP_NUM_THREADS": str(cores), "GOMP_SPINCOUNT": "10000"}, out.stderr
    # a user's settings win, and are left as they were
    env.update(OMP_NUM_THREADS="1", GOMP_SPINCOUNT="20000")
    out = subprocess.run([sys.executable, "-c", _IMPORT_ALL], cwd=REPO, env=env, capture_output=True, text=True,
                         check=True)
    unchanged_by_imports, unchanged, threads, _ = json.loads(out.stdout.strip().splitlines()[-1])
    assert unchanged_by_imports is True and unchanged is True and threads == 1
    assert _libgomp_settings(out.stderr) == {"OMP_NUM_THREADS": "1", "GOMP_SPINCOUNT": "20000"}, out.stderr
    # OMP_WAIT_POLICY set: the spin count is libgomp's for that policy, not the harness's default
    del env["GOMP_SPINCOUNT"]
    env["OMP_WAIT_POLICY"] = "PASSIVE"
    out = subprocess.run([sys.executable, "-c", _IMPORT_ALL], cwd=REPO, env=env, capture_output=True, text=True,
                         check=True)
    assert _libgomp_settings(out.stderr)["GOMP_SPINCOUNT"] != "10000", out.stderr


def test_developer_tools_run_from_the_checkout() -> None:
    for mod in ("tools.bench", "tools.mutation"):
        p = subprocess.run([sys.executable, "-m", mod, "--help"], cwd=REPO, capture_output=True, text=True)
        assert p.returncode == 0 and "usage: python -m " + mod in p.stdout, p.stderr
