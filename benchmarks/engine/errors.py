"""The engine's one error type for a configuration it cannot run."""

from __future__ import annotations


class ConfigError(Exception):
    """A job, spec, scenario, policy or output folder the engine cannot use; the message is
    one line that names what is wrong and what is allowed. The command line shows it and
    exits with status 2 (its ``UsageError`` is a subclass for the options it checks
    itself)."""


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (KeyError without its quotes)."""
    msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
    return str(msg).strip().splitlines()[0] if str(msg).strip() else type(exc).__name__
