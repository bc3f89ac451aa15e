"""Rules of the executors (benchmarks/engine/executors.py) that need no worker process:
the options' ranges, the worker count's floor and description, the current executor,
a lost run's one-line message, the source digest's dependence on the files' contents,
and the identity of a part encoded where its run ran."""

from __future__ import annotations

import dataclasses
import io
import sys

import pandas as pd
import pytest

from mttbench.benchmarks.engine import executors as ex
from mttbench.benchmarks.engine.errors import ConfigError
from mttbench.benchmarks.engine.loop import Job, run_job
from mttbench.benchmarks.engine.specs import TrackerSpec
from mttbench.benchmarks.engine.store import PART_META_KEY, _parquet_bytes, _write_part
from mttbench.scenarios import get as get_scenario


def test_the_options_ranges():
    assert ex.check_retries(0) == 0
    with pytest.raises(ConfigError, match="--retries -1"):
        ex.check_retries(-1)
    assert ex.check_no_worker_timeout(None) is None
    assert ex.check_no_worker_timeout(0.5) == 0.5
    for bad in (0, -1.0, float("inf"), float("nan")):
        with pytest.raises(ConfigError, match="--no-worker-timeout"):
            ex.check_no_worker_timeout(bad)
    pytest.importorskip("distributed")
    with pytest.raises(ConfigError, match="--workers 0 is not allowed"):
        ex.DaskExecutor(workers=0)


def test_a_local_pool_has_at_least_one_worker_and_names_those_it_uses():
    assert ex.LocalExecutor(0).workers == 1
    pool = ex.LocalExecutor(4)
    assert (pool.describe(), pool.describe(2), pool.describe(9)) == (
        "4 worker(s)", "2 worker(s)", "4 worker(s)")
    assert ex.describe_current(3, 2) == "2 worker(s)"
    with ex.use_executor(ex.LocalExecutor(5)):
        assert ex.describe_current(1) == "5 worker(s)"
    assert ex.describe_current(1) == "1 worker(s)"


def test_a_lost_runs_message_is_one_line():
    assert ex._lost(ValueError("a\n  b\tc")) == "worker failed: ValueError: a b c"


def test_the_source_digest_reads_the_files_contents(tmp_path, monkeypatch):
    pkg = tmp_path / "mttbench_rules_digest_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("x = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(ex, "SOURCE_PACKAGES", {"mttbench_rules_digest_pkg": "*.py"})
    before = ex.source_digest()
    (pkg / "a.py").write_text("x = 2\n")  # same name, same length
    assert ex.source_digest() != before
    sys.modules.pop("mttbench_rules_digest_pkg", None)


def test_a_part_encoded_where_it_ran_names_its_jobs_key(tmp_path):
    sc = dataclasses.replace(get_scenario("single-clean"), n_steps=2)
    job = Job(sc, TrackerSpec("null"))
    work = ex.Work(run_job, _write_part, _parquet_bytes, None, c=3.0, p=1.0)
    df = pd.read_parquet(io.BytesIO(work.encoded(job)))
    assert df.attrs[PART_META_KEY]["key"] == job.key(3.0, 1.0) != job.key(None, 1.0)
    assert df["ospa_c"].tolist() == [3.0, 3.0] and df["ospa_p"].tolist() == [1.0, 1.0]
