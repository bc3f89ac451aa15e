"""``compare``'s Bayes reference for the scenarios that have none stored
(benchmarks/app/compare.py ``_compute_missing_bayes``), with the store's look-up and the
ladder's run replaced by recorders: only the scenarios without a stored reference are
run, per policy, each policy in its own ladder folder (``ladder`` for raster,
``ladder-<label with other characters as _>`` for the others), stored in the last
store, resumable."""

from __future__ import annotations

from pathlib import Path

from mttbench.benchmarks.app import bayes, compare
from mttbench.benchmarks.engine.specs import PolicySpec
from mttbench.scenarios import get as get_scenario


def test_only_the_missing_references_run_each_policy_in_its_folder(monkeypatch, tmp_path,
                                                                  capsys):
    scs = [get_scenario("single-clean"), get_scenario("default"), get_scenario("crossing")]
    stored = {("default", "raster"), ("single-clean", "renyi(alpha=0.5)")}
    calls = []
    looked = []
    monkeypatch.setattr(bayes, "find", lambda sc, pol, looks, seeds, c, p, stores: (
        looked.append(list(stores)) or ("stored" if (sc.name, pol.label) in stored else None)))
    monkeypatch.setattr(bayes, "run_command", lambda missing, seeds, ladder, pol, looks,
                        folder, store, **kw: calls.append(
                            ([s.name for s in missing], pol.label, folder, store, kw)))
    pols = [PolicySpec("raster"), PolicySpec("renyi", {"alpha": 0.5})]
    stores = [tmp_path / "a", tmp_path / "b"]
    compare._compute_missing_bayes(scs, [0, 1], tmp_path, stores, bayes.Ladder(), 1, False,
                                   2.0, 2.0, None, pols)
    assert [(names, label, Path(folder).relative_to(tmp_path), store)
            for names, label, folder, store, _ in calls] == [
        (["single-clean", "crossing"], "raster", Path("bayes/ladder"), stores[-1]),
        (["default", "crossing"], "renyi(alpha=0.5)", Path("bayes/ladder-renyi_alpha_0.5_"),
         stores[-1])]
    assert looked and all(s == stores for s in looked)  # every store is looked in
    assert all(kw["resume"] and kw["c"] == 2.0 and kw["workers"] == 1 for *_, kw in calls)
    err = capsys.readouterr().err
    assert "computing the bayes reference of single-clean, crossing (docs/bayes.md)" in err
    assert "of default, crossing under renyi(alpha=0.5)" in err
    # everything stored: nothing runs
    calls.clear()
    monkeypatch.setattr(bayes, "find", lambda *a: "stored")
    compare._compute_missing_bayes(scs, [0], tmp_path, stores, bayes.Ladder(), 1, False,
                                   2.0, 2.0, None, pols)
    assert calls == []
