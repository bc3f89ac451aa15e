"""Scenario specifications: TOML files validated on load, dumped back losslessly.

A scenario is a :class:`~scenarios.model.TrackingModel` (what a tracker may know)
plus what only the simulator knows: the initial targets, the number of steps,
a name and a one-line description. Presets live in ``scenarios/presets/*.toml``.

File layout (every key is checked; unknown keys are refused)::

    name = "default"              # optional in the file: defaults to the file stem
    description = "one line"
    n_steps = 100

    [grid]      nx, ny (int >= 1), cell_size (> 0, default 1.0)
    [dynamics]  tau (> 0), and exactly one of
                q_matrix (4x4 symmetric PSD) or wna_intensity (>= 0)
    [targets]   initial_states ([[px, vx, py, vy], ...]), n_random_initial,
                survival_probability, birth_rate, birth_velocity_std,
                boundary ("reflect" | "die")
    [sensor]    kind = "rayleigh": p_d, snr (linear) or snr_db, looks_per_step
                kind = "superposition": h_matrix (m x 4), r_matrix (m x m)
    [[occlusion]]  optional, any number (rayleigh sensor only): cells not to be looked at,
                x = [first, last] columns, y = [first, last] rows (cell indices,
                inclusive, inside the grid), steps = [first, last] (inclusive, 0-based,
                < n_steps), velocity = [vx, vy] (cells per step, default [0, 0]:
                a moving rectangle is shifted by whole cells, floor(v t) after t
                steps, and wraps around the grid's edges; |vx| < nx, |vy| < ny);
                see scenarios.model.Occlusion

Files are UTF-8 (a byte-order mark is accepted), regular files of at most 1 MiB (a
FIFO or a device is refused unopened). Beyond the per-field ranges, values whose
arithmetic overflows are refused: ``nx * ny <= 2**53`` cells, the workspace
``nx * cell_size``, the entries of ``Q`` and ``F`` and the velocities at most ``1e100``
(their squares stay finite), ``snr_db`` must give a finite linear ``snr``, and the false-alarm
probability ``p_f = p_d ** (1 + snr)`` must not underflow to 0 (``snr <= log(tiny) /
log(p_d) - 1`` with ``tiny`` the smallest normal double, e.g. ``snr <= 1021`` at
``p_d = 0.5``). Names are one line: no control characters.
"""

from __future__ import annotations

import math
import stat
import sys
import tomllib
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from .model import (
    BirthDeath,
    Dynamics,
    Grid,
    Occlusion,
    RayleighGridSensor,
    SuperpositionSensor,
    TrackingModel,
    Visibility,
)

#: the most cells of a grid (flat cell indices stay exact in int64 and float64)
MAX_CELLS = 2**53
#: the largest workspace side, process noise entry and velocity: their squares and the
#: covariances built from them stay finite
MAX_MAGNITUDE = 1e100


class ScenarioError(ValueError):
    """A scenario file or dictionary that cannot be accepted; the message says why."""


@dataclass(frozen=True)
class Scenario:
    """A named, fully specified scenario (model plus initial truth and length)."""

    name: str
    description: str
    n_steps: int
    model: TrackingModel

    @property
    def grid(self) -> Grid:
        return self.model.grid


# ------------------------------------------------------------------ validation kit
def _fail(where: str, value: Any, allowed: str) -> ScenarioError:
    return ScenarioError(f"{where} = {value!r} is not allowed: expected {allowed}")


def _number(where: str, v: Any, *, lo: float | None = None, hi: float | None = None,
            lo_open: bool = False, hi_open: bool = False, integer: bool = False) -> float:
    kind = "an integer" if integer else "a number"
    ok_type = isinstance(v, int) if integer else isinstance(v, int | float)
    lo_txt = "" if lo is None else (f" > {lo}" if lo_open else f" >= {lo}")
    hi_txt = "" if hi is None else (f" < {hi}" if hi_open else f" <= {hi}")
    allowed = kind + (lo_txt + (" and" if lo_txt and hi_txt else "") + hi_txt)
    if isinstance(v, bool) or not ok_type or not math.isfinite(v):
        raise _fail(where, v, allowed)
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise _fail(where, v, allowed)
    if hi is not None and (v >= hi if hi_open else v > hi):
        raise _fail(where, v, allowed)
    return int(v) if integer else float(v)


