"""Scenario files: every preset loads and round-trips; bad files are refused clearly."""

from __future__ import annotations

import re

import pytest

from mttbench import scenarios
from mttbench.scenarios import ScenarioError
from mttbench.scenarios.model import RayleighGridSensor
from mttbench.scenarios.spec import dumps, loads

GOOD = """
description = "test"
n_steps = 10
[grid]
nx = 4
ny = 3
[dynamics]
wna_intensity = 0.001
[targets]
initial_states = [[1.5, 0.1, 1.5, 0.0]]
[sensor]
kind = "rayleigh"
p_d = 0.5
snr = 10.0
looks_per_step = 5
"""


def test_required_presets_exist():
    assert {"paper", "default", "crossing", "births", "large"} <= set(scenarios.preset_names())


@pytest.mark.parametrize("name", scenarios.preset_names())
def test_preset_round_trips(name):
    sc = scenarios.get(name)
    assert sc.name == name
    assert sc.description
    assert loads(dumps(sc)) == sc


def test_paper_preset_is_literal():
    sc = scenarios.get("paper")
    assert (sc.grid.nx, sc.grid.ny, sc.grid.cell_size) == (12, 12, 1.0)
    assert [sc.model.dynamics.Q[i, i] for i in range(4)] == [20.0, 0.2, 20.0, 0.2]
    assert len(sc.model.birth_death.initial_states) == 3


def test_presets_have_realistic_false_alarms():
    for name in ("paper", "default", "crossing", "births", "large"):
        sensor = scenarios.get(name).model.sensor
        assert isinstance(sensor, RayleighGridSensor)
        assert 1e-5 < sensor.p_f < 1e-2


def test_snr_db_converted_once():
    sc = loads(GOOD.replace("snr = 10.0", "snr_db = 10.0"), default_name="x")
    assert sc.model.sensor.snr == pytest.approx(10.0)


