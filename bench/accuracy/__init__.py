"""Monte Carlo accuracy harness: the estimators of ``x`` and ``a`` against the Cramér-Rao
bound over a grid of scenarios and noise levels.

Run from the repository root: ``python -m bench.accuracy --help``; ``python -m
bench.accuracy --write-docs`` regenerates ``docs/accuracy.md`` and its figures.

Modules: :mod:`.core` (batched data, the CRLB recursion, metrics), :mod:`.estimators` (the
estimators behind one batched interface), :mod:`.run` (tasks, processes), :mod:`.report`
(tables, figures), :mod:`.docs` (``docs/accuracy.md``), :mod:`.cli`.
"""
