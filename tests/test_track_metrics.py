"""Track-level scores (benchmarks/engine/track_metrics.py) against independent computations."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.engine import track_metrics
from mttbench.benchmarks.engine.track_metrics import clear_mot, ospa2, trajectory_gospa


def _random_run(rng, n_ids, T, p_present=0.75, spread=3.0, id0=0):
    pos, ids = [], []
    base = rng.uniform(0, spread, (n_ids, 2))
    for k in range(T):
        here = np.nonzero(rng.random(n_ids) < p_present)[0]
        pos.append(base[here] + rng.normal(0, 0.6, (len(here), 2)) + 0.1 * k)
        ids.append(here + id0)
    return pos, ids


def _matchings(nx, ny):
    """Every partial matching of nx rows to ny columns as an (nx, ny) 0/1 matrix."""
    out = []
    for k in range(min(nx, ny) + 1):
        for rows in itertools.combinations(range(nx), k):
            for cols in itertools.permutations(range(ny), k):
                w = np.zeros((nx, ny))
                w[list(rows), list(cols)] = 1
                out.append(w)
    return out


def _brute_tgospa(tpos, tids, epos, elab, c, p, gamma):
    """Minimum over every sequence of per-step assignments (all truths x all tracks of
    the run, present or not), by dynamic programming over the steps."""
    ux = sorted(set(np.concatenate(tids).tolist()))
    uy = sorted(set(np.concatenate(elab).tolist()))
    ms = _matchings(len(ux), len(uy))
    half = c**p / 2
    step_costs = []
    for k in range(len(tpos)):
        X = {i: x for i, x in zip(tids[k].tolist(), tpos[k], strict=True)}
        Y = {j: y for j, y in zip(elab[k].tolist(), epos[k], strict=True)}
        costs = []
        for w in ms:
            tot = 0.0
            for a, i in enumerate(ux):
                j = [uy[b] for b in np.nonzero(w[a])[0]]
                if j:
                    if i in X and j[0] in Y:
                        tot += min(np.linalg.norm(X[i] - Y[j[0]]), c) ** p
                    elif (i in X) != (j[0] in Y):
                        tot += half
                elif i in X:
                    tot += half
            for b, j in enumerate(uy):
                if not w[:, b].any() and j in Y:
                    tot += half
            costs.append(tot)
        step_costs.append(np.array(costs))
    sw = np.array([[np.abs(a - b).sum() for b in ms] for a in ms]) * gamma**p / 2
    best = step_costs[0]
    for k in range(1, len(tpos)):
        best = (best[:, None] + sw).min(axis=0) + step_costs[k]
    return float(best.min()) ** (1 / p)


@pytest.mark.parametrize("seed", range(8))
def test_tgospa_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    nx, ny, T = int(rng.integers(2, 4)), int(rng.integers(2, 4)), int(rng.integers(4, 7))
    tpos, tids = _random_run(rng, nx, T)
    epos, elab = _random_run(rng, ny, T, id0=10)
    c, p, gamma = 2.0, float(rng.choice([1.0, 2.0])), float(rng.choice([0.5, 1.0, 2.0]))
    g = trajectory_gospa(tpos, tids, epos, elab, c=c, p=p, gamma=gamma)
    assert g.total == pytest.approx(_brute_tgospa(tpos, tids, epos, elab, c, p, gamma),
                                    abs=1e-9)
    assert g.localisation + g.missed + g.false + g.switch == pytest.approx(g.total**p)


def _tgospa_fields(g):
    return (g.total, g.localisation, g.missed, g.false, g.switch, g.switches)


def _tgospa_by_highs(monkeypatch, *args, **kwargs):
    """trajectory_gospa with the dynamic programme turned off (HiGHS throughout)."""
    with monkeypatch.context() as mp:
        mp.setattr(track_metrics, "_tgospa_dp", lambda *a, **k: None)
        return track_metrics.trajectory_gospa(*args, **kwargs)


@pytest.mark.parametrize("seed", range(6))
def test_tgospa_dynamic_programme_equals_highs_bit_for_bit(seed, monkeypatch):
    """Where the optimum is unique the dynamic programme finds the W that HiGHS finds, so
    every part is the same number; it settles most random runs (components of one pair
    and of several: shared truths, crossing tracks, gaps)."""
    rng = np.random.default_rng(200 + seed)
    settled = 0
    for _ in range(10):
        nx, ny, T = int(rng.integers(1, 6)), int(rng.integers(1, 7)), int(rng.integers(5, 60))
        tpos, tids = _random_run(rng, nx, T, spread=float(rng.uniform(2, 8)))
        epos, elab = _random_run(rng, ny, T, spread=float(rng.uniform(2, 8)), id0=10)
        c, p, gamma = float(rng.choice([1.0, 2.0])), float(rng.choice([1.0, 2.0])), \
            float(rng.choice([0.5, 1.0, 2.0]))
        g = trajectory_gospa(tpos, tids, epos, elab, c=c, p=p, gamma=gamma)
        ref = _tgospa_by_highs(monkeypatch, tpos, tids, epos, elab, c=c, p=p, gamma=gamma)
        assert ref.solver in ("lp", "milp", "none")
        assert _tgospa_fields(g) == _tgospa_fields(ref), (g, ref)
        settled += g.solver == "dp"
    assert settled >= 5


def test_tgospa_tie_goes_to_highs():
    """One truth followed by track A at 0.5, except at step 2 where A is absent and track
    B sits exactly on the truth. With p = 1, c = 2, gamma = 1, going over to B for that
    step gains c**p = 2 and costs four changes of gamma**p / 2: a tie, so the optimal W
    is not unique and HiGHS decides."""
    T = 5
    tpos = [np.array([[0.0, 0.0]])] * T
    tids = [np.array([1])] * T
    epos = [np.array([[0.0, 0.0]]) if k == 2 else np.array([[0.5, 0.0]]) for k in range(T)]
    elab = [np.array([5]) if k == 2 else np.array([4]) for k in range(T)]
    run = (tpos, tids, epos, elab)
    g = trajectory_gospa(*run, c=2.0, p=1.0, gamma=1.0)
    assert g.solver in ("lp", "milp")
    assert g.total == pytest.approx(_brute_tgospa(*run, 2.0, 1.0, 1.0), abs=1e-12)
    # off the tie the programme settles it: B is worth it when switching is cheaper
    g = trajectory_gospa(*run, c=2.0, p=1.0, gamma=0.9)
    assert g.solver == "dp" and g.switches == 2.0 and g.localisation == 2.0
    g = trajectory_gospa(*run, c=2.0, p=1.0, gamma=1.1)
    assert g.solver == "dp" and g.switches == 0.0 and g.missed == 1.0 and g.false == 1.0


def test_tgospa_large_component_goes_to_highs(monkeypatch):
    """A component with more matchings than the programme enumerates is left to HiGHS."""
    n = track_metrics._DP_MAX_STATES  # one truth near n tracks: n + 1 matchings
    T = 4
    tpos = [np.array([[0.0, 0.0]])] * T
    tids = [np.array([0])] * T
    epos = [np.column_stack([np.linspace(0.0, 0.5, n), np.zeros(n)])] * T
    elab = [np.arange(n)] * T
    g = trajectory_gospa(tpos, tids, epos, elab, c=2.0, p=2.0, gamma=2.0)
    assert g.solver in ("lp", "milp")
    assert g.localisation == 0.0 and g.false == pytest.approx(2.0 * (n - 1) * T)


def _props(dist, runs):
    a, b, z = runs
    assert dist(a, a) == pytest.approx(0.0, abs=1e-12)
    assert dist(a, b) == pytest.approx(dist(b, a), abs=1e-9)
    assert dist(a, z) <= dist(a, b) + dist(b, z) + 1e-9
    assert dist(a, b) > 0


@pytest.mark.parametrize("seed", range(6))
def test_metric_properties(seed):
    rng = np.random.default_rng(100 + seed)
    T = 5
    runs = [_random_run(rng, int(rng.integers(1, 4)), T, id0=10 * r) for r in range(3)]

    def tg(x, y):
        return trajectory_gospa(*x, *y, c=2.0, p=2.0, gamma=1.0).total

    def o2(x, y):
        return ospa2(*x, *y, c=2.0, p=2.0, window=None).per_step[-1]

    _props(tg, runs)
    _props(o2, runs)


def _crossing(swap: bool, T=20):
    """Two targets crossing at step T/2; two tracks that follow them (or swap)."""
    tpos, tids, epos, elab = [], [], [], []
    for k in range(T):
        a = np.array([k * 0.5, 0.0])
        b = np.array([T * 0.5 - k * 0.5, 0.0])
        tpos.append(np.array([a, b]))
        tids.append(np.array([0, 1]))
        labs = np.array([7, 8]) if (not swap or k < T // 2) else np.array([8, 7])
        epos.append(np.array([a, b]) + 0.05)
        elab.append(labs)
    return tpos, tids, epos, elab


def test_clean_swap_counts_one_switch_per_truth():
    run = _crossing(swap=True)
    m = clear_mot(*run, gate=0.5)
    assert m.id_switches == 2 and m.fragmentations == 0 and m.mostly_tracked == 1.0
    g = trajectory_gospa(*run, c=2.0, p=1.0, gamma=1.0)
    assert g.switches == pytest.approx(2.0) and g.switch == pytest.approx(2.0)
    follow = _crossing(swap=False)
    assert clear_mot(*follow, gate=0.5).id_switches == 0
    g0 = trajectory_gospa(*follow, c=2.0, p=1.0, gamma=1.0)
    assert g0.switches == 0 and g0.total < g.total
    assert ospa2(*follow, window=5).total < ospa2(*run, window=5).total


@pytest.mark.parametrize("k", [1, 2, 3, 5])
def test_broken_track_counts_k_minus_1_fragmentations(k):
    T = 6 * k
    tpos, tids, epos, elab = [], [], [], []
    for t in range(T):
        x = np.array([[0.1 * t, 1.0]])
        tpos.append(x)
        tids.append(np.array([3]))
        piece, offset = divmod(t, 6)
        if offset == 5 and piece < k - 1:  # a gap before the next piece
            epos.append(np.zeros((0, 2)))
            elab.append(np.zeros(0, np.int64))
        else:
            epos.append(x + 0.01)
            elab.append(np.array([100 + piece]))
    m = clear_mot(tpos, tids, epos, elab, gate=1.0)
    assert m.fragmentations == k - 1
    assert m.id_switches == k - 1
    assert m.mostly_tracked == 1.0 and m.mostly_lost == 0.0


def test_mostly_lost_and_empty():
    T = 10
    tpos = [np.array([[0.0, 0.0]])] * T
    tids = [np.array([1])] * T
    epos = [np.array([[0.0, 0.1]]) if t < 2 else np.zeros((0, 2)) for t in range(T)]
    elab = [np.array([4]) if t < 2 else np.zeros(0, np.int64) for t in range(T)]
    m = clear_mot(tpos, tids, epos, elab, gate=1.0)
    assert m.mostly_lost == 1.0 and m.mostly_tracked == 0.0
    none = [np.zeros((0, 2))] * T, [np.zeros(0, np.int64)] * T
    g = trajectory_gospa(tpos, tids, *none, c=2.0, p=2.0)
    assert g.total == pytest.approx(np.sqrt(T * 2.0)) and g.missed == pytest.approx(2.0 * T)
    assert ospa2(tpos, tids, *none, c=2.0).total == pytest.approx(2.0)


def test_kfnn_labels_stable_on_one_target():
    from mttbench.benchmarks.engine.loop import play
    from mttbench.testing import _scenario
    from mttbench.trackers.base import make

    sc = _scenario("default", "one-target", n_steps=60,
                   initial_states=((6.5, 0.05, 6.5, 0.03),))
    seen: set[int] = set()
    n_labelled = 0
    for rec in play(sc, make("kfnn"), 0):
        labs = rec.estimate.labels
        assert labs is not None and labs.dtype == np.int64
        assert len(labs) == len(rec.estimate.states)
        seen.update(labs.tolist())
        n_labelled += len(labs) > 0
    assert n_labelled > 30
    assert len(seen) == 1


def test_conformance_kit_checks_labels():
    from mttbench.testing import _assert_estimate_valid
    from mttbench.trackers.base import Estimate

    states = np.zeros((2, 4))
    _assert_estimate_valid(Estimate(2.0, states, labels=np.array([3, 4])), 0)
    with pytest.raises(AssertionError, match="shape"):
        _assert_estimate_valid(Estimate(2.0, states, labels=np.array([3])), 0)
    with pytest.raises(AssertionError, match="repeat"):
        _assert_estimate_valid(Estimate(2.0, states, labels=np.array([3, 3])), 0)


def test_run_level_columns_reach_rows_summary_and_report(tmp_path):
    import dataclasses

    from mttbench.benchmarks.app import report, summary
    from mttbench.benchmarks.engine import loop
    from mttbench.benchmarks.engine.metrics import run_metric_columns
    from mttbench.benchmarks.engine.specs import TrackerSpec
    from mttbench.scenarios.spec import get

    sc = dataclasses.replace(get("crossing"), n_steps=25)
    rows = pd.concat([loop.run_job(loop.Job(sc, TrackerSpec(t), seed=s))
                      for t in ("kfnn", "null") for s in (0, 1)], ignore_index=True)
    from mttbench.benchmarks.engine.track_series import series_columns

    cols = [c for c in run_metric_columns() if c not in series_columns()]  # per step
    assert {"tgospa", "ospa2", "id_switches", "mostly_tracked"} <= set(cols)
    for (tracker, _), g in rows.groupby(["tracker", "seed"]):
        assert (g[cols].nunique(dropna=False) == 1).all()  # constant over the run
        assert g[cols].isna().all().all() == (tracker == "null")
    runs = summary.per_run(rows)
    assert summary.unlabelled_trackers(runs) == ["null"]
    summ = summary.summarize(runs)
    assert "tgospa_mean" in summ.columns and "id_switches_ci95" in summ.columns
    files = report.build_report(rows, tmp_path, reference="kfnn", draw=False)
    text = files.markdown.read_text()
    assert "## Track-level scores" in text and "No track-level scores for `null`" in text


# ------------------------------------------------------------ per-step series
def _brute_ospa2_window(tpos, tids, epos, elab, k, w, c, p):
    """OSPA(2) of the window of ``w`` steps ending at ``k``, from its definition: the
    tracks present in the window, the time-averaged base distance step by step, the
    best injection by enumerating every permutation."""
    steps = range(max(0, k - w + 1), k + 1)

    def tracks(pos, ids):
        out: dict[int, dict[int, np.ndarray]] = {}
        for t in steps:
            for i, x in zip(ids[t].tolist(), pos[t], strict=True):
                out.setdefault(i, {})[t] = np.asarray(x, float)
        return list(out.values())

    X, Y = tracks(tpos, tids), tracks(epos, elab)
    if len(X) > len(Y):
        X, Y = Y, X
    m, n = len(X), len(Y)
    if n == 0:
        return 0.0

    def base(x, y):
        ts = sorted(set(x) | set(y))
        d = [min(np.linalg.norm(x[t] - y[t]), c) if t in x and t in y else c for t in ts]
        return min(sum(d) / len(ts), c)

    best = min(sum(base(X[i], Y[perm[i]]) ** p for i in range(m))
               for perm in itertools.permutations(range(n), m))
    return ((best + c**p * (n - m)) / n) ** (1 / p)


@pytest.mark.parametrize("seed", range(6))
def test_ospa2_series_equals_brute_force_per_window(seed):
    from mttbench.benchmarks.engine.metrics import RunData
    from mttbench.benchmarks.engine.track_series import series_values

    rng = np.random.default_rng(300 + seed)
    T = int(rng.integers(5, 9))
    tpos, tids = _random_run(rng, int(rng.integers(1, 4)), T, p_present=0.6)
    epos, elab = _random_run(rng, int(rng.integers(1, 4)), T, p_present=0.6, id0=20)
    c, p, w = 2.0, float(rng.choice([1.0, 2.0])), int(rng.integers(1, 5))
    got = ospa2(tpos, tids, epos, elab, c=c, p=p, window=w).per_step
    want = [_brute_ospa2_window(tpos, tids, epos, elab, k, w, c, p) for k in range(T)]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    if p == 2.0 and w == 3:  # the registered series: the default window is 10 steps
        return
    run = RunData(tpos, tids, epos, elab, c=c, p=p)
    series = series_values(run)["ospa2_window"]
    want10 = [_brute_ospa2_window(tpos, tids, epos, elab, k, 10, c, p) for k in range(T)]
    np.testing.assert_allclose(series, want10, rtol=0, atol=1e-9)


def test_clean_swap_switches_fall_inside_the_crossing_window_only():
    """Two targets meet at step 10 (distance |k - 10|) and their tracks swap there:
    one switch per target, both at the crossing, inside its window; none outside. At
    step 10 the targets coincide, so the old matches are kept and the swap is counted at
    step 11, when they have parted."""
    from mttbench.benchmarks.engine.track_metrics import crossings

    T, w = 20, 2
    run = _crossing(swap=True, T=T)
    m = clear_mot(*run, gate=0.5)
    assert m.switch_steps.tolist() == [0] * 11 + [2] + [0] * 8
    cr = crossings(run[0], run[1], distance=1.5, window=w)
    dist = np.array([abs(k - 10) for k in range(T)], float)
    close = dist < 1.5  # steps 9, 10, 11
    assert cr.close.tolist() == close.astype(int).tolist()
    assert cr.starts.tolist() == [0] * 9 + [1] + [0] * 10  # one encounter
    near = np.array([close[max(0, k - w):k + w + 1].any() for k in range(T)])
    assert cr.near.tolist() == near.tolist()
    assert m.switch_steps[cr.near].sum() == 2 and m.switch_steps[~cr.near].sum() == 0
    # the same swap far from any crossing: a pair of targets 5 apart swapped at step 15
    far = [np.array([[k * 0.1, 0.0], [k * 0.1, 5.0]]) for k in range(T)]
    ids = [np.array([0, 1])] * T
    labs = [np.array([7, 8]) if k < 15 else np.array([8, 7]) for k in range(T)]
    m2 = clear_mot(far, ids, [x + 0.05 for x in far], labs, gate=0.5)
    cr2 = crossings(far, ids, distance=1.5, window=w)
    assert not cr2.near.any() and cr2.starts.sum() == 0
    assert m2.switch_steps[15] == 2 and m2.switch_steps[~cr2.near].sum() == 2


def test_crossings_against_a_direct_loop():
    from mttbench.benchmarks.engine.track_metrics import crossings

    rng = np.random.default_rng(7)
    T = 30
    tpos, tids = _random_run(rng, 4, T, p_present=0.8, spread=2.5)
    d, w = 1.0, 3
    cr = crossings(tpos, tids, distance=d, window=w)
    close = np.zeros(T, int)
    starts = np.zeros(T, int)
    pairs_prev: set = set()
    for k in range(T):
        now = set()
        for a, b in itertools.combinations(range(len(tids[k])), 2):
            if np.linalg.norm(tpos[k][a] - tpos[k][b]) < d:
                now.add(tuple(sorted((int(tids[k][a]), int(tids[k][b])))))
        close[k] = len(now)
        starts[k] = len(now - pairs_prev)
        pairs_prev = now
    assert close.sum() > 0
    assert cr.close.tolist() == close.tolist() and cr.starts.tolist() == starts.tolist()
    near = [bool((close[max(0, k - w):k + w + 1] > 0).any()) for k in range(T)]
    assert cr.near.tolist() == near


def test_run_job_writes_the_series_one_value_per_step():
    import dataclasses

    from mttbench.benchmarks.app import summary
    from mttbench.benchmarks.engine import loop
    from mttbench.benchmarks.engine.specs import TrackerSpec
    from mttbench.benchmarks.engine.track_series import series_columns
    from mttbench.scenarios.spec import get

    sc = dataclasses.replace(get("crossing"), n_steps=70)
    rows = pd.concat([loop.run_job(loop.Job(sc, TrackerSpec(t), seed=s))
                      for t in ("kfnn", "null") for s in (0, 1)], ignore_index=True)
    assert {"ospa2_window", "id_switches_step", "crossings", "crossings_near"} <= set(
        series_columns())
    assert (rows[series_columns()].dtypes == np.float64).all()
    for (tracker, _), g in rows.groupby(["tracker", "seed"]):
        if tracker == "kfnn":  # the run-level scores are the series' mean and sum
            assert g["ospa2_window"].mean() == pytest.approx(g["ospa2"].iloc[0], abs=1e-12)
            assert g["id_switches_step"].sum() == g["id_switches"].iloc[0]
            assert g["ospa2_window"].nunique() > 1
        else:
            assert g[["ospa2_window", "id_switches_step"]].isna().all().all()
    # the crossings come from the world alone: the same for every tracker of a seed
    wide = rows.pivot_table(index=["seed", "step"], columns="tracker",
                            values=["crossings", "crossings_near"])
    assert (wide.xs("kfnn", axis=1, level=1) == wide.xs("null", axis=1, level=1)).all().all()
    assert rows["crossings"].sum() > 0
    # the per-run tables keep the series out (their run values are ospa2, id_switches)
    assert not set(series_columns()) & set(summary.per_run(rows).columns)


def test_crossing_switches_sum_the_series_in_and_out_of_the_windows():
    rng = np.random.default_rng(11)
    rows = []
    for tracker in ("a", "b"):
        for seed in range(3):
            near = rng.random(40) < 0.3
            sw = rng.integers(0, 2, 40).astype(float)
            for k in range(40):
                rows.append({"scenario": "x", "tracker_label": tracker, "tracker": tracker,
                             "policy_label": "raster", "looks_per_step": 24, "seed": seed,
                             "step": k, "status": "ok", "id_switches_step": sw[k],
                             "crossings": float(k == 3), "crossings_near": float(near[k])})
    df = pd.DataFrame(rows)
    from mttbench.benchmarks.app import summary

    got = summary.crossing_switches(df).set_index(["tracker_label", "seed"])
    for (tracker, seed), g in df.groupby(["tracker_label", "seed"]):
        r = got.loc[(tracker, seed)]
        inside = g["crossings_near"] > 0
        assert r["switches_near"] == g.loc[inside, "id_switches_step"].sum()
        assert r["switches_elsewhere"] == g.loc[~inside, "id_switches_step"].sum()
        assert r["near_rate"] == pytest.approx(r["switches_near"] / inside.sum())
        assert r["elsewhere_rate"] == pytest.approx(r["switches_elsewhere"] / (~inside).sum())
        assert r["crossings"] == 1 and r["near_steps"] == inside.sum()
    summ = summary.crossing_summary(df)
    a = got.loc["a", "switches_near"].to_numpy()
    mean, half = summary.mean_ci95(a)
    row = summ[summ["tracker_label"] == "a"].iloc[0]
    assert row["switches_near_mean"] == pytest.approx(mean)
    assert row["switches_near_ci95"] == pytest.approx(half)
    # an unlabelled tracker (NaN switches) and a failed run have no row
    df.loc[df["tracker_label"] == "b", "id_switches_step"] = np.nan
    df.loc[(df["tracker_label"] == "a") & (df["seed"] == 0) & (df["step"] == 5),
           "status"] = "error"
    left = summary.crossing_switches(df)
    assert sorted(zip(left["tracker_label"], left["seed"], strict=True)) == [("a", 1), ("a", 2)]


def test_mostly_tracked_and_lost_columns_count_truths_at_the_thresholds():
    """Five truths far apart over 10 steps, tracked (an estimate 0.1 away, its own label)
    on their first 0, 2, 5, 8 and 10 steps: coverages 0, 0.2, 0.5, 0.8, 1. By the
    definitions (at least 80% of its life: mostly tracked; at most 20%: mostly lost) the
    run-level columns are 2/5 and 2/5, the thresholds included, as clear_mot's own
    fractions."""
    from mttbench.benchmarks.engine.metrics import RunData, run_level_metrics

    T, tracked = 10, np.array([0, 2, 5, 8, 10])
    ids = np.arange(5)
    where = np.column_stack([10.0 * ids, np.zeros(5)])
    truth = [where] * T
    estimate = [where[tracked > t] + 0.1 for t in range(T)]
    labels = [100 + ids[tracked > t] for t in range(T)]
    values = run_level_metrics(RunData(truth, [ids] * T, estimate, labels))
    coverage = tracked / T
    assert values["mostly_tracked"] == np.mean(coverage >= 0.8) == 0.4
    assert values["mostly_lost"] == np.mean(coverage <= 0.2) == 0.4
    own = clear_mot(truth, [ids] * T, estimate, labels, gate=2.0)
    assert (values["mostly_tracked"], values["mostly_lost"]) == (own.mostly_tracked,
                                                                 own.mostly_lost)
