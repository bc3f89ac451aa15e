"""The Bayes references' ladders as Markdown (docs/bayes.md), from a store's JSON files.

    .venv/bin/python docs/bayes_table.py [STORE]      # default: the package's store

One row per scenario: OSPA (mean ± 95% t half-width over the seeds) at every rung, the
last paired difference OSPA(N) - OSPA(4N) with its half-width and the bound |mean| + half
that the tolerance is checked against, that tolerance (0.02, or 5% of the achievable gap
null minus the reference, whichever is wider), the verdict, and the wall and CPU time it took.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from mttbench.benchmarks.app import bayes


def _pm(mean: float | None, half: float | None, fmt: str = ".3f") -> str:
    if mean is None:
        return "n/a"
    return format(mean, fmt) + ("" if half is None else f" ± {half:.3f}")


def main(argv: list[str]) -> int:
    store = Path(argv[0]) if argv else bayes.default_store()
    provs = [json.loads(p.read_text()) for p in sorted(store.glob("*.json"))]
    rungs = sorted({r["n_particles"] for p in provs for r in p["rungs"]})
    head = ["scenario", "seeds", *(f"N = {n}" for n in rungs), "last step (N -> 4N)",
            "bound", "tolerance", "verdict", "wall s", "CPU s"]
    print("| " + " | ".join(head) + " |")
    print("|---|---:|" + "---:|" * len(rungs) + "---:|---:|---:|---|---:|---:|")
    for p in provs:
        by_n = {r["n_particles"]: r for r in p["rungs"]}
        cells = [f"`{p['scenario']}`", str(len(p["seeds"]))]
        for n in rungs:
            r = by_n.get(n)
            cells.append("" if r is None else _pm(r["ospa_mean"], r["ospa_ci95"]))
        step = (p.get("steps") or [None])[-1]
        if step:
            cells += [_pm(step["diff_mean"], step["diff_ci95"], "+.3f"),
                      "n/a" if step["bound"] is None else f"{step['bound']:.3f}",
                      f"{step.get('tolerance') or p['tolerance']:.3f}"]
        else:
            cells += ["", "", ""]
        verdict = (f"converged at {p['n_reference']}" if p["converged"]
                   else f"not converged at {p['n_reference']}")
        cells += [verdict, f"{p['wall_time_s']:.0f}", f"{p['cpu_time_s']:.0f}"]
        print("| " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
