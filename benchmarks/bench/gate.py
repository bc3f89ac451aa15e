"""The runtime regression gate: its arithmetic, its ratios file and its commands.

Pure functions (no pytest): the conftest gates with them, ``tests/test_bench_gate.py``
tests them on synthetic samples, and the commands below record the stored ratios and
measure the gate's noise. docs/bench_gates.md describes the measurement behind the
numbers.

**Ratio.** A benchmark's ratio is ``min(step rounds) / min(reference runs)``: its fastest
round over the fastest run of a fixed reference workload (conftest
``reference_workload``) timed by the same clock, 15 runs right before and 15 right after
the benchmark. The minimum is the round least disturbed by other processes; the
reference, timed in the same minute, takes out how fast the machine is.

**Decision.** A run fails a benchmark when ``ratio > tol x stored`` (slower only); a
benchmark without a stored ratio fails too, except in the recording mode. ``check``
(``make bench-check``) re-runs a benchmark that exceeded its tolerance, in a fresh
process, up to ``RETRIES`` times, and fails it when every attempt exceeded it: a load
burst on a shared machine seldom lasts through three separate runs, a slower code
always does.

**Tolerance.** From the ``RUNS`` recorded runs (unchanged tree, the gate's own command;
a re-recorded benchmark keeps the larger of its old and its new spreads),
stored ratio their median, the spread upwards ``up = ln(max / median)`` and downwards
``down = ln(median / min)`` (a loaded machine slows a step more than the reference far
more often than the reverse, so the two differ), ``tol = exp(max(K x up, ln FLOOR))``,
capped at ``CAP``. The smallest slowdown the gate catches in every run (one whose noise
puts it at the low end, ``down`` below the stored ratio) is ``tol x exp(down)``
(:func:`catches`).

Commands (``python benchmarks/bench/gate.py --help``)::

    gate.py check [-- PYTEST ARGS]                                # the gate (make bench-check)
    gate.py record [--runs 5] [--moved-by TEXT] [-- PYTEST ARGS]   # (re-)record ratios
    gate.py repeat [--runs 5] [--inject 1.3] [-- PYTEST ARGS]      # the gate's noise
    gate.py table [REPEAT_FOLDER ...]                              # docs/bench_gates.md
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
RATIOS_FILE = HERE / "ratios.toml"

#: the clock of the gate (pytest-benchmark's --benchmark-timer): CPU time of the process
GATE_TIMER = "time.process_time"
#: BLAS threads during a gated run (conftest sets it): with more, the CPU time of a
#: BLAS call includes its helper threads' busy-waiting, which the load decides
BLAS_THREADS = "1"
RUNS = 5  # recorded runs behind a stored ratio; the stored ratio is their median
K = 2.0  # tolerance = exp(K x up), ...
FLOOR = 1.10  # ... at least this (5 runs understate the spread) ...
CAP = 3.0  # ... and at most this


@dataclass(frozen=True)
class Entry:
    """A stored ratio: ``ratio`` (median of ``runs``), ``tol``, the spreads ``up`` and
    ``down`` of the runs (module docstring) and the change that last moved it
    (``moved_by``)."""

    ratio: float
    tol: float
    up: float
    down: float
    runs: tuple[float, ...]
    moved_by: str

    @property
    def catches(self) -> float:
        return catches(self.tol, self.down)


# ------------------------------------------------------------------ arithmetic
def ratio(step_s: Iterable[float], reference_s: Iterable[float]) -> float:
    """``min(step_s) / min(reference_s)`` (seconds by the same clock)."""
    step, ref = min(step_s), min(reference_s)
    if not (ref > 0):
        raise ValueError(f"reference time {ref} is not positive")
    return float(step) / float(ref)


def spreads(runs: Sequence[float]) -> tuple[float, float]:
    """``(up, down) = (ln(max / median), ln(median / min))`` of ``runs``."""
    med = statistics.median(runs)
    return math.log(max(runs) / med), math.log(med / min(runs))


def tolerance(up: float, k: float = K, floor: float = FLOOR, cap: float = CAP) -> float:
    """``exp(max(k x up, ln floor))``, at most ``cap``."""
    return min(cap, math.exp(max(k * up, math.log(floor))))


def catches(tol: float, down: float) -> float:
    """The smallest slowdown failed in every run: one at the low end of the measured
    runs (``stored x exp(-down)``) slowed by it must exceed ``tol x stored``."""
    return tol * math.exp(down)


def entry_from_runs(runs: Sequence[float], moved_by: str, previous: Entry | None = None,
                    **kw) -> Entry:
    """The stored entry of ``runs`` (ratios of one benchmark, unchanged tree). With the
    ``previous`` entry of a benchmark being re-recorded, the spreads are the larger of its
    and the new runs': a few benchmarks re-recorded in a minute see one load, where the
    first recording of all saw many (5 runs over half an hour at load averages 3-10)."""
    up, down = spreads(runs)
    if previous is not None:
        up, down = max(up, previous.up), max(down, previous.down)
    return Entry(statistics.median(runs), tolerance(up, **kw), up, down, tuple(runs),
                 moved_by)


@dataclass(frozen=True)
class Verdict:
    ok: bool
    factor: float  # measured / stored (nan without a stored ratio)
    message: str


def decide(key: str, measured: float, entry: Entry | None, recording: bool = False) -> Verdict:
    """The gate's decision for one benchmark (module docstring)."""
    if recording:
        return Verdict(True, math.nan if entry is None else measured / entry.ratio,
                       "recording")
    if entry is None:
        return Verdict(False, math.nan,
                       f"{key}: no stored ratio in {RATIOS_FILE.name} (step / reference = "
                       f"{measured:.4g}); record it: python benchmarks/bench/gate.py record "
                       f"-- -k '<this benchmark>' (docs/bench_gates.md)")
    factor = measured / entry.ratio
    if factor > entry.tol:
        return Verdict(False, factor,
                       f"{key}: step / reference = {measured:.4g}, {factor:.3f} times the "
                       f"stored {entry.ratio:.4g} (tolerance {entry.tol:.3f}x, from the "
                       f"{len(entry.runs)} recorded runs' spread of {entry.up:.3f} in ln "
                       "above their median)")
    return Verdict(True, factor, "")


