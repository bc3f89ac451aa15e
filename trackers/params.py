"""Parameters declared once: type, range and meaning next to the constructor's default.

Every tracker and cell-selection policy declares its constructor's keyword parameters
in a class attribute (as scikit-learn's ``_parameter_constraints``)::

    parameters = {
        "n_particles": Param(int, low=1, doc="particles N"),
        "birth_rate": Param(float, low=0, allow_none=True, none="the model's rate"),
        "proposal": Param(choices=("bootstrap", "ip")),
    }

The defaults stay in the constructor's signature (one place each: the declaration
says what is allowed, the signature what is used when nothing is given; the keys of
the declaration must equal the constructor's keyword parameters). Validation
(:meth:`Configurable.validate_params`, called by ``trackers.make``, by
``make_policy``, by the spec resolution of every command and by the harness before a
run), ``mttbench trackers`` and the seed of a run (:meth:`Configurable.canonical_config`)
all read it.

Values and how they are read (spec text is first turned into ``bool``/``int``/``float``/
``str`` by :func:`mttbench.benchmarks.engine.specs.parse_value`):

* ``int``: an ``int`` (not a bool), or a float with an integral value, converted
  (``1000.0`` and ``1e3`` -> ``1000``); ``2.5``, ``nan``, text are refused.
* ``float``: an ``int`` or ``float`` (not a bool), stored as ``float``; ``nan`` and
  ``inf`` are refused (no parameter has an infinite setting); ``-0.0`` becomes ``0.0``.
* ``bool``: ``True``/``False`` only (spec text ``true``/``false``); ``1``, ``yes`` are
  refused.
* ``choices``: one of the listed strings, exactly.
* ``None`` (or the spec text ``none``/``None``) only where ``allow_none``; ``none`` says
  what ``None`` means.

A class that declares nothing (``parameters = None``, trackers written elsewhere before
this existed) gets only its parameter *names* checked, and its values pass unchanged.
A bad value raises :class:`ParameterError` (a ``ValueError``) with one line naming the
tracker or policy, the parameter, the value and what is allowed.

**Budgets.** A tracker also declares which of its parameters buy accuracy with time
(particles, Gaussians per track, tracks, combinations) and over which range, next to
``parameters`` (``Tracker.budget``, read by ``mttbench frontier``)::

    budget = {"n_particles": Budget(100, 16000, doc="particles N: 6 us each per step")}

The first entry is the main budget, the one a frontier sweeps (the others stay at their
defaults unless given); ``budget = {}`` says the tracker has no such knob (a frontier
shows it as a single point); ``None`` (the default) says nothing was declared.
:meth:`Budget.grid` is the sweep's log grid and :func:`budget_problem` checks a
declaration against the parameters.
"""

from __future__ import annotations

import inspect
import json
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np


class ParameterError(ValueError):
    """A parameter value that its declaration does not allow (one complete line)."""


def _num(x: float) -> str:
    """A bound as the user would write it (``1`` not ``1.0``, ``0.0001`` as ``1e-04``)."""
    if float(x).is_integer():
        return str(int(x))
    return f"{x:g}"


@dataclass(frozen=True)
class Search:
    """Where ``mttbench tune`` looks for one parameter (optuna's ``suggest_*``).

    Numbers: ``Search(low, high)`` searches ``[low, high]`` (``log=True``: uniform in
    the logarithm; ``step``: a grid), as an integer when the parameter is ``int``.
    Choices: ``Search(choices=(...))`` picks one of the listed values (strings, bools or
    numbers the parameter accepts). Every value searched must be one the parameter's
    :class:`Param` accepts.
    """

    low: float | None = None
    high: float | None = None
    log: bool = False
    step: float | None = None
    choices: tuple[Any, ...] = ()

    def __post_init__(self) -> None:
        numeric = self.low is not None or self.high is not None
        if numeric == bool(self.choices):
            raise TypeError("Search takes either low and high, or choices")
        if numeric and (self.low is None or self.high is None or not self.low < self.high):
            raise TypeError(f"Search needs low < high, got [{self.low}, {self.high}]")
        if self.log and (not numeric or self.low <= 0 or self.step is not None):
            raise TypeError("Search(log=True) needs 0 < low < high and no step")