def _matrix(where: str, v: Any, rows: int | None, cols: int) -> tuple[tuple[float, ...], ...]:
    shape = f"a {rows or 'm'} x {cols} array of numbers"
    if not isinstance(v, list) or not v or (rows is not None and len(v) != rows):
        raise _fail(where, v, shape)
    out = []
    for r in v:
        if not isinstance(r, list) or len(r) != cols:
            raise _fail(where, v, shape)
        out.append(tuple(_number(where, x) for x in r))
    return tuple(out)


def _section(data: dict, name: str, allowed: set[str], required: set[str]) -> dict:
    if name not in data:
        raise ScenarioError(f"missing section [{name}]")
    sec = data[name]
    if not isinstance(sec, dict):
        raise ScenarioError(f"[{name}] must be a table, got {sec!r}")
    unknown = set(sec) - allowed
    if unknown:
        raise ScenarioError(
            f"unknown key(s) {sorted(unknown)} in [{name}]: allowed keys are {sorted(allowed)}"
        )
    missing = required - set(sec)
    if missing:
        raise ScenarioError(f"missing field(s) {sorted(missing)} in [{name}]")
    return sec


def _psd(where: str, m: tuple[tuple[float, ...], ...]) -> None:
    a = np.array(m)
    if not np.allclose(a, a.T) or np.linalg.eigvalsh(a).min() < -1e-12:
        raise _fail(where, [list(r) for r in m], "a symmetric positive semi-definite matrix")


# ------------------------------------------------------------------------ parsing
_TOP = {"name", "description", "n_steps", "grid", "dynamics", "targets", "sensor",
        "occlusion"}
_OCCLUSION_KEYS = {"x", "y", "steps", "velocity"}


def _index_pair(where: str, v: Any, upper: int, what: str) -> tuple[int, int]:
    """``[first, last]``: two integers with ``0 <= first <= last < upper``."""
    allowed = f"two {what} [first, last] with 0 <= first <= last < {upper}"
    if (not isinstance(v, list) or len(v) != 2
            or not all(isinstance(i, int) and not isinstance(i, bool) for i in v)
            or not 0 <= v[0] <= v[1] < upper):
        raise _fail(where, v, allowed)
    return int(v[0]), int(v[1])


def _occlusions(data: Any, grid: Grid, n_steps: int) -> tuple[Occlusion, ...]:
    """The ``[[occlusion]]`` tables, each checked (see the module docstring)."""
    if not isinstance(data, list):
        raise ScenarioError(f"occlusion must be an array of tables ([[occlusion]]), got "
                            f"{data!r}")
    out = []
    for i, o in enumerate(data, start=1):
        where = f"[[occlusion]] #{i}"
        if not isinstance(o, dict):
            raise ScenarioError(f"{where} must be a table, got {o!r}")
        unknown = set(o) - _OCCLUSION_KEYS
        if unknown:
            raise ScenarioError(f"unknown key(s) {sorted(unknown)} in {where}: allowed keys "
                                f"are {sorted(_OCCLUSION_KEYS)}")
        missing = {"x", "y", "steps"} - set(o)
        if missing:
            raise ScenarioError(f"missing field(s) {sorted(missing)} in {where}")
        x = _index_pair(f"{where}.x", o["x"], grid.nx, "column indices")
        y = _index_pair(f"{where}.y", o["y"], grid.ny, "row indices")
        steps = _index_pair(f"{where}.steps", o["steps"], n_steps, "steps")
        v = o.get("velocity", [0.0, 0.0])
        if (not isinstance(v, list) or len(v) != 2
                or not all(isinstance(i, int | float) and not isinstance(i, bool)
                           and math.isfinite(i) for i in v)
                or abs(v[0]) >= grid.nx or abs(v[1]) >= grid.ny):
            raise _fail(f"{where}.velocity", v, f"two numbers [vx, vy] (cells per step) "
                        f"with |vx| < {grid.nx} and |vy| < {grid.ny}")
        out.append(Occlusion(x=x, y=y, steps=steps, velocity=(float(v[0]), float(v[1]))))
    return tuple(out)


