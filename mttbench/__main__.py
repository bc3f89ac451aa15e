"""``python -m mttbench``: the same as the ``mttbench`` command."""

from mttbench.benchmarks.app.cli import main

raise SystemExit(main())