@dataclass(frozen=True)
class Budget:
    """A budget parameter's range for ``mttbench frontier``: ``[low, high]``, swept on a
    log grid (:meth:`grid`). Both ends must be values the parameter accepts
    (:func:`budget_problem`) and should fit a small machine: ``doc`` says what the
    parameter buys and why the range ends where it does."""

    low: float
    high: float
    doc: str = ""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high)
                and 0 < self.low < self.high):
            raise TypeError(f"Budget needs 0 < low < high, got [{self.low}, {self.high}]")

    def grid(self, points: int, low: float | None = None, high: float | None = None,
             integer: bool = True) -> list[float]:
        """``points`` values log-spaced over ``[low, high]`` (default: the declared
        range), ends included: ``low * (high / low) ** (i / (points - 1))``. Integer
        parameters are rounded to the nearest integer and repeats dropped, so a narrow
        integer range gives fewer values; ``points = 1`` gives ``high``. Raises
        ``ValueError`` (one line) for a range outside the declared one."""
        lo = self.low if low is None else float(low)
        hi = self.high if high is None else float(high)
        if points < 1:
            raise ValueError(f"points {points}: expected an integer >= 1")
        if not (self.low <= lo <= hi <= self.high):
            raise ValueError(f"range [{_num(lo)}, {_num(hi)}] is not within the declared "
                             f"[{_num(self.low)}, {_num(self.high)}] with low <= high")
        values = np.geomspace(lo, hi, points) if points > 1 else np.array([hi])
        if integer:
            values = np.unique(np.clip(np.rint(values), math.ceil(lo), math.floor(hi)))
            return [int(v) for v in values]
        return [float(v) for v in np.unique(values)]


