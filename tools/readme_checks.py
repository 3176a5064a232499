"""``python -m tools.readme_checks``: the README's table of checks, from the checks' registry.

The rows are what ``verify --only`` lists: each registered check with its requirement (its case
file's ``[case] requirement``, harness.checks.registry), gated checks in verify's order, then the
experimental ones with a link to their notes (why they are not gated). The table sits between the
``<!-- checks:begin -->`` and ``<!-- checks:end -->`` markers of README.md; ``--check`` exits 1
if the README's copy differs (tests/test_readme_checks.py runs it).
"""

from __future__ import annotations

import importlib
import sys

from harness import paths

BEGIN, END = "<!-- checks:begin -->", "<!-- checks:end -->"


def table() -> str:
    from harness.checks import registry

    rows = registry.all_checks()
    gated = [r for r in rows if r.gated]
    lines = [f"`make verify` runs {len(gated)} checks; a check passes when all its gates hold.", "",
             "| check | requirement (its case file's) |", "|---|---|"]
    for r in gated:
        req = importlib.import_module(r.module).REQUIREMENT.replace("|", "\\|")
        lines.append(f"| `{r.name}` | {req} |")
    lines += ["", "Experimental (run with `--only NAME`; not gated yet, their notes say why): "
              + ", ".join(f"[`{r.name}`]({r.notes})" for r in rows if not r.gated) + "."]
    return "\n".join(lines)


def render(readme: str) -> str:
    if BEGIN not in readme or END not in readme:
        raise ValueError(f"README.md has no {BEGIN} ... {END} block")
    head, rest = readme.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{table()}\n{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m tools.readme_checks",
                                 description="Write the README's table of checks from the checks' registry.")
    ap.add_argument("--check", action="store_true", help="only compare: exit 1 if README.md's table differs")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    path = paths.SOURCE_ROOT / "README.md"
    old = path.read_text(encoding="utf-8")
    new = render(old)
    if args.check:
        if new != old:
            print("README.md's table of checks is not what the checks register; run python -m tools.readme_checks",
                  file=sys.stderr)
            return 1
        return 0
    path.write_text(new, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
