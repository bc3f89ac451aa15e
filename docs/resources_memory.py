"""Calibration of ``benchmarks/app/resources.py``: the peak memory and wall time of one
``run_job`` against the estimate the sweep check makes for it.

Each case runs in a fresh Python process, as a worker would: the imports (the command
line's, as the worker forked from ``mttbench`` has them), a warm-up ``run_job`` of the
tracker with its default parameters and the policy on ``default``'s 12x12 grid for 2
steps (numba's kernels loaded, the first jump table of the simulator built; again on the
case's grid when it has more than 2^31 - 1 cells, whose kernels take int64 cells), then
the peak-RSS high-water mark is reset (``/proc/self/clear_refs``) and the case's
``run_job`` runs. Reported, in MB (2^20 bytes): the resident size after the imports and
after the warm-up (the worker's base, :data:`~mttbench.benchmarks.app.resources.WORKER_BASE`),
the run's growth (peak during the run, ``getrusage(RUSAGE_SELF).ru_maxrss``, minus the
resident size before it) against the estimate without the worker's base, the peak
against the whole estimate; and the run's wall time against the estimated seconds. The
address space is capped (``--limit-gb``) so that an ``O(cells)`` array on a huge grid
fails at once with ``MemoryError``. Worlds: the ``--preset`` (default
``large``: 25 targets, 250 looks) on ``side x side`` grids, or the ``scale`` preset::

    python docs/resources_memory.py --sides 12 50 2000 100000 --steps 20
    python docs/resources_memory.py --trackers jmpd:n_particles=50000 --sides 12 --steps 5
    python docs/resources_memory.py --scale --steps 10 --trackers kfnn truth-aided gpf
    python docs/resources_memory.py --policies renyi:repeats=true --sides 12 100000 --json o.jsonl
    python docs/resources_memory.py --boxes default crossing births large --sides 100000 \
        --steps 100 --trackers kfnn gpf truth-aided ss-gnn ss-gmphd

Linux only (``/proc``).
"""

from __future__ import annotations

import argparse
import json
import sys

from scaling_memory import fmt, run_child  # docs/, the script's folder

DEFAULT_TRACKERS = ["null", "kfnn", "truth-aided", "gpf", "jmpd:t_max=30",
                    "jmpd-ip:t_max=30", "jmpd-ap", "ss-gnn", "ss-gmphd"]

_CHILD = r"""
import dataclasses, gc, json, re, resource, sys, time
limit = int(float(sys.argv[6]) * 2**30)
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

def status():
    text = open("/proc/self/status").read()
    return {k: int(re.search(k + r":\s+(\d+)", text).group(1)) / 1024.0
            for k in ("VmRSS", "VmHWM")}

import mttbench.benchmarks.app.cli  # noqa: F401 - what a worker forked from mttbench holds
from mttbench import scenarios
from mttbench.benchmarks.app import resources
from mttbench.benchmarks.engine.loop import Job, run_job
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec
from mttbench.scenarios.model import Grid

tracker, policy, world, steps = (TrackerSpec.parse(sys.argv[1]), PolicySpec.parse(sys.argv[2]),
                                 sys.argv[3], int(sys.argv[4]))
preset = sys.argv[5]
looks = None if sys.argv[7] == "-" else int(sys.argv[7])
imports = status()["VmRSS"]

def scenario(side):
    if side == "scale":
        return dataclasses.replace(scenarios.get("scale"), n_steps=steps)
    base = scenarios.get(preset)
    n = int(side)
    return dataclasses.replace(base, name=f"{preset}-{n}", n_steps=steps,
                               model=dataclasses.replace(base.model, grid=Grid(n, n, 1.0)))

# warm-up: the tracker's defaults (its kernels, not its buffers) on default's 12x12 grid,
# and on the case's grid when its cells need int64 (other compiled kernels)
small = dataclasses.replace(scenarios.get("default"), n_steps=2)
plain = TrackerSpec(tracker.name)
run_job(Job(small, plain, policy, None, 0))
if world != "scale" and int(world) ** 2 > 2**31 - 1:
    grid = dataclasses.replace(small.model, grid=Grid(int(world), int(world), 1.0))
    run_job(Job(dataclasses.replace(small, model=grid), plain, policy, None, 0))
gc.collect()
after_warm = status()
job = Job(scenario(world), tracker, policy, looks, 0)
est = resources.estimate_job(job)
open("/proc/self/clear_refs", "w").write("5")  # the high-water mark starts again here
before = status()["VmRSS"]
t0 = time.perf_counter()
try:
    rows = run_job(job)
    bad = rows[rows["status"] != "ok"]
    state = "ok" if bad.empty else str(bad["error"].iloc[0])[:120]
except MemoryError:
    state = "MemoryError"
wall = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
print(json.dumps({
    "tracker": sys.argv[1], "policy": sys.argv[2], "world": world, "steps": steps,
    "looks": job.looks_per_step, "status": state, "imports_mb": imports,
    "warm_mb": after_warm["VmRSS"], "warm_peak_mb": after_warm["VmHWM"],
    "before_mb": before, "growth_mb": peak - before, "peak_mb": peak,
    "estimate_mb": (est.memory - resources.WORKER_BASE) / 2**20,
    "full_estimate_mb": est.memory / 2**20,
    "parts_mb": {k: v / 2**20 for k, v in est.parts.items()},
    "wall_s": wall, "estimate_s": est.seconds,
}))
"""


