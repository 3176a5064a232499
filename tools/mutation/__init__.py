"""Mutation testing of the Fortran core: does the test suite catch a seeded bug?

`make mutate` (``python -m tools.mutation``) seeds one small, plausible bug at a time into
``fortran/src/`` and runs the tests against it:

- ``generate``: the mutants. universalmutator's regexp engine with its ``fortran.rules`` and
  this package's ``fortran.rules`` (modern relational operators and physics-aware operators:
  a sign, a factor 1/2, an index off by one, a swapped component, a dropped term), drawn as a
  stratified sample over every source file;
- ``execute``: each mutant is built in a scratch copy of the committed tree (never the user's
  work tree) and run against a fast test tier, then the full ``make test`` for the survivors;
  parallel over the cores, a time limit per mutant (a hang counts as killed), a journal that
  lets an interrupted run resume;
- ``summary``: ``reports/mutation/<date>-<sha>/``: every mutant (file:line, operator, diff,
  verdict, the test that killed it, seconds), the kill rate per file and overall, the
  survivors, as Markdown, JSON and HTML.

Mutants marked equivalent by hand (``equivalent.toml``, each with its reason) do not count; a mark
names its mutant by file, routine, statement and mutation, not by line (``marks``).
"""
