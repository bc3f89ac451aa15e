"""The Bayes references' ladders as Markdown (docs/bayes.md), from a store's JSON files.

    .venv/bin/python docs/bayes_table.py [STORE]      # default: the package's store

One row per scenario: OSPA (mean ± 95% t half-width over the seeds) at every rung, the
last paired difference OSPA(N) - OSPA(4N) with its half-width and the bound |mean| + half
that the tolerance is checked against, that tolerance (0.02, or 5% of the achievable gap
null minus the reference, whichever is wider), the verdict, and the wall and CPU time it took.

Then, for every reference not converged, what deciding it would take: for each of the two
steps the two-step rule checks at the largest rung, the per-seed standard deviation of
the paired difference and the seeds ``n`` with ``|mean| + t_{0.975, n-1} sd / sqrt(n) <=
tolerance`` if the mean stayed as measured ("never" when ``|mean|`` alone exceeds the
tolerance: the ladder is still moving there, more seeds cannot decide it), and the CPU
hours those seeds would cost at the ladder's rungs up to the largest (each rung's
measured CPU s per run).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from scipy import stats

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
    _what_it_would_take([p for p in provs if not p["converged"]])
    return 0


def seeds_needed(mean: float, sd: float, tolerance: float, most: int = 100_000) -> int | None:
    """The fewest seeds ``n >= 2`` whose interval bound ``|mean| + t sd / sqrt(n)`` is within
    ``tolerance``, or None (``|mean| >= tolerance``, or more than ``most``)."""
    if abs(mean) >= tolerance:
        return None
    n = 2
    while n <= most:
        if abs(mean) + stats.t.ppf(0.975, n - 1) * sd / math.sqrt(n) <= tolerance:
            return n
        n = n + 1 if n < 64 else int(n * 1.05) + 1
    return None


def _what_it_would_take(provs: list[dict]) -> None:
    print()
    print("| scenario | seeds | step | mean | per-seed sd | tolerance | seeds to decide | "
          "CPU h for them |")
    print("|---|---:|---|---:|---:|---:|---:|---:|")
    for p in provs:
        cost = {r["n_particles"]: r["run_cpu_s"] for r in p["rungs"]}
        for step in (p.get("steps") or [])[-2:]:
            n = step["n_pairs"]
            sd = step["diff_ci95"] / stats.t.ppf(0.975, n - 1) * math.sqrt(n)
            tol = step.get("tolerance") or p["tolerance"]
            need = seeds_needed(step["diff_mean"], sd, tol)
            per_seed = sum(c for m, c in cost.items() if m <= step["n_high"])
            hours = "" if need is None else f"{need * per_seed / 3600:.1f}"
            print(f"| `{p['scenario']}` | {len(p['seeds'])} | {step['n_low']} -> "
                  f"{step['n_high']} | {step['diff_mean']:+.3f} | {sd:.3f} | {tol:.3f} | "
                  f"{'never' if need is None else need} | {hours} |")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
