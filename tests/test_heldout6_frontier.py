"""``mttbench frontier`` without ``--policy`` runs the default its help states, raster:
the parsed command resolves to the same policy as ``--policy raster`` given."""

from __future__ import annotations

import re

from mttbench.benchmarks.app.cli import build_parser, main
from mttbench.benchmarks.engine.specs import resolve_policies

BASE = ["frontier", "default", "--trackers", "gpf"]


def test_the_default_policy_is_the_one_the_help_names(capsys):
    assert main(["frontier", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    named = re.search(r"cell-selection policy \(default ([\w-]+)\)", text).group(1)
    assert named == "raster"
    parser = build_parser()
    default = resolve_policies(parser.parse_args(BASE).policy)
    given = resolve_policies(parser.parse_args([*BASE, "--policy", named]).policy)
    assert [p.label for p in default] == [p.label for p in given] == ["raster"]