def from_dict(data: dict, *, default_name: str | None = None) -> Scenario:
    """Validate a parsed TOML document and build the :class:`Scenario`.

    Raises :class:`ScenarioError` naming the field, the value and what is allowed.
    """
    unknown = set(data) - _TOP
    if unknown:
        raise ScenarioError(f"unknown top-level key(s) {sorted(unknown)}: allowed {sorted(_TOP)}")
    name = data.get("name", default_name)
    if not isinstance(name, str) or not name.strip() or not name.isprintable():
        raise _fail("name", name, "a non-empty string of printable characters (one line)")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise _fail("description", description, "a string")
    if "n_steps" not in data:
        raise ScenarioError("missing field n_steps")
    n_steps = _number("n_steps", data["n_steps"], lo=1, integer=True)

    g = _section(data, "grid", {"nx", "ny", "cell_size"}, {"nx", "ny"})
    grid = Grid(
        nx=_number("[grid].nx", g["nx"], lo=1, integer=True),
        ny=_number("[grid].ny", g["ny"], lo=1, integer=True),
        cell_size=_number("[grid].cell_size", g.get("cell_size", 1.0), lo=0, lo_open=True),
    )
    if grid.nx * grid.ny > MAX_CELLS:
        raise ScenarioError(f"[grid] nx = {grid.nx}, ny = {grid.ny} is not allowed: expected "
                            f"nx * ny <= {MAX_CELLS} (2**53) cells")
    if not all(math.isfinite(v) and v <= MAX_MAGNITUDE for v in grid.extent):
        raise ScenarioError(f"[grid] nx = {grid.nx}, ny = {grid.ny}, cell_size = "
                            f"{grid.cell_size!r} is not allowed: the workspace nx * cell_size "
                            f"by ny * cell_size must be finite and at most {MAX_MAGNITUDE:g} "
                            "(squared distances stay finite)")

    d = _section(data, "dynamics", {"tau", "q_matrix", "wna_intensity"}, set())
    tau = _number("[dynamics].tau", d.get("tau", 1.0), lo=0, lo_open=True)
    if ("q_matrix" in d) == ("wna_intensity" in d):
        raise ScenarioError("[dynamics] needs exactly one of q_matrix and wna_intensity")
    if "q_matrix" in d:
        q = _matrix("[dynamics].q_matrix", d["q_matrix"], 4, 4)
        _psd("[dynamics].q_matrix", q)
        dynamics = Dynamics(tau=tau, q_matrix=q)
    else:
        dynamics = Dynamics(tau=tau, wna_intensity=_number("[dynamics].wna_intensity",
                                                           d["wna_intensity"], lo=0))
    try:
        finite = bool(np.isfinite(dynamics.Q).all() and np.isfinite(dynamics.F).all())
    except OverflowError:
        finite = False
    if finite:
        finite = bool(np.abs(dynamics.Q).max() <= MAX_MAGNITUDE
                      and np.abs(dynamics.F).max() <= MAX_MAGNITUDE)
    if not finite:
        raise ScenarioError(f"[dynamics] tau = {tau!r} is not allowed with this noise: the "
                            f"process noise Q overflows or exceeds {MAX_MAGNITUDE:g} (expected "
                            "tau and the noise small enough for covariances to stay finite)")

    t = _section(
        data,
        "targets",
        {"initial_states", "n_random_initial", "survival_probability", "birth_rate",
         "birth_velocity_std", "boundary"},
        set(),
    )
    states = t.get("initial_states", [])
    initial = _matrix("[targets].initial_states", states, None, 4) if states else ()
    width, height = grid.extent
    for s in initial:
        if not (0 <= s[0] < width and 0 <= s[2] < height):
            raise _fail("[targets].initial_states", list(s),
                        f"positions inside the workspace [0, {width}) x [0, {height})")
        if max(abs(s[1]), abs(s[3])) > MAX_MAGNITUDE:
            raise _fail("[targets].initial_states", list(s),
                        f"velocities of at most {MAX_MAGNITUDE:g} in magnitude")
    boundary = t.get("boundary", "reflect")
    if boundary not in ("reflect", "die"):
        raise _fail("[targets].boundary", boundary, 'one of "reflect", "die"')
    birth = BirthDeath(
        initial_states=initial,  # type: ignore[arg-type]
        n_random_initial=_number("[targets].n_random_initial", t.get("n_random_initial", 0),
                                 lo=0, integer=True),
        survival_probability=_number("[targets].survival_probability",
                                     t.get("survival_probability", 1.0), lo=0, hi=1),
        birth_rate=_number("[targets].birth_rate", t.get("birth_rate", 0.0), lo=0),
        birth_velocity_std=_number("[targets].birth_velocity_std",
                                   t.get("birth_velocity_std", 0.1), lo=0,
                                   hi=MAX_MAGNITUDE),
        boundary=boundary,
    )

    s = _section(data, "sensor", {"kind", "p_d", "snr", "snr_db", "looks_per_step",
                                  "h_matrix", "r_matrix"}, {"kind"})
    kind = s["kind"]
    if kind == "rayleigh":
        extra = set(s) - {"kind", "p_d", "snr", "snr_db", "looks_per_step"}
        if extra:
            raise ScenarioError(f"key(s) {sorted(extra)} do not apply to a rayleigh [sensor]")
        if ("snr" in s) == ("snr_db" in s):
            raise ScenarioError("[sensor] needs exactly one of snr (linear) and snr_db")
        p_d = _number("[sensor].p_d", s.get("p_d", 0.5), lo=0, hi=1, lo_open=True,
                      hi_open=True)
        # p_f = p_d ** (1 + snr) must stay a normal double (log(p_f) finite)
        snr_max = math.log(sys.float_info.min) / math.log(p_d) - 1.0
        why = (f"with p_d = {p_d!r} (the false-alarm probability p_d ** (1 + snr) "
               "underflows to 0 beyond it)")
        if "snr" in s:
            snr = _number("[sensor].snr", s["snr"], lo=0, lo_open=True)
            if snr > snr_max:
                raise _fail("[sensor].snr", s["snr"], f"a number > 0 and <= {snr_max:.4g} {why}")
        else:  # dB -> linear, compared in dB first: 10 ** (x / 10) overflows above ~3082 dB
            db_max = math.floor(10.0 * math.log10(snr_max) * 100) / 100
            snr_db = _number("[sensor].snr_db", s["snr_db"])
            if snr_db > db_max:
                raise _fail("[sensor].snr_db", s["snr_db"], f"a number <= {db_max:g} {why}")
            snr = 10.0 ** (snr_db / 10.0)
            if snr <= 0.0:
                raise _fail("[sensor].snr_db", s["snr_db"],
                            "a number > -3000 (the linear snr underflows to 0)")
        sensor: RayleighGridSensor | SuperpositionSensor = RayleighGridSensor(
            p_d=p_d,
            snr=snr,
            looks_per_step=_number("[sensor].looks_per_step",
                                   s.get("looks_per_step", grid.n_cells), lo=0, integer=True),
        )
    elif kind == "superposition":
        extra = set(s) - {"kind", "h_matrix", "r_matrix"}
        if extra:
            raise ScenarioError(f"key(s) {sorted(extra)} do not apply to a superposition [sensor]")
        for key in ("h_matrix", "r_matrix"):
            if key not in s:
                raise ScenarioError(f"missing field {key} in superposition [sensor]")
        h = _matrix("[sensor].h_matrix", s["h_matrix"], None, 4)
        r = _matrix("[sensor].r_matrix", s["r_matrix"], len(h), len(h))
        _psd("[sensor].r_matrix", r)
        if np.linalg.eigvalsh(np.array(r)).min() <= 0:
            raise _fail("[sensor].r_matrix", [list(x) for x in r], "a positive definite matrix")
        sensor = SuperpositionSensor(h_matrix=h, r_matrix=r)
    else:
        raise _fail("[sensor].kind", kind, 'one of "rayleigh", "superposition"')

    occlusions: tuple[Occlusion, ...] = ()
    if "occlusion" in data:
        if kind != "rayleigh":
            raise ScenarioError("[[occlusion]] applies to a rayleigh [sensor] only (the "
                                "superposition sensor does not look at cells)")
        occlusions = _occlusions(data["occlusion"], grid, n_steps)
    model = TrackingModel(grid=grid, dynamics=dynamics, birth_death=birth, sensor=sensor,
                          visibility=Visibility(occlusions))
    return Scenario(name=name, description=description, n_steps=n_steps, model=model)