# ------------------------------------------------------------------ the ratios file
def load(path: Path = RATIOS_FILE) -> tuple[dict, dict[str, Entry]]:
    """``(header, entries)`` of the ratios file (empty when missing)."""
    if not path.exists():
        return {}, {}
    with path.open("rb") as f:
        data = tomllib.load(f)
    try:
        entries = {k: Entry(float(v["ratio"]), float(v["tol"]), float(v["up"]),
                            float(v["down"]), tuple(float(r) for r in v["runs"]),
                            str(v["moved_by"]))
                   for k, v in data.get("ratios", {}).items()}
    except KeyError as e:
        raise ValueError(f"{path}: an entry without {e} (written by an older gate): "
                         "re-record (python benchmarks/bench/gate.py record)") from None
    header = {k: v for k, v in data.items() if k != "ratios"}
    return header, entries


HEADER = """\
# Runtime regression gate (benchmarks/bench/gate.py, conftest.py; docs/bench_gates.md).
# A benchmark's ratio: its fastest round over the fastest run of a fixed reference
# workload timed right before and after it, by `timer`, BLAS on `blas_threads`.
# A gated run fails a benchmark whose ratio is above `tol` x `ratio`, and one that is
# not listed here. `ratio` is the median of `runs`, recorded on an unchanged tree by
# `python benchmarks/bench/gate.py record` (`runs` runs); `up` = ln(max(runs) / ratio),
# `down` = ln(ratio / min(runs)), `tol` = exp(max(k x up, ln floor)) capped at `cap`; the
# gate catches any slowdown above tol x exp(down) (gate.py); `moved_by` names the
# change whose recording this is. Re-record a benchmark when a deliberate change moves it.
"""


