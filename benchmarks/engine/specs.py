"""Specifications of trackers and policies (``name:key=val,...``) and their resolution.

This module sits below every command (:mod:`~mttbench.benchmarks.app.cli` imports it,
nothing here imports the command line), so the harness, ``compare`` and
``reproduce`` share one way of turning user text into checked objects and one error
type for bad input, :class:`ConfigError` (reported by the command line in one line
with exit status 2).

Spec text: ``name`` or ``name:key=val,key=val``. ``name`` is a registered name
(``mttbench trackers``) or, for a tracker written elsewhere, a class path
``package.module:ClassName``, the class name capitalised (then
``package.module:ClassName:key=val,...``). Each
value is parsed as ``true``/``false`` (bool, case-insensitive), then ``int``, then
``float``, otherwise kept as a string. Resolution (:func:`resolve_trackers`,
:func:`resolve_policies`, used by every command) then checks each value against the
class's declared parameters (:mod:`mttbench.trackers.params`: type, range, choices,
``none``/``None`` where allowed, rules between parameters) before any run, and keeps
the values in their canonical types (``n_particles=1e3`` -> ``1000``, so the label
reads ``jmpd(n_particles=1000)``).
"""

from __future__ import annotations

import dataclasses
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

from ... import scenarios, trackers
from ...scenarios import envelope
from ...scenarios.spec import Scenario
from ...trackers.params import Configurable, ParameterError
from . import policies
from .errors import ConfigError, first_line


# ------------------------------------------------------------------------ parsing
def parse_value(text: str) -> bool | int | float | str:
    """``"true"``/``"false"`` -> bool, then int, then float, else the string itself."""
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def label(name: str, params: dict[str, Any]) -> str:
    """``name`` without parameters, else ``name(k=v,...)`` with sorted keys."""
    if not params:
        return name
    return f"{name}(" + ",".join(f"{k}={params[k]}" for k in sorted(params)) + ")"


#: ``package.module:ClassName`` at the start of a spec: a class path, told from
#: ``name:key=val`` by the capital letter that starts a class name (PEP 8)
_CLASS_PATH = re.compile(r"^\s*([A-Za-z_][\w.]*:[A-Z]\w*)\s*(?::(.*))?$", re.S)


def parse_spec(text: str, what: str) -> tuple[str, dict[str, Any]]:
    """``name[:key=val,...]`` or ``pkg.mod:Class[:key=val,...]`` -> (name, params).

    ``ValueError`` (one line) for a character outside ASCII (``０.５`` would read as 0.5)
    and for spaces within the spec (``gpf: epsilon = 0.1``): what is typed is what runs."""
    odd = next((ch for ch in text if not ch.isascii()), None)
    if odd is not None:
        raise ValueError(f"the character {odd!r} in {text!r} is not ASCII: type names and "
                         "numbers in ASCII")
    if re.search(r"\s", text.strip()):
        raise ValueError(f"spaces in {text!r}: write name:key=value,key=value without spaces")
    m = _CLASS_PATH.match(text)
    if m:
        name, sep, rest = m.group(1), m.group(2) is not None, m.group(2) or ""
    else:
        name, colon, rest = text.strip().partition(":")
        sep = bool(colon)
    name = name.strip()
    if not name:
        raise ValueError(f"empty {what} name in {text!r}")
    params: dict[str, Any] = {}
    if sep:
        for item in rest.split(","):
            key, eq, value = item.partition("=")
            key = key.strip()
            if not eq or not key:
                raise ValueError(f"bad {what} parameter {item!r} in {text!r}: expected key=value")
            if key in params:
                raise ValueError(f"{what} parameter {key!r} given twice in {text!r}")
            params[key] = parse_value(value.strip())
    return name, params


def split_specs(items: Sequence[str] | str) -> list[str]:
    """Split comma-separated spec lists, keeping ``key=val`` pieces with their spec.

    ``["raster,renyi:alpha=0.5,max_count=3", "all"]`` ->
    ``["raster", "renyi:alpha=0.5,max_count=3", "all"]``: a piece with ``=`` but no
    ``:`` continues the parameter list of the spec before it.
    """
    out: list[str] = []
    for item in [items] if isinstance(items, str) else items:
        for piece in item.split(","):
            piece = piece.strip()
            if not piece:
                continue
            if "=" in piece and ":" not in piece and out and ":" in out[-1]:
                out[-1] += "," + piece
            else:
                out.append(piece)
    return out


# -------------------------------------------------------------------------- specs
@dataclass(frozen=True)
class Spec:
    """A registered name (or class path) and the parameters given to its constructor."""

    name: str
    params: dict[str, Any] = field(default_factory=dict)
    kind: ClassVar[str] = ""

    @property
    def label(self) -> str:
        """``name`` without parameters, else ``name(k=v,...)`` with sorted keys."""
        return label(self.name, self.params)

    def _key(self) -> tuple[str, str, str]:
        # parameters by their JSON text, so True and 1 (equal to Python) stay apart
        return (self.kind, self.name,
                json.dumps(self.params, sort_keys=True, default=repr, allow_nan=True))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Spec) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    @classmethod
    def parse(cls, text: str) -> Self:
        """From ``name`` or ``name:key=val,key=val`` (values as :func:`parse_value`)."""
        return cls(*parse_spec(text, cls.kind))

    def target(self) -> type[Configurable]:
        """The class the spec names (``KeyError`` if none)."""
        raise NotImplementedError

    def validated(self) -> Self:
        """The same spec with each value checked against the class's declaration and in
        its canonical type; raises ``TypeError``/:class:`ParameterError` in one line."""
        return type(self)(self.name, self.target().validate_params(self.params, name=self.name))

    @property
    def config(self) -> str:
        """The canonical configuration (implementation and every resolved parameter, as
        JSON): equal for equal configurations however spelled; it seeds the runs."""
        return self.target().canonical_config(self.params)


