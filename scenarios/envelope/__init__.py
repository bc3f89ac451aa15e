"""The operating envelope: a family of small scenarios around one centre point.

Verdicts measured on a few benign presets do not transfer to other settings. The
envelope spans the settings a user may bring (false alarms, SNR and p_d, target density,
speed, look budget, changing counts, walls), each point cheap enough (12x12 cells, 40
steps; the sparse point 24x24) that every tracker runs on all of them in minutes
(docs/envelope.md has the points, the timings and what every tracker does on them).

It is data, shipped with the package:

* ``template.toml``: a complete scenario file (:mod:`~mttbench.scenarios.spec`), the
  centre, and the scenario every point starts from; its comments say how the axes read off
  the fields (``p_f = p_d ** (1 + snr)``, density, speed, look fraction);
* ``points.toml``: one ``[[point]]`` per point, with ``name`` (``env-<axis>-<value>``),
  ``axis``, ``split`` (``"train"`` or ``"held"``: tuning may use the train points and is
  judged on the held-apart ones), a one-line ``description`` and then the fields it
  overrides, section by section (``sensor = { snr = 2.32 }``).

A point's scenario is the template with the point's fields replaced (a section's keys one
by one), its name and description, validated by :func:`~mttbench.scenarios.spec.from_dict`
like any scenario file. ``mttbench run/compare --suite envelope`` (or ``envelope:train``,
``envelope:held``) runs them; a single point is accepted by name wherever a scenario is
(``--scenarios env-pf-0.3``).
"""

from __future__ import annotations

import copy
import functools
import tomllib
from dataclasses import dataclass
from importlib import resources
from typing import Any

from ..spec import Scenario, ScenarioError, from_dict

__all__ = [
    "AXES", "SPLITS", "EnvelopePoint", "envelope_points", "get_point", "point_names", "points",
    "template",
]

#: what a point may vary (``axis``)
AXES = ("centre", "p_f", "snr", "p_d", "density", "speed", "looks", "count", "boundary",
        "corner")
#: the two halves of the envelope: tuning trains on one and is judged on the other
SPLITS = ("train", "held")
#: keys of a ``[[point]]`` besides the overridden sections
_META = {"name", "axis", "split", "description"}
#: what a point may override: the scenario's sections and its length
_SECTIONS = {"grid", "dynamics", "targets", "sensor"}
_OVERRIDES = _SECTIONS | {"n_steps"}


@dataclass(frozen=True)
class EnvelopePoint:
    """One point: its scenario, the axis it varies, its split and the fields it sets."""

    scenario: Scenario
    axis: str
    split: str
    overrides: dict[str, Any]

    @property
    def name(self) -> str:
        return self.scenario.name


def _read(file: str) -> dict[str, Any]:
    text = resources.files(__package__).joinpath(file).read_text(encoding="utf-8")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"envelope {file}: not valid TOML: {exc}") from None


def _template_dict() -> dict[str, Any]:
    return _read("template.toml")


def _apply(base: dict[str, Any], point: dict[str, Any]) -> dict[str, Any]:
    """The template document with a point's name, description and fields."""
    doc = copy.deepcopy(base)
    doc["name"], doc["description"] = point["name"], point["description"]
    for key in _OVERRIDES & set(point):
        value = point[key]
        if key in _SECTIONS:
            if not isinstance(value, dict):
                raise ScenarioError(f"{key} = {value!r} is not allowed: expected a table of "
                                    f"the [{key}] keys to change")
            doc.setdefault(key, {}).update(copy.deepcopy(value))
        else:
            doc[key] = value
    return doc


def _point(base: dict[str, Any], raw: Any, index: int) -> EnvelopePoint:
    where = f"envelope points.toml, point {index + 1}"
    if not isinstance(raw, dict):
        raise ScenarioError(f"{where}: expected a table, got {raw!r}")
    name = raw.get("name")
    if isinstance(name, str):
        where += f" ({name})"
    unknown = set(raw) - _META - _OVERRIDES
    if unknown:
        raise ScenarioError(f"{where}: unknown key(s) {sorted(unknown)}: allowed "
                            f"{sorted(_META | _OVERRIDES)}")
    missing = _META - set(raw)
    if missing:
        raise ScenarioError(f"{where}: missing {sorted(missing)}")
    if not (isinstance(name, str) and name.startswith("env-")):
        raise ScenarioError(f"{where}: name = {name!r} is not allowed: expected a name "
                            "starting with 'env-'")
    if raw["axis"] not in AXES:
        raise ScenarioError(f"{where}: axis = {raw['axis']!r} is not allowed: expected one "
                            f"of {list(AXES)}")
    if raw["split"] not in SPLITS:
        raise ScenarioError(f"{where}: split = {raw['split']!r} is not allowed: expected "
                            f"one of {list(SPLITS)}")
    try:
        scenario = from_dict(_apply(base, raw))
    except ScenarioError as exc:
        raise ScenarioError(f"{where}: {exc}") from None
    overrides = {k: copy.deepcopy(raw[k]) for k in sorted(_OVERRIDES & set(raw))}
    return EnvelopePoint(scenario, raw["axis"], raw["split"], overrides)


@functools.lru_cache(maxsize=1)
def _all_points() -> tuple[EnvelopePoint, ...]:
    base = _template_dict()
    doc = _read("points.toml")
    if set(doc) != {"point"} or not isinstance(doc["point"], list) or not doc["point"]:
        raise ScenarioError("envelope points.toml: expected only [[point]] tables")
    out = tuple(_point(base, raw, i) for i, raw in enumerate(doc["point"]))
    names = [p.name for p in out]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ScenarioError(f"envelope points.toml: name(s) {dupes} given more than once")
    return out


def _check_split(split: str | None) -> None:
    if split is not None and split not in SPLITS:
        raise ScenarioError(f"envelope split {split!r} is not known: expected one of "
                            f"{list(SPLITS)} (or none for every point)")


def points(split: str | None = None) -> list[EnvelopePoint]:
    """The envelope's points in file order, all or those of one ``split``."""
    _check_split(split)
    return [p for p in _all_points() if split is None or p.split == split]


def envelope_points(split: str | None = None) -> list[Scenario]:
    """The points' scenarios in file order: all, or ``split`` ``"train"`` or ``"held"``."""
    return [p.scenario for p in points(split)]


def point_names(split: str | None = None) -> list[str]:
    """The points' names in file order (all, or one split)."""
    return [p.name for p in points(split)]


def get_point(name: str) -> Scenario:
    """The scenario of the point named ``name``."""
    for p in _all_points():
        if p.name == name:
            return p.scenario
    raise ScenarioError(f"unknown envelope point {name!r}: the points are {point_names()}")


def template() -> Scenario:
    """The template (the centre) as a scenario."""
    return from_dict(_template_dict())