def dump(header: dict, entries: dict[str, Entry], path: Path = RATIOS_FILE) -> None:
    lines = [HEADER.rstrip("\n")]
    top = {k: v for k, v in header.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in header.items() if isinstance(v, dict)}
    lines += [f"{k} = {json.dumps(v)}" for k, v in top.items()]
    for name, table in tables.items():
        lines += ["", f"[{name}]", *(f"{k} = {json.dumps(v)}" for k, v in table.items())]
    lines += ["", "[ratios]"]
    for key, e in sorted(entries.items()):
        runs = ", ".join(f"{r:.6g}" for r in e.runs)
        lines.append(f"{json.dumps(key)} = {{ ratio = {e.ratio:.6g}, tol = {e.tol:.4f}, "
                     f"up = {e.up:.4f}, down = {e.down:.4f}, runs = [{runs}], "
                     f"moved_by = {json.dumps(e.moved_by)} }}")
    path.write_text("\n".join(lines) + "\n")


# ------------------------------------------------------------------ runs of the gate
RETRIES = 2  # re-runs of a benchmark that failed its tolerance before it fails the gate


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def head_description() -> str:
    """``HEAD``'s short hash, with ``+uncommitted`` when the benchmarked code (anything
    but the ratios file) differs from it."""
    head = _git("rev-parse", "--short", "HEAD") or "unknown"
    dirty = _git("status", "--porcelain", "--untracked-files=no", "--", ".",
                 f":(exclude){RATIOS_FILE.relative_to(ROOT)}")
    return head + ("+uncommitted" if dirty else "")


def run_pytest(pytest_args: Sequence[str], log: Path, *, record: bool = False,
               inject: float = 1.0, output: Path | None = None) -> tuple[int, float]:
    """One timed run of the benchmarks (the gate's clock, ``--gate-log log``; pytest's
    output to ``output``, or to this terminal); returns its exit code and wall seconds."""
    cmd = [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-p", "no:hypothesispytest",
           "--benchmark-only", f"--benchmark-timer={GATE_TIMER}", f"--gate-log={log}",
           *(["--record-ratios"] if record else []),
           *([f"--inject-slowdown={inject}"] if inject != 1.0 else []), *pytest_args]
    if not any(a.startswith("benchmarks/") for a in pytest_args):
        cmd.append("benchmarks/bench")
    log.unlink(missing_ok=True)
    t0 = time.perf_counter()
    if output is None:
        rc = subprocess.run(cmd, cwd=ROOT).returncode
    else:
        with output.open("w") as f:
            rc = subprocess.run(cmd, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT).returncode
    return rc, time.perf_counter() - t0


def read_log(log: Path) -> list[dict]:
    if not log.exists():
        return []
    return [json.loads(line) for line in log.read_text().splitlines() if line.strip()]


@dataclass
class Session:
    """One gated run with its re-runs (:func:`gate_session`)."""

    attempts: list[list[dict]]  # the benchmarks' log rows of each attempt
    failed: list[str]  # node ids that failed the gate in every attempt
    other: list[str]  # node ids that failed otherwise (accuracy, errors): not re-run
    rc: int  # the first attempt's pytest exit code
    wall_s: float  # all attempts

    @property
    def first_failed(self) -> list[str]:
        return [r["nodeid"] for r in self.attempts[0] if r.get("gated") and not r["ok"]]

    @property
    def ok(self) -> bool:
        return not self.failed and not self.other and self.rc in (0, 1)