class TrackerSpec(Spec):
    """A tracker and its parameters."""

    kind = "tracker"

    def target(self) -> type[trackers.Tracker]:
        """The tracker class (registered name or class path)."""
        return trackers.get_class(self.name)

    def make(self) -> trackers.Tracker:
        """A new tracker with these parameters (checked against its declaration)."""
        return trackers.make(self.name, **self.params)


class PolicySpec(Spec):
    """A cell-selection policy and its parameters."""

    kind = "policy"

    def target(self) -> type[policies.Policy]:
        """The policy class (registered name or class path)."""
        return policies.get_policy_class(self.name)

    def make(self) -> policies.Policy:
        """A new policy with these parameters (checked against its declaration)."""
        return policies.make_policy(self.name, **self.params)


# --------------------------------------------------------------------- resolution
#: suites of scenarios (``--suite NAME`` or ``NAME:SPLIT``): name -> scenarios of a split
SUITES = {"envelope": envelope.envelope_points}


def resolve_suite(text: str) -> list[str]:
    """``envelope``, ``envelope:train`` or ``envelope:held`` -> the names of its scenarios
    (envelope points, which :func:`resolve_scenarios` accepts by name)."""
    name, sep, split = text.partition(":")
    allowed = " or ".join(f"{s}, " + ", ".join(f"{s}:{x}" for x in envelope.SPLITS)
                          for s in SUITES)
    if name not in SUITES or (sep and split not in envelope.SPLITS):
        raise ConfigError(f"suite {text!r} is not known: expected {allowed}")
    try:
        return [sc.name for sc in SUITES[name](split or None)]
    except scenarios.ScenarioError as exc:
        raise ConfigError(f"suite {text!r}: {first_line(exc)}") from None


def _scenario(name: str) -> Scenario:
    """A preset, a ``.toml`` path, or an envelope point by name (``env-...``)."""
    if name.startswith("env-") and name in envelope.point_names():
        return envelope.get_point(name)
    return scenarios.get(name)


def resolve_scenarios(names: Sequence[str], steps: int | None = None) -> list[Scenario]:
    """Presets, ``.toml`` paths or envelope points (by name) -> scenarios, with ``n_steps``
    overridden if given."""
    out = []
    for name in names:
        try:
            sc = _scenario(name)
        except (scenarios.ScenarioError, OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"scenario {name!r}: {first_line(exc)}") from None
        if steps is not None:
            sc = dataclasses.replace(sc, n_steps=steps)
        out.append(sc)
    seen = [sc.name for sc in out]
    dupes = sorted({n for n in seen if seen.count(n) > 1})
    if dupes:
        raise ConfigError(f"scenario name(s) {dupes} given more than once")
    return out


def _resolve(texts: Sequence[str], spec_type: type[Spec]) -> list:
    """Specs checked against the declarations and by building each one once (unknown
    names, unknown parameters and refused values give one line)."""
    specs = []
    for item in texts:
        if not item.strip():
            raise ConfigError(f"{spec_type.kind}: none given (an empty {spec_type.kind} spec)")
        if any(not piece.strip() for piece in item.split(",")):
            raise ConfigError(f"{spec_type.kind} {item!r}: an empty item (a trailing or "
                              "doubled comma)")
    for text in split_specs(list(texts)):
        try:
            spec = spec_type.parse(text)
            spec.target()
        except (ValueError, KeyError, TypeError, ImportError, AttributeError) as exc:
            raise ConfigError(f"{spec_type.kind} {text!r}: {first_line(exc)}") from None
        try:  # these messages name the tracker or policy, the parameter and the value
            spec = spec.validated()
        except (ParameterError, TypeError) as exc:
            raise ConfigError(first_line(exc)) from None
        try:
            spec.make()
        except (ValueError, KeyError, TypeError, ImportError, AttributeError) as exc:
            raise ConfigError(f"{spec_type.kind} {text!r}: {first_line(exc)}") from None
        specs.append(spec)
    labels = [s.label for s in specs]
    if len(set(labels)) != len(labels):
        raise ConfigError(f"a {spec_type.kind} is given more than once: {labels}")
    return specs


def resolve_trackers(texts: Sequence[str]) -> list[TrackerSpec]:
    """Tracker specs, checked against the registry (or importable as class paths)."""
    return _resolve(texts, TrackerSpec)


def resolve_policies(texts: Sequence[str]) -> list[PolicySpec]:
    """Policy specs, checked against the registry."""
    return _resolve(texts, PolicySpec)