def run_one(tracker: str, policy: str, world: str, steps: int, preset: str,
            limit_gb: float, looks: int | None, timeout_s: float) -> dict:
    """One case in a fresh process; its JSON line (or why there is none)."""
    return run_child(_CHILD, [tracker, policy, world, str(steps), preset, str(limit_gb),
                              "-" if looks is None else str(looks)],
                     {"tracker": tracker, "policy": policy, "world": world, "steps": steps},
                     timeout_s)


def boxes(trackers: list[str], presets: list[str], sides: list[int], steps: int) -> None:
    """Under renyi, the most Gaussians a ``P_c(t)`` was built from, the most entries (cells
    in their 6-sd boxes) and the most own rows, per tracker and world (in this process):
    what :data:`~mttbench.benchmarks.app.resources.BOX_CELLS` is measured on."""
    import dataclasses

    from mttbench import scenarios
    from mttbench.benchmarks.engine.loop import play
    from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec
    from mttbench.scenarios.model import Grid
    from mttbench.trackers import cells

    seen: list[tuple[int, int]] = []
    real = cells.gaussian_cell_mass_sparse

    def counted(grid, means, covs, *args, **kwargs):
        out = real(grid, means, covs, *args, **kwargs)
        seen.append((len(means), len(out[0])))
        return out

    for module in [m for m in sys.modules.values()
                   if getattr(m, "__name__", "").startswith("mttbench.trackers.")]:
        if getattr(module, "gaussian_cell_mass_sparse", None) is real:
            module.gaussian_cell_mass_sparse = counted
    print("| tracker | world | steps | most Gaussians | most entries | entries per Gaussian |"
          " most own rows |")
    print("|---|---|---|---|---|---|---|")
    worlds = [(p, None) for p in presets] + [("large", n) for n in sides]
    for spec in trackers:
        for preset, side in worlds:
            sc = dataclasses.replace(scenarios.get(preset), n_steps=steps)
            if side is not None:
                sc = dataclasses.replace(sc, model=dataclasses.replace(
                    sc.model, grid=Grid(side, side, 1.0)))
            seen.clear()
            rows = [len(r.counts.cells) for r in play(sc, TrackerSpec.parse(spec).make(), 0,
                                                      policy=PolicySpec("renyi").make())]
            g = max((a for a, _ in seen), default=0)
            e = max((b for _, b in seen), default=0)
            label = preset if side is None else f"large on {side}x{side}"
            print(f"| {spec} | {label} | {steps} | {g} | {e} | {e / max(g, 1):.0f} | "
                  f"{max(rows, default=0)} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trackers", nargs="+", default=DEFAULT_TRACKERS)
    ap.add_argument("--policies", nargs="+", default=["raster", "renyi"])
    ap.add_argument("--sides", nargs="+", type=int, default=[12, 50, 2000, 100_000])
    ap.add_argument("--preset", default="large", help="the world put on each side's grid")
    ap.add_argument("--scale", action="store_true", help="the scale preset instead")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--looks", type=int, default=None, help="looks per step (the preset's)")
    ap.add_argument("--limit-gb", type=float, default=8.0)
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per case")
    ap.add_argument("--json", default=None, help="also append each case's JSON line here")
    ap.add_argument("--boxes", nargs="*", metavar="PRESET", default=None,
                    help="instead: the Gaussians' boxes in P_c under renyi on these presets "
                         "and on large at --sides")
    args = ap.parse_args(argv)
    if args.boxes is not None:
        boxes(args.trackers, args.boxes, args.sides, args.steps)
        return 0
    worlds = ["scale"] if args.scale else [str(s) for s in args.sides]
    print("| tracker | policy | world | steps | imports MB | after warm-up MB | run's growth MB |"
          " estimate MB | estimate / growth | peak MB | full estimate MB | wall s | estimate s |"
          " status |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for spec in args.trackers:
        for policy in args.policies:
            for world in worlds:
                r = run_one(spec, policy, world, args.steps, args.preset, args.limit_gb,
                            args.looks, args.timeout)
                if args.json:
                    with open(args.json, "a") as fh:
                        fh.write(json.dumps(r) + "\n")
                g, e = r.get("growth_mb"), r.get("estimate_mb")
                ratio = e / max(g, 1.0) if g is not None and e is not None else None
                label = world if world == "scale" else f"{world}x{world}"
                print(f"| {spec} | {policy} | {label} | {r['steps']} | "
                      f"{fmt(r.get('imports_mb'))} | {fmt(r.get('warm_mb'))} | {fmt(g)} | "
                      f"{fmt(e)} | "
                      f"{fmt(ratio, '.2f')} | {fmt(r.get('peak_mb'))} | "
                      f"{fmt(r.get('full_estimate_mb'))} | {fmt(r.get('wall_s'), '.3g')} | "
                      f"{fmt(r.get('estimate_s'), '.3g')} | {r['status']} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