def test_good_file_loads_from_path(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(GOOD)
    sc = scenarios.get(str(path))
    assert sc.name == "mine" and sc.grid.n_cells == 12


BAD = [
    # (replacement of a line of GOOD, text the error must contain)
    ("nx = 4", "nx = \"four\"", r"\[grid\]\.nx = 'four'.*integer >= 1"),
    ("nx = 4", "nx = 0", r"\[grid\]\.nx = 0.*integer >= 1"),
    ("p_d = 0.5", "p_d = -0.1", r"\[sensor\]\.p_d = -0\.1.*> 0 and < 1"),
    ("p_d = 0.5", "p_d = 1.0", r"\[sensor\]\.p_d = 1\.0"),
    ("p_d = 0.5", "p_d = 0.5\ncolour = \"red\"", r"unknown key.*colour.*allowed"),
    ("n_steps = 10", "", r"missing field n_steps"),
    ("kind = \"rayleigh\"", "kind = \"sonar\"", r"\[sensor\]\.kind = 'sonar'.*rayleigh"),
    ("wna_intensity = 0.001", "", r"exactly one of q_matrix and wna_intensity"),
    ("wna_intensity = 0.001", "wna_intensity = -1.0", r"wna_intensity = -1\.0.*>= 0"),
    ("initial_states = [[1.5, 0.1, 1.5, 0.0]]", "initial_states = [[1.5, 0.1, 1.5]]",
     r"initial_states.*4 array"),
    ("initial_states = [[1.5, 0.1, 1.5, 0.0]]", "initial_states = [[9.5, 0.1, 1.5, 0.0]]",
     r"initial_states.*inside the workspace"),
    ("[targets]", "[targets]\nsurvival_probability = 1.5", r"survival_probability = 1\.5.*<= 1"),
    ("[targets]", "[targets]\nboundary = \"wrap\"", r"boundary = 'wrap'.*reflect"),
    ("looks_per_step = 5", "looks_per_step = 2.5", r"looks_per_step = 2\.5.*integer"),
    ("[grid]", "[gird]\nnx = 1\n[grid]", r"unknown top-level key.*gird"),
    ("snr = 10.0", "snr = true", r"snr = True.*number"),
    # overflow and underflow: one line instead of an OverflowError or a p_f of 0
    ("snr = 10.0", "snr_db = 4000.0", r"snr_db = 4000\.0.*<= 30\.09 with p_d = 0\.5"),
    ("snr = 10.0", "snr = 2000.0", r"snr = 2000\.0.*<= 1021 with p_d = 0\.5.*underflows"),
    ("snr = 10.0", "snr_db = -4000.0", r"snr_db = -4000\.0.*underflows to 0"),
    ("ny = 3", "ny = 3\ncell_size = 1e308", r"cell_size = 1e\+308.*must be finite"),
    ("wna_intensity = 0.001", "tau = 1e200\nwna_intensity = 0.001",
     r"tau = 1e\+200.*overflows"),
    ("description = \"test\"", "name = \"a\\tb\"", r"name = 'a\\tb'.*one line"),
    ("wna_intensity = 0.001",
     "q_matrix = [[1.0, 2.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], "
     "[0.0, 0.0, 0.0, 1.0]]", r"q_matrix.*symmetric positive semi-definite"),
]


@pytest.mark.parametrize(("old", "new", "message"), BAD, ids=[b[2][:30] for b in BAD])
def test_bad_file_refused_with_clear_message(tmp_path, old, new, message):
    assert old in GOOD
    path = tmp_path / "bad.toml"
    path.write_text(GOOD.replace(old, new, 1))
    with pytest.raises(ScenarioError) as err:
        scenarios.load(path)
    assert re.search(message, str(err.value)), str(err.value)
    assert str(path) in str(err.value)


def test_not_toml_and_unknown_preset():
    with pytest.raises(ScenarioError, match="not valid TOML"):
        loads("n_steps = = 3")
    with pytest.raises(ScenarioError, match="unknown scenario 'nope'.*default"):
        scenarios.get("nope")


def test_snr_limits_are_the_float_limits():
    """At the printed bound p_f = p_d ** (1 + snr) is still a normal double."""
    import math
    import sys
    for p_d in (0.1, 0.5, 0.9, 0.999):
        snr_max = math.log(sys.float_info.min) / math.log(p_d) - 1.0
        sc = loads(GOOD.replace("snr = 10.0", f"snr = {snr_max!r}")
                   .replace("p_d = 0.5", f"p_d = {p_d}"), default_name="x")
        assert sc.model.sensor.p_f >= sys.float_info.min * (1 - 1e-9)
        with pytest.raises(ScenarioError, match="underflows"):
            loads(GOOD.replace("snr = 10.0", f"snr = {snr_max * 1.001!r}")
                  .replace("p_d = 0.5", f"p_d = {p_d}"), default_name="x")


def test_byte_order_mark_is_accepted(tmp_path):
    path = tmp_path / "bom.toml"
    path.write_text(GOOD, encoding="utf-8-sig")
    assert path.read_bytes().startswith(b"\xef\xbb\xbf")
    assert scenarios.load(path) == loads(GOOD, default_name="bom")
    assert loads("\ufeff" + GOOD, default_name="bom") == loads(GOOD, default_name="bom")


def test_unreadable_files_are_scenario_errors_naming_the_file_once(tmp_path):
    latin = tmp_path / "latin.toml"
    latin.write_bytes(GOOD.replace('"test"', '"caf\xe9"').encode("latin-1"))
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    for path, message in ((latin, r"not UTF-8 text \(byte \d+"),
                          (folder, r"cannot read the file: Is a directory"),
                          (tmp_path / "none.toml", r"cannot read the file: No such file")):
        with pytest.raises(ScenarioError, match=message) as err:
            scenarios.load(path)
        assert str(err.value).count(str(path)) == 1, str(err.value)
        # get() is what the command line calls: it names the path itself, so the error
        # does not repeat it
        with pytest.raises(ScenarioError, match=message) as err:
            scenarios.get(str(path))
        assert str(path) not in str(err.value)
