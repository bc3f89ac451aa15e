"""The non-myopic ``lookahead`` policy: its value on hand-computed cases, its reduction to
``renyi``, and the ``cdc2004`` reproduction's reduced mode and checks."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pandas as pd
import pytest

from mttbench.benchmarks.app import reproduce_cdc2004 as cdc
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine.policies import make_policy
from mttbench.benchmarks.engine.policy_lookahead import future_blindness
from mttbench.scenarios.model import (
    Dynamics,
    Grid,
    Occlusion,
    RayleighGridSensor,
    TrackingModel,
    Visibility,
)

SENSOR = RayleighGridSensor(p_d=0.5, snr=10.0, looks_per_step=1)


def hand_gain(P: list[float], alpha: float = 0.5) -> float:
    """One binary look's expected Renyi gain on a 0/1 count, written out term by term:
    ``sum_z p(z) / (alpha - 1) log(sum_t P(t) p(z|t)^alpha / p(z)^alpha)``."""
    pd1 = [SENSOR.p_f, SENSOR.p_d]  # p(z = 1 | t) for t = 0, 1
    total = 0.0
    for z in (0, 1):
        lik = [pd1[t] if z else 1.0 - pd1[t] for t in (0, 1)]
        pz = P[0] * lik[0] + P[1] * lik[1]
        inner = sum(P[t] * lik[t] ** alpha for t in (0, 1)) / pz ** alpha
        total += pz * math.log(inner) / (alpha - 1.0)
    return total


def two_cells(occlusions=()) -> TrackingModel:
    return TrackingModel(Grid(2, 1), Dynamics(wna_intensity=0.0), sensor=SENSOR,
                         visibility=Visibility(tuple(occlusions)))


# cell 0 is uncertain (P(1) = 0.5), cell 1 less so (P(1) = 0.2)
COUNTS = np.array([[0.5, 0.5], [0.8, 0.2]])


def test_value_of_two_cells_one_blind_next_step():
    """Cell 1 is blind at step 1 only. With H = 3, gamma = 0.5, beta = 2 at step 0 its
    value is G_1 (1 + 2 * 0.5^1) = 2 G_1; cell 0 keeps G_0. G_0 > G_1 > G_0 / 2, so the
    myopic policy looks at cell 0 and the non-myopic one at cell 1."""
    g0, g1 = hand_gain([0.5, 0.5]), hand_gain([0.8, 0.2])
    assert g0 > g1 > g0 / 2  # the case is the interesting one
    model = two_cells([Occlusion(x=(1, 1), y=(0, 0), steps=(1, 1))])
    la = make_policy("lookahead", horizon=3, discount=0.5, weight=2.0)
    la.reset(model, 1, np.random.default_rng(0))
    assert la.values(0, COUNTS) == pytest.approx([g0, 2.0 * g1], rel=1e-12)
    assert la.select(0, COUNTS).tolist() == [1]
    # step 1: cell 1 is blind (value -inf, never chosen); step 2: nothing blind ahead
    assert la.values(1, COUNTS).tolist()[1] == -math.inf
    assert la.select(1, COUNTS).tolist() == [0]
    assert la.values(2, COUNTS) == pytest.approx([g0, g1], rel=1e-12)
    assert la.select(2, COUNTS).tolist() == [0]
    renyi = make_policy("renyi")
    renyi.reset(model, 1, np.random.default_rng(0))
    assert renyi.select(0, COUNTS).tolist() == [0]


def test_discounted_sum_over_the_horizon():
    """Blind at steps 2 and 4 (two occlusions): at step 0 with H = 4, gamma = 0.5 the
    sum is 0.5^2 + 0.5^4; H = 3 sees only step 2."""
    model = two_cells([Occlusion((1, 1), (0, 0), (2, 2)), Occlusion((1, 1), (0, 0), (4, 4))])
    cells, s = future_blindness(model, 0, 4, 0.5)
    assert cells.tolist() == [1] and s == pytest.approx([0.25 + 0.0625])
    cells, s = future_blindness(model, 0, 3, 0.5)
    assert s == pytest.approx([0.25])
    assert future_blindness(model, 4, 3, 0.5)[0].size == 0


@pytest.mark.parametrize("repeats", [False, True])
@pytest.mark.parametrize("occluded", [False, True])
def test_reduces_to_renyi(repeats, occluded):
    """Without visibility, or with weight 0, the choice is renyi's, bit for bit, given the
    same generator (the harness seeds each policy from its own configuration)."""
    occ = [Occlusion((0, 3), (0, 9), (0, 30), velocity=(1.0, 0.0))] if occluded else []
    model = TrackingModel(Grid(10, 10), Dynamics(wna_intensity=1e-3), sensor=SENSOR,
                          visibility=Visibility(tuple(occ)))
    la = make_policy("lookahead", repeats=repeats, weight=0.0 if occluded else 1.0)
    renyi = make_policy("renyi", repeats=repeats)
    la.reset(model, 7, np.random.default_rng(5))
    renyi.reset(model, 7, np.random.default_rng(5))
    rng = np.random.default_rng(6)
    for k in range(20):
        P = rng.dirichlet(np.full(3, 0.3), size=100)
        assert la.select(k, P).tolist() == renyi.select(k, P).tolist()


def test_top_values_are_chosen():
    """Distinct looks: the chosen cells are the M of largest value (no ties here)."""
    model = TrackingModel(Grid(10, 10), Dynamics(wna_intensity=1e-3), sensor=SENSOR,
                          visibility=Visibility((Occlusion((2, 5), (0, 9), (0, 40),
                                                           velocity=(0.5, 0.0)),)))
    la = make_policy("lookahead", horizon=4)
    la.reset(model, 9, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    for k in range(0, 40, 3):
        P = rng.dirichlet(np.full(3, 0.3), size=100)
        q = la.values(k, P)
        assert la.select(k, P).tolist() == np.sort(np.argsort(-q)[:9]).tolist()


def test_resource_terms_declare_the_lookahead_lists():
    model = two_cells([Occlusion((0, 1), (0, 0), (0, 3))])
    terms = make_policy("lookahead").resource_terms({"horizon": 4}, model, 1)
    assert terms.state_bytes == 16.0 * 4 * 2
    assert terms.dense_rows == 2.0


# --------------------------------------------------------------- the reproduction
@pytest.fixture(scope="module")
def reduced(tmp_path_factory):
    out = tmp_path_factory.mktemp("cdc")
    setting = cdc.SETTINGS["reduced"]
    rep = cdc.reproduce_cdc2004(setting, out, out / "cache", workers=1, progress=False,
                                use_cache=False)
    return setting, rep


def test_reduced_reproduction_writes_and_passes(reduced):
    setting, rep = reduced
    for name in ("policies.csv", "paired.csv", "runs.csv", "report.md", "report.html"):
        assert (rep.out_dir / name).is_file()
    assert len(rep.paired) == 1 and rep.paired["n_pairs"].iloc[0] == len(setting.seeds)
    assert set(rep.table["policy"]) == {"renyi", "lookahead"}
    assert rep.paired["paper_ratio"].iloc[0] == pytest.approx(0.932 / 2.054)
    # the paired difference is the mean of the per-seed differences
    runs = pd.read_csv(rep.out_dir / "runs.csv").pivot_table(index="seed", columns="policy",
                                                             values="ospa")
    d = runs["lookahead"] - runs["renyi"]
    assert rep.paired["diff_mean"].iloc[0] == pytest.approx(d.mean())
    result = cdc.check(setting, rep.specs, rep.results)
    assert result.passed, result.lines
    assert "ratio of medians" in (rep.out_dir / "report.md").read_text()


def test_check_fails_on_a_missing_seed_a_wasted_look_and_a_worse_policy(reduced):
    setting, rep = reduced
    res = rep.results
    first = setting.seeds[0]
    missing = res[~((res["policy"] == "lookahead") & (res["seed"] == first))]
    lines = cdc.check(setting, rep.specs, missing).lines
    assert any(f"seeds [{first}] missing" in x for x in lines)
    wasted = res.copy()
    wasted.loc[wasted.index[5], "n_looks"] -= 1
    lines = cdc.check(setting, rep.specs, wasted).lines
    assert lines == ["1 step(s) made fewer than M looks (a look at a blind cell), first: "
                     + f"{wasted.loc[wasted.index[5], 'tracker_label']} / "
                     + f"{wasted.loc[wasted.index[5], 'policy']} seed "
                     + f"{wasted.loc[wasted.index[5], 'seed']} step "
                     + f"{wasted.loc[wasted.index[5], 'step']}: "
                     + f"{wasted.loc[wasted.index[5], 'n_looks']} of "
                     + f"{wasted.loc[wasted.index[5], 'looks_per_step']}"]
    worse = res.copy()
    worse.loc[worse["policy"] == "lookahead", "ospa"] += 0.5
    worse.loc[worse["policy"] == "lookahead", "ospa"] += 0.01 * worse["seed"]  # spread
    lines = cdc.check(setting, rep.specs, worse).lines
    assert len(lines) == 1 and "worse than renyi beyond noise" in lines[0]


def test_check_fails_without_visibility(reduced, monkeypatch):
    setting, rep = reduced
    plain = dataclasses.replace(cdc.setting_scenario(setting), model=dataclasses.replace(
        cdc.setting_scenario(setting).model, visibility=Visibility()))
    monkeypatch.setattr(cdc, "setting_scenario", lambda s: plain)
    lines = cdc.check(setting, rep.specs, rep.results).lines
    assert lines == [f"no step of 'occlusion' ({setting.n_steps} steps) has a blind cell"]


def test_cli_refuses_reference_flags(tmp_path, capsys):
    code = main(["reproduce", "cdc2004", "--reduced", "--exact", "--check", "--out",
                 str(tmp_path / "x")])
    assert code == 2
    assert "--exact does not apply to cdc2004" in capsys.readouterr().err


# ---------------------------------------------- the look choice against enumeration
def hand_gain_n(P: list[float], n: int, alpha: float = 0.5) -> float:
    """``n`` looks' expected Renyi gain on a 0/1 count, by the number ``s`` of returns:
    ``sum_s p(s) / (alpha - 1) log(sum_t P(t) p(s|t)^alpha / p(s)^alpha)`` with
    ``p(s|t)`` binomial in ``p_d(t)`` (``p_f`` for t = 0)."""
    pd1 = [SENSOR.p_f, SENSOR.p_d]
    total = 0.0
    for s in range(n + 1):
        lik = [math.comb(n, s) * pd1[t] ** s * (1.0 - pd1[t]) ** (n - s) for t in (0, 1)]
        ps = P[0] * lik[0] + P[1] * lik[1]
        inner = sum(P[t] * lik[t] ** alpha for t in (0, 1)) / ps ** alpha
        total += ps * math.log(inner) / (alpha - 1.0)
    return total


@pytest.mark.parametrize("repeats", [False, True])
@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_choice_maximises_the_value_over_every_allocation(repeats, k):
    """On a 3x2 grid with two occlusions, the looks chosen maximise
    ``sum_c w_c G_c(n_c)`` over every allocation of ``M`` looks to the visible cells
    (distinct cells without repeats, any counts with), enumerated; ``w_c`` written out
    from the occlusions by hand: column 2 blind at steps 2-3, cell (0, 1) at step 3."""
    model = TrackingModel(Grid(3, 2), Dynamics(wna_intensity=0.0), sensor=SENSOR,
                          visibility=Visibility((Occlusion((2, 2), (0, 1), (2, 3)),
                                                 Occlusion((0, 0), (1, 1), (3, 3)))))
    H, gamma, beta, M = 2, 0.5, 3.0, 3
    blind = {2: {2, 5}, 3: {2, 5, 3}}  # flat cells iy * 3 + ix blind at each step
    w = [1.0 + beta * sum(gamma ** h for h in (1, 2) if c in blind.get(k + h, ()))
         for c in range(6)]
    visible = [c for c in range(6) if c not in blind.get(k, ())]
    P1 = [0.5, 0.3, 0.45, 0.15, 0.9, 0.35]  # P_c(1); cell 4 nearly certain
    counts = np.array([[1.0 - p, p] for p in P1])

    def value(alloc):
        return sum(w[c] * hand_gain_n([1.0 - P1[c], P1[c]], alloc.count(c)) for c in set(alloc))

    pool = (itertools.combinations_with_replacement(visible, M) if repeats
            else itertools.combinations(visible, M))
    best = max(value(list(a)) for a in pool)
    la = make_policy("lookahead", horizon=H, discount=gamma, weight=beta, repeats=repeats)
    la.reset(model, M, np.random.default_rng(0))
    chosen = la.select(k, counts).tolist()
    assert len(chosen) == M and set(chosen) <= set(visible)
    assert repeats or len(set(chosen)) == M
    assert value(chosen) == pytest.approx(best, rel=1e-12)
