"""Rules of ``mttbench compare``'s helpers (``benchmarks/app/compare.py``) where a slip
shows: a manifest written before the status existed, and one that is JSON but not an
object; a tracker list whose first tracker uses the truth; a bare name with two settings;
seeds sorted but not consecutive; one policy that is not raster; the floor and the Bayes
grid among the registered trackers. Expected values written out by hand."""

from __future__ import annotations

import json

from mttbench.benchmarks.app import compare
from mttbench.benchmarks.engine.specs import PolicySpec, TrackerSpec


def test_a_manifest_without_status_is_a_finished_comparison(tmp_path):
    (tmp_path / "manifest.json").write_text(json.dumps({"command": ["mttbench"]}))
    assert compare.is_finished(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"status": "running"}))
    assert not compare.is_finished(tmp_path)


def test_a_manifest_that_is_not_an_object_is_none(tmp_path):
    (tmp_path / "manifest.json").write_text("[1, 2]")
    assert compare.read_manifest(tmp_path) is None
    assert not compare.is_finished(tmp_path)


def test_the_default_reference_never_uses_the_truth():
    specs = [TrackerSpec("truth-aided"), TrackerSpec("gpf"), TrackerSpec("null")]
    assert compare.default_reference(specs) == "gpf"
    assert compare.default_reference([TrackerSpec("truth-aided")]) is None
    specs = [TrackerSpec("gpf"), TrackerSpec("kfnn"), TrackerSpec("pmb")]
    assert compare.default_reference(specs) == "pmb"


def test_a_bare_reference_name_is_its_first_setting():
    specs = [TrackerSpec("jmpd", {"n_particles": 1000}), TrackerSpec("jmpd", {"n_particles": 250})]
    assert compare._resolve_reference("jmpd", specs) == specs[0].label


def test_seed_text_writes_a_range_only_for_consecutive_seeds():
    assert compare._seed_text(list(range(10))) == "0..9 (10 seeds)"
    assert compare._seed_text([1, 3, 5]) == "1, 3, 5"


def test_one_policy_other_than_raster_is_named_as_itself():
    assert compare._policy_setting([PolicySpec("raster")]).startswith("raster sweep")
    assert compare._policy_setting([PolicySpec("renyi")]).startswith(
        "renyi at each scenario's looks_per_step (every tracker chooses")


def test_the_default_trackers_hold_the_floor_but_not_the_bayes_grid():
    names = {t.split(":", 1)[0] for t in compare.default_tracker_texts()}
    assert "null" in names and "truth-aided" in names
    assert "grid-bayes" not in names