def gate_session(pytest_args: Sequence[str], out: Path, tag: str, *, inject: float = 1.0,
                 quiet: bool = False, retries: int = RETRIES) -> Session:
    """Run the gate, then re-run (each in a fresh process) the benchmarks that exceeded
    their tolerance, up to ``retries`` times: one fails the gate when every attempt
    exceeded it. A load burst on a shared machine rarely lasts through three separate
    runs of one benchmark; a slowdown of the code does. A benchmark without a stored
    ratio, and a test that failed otherwise, are not re-run."""
    out.mkdir(parents=True, exist_ok=True)
    attempts, other, wall = [], [], 0.0
    args, rc = list(pytest_args), None
    for attempt in range(1 + retries):
        log = out / f"{tag}-attempt{attempt + 1}.jsonl"
        code, secs = run_pytest(args, log, inject=inject,
                                output=out / f"{tag}-attempt{attempt + 1}.out" if quiet else None)
        wall += secs
        rc = code if rc is None else rc
        rows = read_log(log)
        attempts.append([r for r in rows if "key" in r])
        other += [r["nodeid"] for r in rows if r.get("other_failure")]
        over = [r for r in attempts[-1] if r["gated"] and not r["ok"]]
        again = [r["nodeid"] for r in over if r["stored"] is not None]
        if not again or attempt == retries:
            failed = [r["nodeid"] for r in over]
            break
        if not quiet:
            print(f"\n== gate: {len(again)} benchmark(s) above their tolerance, re-run "
                  f"{attempt + 1} of {retries}: {' '.join(again)}\n", flush=True)
        keep = [a for a in pytest_args if not a.startswith("benchmarks/")]
        args = [*keep, *again]
    return Session(attempts, failed, other, rc, wall)


def _print_session(s: Session) -> None:
    first = s.attempts[0]
    n = sum(1 for r in first if r["gated"])
    print(f"\n== gate: {n} benchmarks gated in {s.wall_s:.0f} s ({len(s.attempts)} "
          f"attempt(s)); above tolerance in the first: {len(s.first_failed)}; failed the "
          f"gate (every attempt): {len(s.failed)}")
    for nodeid in s.failed:
        rows = [r for a in s.attempts for r in a if r["nodeid"] == nodeid]
        fs = ", ".join(f"{r['ratio'] / r['stored']:.3f}" if r["stored"] else "none stored"
                       for r in rows)
        tol = rows[0]["tol"]
        print(f"   FAILED {nodeid}: measured / stored {fs}"
              + (f" (tolerance {tol:.3f})" if tol else ""))
    for nodeid in s.other:
        print(f"   FAILED {nodeid} (not the gate: see the output above)")
    faster = [r for r in first if r["gated"] and r["stored"] and r["tol"]
              and r["ratio"] < r["stored"] / r["tol"]]
    if faster:
        print(f"   {len(faster)} ran faster than their stored ratio / tolerance: re-record them "
              "(make bench-ratios), or their gate stays looser than measured:")
        for r in faster:
            print(f"      {r['nodeid']}: measured / stored {r['ratio'] / r['stored']:.3f}")


def cmd_check(args) -> int:
    out = Path(args.out or tempfile.mkdtemp(prefix="gate-check-"))
    s = gate_session(args.pytest_args, out, "check", inject=args.inject,
                     retries=args.retries)
    _print_session(s)
    if s.rc not in (0, 1):
        return s.rc
    return 0 if s.ok else 1


def cmd_record(args) -> int:
    if args.logs:
        out = Path(args.logs)
        logs = sorted(out.glob("record*.jsonl"))
    else:
        out = Path(args.out or tempfile.mkdtemp(prefix="gate-record-"))
        out.mkdir(parents=True, exist_ok=True)
        logs = []
        for i in range(args.runs):
            log = out / f"record{i + 1}.jsonl"
            rc, wall = run_pytest(args.pytest_args, log, record=True,
                                  output=out / f"record{i + 1}.out")
            print(f"record run {i + 1}/{args.runs}: exit {rc}, "
                  f"{sum(1 for r in read_log(log) if 'key' in r)} benchmarks, {wall:.0f} s, "
                  f"load {os.getloadavg()[0]:.1f}", flush=True)
            logs.append(log)
    by_key: dict[str, list[float]] = {}
    machine: dict = {}
    for log in logs:
        for r in read_log(log):
            if "key" in r:
                by_key.setdefault(r["key"], []).append(r["ratio"])
                machine = r["machine"]
    header, entries = load()
    moved_by = args.moved_by or head_description()
    short = sorted(k for k, v in by_key.items() if len(v) < len(logs))
    if short:
        print(f"not recorded (missing from some runs): {', '.join(short)}")
    for key, runs in by_key.items():
        if len(runs) == len(logs):
            previous = None if args.reset_spreads else entries.get(key)
            entries[key] = entry_from_runs(runs, moved_by, previous)
    header = {"timer": GATE_TIMER, "blas_threads": BLAS_THREADS, "runs": len(logs), "k": K,
              "floor": FLOOR, "cap": CAP, "recorded": machine or header.get("recorded", {})}
    dump(header, entries)
    print(f"{len(by_key) - len(short)} benchmarks recorded into {RATIOS_FILE} "
          f"(logs in {out})")
    return 0


