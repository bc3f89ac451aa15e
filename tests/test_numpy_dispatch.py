"""``import mttbench`` before numpy turns numpy's AVX-512 targets off, so a seed gives the
same numbers on AVX2 and AVX-512 machines (``mttbench/__init__.py``). Each check runs in
a fresh interpreter, whose numpy reads the variable once when it loads."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest


def _python(code: str, *flags: str, **env: str) -> str:
    """The output of ``code`` in a fresh interpreter with ``flags``, with
    ``NPY_DISABLE_CPU_FEATURES`` as ``env`` gives it (else unset)."""
    environ = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
    environ.update(env)
    return subprocess.run([sys.executable, *flags, "-c", code], env=environ,
                          capture_output=True, text=True, check=True).stdout


def _above_avx2(first: str, **env: str) -> list[str]:
    """:func:`mttbench.numpy_dispatch_above_avx2` after ``first`` in a fresh interpreter."""
    out = _python(f"{first}\nimport json, mttbench\n"
                  "print(json.dumps(mttbench.numpy_dispatch_above_avx2()))", **env)
    return json.loads(out.strip().splitlines()[-1])


def test_importing_mttbench_first_leaves_numpy_at_most_avx2():
    assert _above_avx2("import mttbench") == []


def test_the_variable_set_by_the_user_is_kept():
    """Set and empty, it keeps numpy's AVX-512 code (on a CPU that has it), and so does
    importing numpy first: mttbench changes nothing then."""
    if not _above_avx2("pass", NPY_DISABLE_CPU_FEATURES=""):
        pytest.skip("this CPU has no AVX-512: numpy dispatches at most AVX2 either way")
    assert _above_avx2("import numpy")


def test_only_targets_the_installed_numpy_knows_are_named():
    """numpy warns (ImportWarning) about a name it does not dispatch; under ``-W error``
    that warning would stop numpy from loading."""
    _python("import mttbench, numpy", "-W", "error::ImportWarning")
