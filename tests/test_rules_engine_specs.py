"""Rules of spec parsing and resolution (benchmarks/engine/specs.py), written out by hand:
value types, refused spellings, spec equality, suites' splits, repeated scenarios, empty
items and canonical values."""

from __future__ import annotations

import pytest

from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.specs import (
    TrackerSpec,
    parse_spec,
    parse_value,
    resolve_scenarios,
    resolve_suite,
    resolve_trackers,
    split_specs,
)
from mttbench.scenarios import envelope


def test_values_are_bool_then_int_then_float_then_text():
    got = [parse_value(t) for t in ("3", "-2", "1e3", "0.5", "TRUE", "false", "x1")]
    assert got == [3, -2, 1000.0, 0.5, True, False, "x1"]
    assert [type(v) for v in got] == [int, int, float, float, bool, bool, str]
    assert parse_spec("x:a=1,b=true,c=0.5,d=s", "tracker") == (
        "x", {"a": 1, "b": True, "c": 0.5, "d": "s"})
    assert type(parse_spec("x:a=1", "tracker")[1]["a"]) is int


@pytest.mark.parametrize("text", ["x:a=1\tb=2", "x:a=\t1", "x:=1", "x:a=1,=2"])
def test_whitespace_and_empty_keys_are_refused(text):
    with pytest.raises(ValueError):
        parse_spec(text, "tracker")


def test_a_bare_key_value_continues_only_a_spec_with_parameters():
    assert split_specs(["renyi:alpha=0.5", "repeats=true", "raster"]) == [
        "renyi:alpha=0.5,repeats=true", "raster"]
    assert split_specs(["raster", "alpha=1"]) == ["raster", "alpha=1"]


def test_specs_with_the_same_parameters_in_any_order_are_equal():
    a, b = TrackerSpec("x", {"a": 1, "b": 2}), TrackerSpec("x", {"b": 2, "a": 1})
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
    assert TrackerSpec("x", {"a": True}) != TrackerSpec("x", {"a": 1})


def test_a_suites_split_is_its_share_of_the_points():
    every = resolve_suite("envelope")
    train, held = resolve_suite("envelope:train"), resolve_suite("envelope:held")
    assert train == envelope.point_names("train") and held == envelope.point_names("held")
    assert train and held and sorted(train + held) == sorted(every)


def test_a_scenario_named_twice_is_refused():
    with pytest.raises(ConfigError, match="more than once"):
        resolve_scenarios(["single-clean", "default", "single-clean"])


@pytest.mark.parametrize("text", ["null,,null", ",null", "null,"])
def test_an_empty_item_anywhere_is_refused(text):
    with pytest.raises(ConfigError, match="empty item"):
        resolve_trackers([text])


def test_validated_specs_hold_canonical_values():
    (spec,) = resolve_trackers(["jmpd-ap:n_particles=1e3"])
    assert spec.params["n_particles"] == 1000 and type(spec.params["n_particles"]) is int
    assert spec.label == "jmpd-ap(n_particles=1000)"
    direct = TrackerSpec.parse("jmpd-ap:n_particles=1e3").validated()
    assert type(direct.params["n_particles"]) is int