def to_dict(sc: Scenario) -> dict:
    """The TOML document of a scenario; ``from_dict(to_dict(s)) == s``."""
    m = sc.model
    dyn = {"tau": m.dynamics.tau}
    if m.dynamics.q_matrix is not None:
        dyn["q_matrix"] = [list(r) for r in m.dynamics.q_matrix]
    else:
        dyn["wna_intensity"] = m.dynamics.wna_intensity
    targets = asdict(m.birth_death)
    targets["initial_states"] = [list(r) for r in m.birth_death.initial_states]
    if isinstance(m.sensor, RayleighGridSensor):
        sensor = {"kind": "rayleigh", **asdict(m.sensor)}
    else:
        sensor = {"kind": "superposition", "h_matrix": [list(r) for r in m.sensor.h_matrix],
                  "r_matrix": [list(r) for r in m.sensor.r_matrix]}
    doc = {"name": sc.name, "description": sc.description, "n_steps": sc.n_steps,
           "grid": asdict(m.grid), "dynamics": dyn, "targets": targets, "sensor": sensor}
    if m.visibility.occlusions:  # absent when nothing is blind: older files stay as they were
        doc["occlusion"] = [{"x": list(o.x), "y": list(o.y), "steps": list(o.steps),
                             "velocity": list(o.velocity)} for o in m.visibility.occlusions]
    return doc


