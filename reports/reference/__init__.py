"""Reference numbers of ``mttbench reproduce`` (installed as package data, ``mttbench.reference``).

The CSVs are what ``--check`` compares against; ``<name>.versions.json`` lists the package
versions that produced each. Regenerate with ``mttbench reproduce ... --update-reference``.
"""
