"""Every developer tool in tools/ starts from the repository root as its docstring says
(`python -m tools.NAME`): --help exits 0 and prints its usage."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
# modules the bench imports, not tools of their own: bench_interleave, bench_water, host_probe (tools' extension)
TOOLS = sorted(p.stem for p in (REPO / "tools").glob("*.py") if p.stem not in ("__init__", "bench_interleave",
                                                                                 "bench_water", "host_probe"))


@pytest.mark.parametrize("tool", TOOLS)
def test_tool_starts_as_documented(tool: str) -> None:
    doc = (REPO / "tools" / f"{tool}.py").read_text()
    assert f"python -m tools.{tool}" in doc, f"tools/{tool}.py: say how it is run"
    p = subprocess.run([sys.executable, "-m", f"tools.{tool}", "--help"], cwd=REPO, capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0 and "usage" in p.stdout.lower(), p.stderr[-2000:]
