"""Does a cached kernel run a callee it was compiled with, after the callee's file changed?

Edits ``trackers/gpf/step_kernels.py`` of the checkout it runs in (every full distance of
``pair_distances`` times 0, so that close components merge), asks the GPF's compiled
mixture reduction, in a fresh process, whether two components of one track (Bhattacharyya
distance about 4.4, merge threshold 0.5) merge, then the same with an empty
``NUMBA_CACHE_DIR`` (compiled from the sources as they are), and restores the file. Run it
in a checkout whose kernel cache is warm (``make``); it leaves the cache to be compiled
again on the next import (about two minutes; ``make`` does it first)::

    .venv/bin/python docs/stale_kernel_probe.py

Before ``compiled.drop_stale_caches`` the warm cache said 2 rows (the old helper) and the
sources 1 (docs/suite_time.md, 2026-11-30).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

HELPER = Path(__file__).resolve().parents[1] / "trackers" / "gpf" / "step_kernels.py"
PROBE = """
import numpy as np
from mttbench.trackers.gpf import update_kernels as k
own = np.array([0, 0], np.int64)
a = np.array([0.6, 0.4])
m = np.array([[10.0, 0.0, 10.0, 0.0], [10.3, 0.0, 10.0, 0.0]])
P = np.stack([np.diag([0.3, 0.1, 0.3, 0.1]), np.diag([3.0, 1.0, 3.0, 1.0])])
out = k.reduce_components(own, a, m, P, 1, 8, 0.5, 1e-4, 1e-9)
print(len(out[1]), bool(k.reduce_components.stats.cache_hits))
"""


def probe(env: dict[str, str]) -> str:
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         env=env, check=True).stdout.split()
    return f"{out[0]} row(s), loaded from the cache: {out[1]}"


def main() -> None:
    original = HELPER.read_text()
    edited = original
    for entry in ("d2[i, j]", "d2[j, i]"):
        edited = edited.replace(f"    {entry} = full\n", f"    {entry} = 0.0 * full\n")
    if edited == original:
        raise SystemExit(f"{HELPER} no longer has the lines this probe edits")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    try:
        HELPER.write_text(edited)
        print("edited step_kernels.pair_distances; the checkout's cache:", probe(env))
        with tempfile.TemporaryDirectory() as empty:
            print("an empty NUMBA_CACHE_DIR:", probe({**env, "NUMBA_CACHE_DIR": empty}))
    finally:
        HELPER.write_text(original)


if __name__ == "__main__":
    main()
