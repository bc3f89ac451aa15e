"""Tuned tracker parameters: ``<tracker>.toml`` files written by ``mttbench tune``.

``mttbench compare`` runs a tracker with the parameters of its file here (label
``name(tuned)``; ``--untuned`` runs the defaults). Installed as package data
(``mttbench.tuned``), so an installed ``mttbench`` runs the files checked in when it was
built. Format, location and use: ``mttbench.benchmarks.app.tuned``.
"""
