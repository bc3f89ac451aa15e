"""The application on top of the engine: the command line and everything it writes.

``cli`` (the ``mttbench`` command) and its ``usage``, ``executor_options`` and
``progress`` helpers; ``compare`` (the head-to-head), ``tune`` and ``tuned`` (the tuning
study and its files), ``reproduce`` and ``reproduce_kreucher`` (the paper's and
Kreucher's figures), ``resources`` (a sweep's memory and time, checked before it runs),
``summary`` (per-run values, intervals, gap closed), ``report`` and ``figures`` (Markdown,
HTML and PNG). Nothing in the engine, the trackers or the scenarios imports this package.
"""