def cmd_repeat(args) -> int:
    out = Path(args.out or tempfile.mkdtemp(prefix="gate-repeat-"))
    _, entries = load()
    sessions = []
    for i in range(args.runs):
        s = gate_session(args.pytest_args, out, f"run{i + 1}", inject=args.inject,
                         quiet=True, retries=args.retries)
        sessions.append(s)
        print(f"run {i + 1}/{args.runs}: {sum(1 for r in s.attempts[0] if r['gated'])} "
              f"gated, above tolerance in the first attempt {len(s.first_failed)}, failed "
              f"the gate {len(s.failed)}, other failures {len(s.other)}, {s.wall_s:.0f} s, "
              f"load {os.getloadavg()[0]:.1f}", flush=True)
    keys = sorted({r["key"] for s in sessions for r in s.attempts[0]})
    table = {}
    for key in keys:
        e = entries.get(key)
        firsts = [next((r for r in s.attempts[0] if r["key"] == key), None) for s in sessions]
        nodeid = next(r["nodeid"] for r in firsts if r is not None)
        table[key] = {
            "tol": None if e is None else e.tol, "up": None if e is None else e.up,
            "factors": [None if r is None or e is None else r["ratio"] / e.ratio
                        for r in firsts],
            "first_failed": [nodeid in s.first_failed for s in sessions],
            "failed": [nodeid in s.failed for s in sessions]}
    (out / "summary.json").write_text(json.dumps(
        {"inject": args.inject, "pytest_args": args.pytest_args,
         "wall_s": [s.wall_s for s in sessions], "benchmarks": table}, indent=1))
    print(f"\ninject {args.inject}: benchmarks failing the gate per run "
          f"{[len(s.failed) for s in sessions]}, above tolerance in the first attempt "
          f"{[len(s.first_failed) for s in sessions]}, of {len(table)}")
    for key, r in table.items():
        f = " ".join("  -  " if x is None else f"{x:5.3f}" for x in r["factors"])
        tol = "-" if r["tol"] is None else f"{r['tol']:.3f}"
        print(f"{key:66s} tol {tol:>5s}  {f}  first {sum(r['first_failed'])}/{args.runs}"
              f"  failed {sum(r['failed'])}/{args.runs}")
    print(f"logs and summary.json in {out}")
    return 0


def group_of(key: str) -> str:
    """A benchmark's group: its file and test function (the scaling series' tracker
    steps and selections split by series)."""
    base, _, params = key.partition("[")
    if base.startswith("bench_scaling.py::test_") and not base.endswith("simulator_step"):
        return f"{base}[{params.split('-')[0]}]"
    return base


