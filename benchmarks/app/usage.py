"""The command line's error for bad input: one line on stderr, exit status 2."""

from __future__ import annotations

from ..engine.errors import ConfigError


class UsageError(ConfigError):
    """Bad user input that the application itself finds (an option, a folder, a file). The
    command line reports it, and the engine's :class:`ConfigError`, in one line with exit
    status 2."""
