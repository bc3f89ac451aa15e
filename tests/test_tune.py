"""``mttbench tune`` and the tuned files ``compare`` runs (benchmarks/app/tune.py, tuned.py).

1. Search spaces: each kind of :class:`Search` maps to optuna's distribution of the
   matching ``suggest_*``; a range outside what its :class:`Param` accepts is refused when
   the parameter is declared; every shipped tracker's space yields only settings its
   declaration accepts.
2. Tiny real tunes of ``kfnn`` (``default`` cut to a few steps, two tuning seeds, six
   trials in batches of two, two random trials then TPE), run once per module: the stored
   objective is what a direct ``run_sweep`` of the best parameters gives; the same seed
   gives the same trials (on one worker and on two); a study interrupted in a batch's
   runs or between a batch's asks and resumed gives the trials of the uninterrupted one;
   tuning seeds never meet evaluation seeds; the tuned file carries its provenance and
   round-trips; ``compare`` runs it (``--untuned`` does not); a failing run fails its
   trial and the study goes on.
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
from pathlib import Path
from typing import ClassVar

import numpy as np
import optuna
import pandas as pd
import pytest
from test_packaging import installed_site as plain_install  # noqa: F401 - a fixture
from test_packaging import ok, run_python

from mttbench import Estimate, Tracker, trackers
from mttbench.benchmarks.app import (
    cli,
    cli_common,
    compare,
    progress,
    reproduce,
    reproduce_kreucher,
    tune,
    tuned,
)
from mttbench.benchmarks.app.summary import per_run
from mttbench.benchmarks.engine import loop as harness
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec, resolve_scenarios
from mttbench.trackers.params import Param, Search

STEPS = 8
SEEDS = (tune.TUNING_SEED_BASE, tune.TUNING_SEED_BASE + 1)
TRIALS = 6


def settings(name: str = "kfnn", **kw) -> tune.TuneSettings:
    sc = tuple(resolve_scenarios(["default"], STEPS))
    base = dict(trials=TRIALS, batch_size=2, startup_trials=2, seed=7)
    return tune.TuneSettings(TrackerSpec(name), sc, SEEDS, **{**base, **kw})


def trial_rows(table: pd.DataFrame) -> list[tuple]:
    """The trials as comparable tuples (number, state, value, parameters)."""
    cols = ["number", "state", "value", *sorted(c for c in table if c.startswith("param_"))]
    return [tuple(r) for r in table[cols].astype(object).itertuples(index=False)]


# ============================================================ 1. search spaces
class _Spaces:
    """A class declaring one parameter of each searched kind."""

    parameters: ClassVar[dict[str, Param]] = {
        "a": Param(float, 0, 1, search=Search(0.1, 0.9)),
        "b": Param(float, 0, low_open=True, search=Search(1e-3, 10.0, log=True)),
        "c": Param(float, 0, 1, search=Search(0.0, 1.0, step=0.25)),
        "d": Param(int, 1, search=Search(1, 9)),
        "e": Param(int, 1, search=Search(2, 64, log=True)),
        "f": Param(int, 0, search=Search(0, 10, step=5)),
        "g": Param(choices=("x", "y", "z"), search=Search(choices=("x", "z"))),
        "h": Param(bool, search=Search(choices=(True, False))),
        "i": Param(float, 0, 1, search=Search(choices=(0.9, 0.99))),
        "j": Param(int, 0),  # not searched
    }

    @classmethod
    def declared_parameters(cls):
        return cls.parameters


def test_each_search_kind_maps_to_its_suggest_distribution():
    D = optuna.distributions
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=1))
    space = tune.search_space(_Spaces)
    assert list(space) == list("abcdefghi")
    trial = study.ask()
    values = tune.suggest(trial, space)
    assert trial.distributions == {
        "a": D.FloatDistribution(0.1, 0.9),
        "b": D.FloatDistribution(1e-3, 10.0, log=True),
        "c": D.FloatDistribution(0.0, 1.0, step=0.25),
        "d": D.IntDistribution(1, 9),
        "e": D.IntDistribution(2, 64, log=True),
        "f": D.IntDistribution(0, 10, step=5),
        "g": D.CategoricalDistribution(("x", "z")),
        "h": D.CategoricalDistribution((True, False)),
        "i": D.CategoricalDistribution((0.9, 0.99)),
    }
    kinds = {"a": float, "b": float, "c": float, "d": int, "e": int, "f": int, "g": str,
             "h": bool, "i": float}
    assert {k: type(v) for k, v in values.items()} == kinds
    assert values["c"] in (0.0, 0.25, 0.5, 0.75, 1.0) and values["f"] in (0, 5, 10)
    # a given (fixed) parameter is not searched
    assert "d" not in tune.search_space(_Spaces, {"d": 3})


@pytest.mark.parametrize("make, words", [
    (lambda: Param(int, 1, search=Search(0, 5)), "0 refused"),
    (lambda: Param(float, 0, 1, high_open=True, search=Search(0.5, 1.0)), "1 refused"),
    (lambda: Param(float, 0, low_open=True, search=Search(0.0, 1.0)), "0 refused"),
    (lambda: Param(int, 1, search=Search(1, 5.5)), "not integral"),
    (lambda: Param(int, 0, search=Search(0, 10, step=0.5)), "not integral"),
    (lambda: Param(float, 0, 1, search=Search(0.0, 1.0, step=0.3)), "does not divide"),
    (lambda: Param(choices=("a", "b"), search=Search(choices=("a", "c"))), "choice 'c' refused"),
    (lambda: Param(float, 0, 1, search=Search(choices=(0, 1))), "canonical type"),
    (lambda: Param(bool, search=Search(0, 1)), "numeric"),
    (lambda: Param(int, 0, 3, search=Search(choices=(1, 1))), "repeat"),
])
def test_a_search_outside_what_the_parameter_accepts_is_refused(make, words):
    with pytest.raises(TypeError, match="Param search") as info:
        make()
    assert words in str(info.value)
    assert "\n" not in str(info.value)


def test_every_shipped_search_space_yields_accepted_settings():
    """50 random settings of every tracker's space (its corners included) pass its
    declaration and its rules between parameters; null and truth-aided have none."""
    searched = []
    for name in trackers.available():
        cls = trackers.get_class(name)
        space = tune.search_space(cls)
        if name in ("null", "truth-aided"):
            assert not space, name
        if not space:
            continue
        searched.append(name)
        study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
        corners = [{k: (s.choices[0] if s.choices else s.low) for k, (_, s) in space.items()},
                   {k: (s.choices[-1] if s.choices else s.high) for k, (_, s) in space.items()}]
        draws = [tune.suggest(study.ask(), space) for _ in range(50)]
        for params in corners + draws:
            cls.validate_params(params, name=name)  # raises on a refused setting
    assert {"kfnn", "jmpd-ap"} <= set(searched)


def test_a_tracker_without_search_space_is_refused_in_one_line(tmp_path):
    with pytest.raises(ConfigError, match="'null' has no search space") as info:
        tune.tune_tracker(settings("null"), tmp_path / "out", tuned_dir=tmp_path / "tuned",
                          progress=False)
    assert "\n" not in str(info.value)
    assert cli.main(["tune", "null", "--out", str(tmp_path / "o2")]) == 2
    # a scenario the tracker cannot run is refused before the folder is touched
    assert cli.main(["tune", "jmpd-ip:t_max=5", "--scenarios", "large", "--out",
                     str(tmp_path / "o3")]) == 2
    assert not (tmp_path / "o2").exists() and not (tmp_path / "o3").exists()


# ============================================================ 2. tiny real tunes
@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """One uninterrupted study: (settings, result, its folder)."""
    root = tmp_path_factory.mktemp("tune")
    st = settings()
    res = tune.tune_tracker(st, root / "out", tuned_dir=root / "tuned", workers=1,
                            progress=False, argv=["mttbench", "tune", "kfnn"])
    return st, res, root


def test_the_stored_objective_is_that_of_a_direct_sweep(study, tmp_path):
    st, res, _ = study
    rec = res.record
    assert res.trials["state"].eq("COMPLETE").all()
    table = res.trials.set_index("number")
    best = rec["objective"]["best_trial"]
    assert table.loc[best, "value"] == table["value"].min()
    sc = list(st.scenarios)

    def direct(params: dict) -> float:
        jobs = harness.build_jobs(sc, [TrackerSpec("kfnn", params)], [PolicySpec("raster")],
                                  None, list(SEEDS))
        runs = per_run(progress.run_sweep(jobs, tmp_path / str(len(params)), progress=False))
        assert sorted(runs["seed"]) == list(SEEDS) and (runs["status"] == "ok").all()
        return float(np.mean(runs["ospa"]))

    best_params = {k[6:]: table.loc[best, k] for k in table if k.startswith("param_")}
    best_params = trackers.get_class("kfnn").validate_params(best_params)
    assert direct(best_params) == pytest.approx(rec["objective"]["best_trial_value"],
                                                rel=1e-12, abs=0)
    assert direct({}) == pytest.approx(rec["objective"]["default_value"], rel=1e-12, abs=0)
    if rec["params"]:  # a trial beat the defaults: its parameters are the file's
        assert rec["params"] == best_params
        assert rec["objective"]["value"] == rec["objective"]["best_trial_value"]
        assert rec["objective"]["value"] < rec["objective"]["default_value"]


def test_the_same_seed_gives_the_same_trials_on_any_number_of_workers(study, tmp_path):
    st, res, _ = study
    again = tune.tune_tracker(st, tmp_path / "out", tuned_dir=tmp_path / "tuned", workers=2,
                              progress=False)
    assert trial_rows(again.trials) == trial_rows(res.trials)
    # and the parameters do move with the seed (the comparison can fail)
    other = tune.tune_tracker(dataclasses.replace(st, seed=8, trials=2), tmp_path / "o8",
                              tuned_dir=tmp_path / "t8", progress=False)
    assert trial_rows(other.trials) != trial_rows(res.trials)[:2]


class _Interrupt:
    """Stand-in for ``run_sweep`` that raises KeyboardInterrupt at its ``at``-th call,
    after running the first half of that call's jobs."""

    def __init__(self, at: int) -> None:
        self.at, self.calls = at, 0

    def __call__(self, jobs, out_dir, **kw):
        self.calls += 1
        if self.calls == self.at:
            progress.run_sweep(jobs[: len(jobs) // 2], out_dir, **kw)
            raise KeyboardInterrupt
        return progress.run_sweep(jobs, out_dir, **kw)


def test_an_interrupt_in_a_batch_resumes_to_the_uninterrupted_trials(study, tmp_path):
    st, res, _ = study
    out, tuned_dir = tmp_path / "out", tmp_path / "tuned"
    with pytest.raises(KeyboardInterrupt):
        tune.tune_tracker(st, out, tuned_dir=tuned_dir, progress=False, sweep=_Interrupt(2))
    stored = optuna.load_study(study_name="kfnn", storage=tune._storage(out / "kfnn"))
    states = [t.state.name for t in stored.get_trials()]
    assert states == ["COMPLETE", "COMPLETE", "RUNNING", "RUNNING"]  # batch 1 cut short
    assert not (tuned_dir / "kfnn.toml").exists()
    with pytest.raises(ConfigError, match="--resume"):
        tune.tune_tracker(st, out, tuned_dir=tuned_dir, progress=False)
    done = tune.tune_tracker(st, out, tuned_dir=tuned_dir, progress=False, resume=True)
    assert trial_rows(done.trials) == trial_rows(res.trials)
    assert done.record["params"] == res.record["params"]


def test_an_interrupt_between_asks_resumes_to_the_uninterrupted_trials(study, tmp_path,
                                                                     monkeypatch):
    st, res, _ = study
    out, tuned_dir = tmp_path / "out", tmp_path / "tuned"
    real, calls = tune._draw, []

    def ask_then_stop(settings, storage, study_id, number, space):
        calls.append(number)
        if number == 3:  # trial 2 of batch 1 asked, trial 3 not yet
            raise KeyboardInterrupt
        return real(settings, storage, study_id, number, space)

    monkeypatch.setattr(tune, "_draw", ask_then_stop)
    with pytest.raises(KeyboardInterrupt):
        tune.tune_tracker(st, out, tuned_dir=tuned_dir, progress=False)
    monkeypatch.setattr(tune, "_draw", real)
    done = tune.tune_tracker(st, out, tuned_dir=tuned_dir, progress=False, resume=True)
    assert calls == [0, 1, 2, 3]
    assert trial_rows(done.trials) == trial_rows(res.trials)


def test_a_resumed_study_must_keep_its_settings(study, tmp_path):
    st, _, root = study
    with pytest.raises(ConfigError, match="made with seeds"):
        tune.tune_tracker(dataclasses.replace(st, seeds=(SEEDS[0],)), root / "out",
                          tuned_dir=tmp_path, progress=False, resume=True)


def test_tuning_seeds_never_meet_evaluation_seeds(study):
    _, res, root = study
    base = tuned.TUNING_SEED_BASE
    # the runs of the study used only tuning seeds
    seeds = {int(pd.read_parquet(p)["seed"].iloc[0]) for p in (root / "out/parts").glob("*")}
    assert seeds == set(SEEDS) and min(seeds) >= base
    # every way of choosing evaluation seeds stays below them
    assert cli_common.MAX_SEEDS <= base and compare.COMPARE_SEEDS <= base
    for module in (reproduce, reproduce_kreucher):
        for setting in module.SETTINGS.values():
            assert max(setting.seeds) < base
    with pytest.raises(ConfigError, match="tuning seeds must be >= 1000000"):
        dataclasses.replace(settings(), seeds=(base - 1, base))
    assert cli.main(["tune", "kfnn", "--seed-start", str(base - 1), "--out", "x"]) == 2
    # compare refuses evaluation seeds a tuned file was tuned on
    spec = [TrackerSpec("kfnn")]
    with pytest.raises(ConfigError, match="were used to tune kfnn"):
        tuned.plan_tuning(spec, root / "tuned", seeds=[0, SEEDS[1]])
    tuned.plan_tuning(spec, root / "tuned", seeds=list(range(100)))


def test_the_tuned_file_has_its_provenance_and_round_trips(study):
    st, res, root = study
    path = root / "tuned" / "kfnn.toml"
    assert res.tuned_file == path
    text = path.read_text(encoding="utf-8")
    rec = tomllib.loads(text)
    assert rec["tracker"] == "kfnn" and rec["format"] == tuned.FORMAT
    b = rec["budget"]
    assert (b["trials"], b["tuning_seeds"], b["scenarios"], b["steps"], b["policy"]) == (
        TRIALS, list(SEEDS), ["default"], {"default": STEPS}, "raster")
    assert (b["runs"], b["default_runs"], b["completed"], b["failed"]) == (12, 2, 6, 0)
    obj = rec["objective"]
    assert obj["metric"] == "ospa" and set(obj) >= {"value", "default_value", "per_scenario"}
    prov = rec["provenance"]
    assert {"mttbench", "numpy", "optuna"} <= set(prov["versions"])
    assert prov["versions"]["optuna"] == optuna.__version__
    commit = compare.git_commit()["commit"]  # None outside a git checkout: left out
    assert prov.get("git_commit") == commit and prov["date_utc"].endswith("+00:00")
    assert prov["command"] == "mttbench tune kfnn"
    assert rec["sampler"]["seed"] == 7 and rec["sampler"]["batch_size"] == 2
    assert set(rec["search"]) == set(st.space())
    # round trip: read, checked, written again: the same text
    tf = tuned.read_tuned(path)
    assert tf.params == rec["params"] and tf.seeds == SEEDS and tf.value == obj["value"]
    assert tuned.dumps(tf.record) == text
    assert (root / "out" / "kfnn" / "tuned.toml").read_text(encoding="utf-8") == text
    assert list(pd.read_csv(root / "out" / "kfnn" / "trials.csv")["number"]) == list(
        range(TRIALS))


def test_the_command_writes_its_folder_and_the_tuned_file(tmp_path, capsys):
    out, tuned_dir = tmp_path / "out", tmp_path / "tuned"
    args = ["tune", "kfnn", "--trials", "2", "--tuning-seeds", "2", "--scenarios", "default",
            "--steps", "4", "--workers", "1", "--no-progress", "--out", str(out),
            "--tuned-dir", str(tuned_dir)]
    assert cli.main(args) == 0
    printed = capsys.readouterr()
    assert "2 trials x 2 tuning seeds x 1 scenarios" in printed.err  # the budget, stated
    assert f"wrote {tuned_dir / 'kfnn.toml'}" in printed.out
    man = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    assert man["status"] == "finished" and man["trackers"]["kfnn"]["settings"]["batch_size"] == 1
    # every run of the study, once: the defaults and the two trials, on the tuning seeds
    df = pd.read_parquet(out / "results.parquet")
    runs = df.drop_duplicates(["tracker_label", "seed"])
    assert len(runs) == 6 and set(runs["seed"]) == set(SEEDS)
    assert runs["tracker_label"].nunique() == 3 and "kfnn" in set(runs["tracker_label"])
    assert tuned.read_tuned(tuned_dir / "kfnn.toml").record["budget"]["trials"] == 2


def test_a_bad_tuned_file_is_refused_in_one_line(tmp_path):
    (tmp_path / "kfnn.toml").write_text(
        'tracker = "kfnn"\n[params]\nlost_track_probability = 0\n[objective]\nmetric = "ospa"\n'
        'value = 1.0\n[budget]\ntuning_seeds = [1000000]\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"kfnn.toml: .*lost_track_probability=0 refused") as info:
        tuned.plan_tuning([TrackerSpec("kfnn")], tmp_path)
    assert "\n" not in str(info.value)


def _tuned_dir(tmp_path: Path, params: dict) -> Path:
    """A tuned file for kfnn with ``params`` (written the way tune writes it)."""
    rec = {"format": 1, "tracker": "kfnn", "source": "trial 3", "params": params,
           "objective": {"metric": "ospa", "value": 1.1, "default_value": 1.3},
           "budget": {"trials": 24, "tuning_seeds": list(SEEDS), "scenarios": ["default"],
                      "steps": {"default": STEPS}}}
    tuned.write_tuned(tmp_path / "tuned" / "kfnn.toml", rec)
    return tmp_path / "tuned"


def test_compare_runs_the_tuned_file_and_untuned_does_not(tmp_path):
    params = {"lost_track_probability": 0.2, "false_track_probability": 0.01,
              "gate_probability": 0.99}
    tuned_dir = _tuned_dir(tmp_path, params)
    common = dict(scenario_names=["default"], tracker_texts=["kfnn", "null"], seeds=[0, 1],
                  steps=STEPS, workers=1, progress=False, snapshot=False, tuned_dir=tuned_dir)
    res = compare.run_compare(out_dir=tmp_path / "a", tuning_effect=True, **common)
    labels = set(res.results["tracker_label"])
    assert labels == {"kfnn(tuned)", "kfnn", "null"}
    ran = res.results.drop_duplicates("tracker_label").set_index("tracker_label")
    for k, v in params.items():
        assert ran.loc["kfnn(tuned)", f"param_{k}"] == v
        assert ran.loc["kfnn", f"param_{k}"] != v  # the defaults differ from the file
    assert res.manifest["reference"] == "kfnn(tuned)"
    summary_md = (res.out_dir / "summary.md").read_text(encoding="utf-8")
    assert "| kfnn(tuned) |" in summary_md and "tuned parameters from" in summary_md
    report = res.files.markdown.read_text(encoding="utf-8")
    assert "## Parameters" in report and "## Effect of tuning" in report
    assert "tuned - default (paired)" in report
    # the effect table is the paired difference of the two settings' runs
    runs = per_run(res.results).set_index(["tracker_label", "seed"])["ospa"]
    diff = (runs["kfnn(tuned)"] - runs["kfnn"]).mean()
    assert f"{diff:.3f} ± " in report

    res = compare.run_compare(out_dir=tmp_path / "b", untuned=True, **common)
    assert set(res.results["tracker_label"]) == {"kfnn", "null"}
    kfnn_rows = res.results[res.results["tracker"] == "kfnn"]
    assert kfnn_rows["param_lost_track_probability"].eq(0.1).all()
    assert "defaults (--untuned)" in (res.out_dir / "summary.md").read_text(encoding="utf-8")


def test_given_parameters_win_over_the_tuned_file(tmp_path):
    tuned_dir = _tuned_dir(tmp_path, {"lost_track_probability": 0.2,
                                      "false_track_probability": 0.01})
    plan = tuned.plan_tuning([TrackerSpec("kfnn", {"lost_track_probability": 0.3})], tuned_dir)
    (spec,) = plan.specs
    assert spec.label == "kfnn(tuned,lost_track_probability=0.3)"
    assert spec.params == {"lost_track_probability": 0.3, "false_track_probability": 0.01}


class Flaky(Tracker):
    """Reports nothing; its runs fail at step 2 when ``mode`` is ``"crash"``."""

    summary = "test tracker: fails when told to"
    parameters: ClassVar[dict[str, Param]] = {
        "mode": Param(choices=("ok", "crash"), search=Search(choices=("ok", "crash"))),
        "level": Param(float, 0, 1, search=Search(0.0, 1.0)),
    }

    def __init__(self, mode: str = "ok", level: float = 0.5) -> None:
        self.mode, self.level = mode, level

    def reset(self, model, rng):
        self._k = -1
        self._n = model.grid.n_cells

    def predict(self):
        self._k += 1
        if self.mode == "crash" and self._k == 2:
            raise RuntimeError("told to crash")

    def cell_count_distribution(self):
        return np.tile([1.0, 0.0], (self._n, 1))

    def update(self, looks):
        pass

    def estimate(self):
        return Estimate.empty()


def test_a_failing_run_fails_its_trial_and_the_study_goes_on(tmp_path):
    st = settings("test_tune:Flaky", trials=5, startup_trials=5)
    res = tune.tune_tracker(st, tmp_path / "out", tuned_dir=tmp_path / "tuned",
                            progress=False)
    t = res.trials
    crash = t["param_mode"] == "crash"
    assert crash.any() and (~crash).any()  # this seed draws both
    assert t.loc[crash, "state"].eq("FAIL").all() and t.loc[~crash, "state"].eq("COMPLETE").all()
    assert t.loc[crash, "message"].str.contains(
        r"default / seed 1000000: error: RuntimeError: told to crash").all()
    assert res.record["budget"]["failed"] == int(crash.sum())
    # every run reports nothing, so no trial beats the defaults: the file says so
    assert res.record["params"] == {} and res.record["source"].startswith("defaults")


# ======================================================= 3. where the files live
def test_tuned_files_live_in_the_checkout_or_ship_with_the_package(
        plain_install, tmp_path):  # noqa: F811 - the fixture imported above
    """A checkout reads and writes its tuned/; an installed package reads the tuned/ it
    was built with (package data) and tune writes ./tuned, never into the install."""
    repo = Path(__file__).resolve().parents[1]
    assert tuned.default_tuned_dir() == repo / "tuned" and tuned.is_checkout()
    assert tuned.default_write_dir() == repo / "tuned"
    code = ("from mttbench.benchmarks.app import tuned; print(tuned.default_tuned_dir()); "
            "print(tuned.is_checkout()); print(tuned.default_write_dir())")
    proc = ok(run_python(["-c", code], tmp_path, [plain_install]))
    read_dir, checkout, write_dir = proc.stdout.split()
    assert Path(read_dir) == plain_install / "mttbench" / "tuned"
    assert Path(read_dir).is_dir()  # shipped, with the files of the checkout it was built from
    assert {p.name for p in Path(read_dir).glob("*.toml")} == {
        p.name for p in (repo / "tuned").glob("*.toml")}
    assert (checkout, write_dir) == ("False", "tuned")


def test_the_objective_averages_over_scenarios_and_seeds(tmp_path):
    """Two scenarios of different lengths and seeds: the objective is the mean over
    scenarios of the mean over seeds of each run's mean over steps (computed here from
    the step rows with a groupby), not their sum nor a mean over pooled steps."""
    from types import SimpleNamespace

    from mttbench.benchmarks.engine.loop import build_jobs
    from mttbench.benchmarks.engine.specs import TrackerSpec, resolve_scenarios
    from mttbench.benchmarks.engine.sweep import run_sweep

    scs = resolve_scenarios(["default"], 3) + resolve_scenarios(["births"], 5)
    seeds = [0, 1, 2]
    rows = run_sweep(build_jobs(scs, [TrackerSpec("kfnn")], None, None, seeds),
                     tmp_path / "out")
    want = (rows.groupby(["scenario", "seed"])["ospa"].mean()
            .groupby(level="scenario").mean())
    settings = SimpleNamespace(objective="ospa", scenarios=scs, seeds=seeds)
    value, per_scenario, message = tune.objective_value(rows, "kfnn", settings)
    assert message == "" and len(want) == 2 and want.nunique() == 2
    assert per_scenario == pytest.approx(want.to_dict(), rel=1e-12)
    assert value == pytest.approx(want.mean(), rel=1e-12)
