"""How much a cheaper normal CDF could buy: the committed tree (``git archive HEAD``) laid out
three times as its own package, with the compiled kernels' ``ndtr`` (``trackers/numba_exact.py``)
left as scipy's, replaced by glibc's ``erfc`` inlined, or by a free stand-in (a monotone
rational, no special function at all); then, tree after tree, the per-particle benchmark's
case (28 raster steps from the prior, the fastest of the next 10 steps over N) and the
GPF's step on ``large`` (the benchmarks' warm state, fastest of 200 copies). Only
``scipy`` gives the suite's numbers: the other two are bounds on cost, not trackers
(docs/speed.md, "A cheaper normal CDF: measured bounds"). The free stand-in changes what
the GPF does on ``large`` (its components' tails), so its GPF figure is no bound.

    python docs/cdf_bound.py --rounds 2

The first round after the trees are laid out compiles their kernels (about a minute each)
and is not printed.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCIPY_LINE = 'ndtr = scipy_function("mttbench_scipy_ndtr", "__pyx_fuse_1ndtr")'
VARIANTS = {
    "scipy": SCIPY_LINE,
    "libm-erfc": ("import math\n\n\n@njit(cache=True, inline='always')\ndef ndtr(x, skip):\n"
                  "    return 0.5 * math.erfc(-x * 0.7071067811865476)\n"),
    "free": ("@njit(cache=True, inline='always')\ndef ndtr(x, skip):\n"
             "    return 0.5 * (1.0 + x / (1.0 + abs(x)))\n"),
}
CASES = [("ap", "default", 4000), ("ap", "default", 16000), ("ap", "env-pf-0.1", 4000),
         ("gpf", "large", 0)]


def lay_out(into: Path) -> None:
    """Each variant's package under ``into/<variant>/mttbench``, as the installed layout."""
    src = into / "src"
    src.mkdir()
    archive = subprocess.run(["git", "archive", "HEAD"], cwd=ROOT, check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    for name, line in VARIANTS.items():
        pkg = into / name / "mttbench"
        shutil.copytree(src / "mttbench", pkg)
        for part in ("trackers", "scenarios", "benchmarks", "tuned"):
            shutil.copytree(src / part, pkg / part)
        shutil.copytree(src / "reports" / "reference", pkg / "reference")
        exact = pkg / "trackers" / "numba_exact.py"
        text = exact.read_text()
        assert SCIPY_LINE in text, "numba_exact.py no longer binds ndtr as this script expects"
        exact.write_text(text.replace(SCIPY_LINE, line))


def measure(kind: str, scenario: str, n: int) -> str:
    """One case in this process (the package on ``sys.path`` is the variant's)."""
    import time

    from mttbench import scenarios
    from mttbench.benchmarks.bench.conftest import warm_up
    from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios
    from mttbench.trackers import numba_exact
    from mttbench.trackers.jmpd import JMPDAPTracker

    # the variant's kernels, not an installed tree's
    assert numba_exact.__file__.startswith(os.environ["PYTHONPATH"]), numba_exact.__file__
    if kind == "ap":
        warm = warm_up(resolve_scenarios([scenario])[0], JMPDAPTracker(n_particles=n), 28)
        step, _ = warm.advance(11)
        step()
        times = []
        for _ in range(10):
            t0 = time.process_time()
            step()
            times.append(time.process_time() - t0)
        return f"{min(times) / n * 1e6:.3f} us per particle-step"
    warm = warm_up(scenarios.get(scenario), TrackerSpec.parse("gpf").make(), 60)
    setup, step, _ = warm.repeat_step()
    times = []
    for _ in range(200):
        setup()
        t0 = time.process_time()
        step()
        times.append(time.process_time() - t0)
    return f"{min(times) * 1e3:.3f} ms a step"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--measure", nargs=3, metavar=("KIND", "SCENARIO", "N"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        kind, scenario, n = args.measure
        print(measure(kind, scenario, int(n)))
        return
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as tmp:
        lay_out(Path(tmp))
        for r in range(args.rounds + 1):
            for name in VARIANTS:
                for kind, scenario, n in CASES:
                    out = subprocess.run(
                        [sys.executable, __file__, "--measure", kind, scenario, str(n)],
                        env={**env, "PYTHONPATH": str(Path(tmp) / name)}, check=True,
                        capture_output=True, text=True, cwd=tmp).stdout.strip()
                    if r:  # round 0 compiles the kernels
                        label = f"jmpd-ap {scenario} N={n}" if kind == "ap" else f"gpf {scenario}"
                        print(f"round {r}  {name:<10} {label:<26} {out}", flush=True)


if __name__ == "__main__":
    main()
