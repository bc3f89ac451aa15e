"""A registry of classes by name, filled by decorators and by other packages' entry points.

Trackers (:mod:`~mttbench.trackers.base`) and cell-selection policies
(:mod:`~mttbench.benchmarks.engine.policies`) each keep one. An entry point
``name = "package.module:Class"`` in the registry's group names a subclass of the
registry's base class whose ``name`` attribute is ``name``; entry points are loaded on
the first look-up, once per process. One that fails to load is kept with its reason
(:meth:`Registry.broken`) and never stops the others.
"""

from __future__ import annotations

import importlib
from importlib import metadata
from typing import Generic, TypeVar

T = TypeVar("T", bound=type)


class Registry(Generic[T]):
    """Classes of ``kind`` (subclasses of ``base``) by their ``name`` attribute."""

    def __init__(self, kind: str, base: type, group: str, plural: str | None = None) -> None:
        self.kind, self.base, self.group = kind, base, group
        self.plural = plural or kind + "s"
        self._classes: dict[str, T] = {}
        self._broken: dict[str, str] = {}
        self._plugins_loaded = False

    def register(self, cls: T) -> T:
        """Class decorator: register ``cls`` under ``cls.name``."""
        if not (isinstance(cls, type) and issubclass(cls, self.base)):
            raise TypeError(f"{cls!r} is not a subclass of {self.base.__qualname__}")
        if not cls.name:
            raise ValueError(f"{cls.__name__} needs a non-empty `name`")
        if self._classes.get(cls.name, cls) is not cls:
            raise ValueError(f"{self.kind} name {cls.name!r} is already registered")
        self._classes[cls.name] = cls
        return cls

    def unregister(self, name: str) -> None:
        """Remove ``name`` (for tests that register temporary classes)."""
        self._classes.pop(name, None)

    def load_plugins(self) -> None:
        """Register the classes of installed packages' entry points in :attr:`group`."""
        if self._plugins_loaded:
            return
        self._plugins_loaded = True
        for ep in metadata.entry_points(group=self.group):
            if ep.name in self._classes:
                continue
            try:
                cls = ep.load()
                if not (isinstance(cls, type) and issubclass(cls, self.base)):
                    raise TypeError(f"{ep.value} is not a subclass of {self.base.__qualname__}")
                if cls.name != ep.name:
                    raise ValueError(f"{ep.value}.name is {cls.name!r}, not {ep.name!r}")
                self.register(cls)
            except Exception as exc:  # noqa: BLE001 - a broken plugin must not stop the suite
                self._broken[ep.name] = f"{type(exc).__name__}: {exc}".splitlines()[0]

    def names(self) -> list[str]:
        """Registered names (shipped and from entry points), sorted."""
        self.load_plugins()
        return sorted(self._classes)

    def broken(self) -> dict[str, str]:
        """Entry points that failed to load: name -> one-line reason."""
        self.load_plugins()
        return dict(self._broken)

    def get(self, name: str) -> T:
        """The class registered as ``name``, or named by a class path
        ``package.module:Class`` (a class written elsewhere, used without registering
        it); ``KeyError`` naming the choices otherwise."""
        self.load_plugins()
        if name in self._classes:
            return self._classes[name]
        if ":" in name and name not in self._broken:
            return self._import(name)
        why = f" failed to load: {self._broken[name]}" if name in self._broken else ""
        raise KeyError(f"unknown {self.kind} {name!r}{why}: the {self.plural} are {self.names()}"
                       "; one from elsewhere is named package.module:ClassName")

    def _import(self, path: str) -> T:
        module, _, attr = path.partition(":")
        try:
            cls = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as exc:
            raise KeyError(f"cannot import {self.kind} {path!r}: {exc}") from None
        if not (isinstance(cls, type) and issubclass(cls, self.base)):
            raise KeyError(f"{path!r} is not a subclass of {self.base.__qualname__}")
        return cls

    def __contains__(self, name: str) -> bool:
        self.load_plugins()
        return name in self._classes
