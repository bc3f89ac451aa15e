"""Rules of scenario files (scenarios/spec.py) at their edges, each against the module
docstring's layout: open and closed bounds, booleans, names, the cell limit, the
defaults, the sensor's matrices, the file size limit and the byte-order mark."""

from __future__ import annotations

import copy

import pytest

from mttbench.scenarios import spec
from mttbench.scenarios.spec import MAX_FILE_BYTES, ScenarioError, from_dict, load, loads

BASE = {"name": "t", "n_steps": 4, "grid": {"nx": 3, "ny": 2},
        "dynamics": {"wna_intensity": 0.01},
        "targets": {"initial_states": [[0.5, 0.0, 0.5, 0.0]]},
        "sensor": {"kind": "rayleigh", "p_d": 0.5, "snr": 4.0}}
SUPER = {**BASE, "sensor": {"kind": "superposition", "h_matrix": [[1, 0, 0, 0], [0, 0, 1, 0]],
                            "r_matrix": [[1.0, 0.0], [0.0, 1.0]]}}


def _with(doc, section, **values):
    out = copy.deepcopy(doc)
    if section is None:
        out.update(values)
    else:
        out[section].update(values)
    return out


@pytest.mark.parametrize("section, key, value", [
    ("sensor", "p_d", 1.0), ("sensor", "p_d", 0.0), ("dynamics", "tau", 0.0),
    (None, "n_steps", True), ("grid", "nx", True), ("sensor", "looks_per_step", False),
    (None, "name", "two\nlines"), (None, "name", "tab\there"),
    ("targets", "initial_states", [[3.0, 0.0, 0.5, 0.0]]),  # x = nx * cell_size: outside
])
def test_values_outside_their_range_are_refused(section, key, value):
    with pytest.raises(ScenarioError, match=key.split("_")[0]):
        from_dict(_with(BASE, section, **{key: value}))


def test_the_defaults_of_the_layout():
    sc = from_dict(BASE)
    assert sc.model.birth_death.boundary == "reflect"
    assert sc.model.birth_death.birth_velocity_std == 0.1
    assert sc.model.sensor.looks_per_step == 6  # every cell of the 3 x 2 grid
    assert sc.model.dynamics.tau == 1.0 and sc.grid.cell_size == 1.0


def test_the_cell_limit_is_inclusive():
    big = _with(BASE, "grid", nx=2**27, ny=2**26)
    assert from_dict(big).grid.n_cells == 2**53 == spec.MAX_CELLS
    with pytest.raises(ScenarioError, match="2\\*\\*53"):
        from_dict(_with(BASE, "grid", nx=2**27 + 1, ny=2**26))


def test_the_noise_matrix_is_square_of_hs_rows_and_positive_definite():
    assert from_dict(SUPER).model.sensor.R.shape == (2, 2)
    three = _with(SUPER, "sensor", r_matrix=[[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    with pytest.raises(ScenarioError, match="r_matrix"):
        from_dict(three)
    singular = _with(SUPER, "sensor", r_matrix=[[1.0, 1.0], [1.0, 1.0]])
    with pytest.raises(ScenarioError, match="positive definite"):
        from_dict(singular)


def test_a_file_over_the_limit_is_refused_and_one_at_it_is_read(tmp_path):
    text = spec.dumps(from_dict(BASE))
    at = tmp_path / "at.toml"
    at.write_text(text + "#" * (MAX_FILE_BYTES - len(text.encode())))
    assert at.stat().st_size == MAX_FILE_BYTES and load(at).name == "t"
    over = tmp_path / "over.toml"
    over.write_text(text + "#" * (MAX_FILE_BYTES + 1 - len(text.encode())))
    with pytest.raises(ScenarioError, match="larger than"):
        load(over)


def test_text_with_a_byte_order_mark_is_read():
    text = spec.dumps(from_dict(BASE))
    assert loads("\ufeff" + text) == loads(text)