def cmd_table(args) -> int:
    """Markdown tables of the stored spreads and tolerances per group, and of the runs of
    ``repeat`` (``summary.json`` folders) per group."""
    _, entries = load()
    groups: dict[str, list[str]] = {}
    for key in sorted(entries):
        groups.setdefault(group_of(key), []).append(key)
    print("| group | n | up: median, max | down: median, max | tol: min-max | "
          "catches: median, max |")
    print("|---|---:|---:|---:|---:|---:|")
    for g, keys in groups.items():
        es = [entries[k] for k in keys]
        up, down = [e.up for e in es], [e.down for e in es]
        c = [e.catches for e in es]
        print(f"| {g} | {len(es)} | {statistics.median(up):.3f}, {max(up):.3f} | "
              f"{statistics.median(down):.3f}, {max(down):.3f} | "
              f"{min(e.tol for e in es):.3f}-{max(e.tol for e in es):.3f} | "
              f"{statistics.median(c):.2f}, {max(c):.2f} |")
    wide = sorted((k for k, e in entries.items() if e.catches > 1.3),
                  key=lambda k: -entries[k].catches)
    print(f"\n{len(wide)} of {len(entries)} benchmarks cannot be sure to catch 1.3x "
          "(tol x exp(down) > 1.3):")
    for k in wide:
        e = entries[k]
        print(f"- `{k}`: up {e.up:.3f}, down {e.down:.3f}, tol {e.tol:.3f}, catches "
              f"{e.catches:.2f}x")
    for folder in args.repeat:
        data = json.loads((Path(folder) / "summary.json").read_text())
        bench = data["benchmarks"]
        n_runs = len(data["wall_s"])
        print(f"\n`{folder}` (inject {data['inject']}, {n_runs} runs, "
              f"{' '.join(data['pytest_args']) or 'all'}; wall s "
              f"{', '.join(f'{w:.0f}' for w in data['wall_s'])}):\n")
        print("| group | n | measured/stored min | max | above tol, 1st attempt "
              "(per run) | failed the gate (per run) |")
        print("|---|---:|---:|---:|---|---|")
        per: dict[str, list[str]] = {}
        for key in bench:
            per.setdefault(group_of(key), []).append(key)
        for g, keys in per.items():
            fs = [f for k in keys for f in bench[k]["factors"] if f is not None]
            first = [sum(bench[k]["first_failed"][i] for k in keys) for i in range(n_runs)]
            failed = [sum(bench[k]["failed"][i] for k in keys) for i in range(n_runs)]
            lo, hi = (f"{min(fs):.3f}", f"{max(fs):.3f}") if fs else ("-", "-")
            print(f"| {g} | {len(keys)} | {lo} | {hi} | {first} | {failed} |")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    helps = {"check": "run the gate (re-running what exceeded its tolerance); exit 1 if a "
                      "benchmark failed it",
             "record": "run the benchmarks RUNS times, unchanged, and store each one's "
                       "median ratio, spreads and tolerance",
             "repeat": "run the gate RUNS times and list each benchmark's measured / stored "
                       "and failures (the noise measurement)"}
    for name, helptext in helps.items():
        s = sub.add_parser(name, help=helptext)
        if name != "check":
            s.add_argument("--runs", type=int, default=RUNS)
        s.add_argument("--out", help="folder for the runs' logs (default: a temporary one)")
        if name == "record":
            s.add_argument("--moved-by", help="the change whose ratios these are (default: "
                                              "HEAD's short hash, +uncommitted if dirty)")
            s.add_argument("--logs", help="store from the logs of an earlier record (its "
                                          "--out folder) instead of running")
            s.add_argument("--reset-spreads", action="store_true",
                           help="spreads from these runs alone (default: a benchmark "
                                "already stored keeps the larger of its and these runs')")
        else:
            s.add_argument("--retries", type=int, default=RETRIES)
            s.add_argument("--inject", type=float, default=1.0,
                           help="slow every timed call by this factor (conftest "
                                "--inject-slowdown)")
        s.add_argument("pytest_args", nargs="*", help="after --: more pytest arguments "
                                                      "(e.g. -m quick, -k ...)")
    t = sub.add_parser("table", help="markdown tables of the stored spreads and "
                                     "tolerances, and of repeat's runs, per group")
    t.add_argument("repeat", nargs="*", help="folders of gate.py repeat (summary.json)")
    args = p.parse_args(argv)
    return {"check": cmd_check, "record": cmd_record, "repeat": cmd_repeat,
            "table": cmd_table}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