@dataclass(frozen=True)
class Param:
    """What one parameter accepts.

    ``kind``: ``int``, ``float``, ``bool`` or ``str`` (``str`` with ``choices``: one of
    them; ``choices`` alone implies ``str``). ``low``/``high``: bounds (None: none),
    inclusive unless ``low_open``/``high_open``. ``allow_none``: ``None`` is allowed and
    means ``none``. ``doc``: a few words for ``mttbench trackers``. ``search``: the
    tuning range (:class:`Search`), declared next to what the parameter accepts.
    """

    kind: type = str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    allow_none: bool = False
    none: str = ""
    doc: str = ""
    #: where ``mttbench tune`` searches this parameter; None: not tuned
    search: Search | None = None

    def __post_init__(self) -> None:
        if self.kind not in (int, float, bool, str):
            raise TypeError(f"Param kind must be int, float, bool or str, got {self.kind!r}")
        if self.choices and self.kind is not str:
            raise TypeError("Param choices need kind str")
        if (self.low is not None or self.high is not None) and self.kind not in (int, float):
            raise TypeError("Param bounds need kind int or float")
        if self.search is not None:
            problem = self.search_problem()
            if problem:
                raise TypeError(f"Param search {problem}")

    def search_problem(self) -> str | None:
        """None if every value :attr:`search` can draw is one this parameter accepts, else
        why not (one line). Numbers: both ends accepted (an integer parameter needs
        integral ends and step), ``step`` dividing ``high - low``; choices: each accepted
        in its canonical type (``1`` is not a choice of a ``float`` parameter)."""
        s = self.search
        if s is None:
            return None
        if s.choices:
            for c in s.choices:
                try:
                    ok = self.parse(c)
                except ValueError:
                    return f"choice {_value_text(c)} refused; allowed: {self.allowed()}"
                if type(ok) is not type(c) or ok != c:
                    return (f"choice {_value_text(c)} is not in the parameter's canonical "
                            f"type ({self.kind.__name__}): write {_value_text(ok)}")
            if len(set(map(repr, s.choices))) != len(s.choices):
                return f"choices {s.choices} repeat a value"
            return None
        rng = f"[{_num(s.low)}, {_num(s.high)}]"
        if self.kind not in (int, float):
            return f"{rng} is numeric; the parameter takes {self.allowed()}"
        ends = [s.low, s.high] + ([s.step] if s.step is not None else [])
        if self.kind is int and not all(float(x).is_integer() for x in ends):
            return f"{rng} (step {s.step}) is not integral; the parameter is an int"
        for end in (s.low, s.high):
            try:
                self.parse(end)
            except ValueError:
                return f"{rng}: {_num(end)} refused; allowed: {self.allowed()}"
        if s.step is not None:
            n = (s.high - s.low) / s.step
            if not s.step > 0 or abs(n - round(n)) > 1e-9 * max(1.0, abs(n)):
                return f"step {_num(s.step)} does not divide {rng}"
        return None

    # ------------------------------------------------------------------ text
    def allowed(self) -> str:
        """What is allowed, in words: ``an integer >= 1``, ``a float in (0, 1)``, ..."""
        if self.kind is bool:
            text = "true or false"
        elif self.choices:
            text = "one of " + ", ".join(self.choices)
        elif self.kind is str:
            text = "a string"
        else:
            noun = "an integer" if self.kind is int else "a number"
            lo, hi = self.low, self.high
            if lo is not None and hi is not None:
                text = (f"{noun} in {'(' if self.low_open else '['}{_num(lo)}, "
                        f"{_num(hi)}{')' if self.high_open else ']'}")
            elif lo is not None:
                text = f"{noun} {'>' if self.low_open else '>='} {_num(lo)}"
            elif hi is not None:
                text = f"{noun} {'<' if self.high_open else '<='} {_num(hi)}"
            else:
                text = noun
        if self.allow_none:
            text += ", or None" + (f" ({self.none})" if self.none else "")
        return text

    # ---------------------------------------------------------------- checks
    def parse(self, value: Any) -> Any:
        """``value`` in its canonical type; ``ValueError(allowed text)`` if not allowed."""
        if value is None or (isinstance(value, str) and value.strip().lower() == "none"
                             and "none" not in self.choices):
            if self.allow_none:
                return None
            raise ValueError(self.allowed())
        if self.kind is bool:
            if isinstance(value, bool | np.bool_):
                return bool(value)
            raise ValueError(self.allowed())
        if self.kind is str:
            if not isinstance(value, str) or (self.choices and value not in self.choices):
                raise ValueError(self.allowed())
            return value
        # numbers: never a bool (True is an int to Python, not to a user)
        if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
            raise ValueError(self.allowed())
        try:
            x = float(value)
        except OverflowError:  # an int beyond the float range: out of any range we declare
            raise ValueError(self.allowed()) from None
        if not math.isfinite(x):
            raise ValueError(self.allowed())
        if self.kind is int:
            if isinstance(value, numbers.Integral):
                out: int | float = int(value)
            elif x.is_integer():
                out = int(x)
            else:
                raise ValueError(self.allowed())
        else:
            out = x + 0.0  # -0.0 -> 0.0: one spelling per value
        if self.low is not None and (out < self.low or (self.low_open and out == self.low)):
            raise ValueError(self.allowed())
        if self.high is not None and (out > self.high or (self.high_open and out == self.high)):
            raise ValueError(self.allowed())
        return out


def _value_text(value: Any) -> str:
    """A value as it appears in an error: text quoted (``''`` shows an empty value)."""
    return repr(value) if isinstance(value, str) else str(value)


