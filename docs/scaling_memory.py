"""Peak memory of a run against the grid's size (the goal: a 1e5 x 1e5 grid runs
in the memory of a 50x50 one), and of the ``scale`` preset, each run in a fresh process.

Every run plays ``--steps`` steps of a world through the harness
(:func:`~mttbench.benchmarks.engine.loop.play`) in its own Python process and reports that
process's peak resident memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss``), its
resident memory after the imports (the interpreter, numpy, scipy, numba's kernels: the
same for every run), and the per-step medians of the tracker's time and of the
selection's (CPU). The process's address space is capped (``--limit-gb``, default 6) so
that an ``O(cells)`` array on 1e10 cells fails at once with ``MemoryError`` instead of
swamping the machine. Worlds: the ``large`` preset's 25 targets and 250 looks on a
``side x side`` grid (``--sides``, default 50 and 100000), and the ``scale`` preset
(``--scale``)::

    python docs/scaling_memory.py                       # kfnn, truth-aided, null, ...
    python docs/scaling_memory.py --trackers kfnn gpf --policies raster renyi --steps 10
    python docs/scaling_memory.py --scale --steps 50 --trackers kfnn null
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

DEFAULT_TRACKERS = ["kfnn", "truth-aided", "null", "ss-gnn", "ss-gmphd", "gpf",
                    "jmpd:t_max=30", "jmpd-ip:t_max=30", "jmpd-ap"]

_CHILD = r"""
import dataclasses, json, resource, sys, time
limit = int(float(sys.argv[5]) * 2**30)
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
import numpy as np
from mttbench import scenarios
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.policies import make_policy
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.scenarios.model import Grid

spec, policy, side, steps = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
tracker = TrackerSpec.parse(spec).make()
if side == "scale":
    sc = dataclasses.replace(scenarios.get("scale"), n_steps=steps)
else:
    base = scenarios.get("large")
    n = int(side)
    sc = dataclasses.replace(base, name=f"large-{n}", n_steps=steps,
                             model=dataclasses.replace(base.model, grid=Grid(n, n, 1.0)))
kb = 1024.0  # ru_maxrss is in kilobytes on Linux
after_imports = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / kb
status, step_s, select_s = "ok", [], []
try:
    for rec in play(sc, tracker, 0, policy=make_policy(policy)):
        step_s.append(rec.tracker_cpu_s)
        select_s.append(rec.select_cpu_s)
except MemoryError:
    status = "MemoryError"
except Exception as exc:  # noqa: BLE001 - reported, not raised
    status = f"{type(exc).__name__}: {exc}"[:120]
print(json.dumps({
    "tracker": spec, "policy": policy, "world": side, "steps": len(step_s),
    "status": status, "after_imports_mb": after_imports,
    "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / kb,
    "step_ms": float(np.median(step_s)) * 1e3 if step_s else None,
    "select_ms": float(np.median(select_s)) * 1e3 if select_s else None,
}))
"""


def run_child(script: str, args: list[str], head: dict, timeout_s: float) -> dict:
    """``python -c script *args`` in a fresh process; its last JSON line, or ``head`` with
    the reason there is none (a timeout, the last line of stderr) as ``status``. Shared
    with docs/resources_memory.py."""
    try:
        out = subprocess.run([sys.executable, "-c", script, *args], capture_output=True,
                             text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return {**head, "status": "timeout"}
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        tail = (out.stderr.strip().splitlines() or ["no output"])[-1][:120]
        return {**head, "status": tail}
    return json.loads(lines[-1])


def run_one(spec: str, policy: str, world: str, steps: int, limit_gb: float,
            timeout_s: float) -> dict:
    """One run in a fresh process; its JSON line (or why there is none)."""
    return run_child(_CHILD, [spec, policy, world, str(steps), str(limit_gb)],
                     {"tracker": spec, "policy": policy, "world": world}, timeout_s)


def fmt(v, spec: str = ".1f") -> str:
    return "-" if v is None else format(v, spec)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trackers", nargs="+", default=DEFAULT_TRACKERS)
    ap.add_argument("--policies", nargs="+", default=["raster", "renyi"])
    ap.add_argument("--sides", nargs="+", type=int, default=[50, 100_000])
    ap.add_argument("--scale", action="store_true",
                    help="the scale preset instead of the sides")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--limit-gb", type=float, default=6.0)
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per run")
    args = ap.parse_args(argv)
    worlds = ["scale"] if args.scale else [str(s) for s in args.sides]
    print("| tracker | policy | world | steps | peak RSS MB | after imports MB | "
          "run's own MB | step ms | selection ms | status |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for spec in args.trackers:
        for policy in args.policies:
            for world in worlds:
                r = run_one(spec, policy, world, args.steps, args.limit_gb, args.timeout)
                own = (r["peak_mb"] - r["after_imports_mb"]) if "peak_mb" in r else None
                label = world if world == "scale" else f"{world}x{world}"
                print(f"| {spec} | {policy} | {label} | {r.get('steps', '-')} | "
                      f"{fmt(r.get('peak_mb'))} | {fmt(r.get('after_imports_mb'))} | "
                      f"{fmt(own)} | {fmt(r.get('step_ms'), '.3g')} | "
                      f"{fmt(r.get('select_ms'), '.3g')} | {r['status']} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
