"""Declared parameters (trackers/params.py): every declaration matches its constructor,
bad values are refused before any run in one line naming the tracker or policy, the
parameter, the value and what is allowed; good values keep their types; and the random
streams of a run follow the canonical configuration, not its spelling."""

from __future__ import annotations

import dataclasses
import json
import math
from typing import ClassVar

import numpy as np
import pytest

from mttbench import scenarios, trackers
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine import loop as harness
from mttbench.benchmarks.engine import policies
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.loop import TIMING_COLUMNS, Job, play, run_job
from mttbench.benchmarks.engine.specs import (
    PolicySpec,
    TrackerSpec,
    resolve_policies,
    resolve_trackers,
)
from mttbench.trackers.base import Estimate, Tracker, register, unregister
from mttbench.trackers.params import Param, ParameterError


def shipped(names, get):
    """The registered classes that ship with mttbench (not test or plugin ones)."""
    return [(n, get(n)) for n in names() if get(n).__module__.startswith("mttbench.")]


TRACKERS = shipped(trackers.available, trackers.get_class)
POLICIES = shipped(policies.available_policies, policies.get_policy_class)
ALL = TRACKERS + POLICIES


def short(name: str, n_steps: int) -> scenarios.Scenario:
    return dataclasses.replace(scenarios.get(name), n_steps=n_steps)


# ------------------------------------------------------------------ declarations
@pytest.mark.parametrize(("name", "cls"), ALL, ids=[n for n, _ in ALL])
def test_every_declaration_matches_its_constructor(name, cls):
    declared = cls.declared_parameters()
    assert declared is not None, f"{name} declares no parameters"
    assert sorted(declared) == sorted(cls.param_names()), name
    assert cls.declaration_problem() is None
    assert all(isinstance(p, Param) for p in declared.values())
    # every default is allowed by its own declaration and keeps its value and type
    defaults = cls.param_defaults()
    checked = cls.validate_params(defaults)
    for k, v in defaults.items():
        assert checked[k] == v and type(checked[k]) is type(v), (name, k, v, checked[k])


def test_the_shipped_classes_are_all_covered():
    assert {"gpf", "jmpd", "jmpd-ip", "kfnn", "null"} <= {n for n, _ in TRACKERS}
    assert {"all", "random", "raster", "oracle", "renyi"} <= {n for n, _ in POLICIES}


# ------------------------------------------------------------------- bad values
#: spec -> (parameter and value as the message shows them, a piece of the allowed set)
BAD_TRACKERS = {
    "jmpd:n_particles=0": ("n_particles=0", "an integer >= 1"),
    "jmpd:n_particles=-5": ("n_particles=-5", "an integer >= 1"),
    "jmpd:n_particles=abc": ("n_particles='abc'", "an integer >= 1"),
    "jmpd:n_particles=": ("n_particles=''", "an integer >= 1"),
    "jmpd:n_particles=2.5": ("n_particles=2.5", "an integer >= 1"),
    "jmpd:n_particles=true": ("n_particles=True", "an integer >= 1"),
    "jmpd:t_max=0": ("t_max=0", "an integer >= 1"),
    "jmpd:proposal=bogus": ("proposal='bogus'", "one of bootstrap, ip"),
    "jmpd:birth_rate=-1": ("birth_rate=-1", "a number >= 0, or None"),
    "jmpd:resample_threshold=2": ("resample_threshold=2", "a number in [0, 1]"),
    "jmpd:initial_count=-1": ("initial_count=-1", "an integer >= 0, or None"),
    "kfnn:association=bogus": ("association='bogus'", "one of global, greedy"),
    "kfnn:gate_probability=2": ("gate_probability=2", "a number in (0, 1)"),
    "kfnn:gate_probability=1": ("gate_probability=1", "a number in (0, 1)"),
    "kfnn:false_track_probability=0": ("false_track_probability=0", "a number in (0, 1)"),
    "kfnn:birth_velocity_scale=-1": ("birth_velocity_scale=-1", "a number > 0"),
    "kfnn:birth_velocity_scale=fast": ("birth_velocity_scale='fast'", "a number > 0"),
    "gpf:extraction=bogus": ("extraction='bogus'", "one of round_sum, threshold"),
    "gpf:max_combinations=0": ("max_combinations=0", "an integer >= 1"),
    "gpf:epsilon=abc": ("epsilon='abc'", "a number in [0, 1)"),
    "gpf:epsilon=-1": ("epsilon=-1", "a number in [0, 1)"),
    "gpf:epsilon=nan": ("epsilon=nan", "a number in [0, 1)"),
    "gpf:epsilon=inf": ("epsilon=inf", "a number in [0, 1)"),
    "gpf:max_particles=0": ("max_particles=0", "an integer >= 1"),
    "gpf:split_share=1": ("split_share=1", "a number in [0, 1)"),
    "gpf:max_components=0": ("max_components=0", "an integer >= 1"),
    "jmpd-ap:undetected_in_policy=yes": ("undetected_in_policy='yes'", "true or false"),
    "jmpd-ap:undetected_in_policy=1": ("undetected_in_policy=1", "true or false"),
    "gpf:n_counts=1": ("n_counts=1", "an integer >= 2"),
    "gpf:death_probability=1.5": ("death_probability=1.5", "a number in [0, 1], or None"),
}
BAD_POLICIES = {
    "renyi:alpha=0": ("alpha=0", "a number in (0, 100]"),
    "renyi:alpha=-1": ("alpha=-1", "a number in (0, 100]"),
    "renyi:alpha=abc": ("alpha='abc'", "a number in (0, 100]"),
    "renyi:alpha=nan": ("alpha=nan", "a number in (0, 100]"),
    "renyi:alpha=101": ("alpha=101", "a number in (0, 100]"),
    "renyi:repeats=yes": ("repeats='yes'", "true or false"),
}