class Configurable:
    """What trackers and policies share: declared parameters, their validation, and the
    canonical configuration that seeds a run.

    Class attributes: ``kind`` (``"tracker"``/``"policy"``, for messages), ``name``,
    ``parameters`` (the declaration, ``{name: Param}``; None: undeclared) and
    ``defaults_only``. Subclasses override :meth:`param_conflict` for rules between
    parameters.
    """

    kind: ClassVar[str] = "object"
    name: ClassVar[str] = ""
    #: ``{parameter: Param}`` with the constructor's keyword parameters as keys; None: not
    #: declared (only the names are checked)
    parameters: ClassVar[Mapping[str, Param] | None] = None
    #: True on a subclass that only changes its parent's parameter defaults (``jmpd-ip``):
    #: it runs the parent's code, so equal resolved parameters give equal random numbers.
    #: Read from the class itself, not inherited (see :meth:`implementation`).
    defaults_only: ClassVar[bool] = False

    # ----------------------------------------------------------- declaration
    @classmethod
    def param_names(cls) -> list[str]:
        """The constructor's keyword parameters, in order."""
        if cls.__init__ is object.__init__:
            return []
        sig = inspect.signature(cls.__init__)
        kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
        return [p.name for p in sig.parameters.values() if p.name != "self" and p.kind in kinds]

    @classmethod
    def param_defaults(cls) -> dict[str, Any]:
        """Constructor parameters and their defaults (empty when it takes none)."""
        if cls.__init__ is object.__init__:
            return {}
        sig = inspect.signature(cls.__init__)
        return {n: sig.parameters[n].default for n in cls.param_names()}

    @classmethod
    def display_name(cls) -> str:
        """``name``, or the class name when it has none (messages)."""
        return cls.name if isinstance(cls.name, str) and cls.name else cls.__name__

    @classmethod
    def declared_parameters(cls) -> Mapping[str, Param] | None:
        """The declaration that applies to this class's constructor, or None.

        A class's own :attr:`parameters` always applies (and must match its constructor:
        :meth:`declaration_problem`). An inherited one applies when its keys are the
        constructor's parameters (``jmpd-ip`` inherits ``jmpd``'s); a subclass whose
        constructor takes other parameters and declares none of its own is undeclared."""
        declared = cls.parameters
        if declared is None or "parameters" in cls.__dict__:
            return declared
        return declared if set(declared) == set(cls.param_names()) else None

    @classmethod
    def declaration_problem(cls) -> str | None:
        """None if the class's own :attr:`parameters` (if any) has exactly the
        constructor's parameters as keys, else what differs."""
        declared = cls.declared_parameters()
        if declared is None:
            return None
        names = cls.param_names()
        missing = [n for n in names if n not in declared]
        extra = [n for n in declared if n not in names]
        if missing or extra:
            return (f"{cls.kind} {cls.display_name()!r}: its declared parameters do not match "
                    f"its constructor (undeclared: {missing}; not in the constructor: {extra})")
        return None

    @classmethod
    def param_conflict(cls, params: Mapping[str, Any]) -> str | None:
        """None if the resolved parameters (every one, defaults filled in, values already
        checked one by one) go together, otherwise a one-line reason naming them."""
        return None

    # ------------------------------------------------------------ validation
    @classmethod
    def validate_params(cls, params: Mapping[str, Any], *, name: str | None = None
                        ) -> dict[str, Any]:
        """The given ``params`` with each value checked and in its canonical type (same
        keys). Raises ``TypeError`` for an unknown parameter name and
        :class:`ParameterError` (one line: the tracker or policy, the parameter, the value
        and what is allowed) for a value its :class:`Param` refuses or a combination
        :meth:`param_conflict` refuses (checked with the defaults filled in)."""
        who = f"{cls.kind} {name or cls.display_name()!r}"
        names = cls.param_names()
        unknown = [k for k in params if k not in names]
        if unknown:
            known = ", ".join(names) if names else "none"
            raise TypeError(f"{who} has no parameter(s) {', '.join(map(repr, unknown))}; "
                            f"its parameters: {known}")
        problem = cls.declaration_problem()
        if problem:
            raise TypeError(problem)
        declared = cls.declared_parameters()
        if declared is None:
            return dict(params)
        out = {}
        for key, value in params.items():
            try:
                out[key] = declared[key].parse(value)
            except ValueError as exc:
                raise ParameterError(f"{who}: parameter {key}={_value_text(value)} refused; "
                                     f"allowed: {exc}") from None
        full = {**cls.param_defaults(), **out}
        conflict = cls.param_conflict(full)
        if conflict:
            raise ParameterError(f"{who}: {conflict}")
        return out

    @classmethod
    def resolved_params(cls, params: Mapping[str, Any] | None = None, *,
                        name: str | None = None) -> dict[str, Any]:
        """Every parameter: the defaults with ``params`` over them, validated."""
        given = cls.validate_params(params or {}, name=name)
        # the defaults in their canonical types too (and a wrong default is caught)
        return {**cls.validate_params(cls.param_defaults(), name=name), **given}

    # ---------------------------------------------------------------- seeding
    @classmethod
    def implementation(cls) -> str:
        """The identity of the code this class runs, for seeding: the ``name`` of the
        nearest class up the hierarchy that is not ``defaults_only``, or its class path
        ``module:QualName`` when it has no name of its own. Names are stable across
        refactorings that move code, class paths are not, so a named class keeps its
        numbers when its module moves."""
        for klass in cls.__mro__:
            if klass.__dict__.get("defaults_only", False):
                continue
            own = klass.__dict__.get("name")
            if isinstance(own, str) and own:
                return own
            return f"{klass.__module__}:{klass.__qualname__}"
        raise TypeError(f"{cls!r} has no implementation")  # pragma: no cover

    @classmethod
    def canonical_config(cls, params: Mapping[str, Any] | None = None) -> str:
        """The configuration as canonical JSON: kind, :meth:`implementation` and every
        parameter (defaults resolved, values validated and in canonical types), sorted
        keys, no spaces. Equal configurations, however spelled (``jmpd-ip``,
        ``jmpd:proposal=ip``), give equal text, and so the same seed of a run."""
        resolved = cls.resolved_params(params)
        doc = {"kind": cls.kind, "implementation": cls.implementation(),
               "params": {k: _canonical_value(v) for k, v in resolved.items()}}
        return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False,
                          default=repr)


