"""Every check reads its case file through harness.paths (the checkout's cases/, a pip-installed copy's
_data/cases/, or CPDI_DATA_DIR's), never through a path of its own beside the source: floating_block
once built its own and its runs failed in an installed copy ("case file .../site-packages/cases/
floating_block.toml does not exist")."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def test_every_checks_case_file_follows_the_data_root(tmp_path: Path) -> None:
    data = tmp_path / "data"
    shutil.copytree(REPO / "cases", data / "cases")
    shutil.copytree(REPO / "reference", data / "reference")
    code = ("import importlib, json; from harness.verify import CHECKS, EXPERIMENTAL\n"
            "out = {}\n"
            "for n in CHECKS + EXPERIMENTAL:\n"
            "    case = getattr(importlib.import_module(f'harness.checks.{n}'), 'CASE', None)\n"
            "    if case is not None: out[n] = str(case)\n"
            "print(json.dumps(out))\n")
    env = dict(os.environ, CPDI_DATA_DIR=str(data), PYTHONPATH=str(REPO))
    p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                       check=True)
    found = json.loads(p.stdout.strip().splitlines()[-1])
    assert len(found) >= 6, found   # the checks that run a case file of their own
    wrong = {n: c for n, c in found.items() if Path(c).parent != (data / "cases").resolve()}
    assert not wrong, f"case files read from outside the data root: {wrong}"