def _one_line(msg: str) -> str:
    assert msg and "\n" not in msg and "Traceback" not in msg, msg
    return msg


@pytest.mark.parametrize("text", list(BAD_TRACKERS) + list(BAD_POLICIES))
def test_bad_value_refused_naming_owner_parameter_value_and_allowed_set(text):
    is_tracker = text in BAD_TRACKERS
    shown, allowed = (BAD_TRACKERS if is_tracker else BAD_POLICIES)[text]
    name = text.partition(":")[0]
    kind = "tracker" if is_tracker else "policy"
    with pytest.raises(ConfigError) as err:
        (resolve_trackers if is_tracker else resolve_policies)([text])
    msg = _one_line(str(err.value))
    assert msg.startswith(f"{kind} {name!r}: parameter {shown} refused; allowed: {allowed}"), msg
    # the Python API refuses the same value with the same line
    spec = (TrackerSpec if is_tracker else PolicySpec).parse(text)
    with pytest.raises(ParameterError) as err2:
        spec.make()
    assert str(err2.value) == msg


@pytest.mark.parametrize(("text", "shown"), [
    ("jmpd:initial_count=6,t_max=5", "initial_count=6 with t_max=5"),
    ("jmpd-ip:initial_count=8,t_max=7", "initial_count=8 with t_max=7"),
])
def test_inconsistent_combinations_refused(text, shown):
    with pytest.raises(ConfigError) as err:
        resolve_trackers([text])
    msg = _one_line(str(err.value))
    name = text.partition(":")[0]
    assert msg.startswith(f"tracker {name!r}: {shown}: need"), msg


def test_unknown_parameter_names_the_known_ones():
    with pytest.raises(ConfigError) as err:
        resolve_trackers(["kfnn:gate=0.9"])
    msg = _one_line(str(err.value))
    assert "'gate'" in msg and "gate_probability" in msg and "lost_track_probability" in msg
    with pytest.raises(TypeError):
        trackers.make("kfnn", gate=0.9)


@pytest.mark.parametrize("text", ["gpf:truncate=false", "gpf:merge_weight=union",
                                  "gpf:births=false", "gpf:interaction_threshold=0",
                                  "jmpd:move_steps=1", "jmpd-ip:move_scale=2",
                                  "kfnn:max_misses=6", "kfnn:confirm_m=1",
                                  "ss-gnn:min_points=1", "ss-gmphd:birth_intensity=0.01"])
def test_retired_switches_are_refused_as_unknown(text):
    """The switches retired with their code (docs/gpf.md, docs/jmpd.md) are unknown names,
    not values that are silently ignored."""
    with pytest.raises(ConfigError) as err:
        resolve_trackers([text])
    msg = _one_line(str(err.value))
    assert repr(text.partition(":")[2].partition("=")[0]) in msg, msg