def _canonical_value(v: Any) -> Any:
    """numpy scalars as Python ones; ``-0.0`` as ``0.0`` (undeclared parameters)."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not isinstance(v, bool):
        return v + 0.0 if math.isfinite(v) else repr(v)
    return v


def budget_problem(cls: type[Configurable]) -> str | None:
    """None if ``cls.budget`` (a tracker's :class:`Budget` declarations; None: none
    declared) names declared ``int`` or ``float`` parameters whose :class:`Param`
    accepts both ends of each range, else what is wrong (one line)."""
    budget = getattr(cls, "budget", None)
    if budget is None:
        return None
    declared = cls.declared_parameters() or {}
    for key, b in budget.items():
        p = declared.get(key)
        if p is None or p.kind not in (int, float):
            return (f"{cls.kind} {cls.display_name()!r}: budget {key!r} is not a declared "
                    "numeric parameter")
        if not isinstance(b, Budget):
            return f"{cls.kind} {cls.display_name()!r}: budget {key!r} is not a Budget"
        for end in (b.low, b.high):
            try:
                p.parse(end)
            except ValueError:
                return (f"{cls.kind} {cls.display_name()!r}: budget {key}={_num(end)} "
                        f"refused; allowed: {p.allowed()}")
    return None


def spec_text(value: Any) -> str:
    """A value as it is written in a spec (``true``, ``None``, ``auto``, ``0.0001``)."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return value if value.strip() and value.strip() == value else repr(value)
    return str(value)


def describe(cls: type[Configurable]) -> list[tuple[str, str, str]]:
    """``(name, default as spec text, allowed)`` per parameter, for listings
    (``mttbench trackers``); ``allowed`` is ``"(values not declared)"`` for a class
    without a declaration, and ends with the budget range of a budget parameter."""
    rows = []
    budget = getattr(cls, "budget", None) or {}
    for n, d in cls.param_defaults().items():
        p = (cls.declared_parameters() or {}).get(n)
        allowed = "(values not declared)" if p is None else (
            p.allowed() + (f"; {p.doc}" if p.doc else ""))
        if n in budget:
            allowed += f"; budget {_num(budget[n].low)}-{_num(budget[n].high)} (frontier)"
        rows.append((n, spec_text(d), allowed))
    return rows
