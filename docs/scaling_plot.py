"""The scaling series of benchmarks/bench/bench_scaling.py as a figure and a table.

Reads the JSON of a timed run (pytest-benchmark's ``--benchmark-json``; runs the series
first when the file is missing) and writes a PNG with four panels, median time per step
(log-log) against the number of targets (the ``targets`` series, fixed density) and
against the grid's side (the ``grid`` series, 25 targets and 250 looks): the tracker's
step and the selection (``P_c(t)`` and the renyi policy's looks), one line per tracker,
the simulator's step on the first two. Prints the medians as Markdown tables, and the
ratio of each step on the 2000x2000 grid to its step on 50x50 (the goal: <= 1.5)::

    python docs/scaling_plot.py scaling.json docs/scaling.png
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench" / "bench_scaling.py"
KINDS = {"test_tracker_step": "tracker step (predict + update + estimate)",
         "test_selection": "selection (P_c(t) + renyi looks)"}


def run_series(json_path: Path) -> None:
    """Time the series (about 10 minutes on 2 cores, most of it Stone Soup's peers at
    1,000 targets) into ``json_path``."""
    subprocess.run([sys.executable, "-m", "pytest", "-q", str(BENCH), "--benchmark-only",
                    "--benchmark-timer=time.process_time",
                    f"--benchmark-json={json_path}"], check=True)


def medians(json_path: Path) -> dict[tuple[str, str, str], dict[int, float]]:
    """``{(kind, series, tracker): {size: median seconds}}``; the simulator's tracker is
    ``"simulator"`` and its kind ``test_tracker_step``."""
    data = json.loads(json_path.read_text())
    out: dict[tuple[str, str, str], dict[int, float]] = defaultdict(dict)
    for b in data["benchmarks"]:
        kind = b["name"].split("[")[0]
        info = b["extra_info"]
        tracker = b["params"].get("spec", "simulator")
        if kind == "test_simulator_step":
            kind = "test_tracker_step"
        out[(kind, info["series"], tracker)][int(info["size"])] = float(b["stats"]["median"])
    return out


def table(data, kind: str, series: str) -> str:
    rows = {t: v for (k, s, t), v in data.items() if k == kind and s == series}
    sizes = sorted({size for v in rows.values() for size in v})
    head = "| " + ("targets" if series == "targets" else "side") + " | " + " | ".join(
        str(s) for s in sizes) + " |"
    lines = [head, "|---" * (len(sizes) + 1) + "|"]
    for tracker in sorted(rows):
        cells = [f"{rows[tracker][s] * 1e3:.3g}" if s in rows[tracker] else "-"
                 for s in sizes]
        lines.append(f"| {tracker} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def grid_ratios(data, lo: int = 50, hi: int = 2000) -> str:
    lines = ["| tracker | step 50x50 ms | step 2000x2000 ms | ratio | selection ratio |",
             "|---|---|---|---|---|"]
    trackers = sorted({t for (k, s, t) in data if s == "grid"})
    for tracker in trackers:
        step = data.get(("test_tracker_step", "grid", tracker), {})
        sel = data.get(("test_selection", "grid", tracker), {})
        if lo in step and hi in step:
            r_sel = f"{sel[hi] / sel[lo]:.2f}" if lo in sel and hi in sel else "-"
            lines.append(f"| {tracker} | {step[lo] * 1e3:.3g} | {step[hi] * 1e3:.3g} | "
                         f"{step[hi] / step[lo]:.2f} | {r_sel} |")
    return "\n".join(lines)


def plot(data, png: Path) -> None:
    names = sorted({t for (_, _, t) in data} - {"simulator"})
    cmap = plt.get_cmap("tab10" if len(names) <= 10 else "tab20")
    color = {t: cmap(i % cmap.N) for i, t in enumerate(names)}  # one colour per tracker
    fig, axes = plt.subplots(2, 2, figsize=(12, 9), sharey="row")
    for col, series in enumerate(("targets", "grid")):
        for row, kind in enumerate(KINDS):
            ax = axes[row, col]
            for (k, s, tracker), v in sorted(data.items()):
                if k != kind or s != series:
                    continue
                sizes = sorted(v)
                style = ({"color": "black", "linewidth": 2.5} if tracker == "simulator"
                         else {"color": color[tracker]})
                ax.plot(sizes, [v[x] * 1e3 for x in sizes], marker="o", label=tracker, **style)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.grid(True, which="both", alpha=0.3)
            ax.set_xlabel("targets (250 cells and 2.5 looks per target)" if series == "targets"
                          else "grid side (25 targets, 250 looks)")
            ax.set_ylabel(f"{KINDS[kind]}, median ms")
            ax.legend(fontsize=7, ncol=2)
    fig.suptitle("Step time against targets (fixed density) and against the grid (fixed "
                 "targets and looks): benchmarks/bench/bench_scaling.py")
    fig.tight_layout()
    fig.savefig(png, dpi=110)


def main(argv: list[str]) -> int:
    json_path = Path(argv[1]) if len(argv) > 1 else Path("scaling.json")
    png = Path(argv[2]) if len(argv) > 2 else Path("docs/scaling.png")
    if not json_path.exists():
        run_series(json_path)
    data = medians(json_path)
    plot(data, png)
    for kind, what in KINDS.items():
        for series in ("targets", "grid"):
            print(f"\n{what}, {series} series, median ms\n")
            print(table(data, kind, series))
    print("\n2000x2000 against 50x50 (goal <= 1.5)\n")
    print(grid_ratios(data))
    print(f"\nwrote {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
