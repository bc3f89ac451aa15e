"""The registry's entry-point plugins (trackers/registry.py ``load_plugins``), through
fake entry points of a fresh registry: a good plugin is registered under its name, a
broken one is kept with its one-line reason and never stops the others, a name already
registered is not replaced, and the group is read once per process."""

from __future__ import annotations

from importlib import metadata

import pytest

from mttbench.benchmarks.engine import policies
from mttbench.trackers import registry as registry_module
from mttbench.trackers.registry import Registry

GROUP = "mttbench.test-plugins"
POLICIES = "mttbench.benchmarks.engine.policies"


@pytest.fixture
def plugins(monkeypatch, tmp_path):
    """A fresh policy registry whose group holds the entry points a test sets, and a
    count of the reads of the group."""
    (tmp_path / "mttbench_rules_bad_plugin.py").write_text(
        'raise RuntimeError("first line of the reason\\nsecond line")\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    entries: list[metadata.EntryPoint] = []
    reads: list[str] = []

    def entry_points(*, group):
        reads.append(group)
        return [ep for ep in entries if ep.group == group]

    monkeypatch.setattr(registry_module.metadata, "entry_points", entry_points)

    def make(*pairs: tuple[str, str]) -> Registry:
        entries[:] = [metadata.EntryPoint(name, value, GROUP) for name, value in pairs]
        return Registry("policy", policies.Policy, GROUP, plural="policies")

    make.reads = reads
    return make


def test_a_good_plugin_is_registered_and_broken_ones_are_kept_with_their_reason(plugins):
    reg = plugins(("raster", f"{POLICIES}:Raster"),
                  ("wrong-name", f"{POLICIES}:Raster"),
                  ("not-a-policy", f"{POLICIES}:PolicyTerms"),
                  ("missing", "mttbench_rules_no_such_module:Thing"),
                  ("raises", "mttbench_rules_bad_plugin:Thing"),
                  ("oracle", f"{POLICIES}:Oracle"))
    assert reg.names() == ["oracle", "raster"]
    assert reg.get("raster") is policies.Raster
    assert reg.get("oracle") is policies.Oracle
    broken = reg.broken()
    assert sorted(broken) == ["missing", "not-a-policy", "raises", "wrong-name"]
    assert broken["wrong-name"] == (f"ValueError: {POLICIES}:Raster.name is 'raster', "
                                    "not 'wrong-name'")
    assert broken["not-a-policy"] == (f"TypeError: {POLICIES}:PolicyTerms is not a "
                                      "subclass of Policy")
    assert broken["missing"].startswith("ModuleNotFoundError: ")
    assert "mttbench_rules_no_such_module" in broken["missing"]
    # a multi-line reason is kept as its first line
    assert broken["raises"] == "RuntimeError: first line of the reason"
    with pytest.raises(KeyError, match="'raises' failed to load: RuntimeError: first line"):
        reg.get("raises")


def test_a_name_already_registered_is_not_replaced_and_the_group_is_read_once(plugins):
    reg = plugins(("random", f"{POLICIES}:Raster"), ("raster", f"{POLICIES}:Raster"))
    reg.register(policies.RandomCells)  # shipped under the plugin's name first
    assert reg.get("random") is policies.RandomCells
    assert reg.broken() == {}
    assert "raster" in reg and reg.names() == ["random", "raster"]
    assert plugins.reads == [GROUP]  # however many look-ups
