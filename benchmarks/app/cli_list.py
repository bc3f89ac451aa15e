"""``mttbench scenarios`` and ``mttbench trackers``: what can be run."""

from __future__ import annotations

import argparse
import textwrap

from ... import scenarios, trackers
from ..engine import policies


def cmd_scenarios(args: argparse.Namespace) -> int:
    names = scenarios.preset_names()
    width = max(len(n) for n in names)
    for name in names:
        sc = scenarios.get(name)
        print(f"{name:<{width}}  {sc.n_steps:>4} steps  {sc.description}")
    return 0


def _print_entry(name: str, cls: type) -> None:
    """A tracker or policy: its summary, then one line per parameter with its default and
    what it accepts (the class's declaration, :mod:`mttbench.trackers.params`)."""
    from ...trackers.params import describe

    print(f"  {name:<8} {cls.summary}")
    rows = describe(cls)
    if not rows:
        print(" " * 11 + "(no parameters)")
    for key, default, allowed in rows:
        head = f"{key}={default}"
        print(textwrap.fill(allowed, width=100, initial_indent=" " * 11 + f"{head:<28} ",
                            subsequent_indent=" " * 40))


def cmd_trackers(args: argparse.Namespace) -> int:
    print("Trackers (use as NAME or NAME:key=value,key=value; a tracker from elsewhere as "
          "package.module:ClassName):")
    print("Each parameter: NAME=DEFAULT and what it accepts; bad values are refused before "
          "any run.")
    for name in trackers.available():
        _print_entry(name, trackers.get_class(name))
        missing = getattr(trackers.get_class(name), "missing_extra", None)
        if callable(missing) and missing():  # an optional extra not installed (Stone Soup)
            print(" " * 11 + f"NOT AVAILABLE: {missing()}")
    for name, why in trackers.broken_plugins().items():
        print(f"  {name:<8} NOT LOADED (entry point failed): {why}")
    print("\nCell-selection policies (--policy NAME or NAME:key=value,...):")
    for name in policies.available_policies():
        _print_entry(name, policies.get_policy_class(name))
    for name, why in policies.broken_plugins().items():
        print(f"  {name:<8} NOT LOADED (entry point failed): {why}")
    return 0


def add_parser(sub: argparse._SubParsersAction, fmt: type[argparse.HelpFormatter]) -> None:
    """The ``scenarios`` and ``trackers`` sub-commands."""
    p = sub.add_parser("scenarios", help="list the scenario presets",
                       description="List the shipped scenario presets with their descriptions. "
                                   "Any command also accepts a path to a scenario .toml file.")
    p.set_defaults(func=cmd_scenarios)

    p = sub.add_parser("trackers", help="list trackers (with parameters) and policies",
                       description="List the registered trackers with their parameters and "
                                   "defaults, and the cell-selection policies.")
    p.set_defaults(func=cmd_trackers)
