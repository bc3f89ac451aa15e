"""Scenario files and the simulator's inputs, behaviours no earlier test reached."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest

from mttbench.scenarios import spec

MEM = Path("/proc/self/mem")


def _read_error(path: Path) -> str | None:
    """The reason reading ``path`` fails, None if it reads."""
    try:
        with path.open("rb") as f:
            f.read(16)
    except OSError as exc:
        return exc.strerror or str(exc)
    return None


@pytest.mark.skipif(not (MEM.exists() and stat.S_ISREG(os.stat(MEM).st_mode)
                         and _read_error(MEM)),
                    reason="needs a regular file whose read fails (Linux /proc/self/mem)")
def test_a_regular_file_that_fails_to_read_is_a_scenario_error():
    """A regular file whose read fails after its stat (an I/O error) is refused with one
    line naming the file and the reason, like any unreadable scenario file."""
    with pytest.raises(spec.ScenarioError) as err:
        spec.load(MEM)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(f"{MEM}: cannot read the file: ")
    assert msg.endswith(_read_error(MEM))  # the reader's own reason


def _with(doc: dict, section: str, key: str, value) -> dict:
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in doc.items()}
    out[section][key] = value
    return out


@pytest.mark.parametrize("preset, section, key", [
    ("default", "targets", "initial_states"),
    ("superposition", "sensor", "h_matrix"),
    ("superposition", "sensor", "r_matrix"),
])
@pytest.mark.parametrize("change", ["longer", "shorter"])
def test_a_matrix_row_of_the_wrong_length_is_refused_naming_the_field(preset, section, key, change):
    """Each matrix field's rows have the documented number of columns (4 for the states
    and h, m for r); a row one number longer or shorter is refused with the field named,
    whichever row it is."""
    doc = spec.to_dict(spec.get(preset))
    rows = [list(r) for r in doc[section][key]]
    assert rows, "the preset has rows to change"
    for i in range(len(rows)):
        bad = [list(r) for r in rows]
        bad[i] = bad[i] + [0.0] if change == "longer" else bad[i][:-1]
        with pytest.raises(spec.ScenarioError, match=rf"\[{section}\]\.{key}"):
            spec.from_dict(_with(doc, section, key, bad))
    assert spec.from_dict(_with(doc, section, key, rows)) == spec.get(preset)


def test_the_counter_based_uniforms_are_the_generators_numbers_at_those_positions():
    """``pcg64_uniforms(state, inc, n)`` is draw ``n`` of ``Generator.random`` on a PCG64
    in that state: the reference draws the whole prefix with numpy, for positions
    spanning several 16-bit digits of the jump."""
    from mttbench.scenarios.simulator import pcg64_uniforms

    for seed in (0, 1, 12345):
        bits = np.random.PCG64(seed)
        st = bits.state["state"]
        ref = np.random.Generator(np.random.PCG64(seed)).random(70_000)
        pos = np.array([0, 1, 2, 3, 255, 65_535, 65_536, 65_537, 69_999, 4_095, 31])
        np.testing.assert_array_equal(pcg64_uniforms(st["state"], st["inc"], pos), ref[pos])
