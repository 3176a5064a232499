"""Developer tools of cpdi-verify: the benchmark, the mutation tool and maintenance scripts.

Not part of the installed package (`pip install .` installs `harness` only); run from a checkout,
e.g. `python -m tools.bench` (make bench) or `python -m tools.mutation` (make mutate).
"""
