"""``import mttbench`` fixes glibc's heap thresholds (``mttbench.steady_heap``): a step's
freed temporaries are reused, not trimmed or unmapped and faulted back every step."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

#: in a fresh process (importing mttbench first, or not): 20 rounds of three 4 MiB arrays,
#: touched, then freed, as a step's temporaries; prints the minor page faults of the
#: last 10 rounds
PROBE = """
import resource, sys
if sys.argv[1] == "mttbench":
    import mttbench
import numpy as np
faults = []
for _ in range(20):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a, b, c = np.ones(1 << 19), np.ones(1 << 19), np.ones(1 << 19)
    del a, b, c
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(sum(faults[10:]))
"""


def _faults(first: str) -> int:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", PROBE, first], env=env, capture_output=True,
                         text=True, check=True).stdout
    return int(out)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_a_steps_freed_arrays_are_reused_without_page_faults():
    # glibc's moving thresholds: the 12 MiB freed at the heap's top exceed its trim
    # threshold (twice the largest block freed), so every round faults its pages again
    assert _faults("numpy") > 10 * 1000
    assert _faults("mttbench") < 100
    # a user's own setting is kept
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "1"}
    out = subprocess.run([sys.executable, "-c", "import mttbench; print(mttbench.steady_heap())"],
                         env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