def test_directly_built_trackers_are_checked_at_reset_and_by_play():
    model = scenarios.get("default").model
    bad = trackers.get_class("jmpd")(n_particles=0)  # constructors only store
    with pytest.raises(ParameterError, match="n_particles=0"):
        bad.reset(model, np.random.default_rng(0))
    with pytest.raises(ParameterError, match="false_track_probability=0"):
        play(short("default", 2), trackers.get_class("kfnn")(false_track_probability=0), 0)
    with pytest.raises(ParameterError, match="alpha=0"):
        play(short("default", 2), trackers.make("null"), 0, policy=policies.RenyiGain(alpha=0))


@pytest.mark.parametrize("text", ["jmpd:n_particles=2.5", "kfnn:false_track_probability=2",
                                  "gpf:max_particles=0", "jmpd:initial_count=6,t_max=5"])
def test_cli_exits_2_with_one_line_before_any_run(text, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["run", "--scenarios", "default", "--trackers", "null", text, "--seeds", "1",
                 "--steps", "2", "--workers", "1", "--no-progress", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert text.partition(":")[0] in lines[0] and ("refused" in lines[0] or "need" in lines[0])
    assert not (out / "results.parquet").exists()


def test_cli_refuses_a_bad_policy_value(tmp_path, capsys):
    code = main(["run", "--scenarios", "default", "--trackers", "null", "--policy",
                 "renyi:alpha=-1", "--seeds", "1", "--steps", "2", "--workers", "1",
                 "--no-progress", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "policy 'renyi': parameter alpha=-1 refused; allowed: a number in (0, 100]" in err[0]


# ------------------------------------------------------------------ good values
@pytest.mark.parametrize(("text", "key", "value", "kind"), [
    ("jmpd:n_particles=1000", "n_particles", 1000, int),
    ("jmpd:n_particles=1000.0", "n_particles", 1000, int),  # integral floats become ints
    ("jmpd:n_particles=1e3", "n_particles", 1000, int),
    ("jmpd:birth_rate=None", "birth_rate", None, type(None)),
    ("jmpd:birth_rate=0", "birth_rate", 0.0, float),  # ints for floats become floats
    ("jmpd:initial_count=none", "initial_count", None, type(None)),
    ("kfnn:birth_velocity_scale=2", "birth_velocity_scale", 2.0, float),
    ("kfnn:gate_probability=0.99", "gate_probability", 0.99, float),
    ("gpf:merge_threshold=4", "merge_threshold", 4.0, float),
    ("jmpd-ap:undetected_in_policy=FALSE", "undetected_in_policy", False, bool),
    ("gpf:epsilon=-0.0", "epsilon", 0.0, float),
    ("gpf:extraction=threshold", "extraction", "threshold", str),
    ("renyi:alpha=1", "alpha", 1.0, float),
    ("renyi:repeats=true", "repeats", True, bool),
])
def test_good_values_pass_in_their_canonical_types(text, key, value, kind):
    is_policy = text.startswith("renyi")
    (spec,) = (resolve_policies if is_policy else resolve_trackers)([text])
    got = spec.params[key]
    assert got == value and type(got) is kind, (got, type(got))
    if isinstance(value, float):
        assert math.copysign(1.0, got) == 1.0  # -0.0 is spelled 0.0
    built = spec.make()
    assert getattr(built, key) == value and type(getattr(built, key)) is kind
    assert "None" not in json.dumps(built.get_params())  # None is null, never the text


def test_labels_use_the_canonical_values():
    (a, b) = resolve_trackers(["jmpd:n_particles=1e3,birth_rate=none",
                               "kfnn:birth_velocity_scale=2"])
    assert a.label == "jmpd(birth_rate=None,n_particles=1000)"
    assert b.label == "kfnn(birth_velocity_scale=2.0)"
    with pytest.raises(ConfigError, match="more than once"):
        resolve_trackers(["jmpd:n_particles=1000", "jmpd:n_particles=1000.0"])


def test_param_columns_keep_their_types():
    df = run_job(Job(short("default", 2), TrackerSpec("jmpd", {"n_particles": 50.0}), None,
                     None, 0))
    assert (df["status"] == "ok").all(), df["error"].iloc[0]
    assert df["param_n_particles"].dtype == np.int64 and (df["param_n_particles"] == 50).all()
    assert df["param_resample_threshold"].dtype == np.float64
    assert json.loads(df["tracker_params"].iloc[0])["n_particles"] == 50


# ----------------------------------------------------------------- Param itself
def test_param_bounds_and_kinds():
    p = Param(float, 0, 1, low_open=True)
    assert p.allowed() == "a number in (0, 1]"
    assert p.parse(1) == 1.0 and type(p.parse(1)) is float
    assert p.parse(np.float32(0.5)) == 0.5
    for bad in (0, 0.0, 1.0000001, math.inf, -math.inf, math.nan, True, "0.5", None):
        with pytest.raises(ValueError):
            p.parse(bad)
    i = Param(int, 1, 10, high_open=True)
    assert i.parse(np.int64(3)) == 3 and type(i.parse(np.int64(3))) is int
    assert i.parse(9.0) == 9 and type(i.parse(9.0)) is int
    for bad in (10, 0, 2.5, False, "3", math.nan):
        with pytest.raises(ValueError):
            i.parse(bad)
    b = Param(bool)
    assert b.parse(np.bool_(True)) is True
    for bad in (0, 1, "yes", "true", None):
        with pytest.raises(ValueError):
            b.parse(bad)
    c = Param(choices=("a", "none"))  # a choice called "none" stays a string
    assert c.parse("none") == "none" and c.parse("a") == "a"
    with pytest.raises(ValueError, match="one of a, none"):
        c.parse("A")
    n = Param(int, 0, allow_none=True, none="automatic")
    assert n.parse("None") is None and n.parse(None) is None
    assert n.allowed() == "an integer >= 0, or None (automatic)"
    with pytest.raises(TypeError):
        Param(bool, low=0)
    with pytest.raises(TypeError):
        Param(int, choices=("a",))


# ------------------------------------------------------- classes without declarations
class Undeclared(Tracker):
    """Written elsewhere, before declarations: values pass unchanged."""

    name = "test_undeclared"
    summary = "test only"

    def __init__(self, level: object = 1) -> None:
        self.level = level

    def reset(self, model, rng):
        self._n = model.grid.n_cells

    def predict(self):
        pass

    def cell_count_distribution(self):
        P = np.zeros((self._n, 2))
        P[:, 0] = 1.0
        return P

    def update(self, looks):
        pass

    def estimate(self):
        return Estimate.empty()


class Declared(Undeclared):
    name = "test_declared"
    parameters: ClassVar[dict[str, Param]] = {"level": Param(int, 0)}


class NewConstructor(Declared):
    """Inherits a declaration that does not fit its constructor: undeclared."""

    name = "test_new_constructor"

    def __init__(self, level: int = 1, extra: str = "x") -> None:
        self.level, self.extra = level, extra


class WrongDeclaration(Declared):
    name = "test_wrong_declaration"
    parameters: ClassVar[dict[str, Param]] = {"levle": Param(int, 0)}


def test_undeclared_values_pass_unchanged_and_names_are_still_checked():
    assert Undeclared.validate_params({"level": "anything"}) == {"level": "anything"}
    with pytest.raises(TypeError, match="no parameter"):
        Undeclared.validate_params({"lvl": 1})
    assert NewConstructor.declared_parameters() is None
    assert NewConstructor.validate_params({"level": -3, "extra": "y"}) == {
        "level": -3, "extra": "y"}
    with pytest.raises(ParameterError, match="level=-3"):
        Declared.validate_params({"level": -3})
    with pytest.raises(TypeError, match=r"undeclared: \['level'\].*constructor: \['levle'\]"):
        WrongDeclaration.validate_params({})


# ---------------------------------------------------------------------- seeding
class Draws(Undeclared):
    """Records the first draw of its generator; declared parameters."""

    name = "test_draws"
    parameters: ClassVar[dict[str, Param]] = {"size": Param(int, 1), "mode": Param(
        choices=("a", "b"))}
    first: ClassVar[list[float]] = []

    def __init__(self, size: int = 3, mode: str = "a") -> None:
        self.size, self.mode = size, mode

    def reset(self, model, rng):
        super().reset(model, rng)
        type(self).first.append(float(rng.random()))


class DrawsB(Draws):
    """Only the default of ``mode`` differs: the same implementation as ``Draws``."""

    name = "test_draws_b"
    defaults_only = True

    def __init__(self, size: int = 3, mode: str = "b") -> None:
        super().__init__(size=size, mode=mode)


class DrawsOther(Draws):
    """Same parameters, other code (not ``defaults_only``): its own stream."""

    name = "test_draws_other"


@pytest.fixture
def draws():
    classes = [Draws, DrawsB, DrawsOther]
    for cls in classes:
        register(cls)
    Draws.first = []
    yield Draws.first
    for cls in classes:
        unregister(cls.name)


def _first_draw(first: list[float], text: str, label: str | None = None) -> float:
    (spec,) = resolve_trackers([text])
    play(short("default", 1), spec.make(), 5, tracker_label=label or spec.label)
    return first[-1]


def test_equal_configurations_draw_equal_numbers_however_spelled(draws):
    base = _first_draw(draws, "test_draws")
    for text in ("test_draws:size=3", "test_draws:size=3.0", "test_draws:mode=a,size=3",
                 "test_draws_b:mode=a"):
        assert _first_draw(draws, text) == base, text
    assert _first_draw(draws, "test_draws", label="another label") == base  # labels: names
    b = _first_draw(draws, "test_draws_b")
    assert b == _first_draw(draws, "test_draws:mode=b") != base
    assert _first_draw(draws, "test_draws:size=4") != base
    assert _first_draw(draws, "test_draws_other") != base  # another implementation
    assert (Draws.implementation(), DrawsB.implementation(), DrawsOther.implementation()) == (
        "test_draws", "test_draws", "test_draws_other")


@pytest.mark.parametrize(("name", "cls"), ALL, ids=[n for n, _ in ALL])
def test_defaults_spelled_out_give_the_same_configuration(name, cls):
    base = cls.canonical_config({})
    assert json.loads(base)["params"].keys() == set(cls.param_names())
    for key, default in cls.param_defaults().items():
        assert cls.canonical_config({key: default}) == base, (name, key)
    assert cls.canonical_config(cls.param_defaults()) == base


def test_jmpd_ip_is_jmpd_with_the_ip_proposal():
    """``jmpd-ip`` changes only a default: it declares ``defaults_only`` and overrides
    nothing but the constructor, so sharing ``jmpd``'s identity is honest."""
    ip, jmpd = trackers.get_class("jmpd-ip"), trackers.get_class("jmpd")
    assert ip.defaults_only and ip.implementation() == jmpd.implementation() == "jmpd"
    own = {k for k, v in vars(ip).items() if callable(v) and not k.startswith("__")}
    assert own <= {"param_conflict"} and not any(
        k in vars(ip) for k in ("reset", "predict", "update", "estimate"))
    assert ip.canonical_config({}) == jmpd.canonical_config({"proposal": "ip"})
    assert jmpd.canonical_config({}) != jmpd.canonical_config({"n_particles": 2001})


def _rows(text: str, policy: str = "raster", n_steps: int = 6, seed: int = 2):
    (spec,) = resolve_trackers([text])
    (pol,) = resolve_policies([policy])
    df = run_job(Job(short("default", n_steps), spec, pol, 12, seed))
    assert (df["status"] == "ok").all(), df["error"].iloc[-1]
    return df.drop(columns=["tracker", "tracker_label", *TIMING_COLUMNS, "peak_rss_mb"])


@pytest.mark.parametrize("group", [
    ("jmpd-ip:n_particles=300", "jmpd:n_particles=300,proposal=ip",
     "jmpd-ip:proposal=ip,n_particles=300"),
    ("jmpd", "jmpd:n_particles=2000"),
    ("kfnn", "kfnn:lost_track_probability=0.1", "kfnn:gate_probability=0.9999"),
])
def test_equal_configurations_give_identical_rows(group, monkeypatch):
    policy = "renyi" if group[0].startswith("kfnn") else "random"
    first = _rows(group[0], policy)
    for text in group[1:]:
        other = _rows(text, policy)
        assert other.equals(first), text
    assert first["est_count"].notna().all()
    if group[0].startswith("jmpd"):  # the rows do follow the tracker's stream (KF-NN has none)
        seed_of = harness.tracker_seed
        monkeypatch.setattr(harness, "tracker_seed", lambda sc, seed, config: seed_of(
            sc, seed, config + " salted" if '"kind":"tracker"' in config else config))
        assert not _rows(group[0], policy).equals(first)

