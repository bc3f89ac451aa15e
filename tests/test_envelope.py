"""The operating envelope (scenarios/envelope/): every point a valid scenario that round-trips,
the points span the envelope's ranges (read from the models, not the names), the train and
held splits, and ``--suite envelope`` on the command line."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.specs import resolve_scenarios, resolve_suite
from mttbench.scenarios import envelope
from mttbench.scenarios.model import RayleighGridSensor
from mttbench.scenarios.spec import dumps, from_dict, loads, to_dict

POINTS = envelope.points()
IDS = [p.name for p in POINTS]


def p_f(sc) -> float:
    s = sc.model.sensor
    return s.p_d ** (1.0 + s.snr)


def density(sc) -> float:
    """(initial + expected births) / cells."""
    bd = sc.model.birth_death
    targets = len(bd.initial_states) + bd.n_random_initial + bd.birth_rate * (sc.n_steps - 1)
    return targets / sc.grid.n_cells


def speeds(sc) -> list[float]:
    """Mean speed of a random target (velocity N(0, std^2) per axis: std sqrt(pi/2)) when
    random targets appear, and the speed of each explicit initial target."""
    bd = sc.model.birth_death
    out = [math.hypot(s[1], s[3]) for s in bd.initial_states]
    if bd.n_random_initial or bd.birth_rate:
        out.append(bd.birth_velocity_std * math.sqrt(math.pi / 2))
    return out


def look_fraction(sc) -> float:
    return sc.model.sensor.looks_per_step / sc.grid.n_cells


@pytest.mark.parametrize("point", POINTS, ids=IDS)
def test_point_validates_and_round_trips(point):
    sc = point.scenario
    assert isinstance(sc.model.sensor, RayleighGridSensor)
    assert from_dict(to_dict(sc)) == sc
    assert loads(dumps(sc)) == sc
    assert sc.name.startswith("env-") and sc.name.isprintable() and sc.description
    assert "\n" not in sc.description
    assert point.axis in envelope.AXES and point.split in envelope.SPLITS
    # cheap: small grids, short runs
    assert 12 <= sc.grid.nx <= 24 and 12 <= sc.grid.ny <= 24
    assert 40 <= sc.n_steps <= 60


def test_template_is_the_centre_and_points_differ_from_it():
    centre = envelope.get_point("env-centre")
    template = envelope.template()
    assert (template.name, template.model, template.n_steps) == \
        (centre.name, centre.model, centre.n_steps)
    for p in POINTS:
        if p.axis != "centre":
            assert p.overrides and p.scenario.model != centre.model, p.name


def test_names_unique_and_resolvable():
    assert len(set(IDS)) == len(IDS) and 15 <= len(IDS) <= 25
    assert not set(IDS) & set(scenarios.preset_names())
    assert [sc.name for sc in resolve_scenarios(["env-pf-0.3", "default"])] == \
        ["env-pf-0.3", "default"]
    with pytest.raises(scenarios.ScenarioError, match="env-nowhere"):
        envelope.get_point("env-nowhere")


def test_points_span_the_envelope():
    scs = [p.scenario for p in POINTS]
    pf = [p_f(sc) for sc in scs]
    assert min(pf) <= 1e-4 and max(pf) >= 0.3 * (1 - 1e-3)
    dens = [density(sc) for sc in scs]
    assert min(dens) <= 0.002 and max(dens) >= 0.06
    sp = [v for sc in scs for v in speeds(sc)]
    assert min(sp) <= 0.05 and max(sp) >= 0.4
    snr = [sc.model.sensor.snr for sc in scs]
    p_d = [sc.model.sensor.p_d for sc in scs]
    assert min(snr) <= 3 and max(snr) >= 20 and min(p_d) <= 0.5 and max(p_d) >= 0.9
    looks = [look_fraction(sc) for sc in scs]
    assert min(looks) <= 0.1 and max(looks) >= 1.0
    bds = [sc.model.birth_death for sc in scs]
    assert any(b.birth_rate == 0 and b.survival_probability == 1 for b in bds)  # fixed count
    assert any(b.birth_rate > 0 for b in bds) and any(b.survival_probability < 1 for b in bds)
    assert {b.boundary for b in bds} == {"reflect", "die"}


@pytest.mark.parametrize("point", POINTS, ids=IDS)
def test_manoeuvre_noise_matches_speed(point):
    """wna_intensity = speed^2 / 100 (velocity noise a tenth of the speed per step)."""
    sc = point.scenario
    (speed,) = speeds(sc)
    assert sc.model.dynamics.wna_intensity == pytest.approx(speed**2 / 100, rel=0.02)


def test_each_axis_is_covered():
    by_axis = {}
    for p in POINTS:
        by_axis.setdefault(p.axis, []).append(p.name)
    assert set(by_axis) == set(envelope.AXES)
    assert by_axis["centre"] == ["env-centre"]


def test_train_and_held_splits():
    train, held = envelope.point_names("train"), envelope.point_names("held")
    assert train and held and not set(train) & set(held)
    assert sorted(train + held) == sorted(IDS)
    assert 0.25 <= len(held) / len(IDS) <= 0.45  # about a third held apart
    assert "env-centre" in train
    assert all(p.split == "held" for p in POINTS if p.axis == "corner")
    held_axes = {p.axis for p in POINTS if p.split == "held"}
    assert len(held_axes - {"corner"}) >= 4  # spread over the axes
    assert [sc.name for sc in envelope.envelope_points("held")] == held
    with pytest.raises(scenarios.ScenarioError, match="split"):
        envelope.points("test")


def test_resolve_suite():
    assert resolve_suite("envelope") == IDS
    assert resolve_suite("envelope:held") == envelope.point_names("held")
    assert resolve_suite("envelope:train") == envelope.point_names("train")
    for bad in ("nope", "envelope:test", "envelope:", ""):
        with pytest.raises(ConfigError, match="suite"):
            resolve_suite(bad)


def test_run_suite_smoke(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    rc = main(["run", "--suite", "envelope:held", "--trackers", "null", "--seeds", "1",
               "--steps", "2", "--workers", "1", "--out", "out", "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    df = pd.read_parquet(tmp_path / "out" / "results.parquet")
    held = envelope.envelope_points("held")
    assert set(df["scenario"]) == {sc.name for sc in held}
    assert len(df) == 2 * len(held)
    budget = {sc.name: sc.model.sensor.looks_per_step for sc in held}
    assert (df["looks_per_step"] == df["scenario"].map(budget)).all()  # each point's own


@pytest.mark.parametrize("argv", [
    ["run", "--suite", "nope", "--trackers", "null"],
    ["run", "--suite", "envelope:test", "--trackers", "null"],
    ["compare", "--suite", "nope", "--trackers", "null"],
])
def test_bad_suite_refused_with_one_line(argv, tmp_path, capsys):
    assert main([*argv, "--out", str(tmp_path / "never"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    assert err.startswith("mttbench") and "suite" in err and argv[2] in err, err
    assert not (tmp_path / "never").exists()


def test_suite_and_scenarios_exclusive(capsys):
    assert main(["run", "--suite", "envelope", "--scenarios", "default",
                 "--trackers", "null"]) == 2
    assert "not allowed with" in capsys.readouterr().err
