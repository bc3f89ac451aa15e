"""``import mttbench`` before numpy turns numpy's AVX-512 targets off, so a seed gives the
same numbers on AVX2 and AVX-512 machines (``mttbench/__init__.py``). Each check runs in
a fresh interpreter, whose numpy reads the variable once when it loads."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_PROBE = """
import json
{first}
from numpy._core import _multiarray_umath as umath
on = umath.__cpu_features__
print(json.dumps({{"dispatch": [t for t in umath.__cpu_dispatch__ if on.get(t)],
                  "features": sorted(f for f, v in on.items() if v)}}))
"""


def _dispatch(first: str, **env: str) -> dict:
    environ = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
    environ.update(env)
    out = subprocess.run([sys.executable, "-c", _PROBE.format(first=first)], env=environ,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _above_avx2(targets: list[str]) -> list[str]:
    return [t for t in targets if "AVX512" in t or t == "X86_V4"]


def test_importing_mttbench_first_leaves_numpy_at_most_avx2():
    got = _dispatch("import mttbench")
    assert _above_avx2(got["dispatch"]) == []


def test_the_variable_set_by_the_user_is_kept():
    """Set and empty, it keeps numpy's AVX-512 code (on a CPU that has it), and so does
    importing numpy first: mttbench changes nothing then."""
    if "AVX512F" not in _dispatch("import mttbench")["features"]:
        pytest.skip("this CPU has no AVX-512: numpy dispatches at most AVX2 either way")
    assert _above_avx2(_dispatch("import mttbench", NPY_DISABLE_CPU_FEATURES="")["dispatch"])
    assert _above_avx2(_dispatch("import numpy\nimport mttbench")["dispatch"])


def test_only_targets_the_installed_numpy_knows_are_named():
    """numpy warns (ImportWarning) about a name it does not dispatch; under ``-W error``
    that warning would stop numpy from loading."""
    environ = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
    subprocess.run([sys.executable, "-W", "error::ImportWarning", "-c",
                    "import mttbench, numpy"], env=environ, check=True)
