"""The operating envelope's tables (docs/envelope.md) from a sweep's results.parquet.

    .venv/bin/python docs/envelope_table.py RESULTS_PARQUET [RESULTS_PARQUET ...] [--points]
        [--metric gospa] [--policies raster renyi ...]

For each policy in the table (one section per policy and look budget set), per envelope
point x tracker, Markdown tables of:

1. the share of the OSPA gap closed between the floor `null` and the ceiling `truth-aided`
   (mttbench.benchmarks.app.summary.gap_closed: whole runs, paired by seed);
2. the counts over the second half of each run (steps >= n_steps // 2): the true count, and
   per tracker the mean number of REPORTED states / the tracker's own `est_count`. The number
   of reported states is recovered exactly from the GOSPA parts: reported = true_count +
   (gospa_false - gospa_missed) / (c^p / 2). A count EXPLODES (^) when its mean is above
   1.5 x true + 2 and COLLAPSES (v) when below 0.5 x true - 1 (the mean over seeds of the
   per-run second-half means, against the true count averaged the same way);
3. OSPA minus null's OSPA, paired by seed (mean and 95% t half-width of the per-seed
   differences of per-run means): `x` when worse than null (lower bound > 0), `?` when not
   better than null (upper bound >= 0: equal to null, as a tracker that reports nothing is,
   counts), nothing when better (upper bound < 0);

Where a converged Bayes reference is stored for a point (`mttbench bayes --suite envelope`;
the package's store, or `--bayes-store DIR`) and the run's seeds, the gap table gains the
share of the floor-to-ceiling gap the Bayes filter closes (`bayes closes`; * where it is below
0.5, the problem limiting accuracy there) and a table of each tracker's share of the
achievable gap `(null - X) / (null - bayes)`;
then every flagged (point, tracker) as a list, and per tracker how many points it fails and
its median share of the gap closed over the points. Several tables (say a raster and a renyi
sweep) are read as one.

Where a point ran under two policies or more (`mttbench compare --suite envelope --policies
raster renyi`, or several sweeps read as one), a last section puts them side by side
(mttbench.benchmarks.app.policy_axis): per point and tracker the share of the gap closed under
each policy, the paired difference `Q - base` of each other policy against the first
(`--policies` gives the order; default raster first, then as they appear), and the best
tracker-policy pair per point with whether it is ahead of the runner-up beyond noise. The Bayes
reference is looked up per policy (its key holds the policy): a point with a stored raster
reference and none for renyi gets the raster rows only.
The references `null` (reports nothing) and `truth-aided` (uses the truth) are shown in the
count table but never flagged. `--points` first prints the points table (name, axis, split,
p_f, density, speed, look fraction, description) from the package's envelope. `--metric
gospa` computes tables 1 and 3 (and their flags) on GOSPA instead of OSPA.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np
import pandas as pd

from mttbench.benchmarks.app import bayes, policy_axis
from mttbench.benchmarks.app.summary import (
    PROBLEM_LIMITED_SHARE,
    gap_closed,
    paired_difference,
    per_run,
)
from mttbench.benchmarks.engine.specs import PolicySpec, resolve_scenarios
from mttbench.scenarios import envelope

FLOOR, CEILING = "null", "truth-aided"
BAYES = bayes.REFERENCE
#: a row of the tables: one point at one look budget under one policy
ROW = ["scenario", "looks_per_step"]


def short(label: str) -> str:
    """A tracker label short enough for a column header."""
    return label.replace("n_particles=", "N=")


def cell(mean: float, half: float, fmt: str = "{:+.2f}") -> str:
    if math.isnan(mean):
        return "n/a"
    text = fmt.format(mean)
    return text if math.isnan(half) else f"{text} ± {half:.2f}"


#: columns of text, aligned left (the others hold numbers, aligned right)
TEXT = {"point", "axis", "split", "grid", "description", "tracker", "best", "runner-up"}


def md(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join("---" if h in TEXT else "---:" for h in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def points_table() -> str:
    rows = []
    for p in envelope.points():
        sc = p.scenario
        s, bd = sc.model.sensor, sc.model.birth_death
        n0 = len(bd.initial_states) + bd.n_random_initial
        dens = (n0 + bd.birth_rate * (sc.n_steps - 1)) / sc.grid.n_cells
        speed = bd.birth_velocity_std * math.sqrt(math.pi / 2)
        rows.append([f"`{sc.name}`", p.axis, p.split, f"{s.p_d:g}", f"{s.snr:g}",
                     f"{s.p_d ** (1 + s.snr):.2g}", f"{sc.grid.nx}x{sc.grid.ny}",
                     f"{dens:.3g}", f"{speed:.2f}",
                     f"{s.looks_per_step / sc.grid.n_cells:.0%}", sc.description])
    return md(["point", "axis", "split", "p_d", "snr", "p_f", "grid", "targets/cell",
               "speed", "looks", "description"], rows)


def second_half_counts(df: pd.DataFrame) -> pd.DataFrame:
    """Per run: mean true count, reported states and est_count over steps >= n // 2."""
    ok = df[df["status"] == "ok"].copy()
    unit = ok["ospa_c"] ** ok["ospa_p"] / 2.0
    ok["reported"] = ok["true_count"] + (ok["gospa_false"] - ok["gospa_missed"]) / unit
    n_steps = ok.groupby("scenario")["step"].transform("max") + 1
    late = ok[ok["step"] >= n_steps // 2]
    keys = [*ROW, "policy_label", "tracker_label", "seed"]
    return late.groupby(keys, sort=True)[["true_count", "reported", "est_count"]].mean() \
        .reset_index()


def count_flag(value: float, true: float) -> str:
    if value > 1.5 * true + 2:
        return "^"
    if value < 0.5 * true - 1:
        return "v"
    return ""


def tables(df: pd.DataFrame, metric: str = "ospa") -> str:
    order = {n: i for i, n in enumerate(envelope.point_names())}
    labels = sorted(set(df["tracker_label"].astype(str)))
    floor = next((lab for lab in labels if lab.split("(")[0] == FLOOR), None)
    refs = {lab for lab in labels if lab.split("(")[0] in (FLOOR, CEILING, BAYES)}
    players = [lab for lab in labels if lab not in refs]
    gc = gap_closed(df, metric)
    with_bayes = gc.bayes_label is not None
    name_m = metric.upper()
    counts = second_half_counts(df)
    diffs = paired_difference(df, floor, metric) if floor else pd.DataFrame(
        columns=[*ROW, "policy_label", "tracker_label", "diff_mean", "diff_ci95"])
    out = []
    for policy, g in df.groupby("policy_label", sort=True):
        pairs = sorted({(str(s), int(m)) for s, m in zip(g["scenario"], g["looks_per_step"],
                                                          strict=True)},
                       key=lambda k: (order.get(k[0], 1e9), k))
        several = {s for s, _ in pairs if sum(1 for x, _ in pairs if x == s) > 1}
        name = {k: f"`{k[0]}`" + (f" @{k[1]}" if k[0] in several else "") for k in pairs}

        def sel(t: pd.DataFrame, k: tuple[str, int], policy=policy) -> pd.DataFrame:
            return t[(t["policy_label"] == policy) & (t["scenario"] == k[0])
                     & (t["looks_per_step"].astype(np.int64) == k[1])]

        out.append(f"## policy {policy}\n")
        flags: list[tuple[str, str, str]] = []

        # 1. gap closed
        rows = []
        for s in pairs:
            gap = sel(gc.gaps, s)
            gap_text = ("n/a" if gap.empty else
                        cell(float(gap["gap_mean"].iloc[0]), float(gap["gap_ci95"].iloc[0]),
                             "{:.2f}") + ("" if bool(gap["rankable"].iloc[0]) else " (!)"))
            row = [name[s], gap_text]
            if with_bayes:
                closes = float(gap["bayes_share_mean"].iloc[0]) if not gap.empty else math.nan
                row.append("–" if math.isnan(closes) else f"{closes:.2f}"
                           + ("*" if closes < PROBLEM_LIMITED_SHARE else ""))
            shares = sel(gc.shares, s)
            for lab in players:
                sh = shares[shares["tracker_label"] == lab]
                row.append("n/a" if sh.empty else
                           cell(float(sh["share_mean"].iloc[0]), math.nan, "{:.2f}"))
            rows.append(row)
        out.append(f"### Share of the {name_m} gap closed (1 = truth-aided, 0 = null)\n\n"
                   f"gap = {name_m}(null) - {name_m}(truth-aided) ± 95% half-width; (!) the gap "
                   "cannot rank trackers (below 0.15 or its interval reaches 0).\n")
        out.append(md(["point", "gap", *(["bayes closes"] if with_bayes else []),
                       *map(short, players)], rows))
        if with_bayes:
            out.append("\nbayes closes: the converged Bayes reference's share of the same gap "
                       "(`mttbench bayes`, docs/bayes.md); * below "
                       f"{PROBLEM_LIMITED_SHARE:g}: the problem, not the trackers, limits "
                       "accuracy there; – no stored reference.\n")
            rows = []
            for s in pairs:
                gap = sel(gc.gaps, s)
                if gap.empty or math.isnan(float(gap["bayes_mean"].iloc[0])):
                    continue
                shares = sel(gc.shares, s)
                row = [name[s], cell(float(gap["achievable_mean"].iloc[0]),
                                     float(gap["achievable_ci95"].iloc[0]), "{:.2f}")]
                for lab in players:
                    sh = shares[shares["tracker_label"] == lab]
                    row.append("n/a" if sh.empty else
                               cell(float(sh["achievable_mean"].iloc[0]), math.nan, "{:.2f}"))
                rows.append(row)
            out.append(f"\n### Share of the achievable {name_m} gap closed (1 = bayes, "
                       "0 = null)\n\nachievable gap = "
                       f"{name_m}(null) - {name_m}(bayes) ± 95% half-width.\n")
            out.append(md(["point", "achievable gap", *map(short, players)], rows))

        # 2. counts over the second half
        rows = []
        for s in pairs:
            c = sel(counts, s)
            if c.empty:
                continue
            true = float(c.groupby("seed")["true_count"].mean().mean())
            row = [name[s], f"{true:.1f}"]
            for lab in [*players, *sorted(refs)]:
                t = c[c["tracker_label"] == lab]
                if t.empty:
                    row.append("n/a")
                    continue
                tr = float(t["true_count"].mean())
                rep, est = float(t["reported"].mean()), float(t["est_count"].mean())
                fr, fe = count_flag(rep, tr), count_flag(est, tr)
                row.append(f"{rep:.1f}{fr} / {est:.1f}{fe}")
                if lab not in refs:
                    for what, f, v in (("reported", fr, rep), ("est_count", fe, est)):
                        if f:
                            flags.append((name[s], lab, f"{what} count "
                                          f"{'explodes' if f == '^' else 'collapses'}: "
                                          f"{v:.1f} against {tr:.1f} true"))
            rows.append(row)
        out.append("\n### Counts over the second half of the run\n\n"
                   "true = mean true count; per tracker `reported / est_count`; ^ explodes "
                   "(> 1.5 true + 2), v collapses (< 0.5 true - 1).\n")
        out.append(md(["point", "true", *map(short, players), *map(short, sorted(refs))], rows))

        # 3. OSPA against null, paired
        rows = []
        for s in pairs:
            row = [name[s]]
            d_s = sel(diffs, s)
            for lab in players:
                d = d_s[d_s["tracker_label"] == lab]
                if d.empty:
                    row.append("n/a")
                    continue
                m, h = float(d["diff_mean"].iloc[0]), float(d["diff_ci95"].iloc[0])
                h0 = 0.0 if math.isnan(h) else h
                mark = "x" if m - h0 > 0 else "?" if m + h0 >= 0 else ""
                row.append(cell(m, h) + (f" {mark}" if mark else ""))
                if mark:
                    flags.append((name[s], lab, (f"{name_m} worse than null" if mark == "x"
                                                 else f"{name_m} not better than null")
                                  + f": {cell(m, h)}"))
            rows.append(row)
        out.append(f"\n### {name_m} minus null's {name_m} (paired by seed; negative = better "
                   "than null)\n\nx worse than null (lower bound > 0), ? not better than null "
                   "(upper bound >= 0).\n")
        out.append(md(["point", *map(short, players)], rows))

        # flags
        out.append(f"\n### Flags ({len(flags)})\n")
        rank = {name[k]: i for i, k in enumerate(pairs)}
        for s, lab, why in sorted(flags, key=lambda f: (rank[f[0]], f[1])):
            out.append(f"- {s} {short(lab)}: {why}")
        tally = []
        shares_all = gc.shares[gc.shares["policy_label"] == policy]
        for lab in players:
            med = shares_all.loc[shares_all["tracker_label"] == lab, "share_mean"].median()
            mine = [f for f in flags if f[1] == lab]
            n = [len({f[0] for f in mine if word in f[2]}) for word in
                 ("explodes", "collapses", "worse than null", "not better than null")]
            ach = shares_all.loc[shares_all["tracker_label"] == lab, "achievable_mean"]
            tally.append([short(lab), *map(str, n), str(len({f[0] for f in mine})),
                          "n/a" if math.isnan(med) else f"{med:.2f}"]
                         + ([f"{ach.median():.2f} ({ach.notna().sum()} points)"
                             if ach.notna().any() else "n/a"] if with_bayes else []))
        out.append(f"\n### Points flagged per tracker (of {len(pairs)})\n")
        out.append(md(["tracker", "explodes", "collapses", "worse than null",
                       "not better than null", "any flag", "median gap closed",
                       *(["median share of achievable"] if with_bayes else [])], tally))
        out.append("")
    return "\n".join(out)


def _policy_spec(g: pd.DataFrame) -> PolicySpec:
    """The policy of rows ``g`` (one policy label) from their name and parameters."""
    params = json.loads(str(g["policy_params"].iloc[0])) if "policy_params" in g.columns \
        else {}
    return PolicySpec(str(g["policy"].iloc[0]), params or {})


def with_bayes_rows(df: pd.DataFrame, stores: list[str] | None) -> pd.DataFrame:
    """``df`` with the stored Bayes reference's rows of every point and policy whose seeds
    it covers (one line on stderr per point and policy without one); a reference is keyed
    by its policy, so one policy's is never attached to another's rows."""
    frames = [df]
    cells = df[df["policy_label"].astype(str) != policy_axis.NO_POLICY]
    for (sc_name, looks, pol), g in cells.groupby(["scenario", "looks_per_step",
                                                   "policy_label"], sort=True):
        n_steps = int(g["step"].max()) + 1
        try:
            (sc,) = resolve_scenarios([str(sc_name)], n_steps)
        except Exception:  # noqa: BLE001 - a scenario this package does not know
            continue
        default_looks = int(sc.model.sensor.looks_per_step)
        ref = bayes.find(sc, _policy_spec(g), None if int(looks) == default_looks
                         else int(looks), sorted(set(g["seed"].astype(int))),
                         float(g["ospa_c"].iloc[0]), float(g["ospa_p"].iloc[0]), stores)
        if ref is None:
            print(f"no stored bayes reference for {sc_name} @{looks} under {pol}",
                  file=sys.stderr)
            continue
        frames.append(ref.rows)
    return pd.concat(frames, ignore_index=True, sort=False)


def policy_tables(df: pd.DataFrame, metric: str = "ospa",
                  order: list[str] | None = None) -> str:
    """The policies side by side (``""`` when no point ran two policies): per point the
    share of the gap closed of each tracker under each policy, the paired difference of
    each other policy against the first, the best pair, and per tracker a tally."""
    runs = per_run(df)
    order = order or (["raster"] if "raster" in set(runs["policy_label"].astype(str)) else [])
    axis = policy_axis.policy_axis(runs, None, metric, order)
    if not axis.available:
        return ""
    rank = {n: i for i, n in enumerate(envelope.point_names())}
    t = axis.table
    players = sorted(set(t.loc[(t["role"] == "") & ~t["tracker_uses_truth"].astype(bool),
                               "tracker_label"].astype(str)))
    ceiling = sorted(set(t.loc[t["role"] == "ceiling", "tracker_label"].astype(str)))
    pols, base = axis.policies, axis.policies[0]
    keys = sorted({(str(s), int(m)) for s, m in zip(t["scenario"], t["looks_per_step"],
                                                     strict=True)},
                  key=lambda k: (rank.get(k[0], 1e9), k))
    several = {s for s, _ in keys if sum(1 for x, _ in keys if x == s) > 1}
    name = {k: f"`{k[0]}`" + (f" @{k[1]}" if k[0] in several else "") for k in keys}
    name_m = metric.upper()

    def at(frame: pd.DataFrame, k: tuple[str, int]) -> pd.DataFrame:
        return frame[(frame["scenario"].astype(str) == k[0])
                     & (frame["looks_per_step"].astype(np.int64) == k[1])]

    out = [f"## Policies side by side ({', '.join(pols)})\n",
           "Every tracker under every policy on the same worlds (paired by seed). "
           f"{policy_axis.BEYOND_NOISE_MARK.strip()} a paired difference whose 95% interval "
           "excludes 0.\n"]
    # 1. share of the gap closed per tracker and policy
    rows = []
    for k in keys:
        here = at(t, k)
        row = [name[k]]
        for lab in players:
            for p in pols:
                r = here[(here["tracker_label"] == lab) & (here["policy_label"] == p)]
                row.append("n/a" if r.empty else cell(float(r["share_mean"].iloc[0]),
                                                      math.nan, "{:.2f}"))
        rows.append(row)
    out.append(f"### Share of the {name_m} gap closed per policy (each policy's own null and "
               "truth-aided)\n")
    out.append(md(["point", *(f"{short(lab)} {p}" for lab in players for p in pols)], rows))
    # 2. paired differences against the base policy
    d = axis.diffs
    for q in pols[1:]:
        rows = []
        tally = {lab: [0, 0, 0] for lab in players}  # better, level, worse under q
        for k in keys:
            here = at(d, k)
            row = [name[k]]
            for lab in [*players, *ceiling]:
                r = here[(here["tracker_label"] == lab) & (here["policy_label"] == q)]
                if r.empty:
                    row.append("n/a")
                    continue
                m, h = float(r["diff_mean"].iloc[0]), float(r["diff_ci95"].iloc[0])
                beyond = not math.isnan(h) and abs(m) > h
                row.append(cell(m, h, "{:+.3f}")
                           + (policy_axis.BEYOND_NOISE_MARK if beyond else ""))
                if lab in tally:
                    tally[lab][0 if beyond and m < 0 else 2 if beyond else 1] += 1
            rows.append(row)
        out.append(f"\n### {name_m} under {q} minus under {base} (paired by seed; negative = "
                   f"{q} better)\n")
        out.append(md(["point", *map(short, players),
                       *(f"{short(c)} (reference)" for c in ceiling)], rows))
        out.append(f"\nPoints where {q} is better / level / worse than {base} beyond noise: "
                   + "; ".join(f"{short(lab)} {a}/{b}/{c}" for lab, (a, b, c) in tally.items())
                   + ".\n")
    # 3. the best pair per point
    rows = []
    for k in keys:
        b = at(axis.best, k)
        if b.empty:
            continue
        r = b.iloc[0]
        rows.append([name[k], f"{short(r['tracker_label'])} / {r['policy_label']}",
                     cell(float(r["mean"]), float(r["ci95"]), "{:.3f}"),
                     "–" if not r["runner_tracker"] else
                     f"{short(r['runner_tracker'])} / {r['runner_policy']}",
                     cell(float(r["diff_mean"]), float(r["diff_ci95"]), "{:+.3f}"),
                     "yes" if bool(r["beyond_noise"]) else "no"])
    out.append(f"\n### Best tracker / policy per point (least mean {name_m}; runner-up minus "
               "best, paired)\n")
    out.append(md(["point", "best", name_m, "runner-up", "runner-up - best",
                   "beyond noise"], rows))
    med = []
    for lab in players:
        mine = t[t["tracker_label"] == lab]
        med.append([short(lab), *(
            f"{mine.loc[mine['policy_label'] == p, 'share_mean'].median():.2f}" for p in pols)])
    out.append("\n### Median share of the gap closed over the points\n")
    out.append(md(["tracker", *pols], med))
    out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+",
                    help="results.parquet of runs or compares over the envelope")
    ap.add_argument("--points", action="store_true", help="print the points table first")
    ap.add_argument("--metric", default="ospa", choices=["ospa", "gospa"],
                    help="metric of the gap closed and of the paired differences (default ospa)")
    ap.add_argument("--bayes-store", nargs="+", default=None, metavar="DIR",
                    help="stored Bayes references (default: the package's)")
    ap.add_argument("--no-bayes", action="store_true", help="leave the Bayes reference out")
    ap.add_argument("--policies", nargs="+", default=None, metavar="LABEL",
                    help="policy labels in the order of the side-by-side tables (the first is "
                         "the base of the paired differences; default raster first)")
    args = ap.parse_args(argv)
    if args.points:
        print(points_table() + "\n")
    df = pd.concat([pd.read_parquet(f) for f in args.results], ignore_index=True)
    if not args.no_bayes:
        df = with_bayes_rows(df, args.bayes_store)
    print(tables(df, args.metric))
    side = policy_tables(df, args.metric, args.policies)
    if side:
        print(side)
    return 0


if __name__ == "__main__":
    sys.exit(main())
