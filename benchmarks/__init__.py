"""Benchmarks in two layers: ``engine`` (jobs, the one step loop, metrics, policies,
executors, the result store) and ``app`` on top of it (command line, compare, tune,
reproduce, resources, summaries, reports). ``bench/`` holds the runtime benchmarks
(pytest-benchmark; not installed)."""
