"""One-line errors: the engine's ``first_line`` (what the command line shows of an
exception) and the registries' class paths (``package.module:Name``)."""

from __future__ import annotations

import pytest

from mttbench.benchmarks.engine.errors import first_line


@pytest.mark.parametrize("exc, want", [
    (ValueError("the value is bad\nbecause of this\nand that"), "the value is bad"),
    (RuntimeError("  \n  leading blank lines\nsecond"), "leading blank lines"),
    (KeyError("unknown tracker 'x'\nthe trackers are ..."), "unknown tracker 'x'"),
    (KeyError("k"), "k"),  # a KeyError's text without the quotes str() adds
    (ValueError(""), "ValueError"),
    (OSError(), "OSError"),
])
def test_first_line_is_the_messages_first_nonblank_line(exc, want):
    """The reference is the message split by hand: its first line after leading
    whitespace; a KeyError's argument rather than its repr; the type's name when the
    message is empty."""
    assert first_line(exc) == want
    assert "\n" not in first_line(exc)


@pytest.mark.parametrize("path, why", [
    ("mttbench.trackers.null:NoSuchTracker", "has no attribute"),  # the module, not the name
    ("mttbench.no_such_module:Tracker", "No module named"),
])
def test_a_class_path_that_does_not_resolve_is_a_key_error_naming_it(path, why):
    """The registries (``Registry.get``) document a ``KeyError`` for a name they cannot
    resolve, as for an unknown registered name: a class path whose module is missing or
    lacks the attribute is one such name, for trackers and policies alike."""
    from mttbench.benchmarks.engine.policies import get_policy_class
    from mttbench.trackers.base import get_class

    for get, kind in ((get_class, "tracker"), (get_policy_class, "policy")):
        with pytest.raises(KeyError) as err:
            get(path)
        msg = first_line(err.value)
        assert msg.startswith(f"cannot import {kind} {path!r}: ")
        assert why in msg
