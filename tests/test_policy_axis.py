"""Policies as an axis of ``mttbench compare``: the option, the tracker x policy table's
paired differences (against a hand computation with scipy's t quantile), the best pair
(ties, noise, no truth), the Bayes reference kept per policy, common random numbers across
policies, and a tiny compare under two policies end to end."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from test_bayes import TINY, stored
from test_gap_closed import frame

from mttbench import trackers
from mttbench.benchmarks.app import bayes, policy_axis, summary
from mttbench.benchmarks.app.cli import build_parser, main
from mttbench.benchmarks.engine.loop import play
from mttbench.benchmarks.engine.policies import make_policy
from mttbench.benchmarks.engine.specs import PolicySpec, resolve_scenarios


def two_policies(raster: dict, renyi: dict, extra: dict | None = None) -> pd.DataFrame:
    """A step table of the same trackers under raster and renyi (and any ``extra``
    ``{policy: per_seed}``): ``per_seed`` maps ``(scenario, tracker) -> OSPA per seed``."""
    parts = [frame(raster, "raster"), frame(renyi, "renyi")]
    parts += [frame(v, k) for k, v in (extra or {}).items()]
    return pd.concat(parts, ignore_index=True)


def t_half(d: np.ndarray) -> float:
    return float(stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / np.sqrt(d.size))


# --------------------------------------------------------------------- the option
def test_policies_option_and_its_alias_parse():
    parser = build_parser()
    args = parser.parse_args(["compare", "--policies", "raster", "renyi:alpha=0.9"])
    assert args.policies == ["raster", "renyi:alpha=0.9"]
    assert parser.parse_args(["compare", "--policy", "renyi"]).policies == ["renyi"]
    assert parser.parse_args(["compare"]).policies == ["raster"]
    specs = policy_axis.resolve(["raster,renyi:alpha=0.9"])
    assert [s.label for s in specs] == ["raster", "renyi(alpha=0.9)"]


@pytest.mark.parametrize("policies, needle", [
    (["wild"], "wild"),
    (["raster", "raster"], "more than once"),
    (["renyi", "renyi:alpha=0.5"], "same policy"),       # alpha 0.5 is renyi's default
    (["renyi:alpha=-1"], "alpha"),
    (["raster,"], "empty item"),
])
def test_bad_policies_exit_2_in_one_line_before_any_run(tmp_path, capsys, policies, needle):
    out = tmp_path / "never"
    rc = main(["compare", "--scenarios", "default", "--trackers", "null", "--seeds", "1",
               "--steps", "2", "--policies", *policies, "--out", str(out), "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err and needle in err, err
    assert not out.exists()


# ------------------------------------------------------------ the tracker x policy table
RASTER = {("s", "null"): [2.0, 2.0, 2.0, 2.0], ("s", "truth-aided"): [0.5, 0.6, 0.4, 0.5],
          ("s", "kfnn"): [1.0, 1.2, 0.9, 1.1], ("s", "gpf"): [0.9, 1.0, 1.0, 0.8]}
RENYI = {("s", "null"): [2.0, 2.0, 2.0, 2.0], ("s", "truth-aided"): [0.4, 0.5, 0.4, 0.45],
         ("s", "kfnn"): [0.8, 1.1, 0.7, 1.05], ("s", "gpf"): [0.6, 0.75, 0.5, 0.5]}


def test_paired_differences_between_policies_match_a_hand_computation():
    df = two_policies(RASTER, RENYI)
    # a failed renyi run of kfnn on seed 3: that seed leaves kfnn's pairs
    bad = (df["policy_label"] == "renyi") & (df["tracker_label"] == "kfnn") & (df["seed"] == 3)
    df.loc[bad, "status"] = "error"
    df = df.sample(frac=1.0, random_state=1)  # row order must not matter
    axis = policy_axis.policy_axis(df, order=["raster", "renyi"])
    d = axis.diffs.set_index("tracker_label")
    assert set(d["policy_label"]) == {"renyi"} and set(d["base_label"]) == {"raster"}
    for lab, seeds in (("gpf", [0, 1, 2, 3]), ("kfnn", [0, 1, 2]), ("truth-aided", [0, 1, 2, 3])):
        hand = np.array([RENYI[("s", lab)][i] - RASTER[("s", lab)][i] for i in seeds])
        assert d.loc[lab, "diff_mean"] == pytest.approx(hand.mean(), abs=1e-12), lab
        assert d.loc[lab, "diff_ci95"] == pytest.approx(t_half(hand), abs=1e-12), lab
        assert d.loc[lab, "n_pairs"] == len(seeds)
    # the floor reports nothing on the same truth: zero difference (up to the order of
    # the sum over the shuffled steps)
    assert d.loc["null", "diff_mean"] == pytest.approx(0.0, abs=1e-12)
    assert d.loc["null", "diff_ci95"] == pytest.approx(0.0, abs=1e-12)
    # the table: each policy's own floor and ceiling for the share of the gap
    t = axis.table.set_index(["tracker_label", "policy_label"])
    for pol, vals in (("raster", RASTER), ("renyi", RENYI)):
        f, c, x = (np.array(vals[("s", n)]) for n in ("null", "truth-aided", "gpf"))
        assert t.loc[("gpf", pol), "share_mean"] == pytest.approx(
            (f - x).mean() / (f - c).mean(), abs=1e-12)
        assert t.loc[("gpf", pol), "ospa_mean"] == pytest.approx(x.mean(), abs=1e-12)
    # the base is the first given, whatever the order in the table
    rev = policy_axis.policy_axis(df, order=["renyi", "raster"])
    r = rev.diffs.set_index("tracker_label")
    assert set(r["base_label"]) == {"renyi"}
    assert r.loc["gpf", "diff_mean"] == pytest.approx(-d.loc["gpf", "diff_mean"], abs=1e-12)


def test_display_table_marks_differences_beyond_noise():
    axis = policy_axis.policy_axis(two_policies(RASTER, RENYI), order=["raster", "renyi"])
    ((head, table),) = policy_axis.display_tables(axis)
    assert head == "`s` (24 looks)"
    assert list(table["tracker"]) == ["null", "gpf", "kfnn", "truth-aided (uses truth)"]
    row = table.set_index("tracker").loc["gpf"]
    hand = np.subtract(RENYI[("s", "gpf")], RASTER[("s", "gpf")])
    assert row["renyi − raster"] == (f"{hand.mean():+.3f} ± {t_half(hand):.3f}"
                                     + policy_axis.BEYOND_NOISE_MARK)
    assert table.set_index("tracker").loc["null", "raster gap closed"] == "0 (floor)"
    assert "of achievable" not in " ".join(table.columns)  # no Bayes reference here


def test_one_policy_has_no_axis():
    axis = policy_axis.policy_axis(frame(RASTER, "raster"))
    assert not axis.available and policy_axis.markdown(axis) == ""


# ------------------------------------------------------------------------- best pair
def best_of(raster: dict, renyi: dict, extra: dict | None = None) -> pd.Series:
    axis = policy_axis.policy_axis(two_policies(raster, renyi, extra), order=["raster"])
    (row,) = axis.best.itertuples(index=False)
    return pd.Series(row._asdict())


def test_the_best_pair_beyond_noise_against_the_runner_up():
    b = best_of(RASTER, RENYI)
    assert (b.tracker_label, b.policy_label) == ("gpf", "renyi")
    # runner-up: the next least mean, kfnn under renyi (0.9125) before gpf under raster
    assert (b.runner_tracker, b.runner_policy) == ("kfnn", "renyi")
    hand = np.subtract(RENYI[("s", "kfnn")], RENYI[("s", "gpf")])
    assert b.diff_mean == pytest.approx(hand.mean(), abs=1e-12)
    assert b.diff_ci95 == pytest.approx(t_half(hand), abs=1e-12)
    assert b.beyond_noise == bool(hand.mean() - t_half(hand) > 0) is True
    line = policy_axis.best_lines(policy_axis.policy_axis(two_policies(RASTER, RENYI)))[0]
    assert "best pair `gpf` under `renyi`" in line and "beyond noise" in line


def test_a_tie_goes_by_label_and_is_not_beyond_noise():
    renyi = {**RENYI, ("s", "kfnn"): RENYI[("s", "gpf")]}  # kfnn = gpf under renyi, seed by seed
    b = best_of(RASTER, renyi)
    assert (b.tracker_label, b.policy_label, b.runner_tracker) == ("gpf", "renyi", "kfnn")
    assert b.diff_mean == 0.0 and b.diff_ci95 == 0.0 and not b.beyond_noise
    line = policy_axis.best_lines(policy_axis.policy_axis(two_policies(RASTER, renyi)))[0]
    assert "level within noise" in line


def test_a_runner_up_within_noise_is_level():
    # gpf under renyi ahead on average, behind on one seed: the interval reaches 0
    renyi = {**RENYI, ("s", "kfnn"): [0.7, 0.7, 0.8, 0.4]}
    b = best_of(RASTER, renyi)
    hand = np.subtract(renyi[("s", "kfnn")], RENYI[("s", "gpf")])
    assert hand.mean() > 0 and hand.mean() - t_half(hand) < 0
    assert (b.tracker_label, b.policy_label) == ("gpf", "renyi") and not b.beyond_noise


def test_references_baselines_and_truth_policies_never_win():
    oracle = {("s", "null"): [2.0] * 4, ("s", "truth-aided"): [0.1] * 4,
              ("s", "kfnn"): [0.01, 0.02, 0.01, 0.02], ("s", "gpf"): [0.02] * 4}
    low_null = {**RASTER, ("s", "null"): [0.0] * 4}  # a floor that happens to be least
    b = best_of(low_null, RENYI, {"oracle": oracle})
    assert b.policy_label != "oracle" and b.tracker_label not in ("null", "truth-aided")
    assert (b.tracker_label, b.policy_label) == ("gpf", "renyi")


# ------------------------------------------------------------ the Bayes reference per policy
def test_a_raster_reference_is_never_attached_under_another_policy(tmp_path):
    stored(tmp_path)  # a raster reference of TINY for seeds 0..2
    base = frame({(TINY.name, "null"): [2.0] * 2}, "renyi")
    merged, notes = bayes.attach(base, [TINY], [0, 1], PolicySpec("renyi"),
                                 stores=[tmp_path / "store"])
    assert "bayes" not in set(merged["tracker_label"])
    (note,) = notes
    assert f"`{TINY.name}` under `renyi`: no stored `bayes` reference" in note
    assert "--policy renyi" in note
    both = pd.concat([frame({(TINY.name, "null"): [2.0] * 2}, "raster"), base])
    merged, notes = bayes.attach(both, [TINY], [0, 1], PolicySpec("raster"),
                                 stores=[tmp_path / "store"], name_policy=True)
    assert set(merged.loc[merged["tracker_label"] == "bayes", "policy_label"]) == {"raster"}
    assert notes[0].startswith(f"`{TINY.name}` under `raster`: `bayes` converged")
    # a group with the reference under raster only says so
    runs = pd.concat([merged, frame({(TINY.name, "kfnn"): [1.0, 1.1]}, "raster"),
                      frame({(TINY.name, "kfnn"): [0.9, 1.0]}, "renyi")])
    looks = int(merged.loc[merged["tracker_label"] == "bayes", "looks_per_step"].iloc[0])
    runs["looks_per_step"] = looks  # the synthetic rows at the reference's budget
    axis = policy_axis.policy_axis(runs, order=["raster", "renyi"])
    assert axis.bayes_policies[(TINY.name, looks)] == {"raster"}
    (line,) = policy_axis.bayes_lines(axis)
    assert "stored under `raster` only; none under `renyi`" in line


# ------------------------------------------------------------ common random numbers
def test_truth_and_returns_do_not_depend_on_the_policy():
    """Two policies on one world: the truth of every step and the return of every cell
    both look at (its first look of the step) are the same."""
    sc = resolve_scenarios(["default"], steps=6)[0]
    recs = {}
    for name in ("raster", "renyi"):
        recs[name] = list(play(sc, trackers.make("kfnn"), 3, policy=make_policy(name)))
    shared = 0
    for a, b in zip(recs["raster"], recs["renyi"], strict=True):
        np.testing.assert_array_equal(a.truth, b.truth)
        np.testing.assert_array_equal(a.truth_ids, b.truth_ids)
        first_a = {int(c): bool(r) for c, r in zip(a.looks.cells[::-1], a.looks.returns[::-1],
                                                    strict=True)}
        first_b = {int(c): bool(r) for c, r in zip(b.looks.cells[::-1], b.looks.returns[::-1],
                                                    strict=True)}
        common = set(first_a) & set(first_b)
        shared += len(common)
        assert all(first_a[c] == first_b[c] for c in common)
    assert shared > 0
    assert any(not np.array_equal(a.looks.cells, b.looks.cells)
               for a, b in zip(recs["raster"], recs["renyi"], strict=True))


# ------------------------------------------------------------------------ end to end
def test_compare_under_two_policies_end_to_end(tmp_path, capsys):
    out = tmp_path / "cmp"
    rc = main(["compare", "--untuned", "--scenarios", "default", "--trackers", "null",
               "truth-aided", "kfnn", "--policies", "raster", "renyi", "--seeds", "2",
               "--steps", "4", "--workers", "1", "--out", str(out), "--no-progress"])
    assert rc == 0
    assert "12 runs (1 scenarios x 3 trackers x 2 policies x 2 seeds)" in capsys.readouterr().err
    df = pd.read_parquet(out / "results.parquet")
    assert set(zip(df["tracker_label"], df["policy_label"], strict=True)) == {
        (t, p) for t in ("null", "truth-aided", "kfnn") for p in ("raster", "renyi")}
    # one world per seed: the true count of every step, and the floor's OSPA, agree
    wide = df.pivot_table(index=["tracker_label", "seed", "step"], columns="policy_label",
                          values=["true_count", "ospa"])
    np.testing.assert_array_equal(wide["true_count"]["raster"], wide["true_count"]["renyi"])
    np.testing.assert_array_equal(wide["ospa"]["raster"].loc["null"],
                                  wide["ospa"]["renyi"].loc["null"])
    man = json.loads((out / "manifest.json").read_text())
    assert man["policies"] == ["raster", "renyi"]
    assert all("under `raster`" in n or "under `renyi`" in n for n in man["bayes"])
    md = (out / "report.md").read_text()
    verdict = md.split("## Floor and ceiling")[0]
    assert "Best tracker-policy pair per scenario" in verdict
    assert "`default` (24 looks): best pair `kfnn` under `" in verdict
    assert "## Trackers x policies" in md and "| renyi − raster |" in md
    assert "| raster OSPA | raster gap closed | renyi OSPA | renyi gap closed |" in md
    assert "raster, renyi at each scenario's looks_per_step" in md
    assert "## Trackers x policies" in (out / "summary.md").read_text()
    # the differences in the report are those of the rows
    runs = summary.per_run(df)
    k = runs[runs["tracker_label"] == "kfnn"].pivot(index="seed", columns="policy_label",
                                                    values="ospa")
    d = (k["renyi"] - k["raster"]).to_numpy()
    assert f"{d.mean():+.3f} ± {t_half(d):.3f}" in md


# ------------------------------------------------------------------ the envelope tables
def test_envelope_tables_put_the_policies_side_by_side():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "docs" / "envelope_table.py"
    spec = importlib.util.spec_from_file_location("envelope_table", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    df = two_policies(RASTER, RENYI)
    text = mod.policy_tables(df)
    hand = np.subtract(RENYI[("s", "gpf")], RASTER[("s", "gpf")])
    assert "## Policies side by side (raster, renyi)" in text
    assert f"{hand.mean():+.3f} ± {t_half(hand):.2f}{policy_axis.BEYOND_NOISE_MARK}" in text
    assert "| `s` | gpf / renyi |" in text
    # renyi first: the differences change sign
    assert f"{-hand.mean():+.3f} ± {t_half(hand):.2f}" in mod.policy_tables(df, order=["renyi"])
    assert mod.policy_tables(frame(RASTER, "raster")) == ""
