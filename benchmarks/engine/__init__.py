"""The engine: what a sweep is and how it runs, with no command line in it.

================  =============================================================
module            what it holds
================  =============================================================
``errors``        :class:`~.errors.ConfigError`, the one error for a bad configuration
``specs``         tracker and policy specifications (``name:key=value``), resolved
``loop``          :class:`~.loop.Job`, the results table's columns, the one step loop
                  :func:`~.loop.play` and one run's rows :func:`~.loop.run_job`
``metrics``       per-step scores and the metric registry
``policies``      cell-selection policies; ``information``: the Renyi gains;
                  ``policy_search``: ``search-track`` (registered on import of the engine);
                  ``policy_lookahead``: the non-myopic ``lookahead`` policy (likewise)
``executors``     where runs go: local processes or a Dask cluster
``store``         parts written atomically, read back, the results table
``sweep``         :func:`~.sweep.run_sweep`: jobs -> parts -> ``results.parquet``
``snapshot``      a traced run (the step loop's states, for figures)
================  =============================================================

Nothing here imports :mod:`mttbench.benchmarks.app` (a test enforces it).
"""

# register their policies whichever engine module is imported first (each imports
# policies, so policies cannot import them)
from . import policy_lookahead as _policy_lookahead  # noqa: E402,F401  (registers lookahead)
from . import policy_search as _policy_search  # noqa: E402,F401  (registers search-track)