def loads(text: str, *, default_name: str | None = None) -> Scenario:
    """Parse and validate TOML text (a leading byte-order mark is ignored)."""
    try:
        data = tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"not valid TOML: {exc}") from exc
    return from_dict(data, default_name=default_name)


def dumps(sc: Scenario) -> str:
    return tomli_w.dumps(to_dict(sc))


#: the largest scenario file read (bytes): the presets are about 1 kB
MAX_FILE_BYTES = 1 << 20


def _read_scenario_file(path: Path) -> str:
    """The text of a regular file of at most :data:`MAX_FILE_BYTES` (a FIFO, a device or
    a symlink to one is refused before it is opened; a longer file before it is read to
    its end)."""
    try:
        info = path.stat()
    except OSError as exc:
        raise ScenarioError(f"cannot read the file: {exc.strerror or exc}") from None
    if stat.S_ISDIR(info.st_mode):
        raise ScenarioError("cannot read the file: Is a directory")
    if not stat.S_ISREG(info.st_mode):
        raise ScenarioError("not a regular file (a scenario is a .toml file)")
    with path.open("rb") as f:
        data = f.read(MAX_FILE_BYTES + 1)
    if len(data) > MAX_FILE_BYTES:
        raise ScenarioError(f"the file is larger than {MAX_FILE_BYTES} bytes (a scenario is "
                            "a few kB)")
    return data.decode("utf-8-sig")  # -sig: a byte-order mark is fine


def _load(path: Path) -> Scenario:
    """Load and validate a scenario file; errors name the field, not the file."""
    try:
        text = _read_scenario_file(path)
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except OSError as exc:
        raise ScenarioError(f"cannot read the file: {exc.strerror or exc}") from None
    return loads(text, default_name=path.stem)


def load(path: str | Path) -> Scenario:
    """Load and validate a scenario file; errors (one line) name the file and the field.
    A file that cannot be read or is not UTF-8 is a :class:`ScenarioError` too."""
    path = Path(path)
    try:
        return _load(path)
    except ScenarioError as exc:
        raise ScenarioError(f"{path}: {exc}") from None


# ------------------------------------------------------------------------ presets
def preset_names() -> list[str]:
    """Names of the shipped presets, sorted."""
    folder = resources.files(__package__ + ".presets")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def get(name_or_path: str) -> Scenario:
    """A shipped preset by name, or a scenario file by path (anything ending .toml).

    The error of a file does not repeat its path (the caller named it): use
    :func:`load` for messages that name the file."""
    if name_or_path.endswith(".toml"):
        return _load(Path(name_or_path))
    names = preset_names()
    if name_or_path not in names:
        raise ScenarioError(f"unknown scenario {name_or_path!r}: presets are {names}, "
                            "or give a path to a .toml file")
    text = resources.files(__package__ + ".presets").joinpath(
        f"{name_or_path}.toml").read_text(encoding="utf-8")
    return loads(text, default_name=name_or_path)
