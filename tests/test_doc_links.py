"""The docs name only files that exist (issue 39, item 5): every relative Markdown link in the
README, docs/, cases/README.md and reports/README.md, and every repository path written there, in
backticks or not (`docs/x.md`, `harness/y.py`, `tools/z.py`, ...), resolves in the checkout; so
does every repository path the code names in its comments, docstrings and help (fortran/src,
harness, tools, cases, the Makefile, ...: "see docs/notes/threads.md"). A file that moves or is
deleted without its references fails here."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")
# a path under one of the repository's top-level folders, ending in a file suffix, anywhere in a
# line (in backticks or not; not after a word, a slash or a dot)
BARE = re.compile(r"(?<![\w/.-])((?:docs|harness|tools|tests|cases|fortran|reference|\.ci)/[\w./-]+\.\w+)")
# where code names repository files by their path from the top (tests/ builds made-up paths on
# purpose, and the meson files name theirs from their own folder, which meson checks: not scanned)
SOURCES = ("fortran/src/*.f90", "fortran/tests/*.f90", "harness/**/*.py", "tools/**/*.py", "tools/mutation/*.toml",
           "tools/mutation/*.rules", "cases/*.toml", "reference/**/*.md", "Makefile", "pyproject.toml", ".ci/*")

INSTALLED = "harness/_data/"  # where pip puts cases/ and reference/ (docs/running.md): not in a checkout


def _docs() -> list[Path]:
    return [REPO / "README.md", REPO / "cases" / "README.md", REPO / "reports" / "README.md",
            *sorted((REPO / "docs").rglob("*.md"))]


def _missing(doc: Path) -> list[str]:
    text = doc.read_text()
    bad = []
    for target in LINK.findall(text):
        if "://" in target or target.startswith("mailto:"):
            continue
        if not (doc.parent / target).exists():
            bad.append(target)
    if "notes" not in doc.parts:  # the notes record history: a path there may name a file as it was then
        bad += _absent(BARE.findall(text))
    return bad


def _absent(found: list[str]) -> list[str]:
    """The repository paths of found that are not in the checkout. A one-letter name (`cases/x.toml`,
    `fortran/src/x.f90` in a help text) stands for any file; harness/_data/ is the installed copy."""
    return [p for p in found if "*" not in p and not p.startswith(INSTALLED) and len(Path(p).stem) > 1
            and not (REPO / p).exists()]


def _missing_in_code(src: Path) -> list[str]:
    """Repository paths src names that are not in the checkout."""
    return _absent(BARE.findall(src.read_text(errors="replace")))


def test_every_link_and_path_in_the_docs_exists() -> None:
    bad = {str(d.relative_to(REPO)): m for d in _docs() if (m := _missing(d))}
    assert not bad, bad


def test_every_path_the_code_names_exists() -> None:
    files = sorted({f for pattern in SOURCES for f in REPO.glob(pattern) if f.is_file()})
    assert len(files) > 50, "the source patterns found almost nothing: has the layout changed?"
    bad = {str(f.relative_to(REPO)): m for f in files if (m := _missing_in_code(f))}
    assert not bad, bad


def test_a_missing_target_is_found(tmp_path: Path) -> None:
    doc = tmp_path / "x.md"
    doc.write_text("see [the design](design.md), `harness/nowhere.py` and tools/nowhere.py; `docs/x.md`\n")
    assert _missing(doc) == ["design.md", "harness/nowhere.py", "tools/nowhere.py"]
    src = tmp_path / "x.f90"
    src.write_text("  !! see docs/notes/nowhere.md. Use cases/x.toml; docs/design.md, harness/_data/cases/a.toml\n")
    assert _missing_in_code(src) == ["docs/notes/nowhere.md"]


def test_the_readme_stays_within_12_kb() -> None:
    """Issue 39, item 5: the README is a user guide of at most 12 KB; details live in docs/."""
    size = (REPO / "README.md").stat().st_size
    assert size <= 12 * 1024, f"README.md is {size} B, more than 12 KB: move details to docs/"
