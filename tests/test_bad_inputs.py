"""Bad input, as a new user would type it: every case, in-process.

Each refused case asserts the exit status, that stderr holds exactly one non-empty line
naming the problem (no traceback), and that the results of an earlier sweep in the same
output folder are byte-identical afterwards. Cases that run (exit 0 or 1) check what the
user gets instead: the failure line and the kept rows, the effective number of looks,
an escaped table, a recomputed damaged part.
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd
import pytest

from mttbench import scenarios
from mttbench.benchmarks.app import cli, report, resources
from mttbench.benchmarks.app.cli import main
from mttbench.benchmarks.engine import executors
from mttbench.scenarios.spec import dumps

SMALL = ["--seeds", "1", "--steps", "2", "--workers", "1", "--no-progress"]
GOOD_RUN = ["run", "--scenarios", "default", "--trackers", "null", *SMALL]
TIMING = ["tracker_wall_s", "tracker_cpu_s", "select_wall_s", "select_cpu_s", "peak_rss_mb"]


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes)."""
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def temp_files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.name.endswith(".tmp")]


def lines(text: str) -> list[str]:
    return [x for x in text.splitlines() if x.strip()]


@pytest.fixture(scope="module")
def earlier(tmp_path_factory) -> Path:
    """A folder holding the results of one successful sweep."""
    out = tmp_path_factory.mktemp("earlier") / "out"
    assert main([*GOOD_RUN, "--out", str(out)]) == 0
    assert (out / "results.parquet").is_file() and (out / "summary.md").is_file()
    return out


def scenario_file(folder: Path, name: str, edit=None, text: str | None = None) -> Path:
    """The ``default`` preset as a file, its text edited by ``edit`` (a function)."""
    body = text if text is not None else dumps(scenarios.get("default"))
    if edit is not None:
        body = edit(body)
    path = folder / f"{name}.toml"
    path.write_text(body, encoding="utf-8")
    return path


def _sub(pattern: str, repl: str):
    def edit(text: str) -> str:
        out, n = re.subn(pattern, repl, text, count=1, flags=re.M)
        assert n == 1, pattern
        return out
    return edit


# --------------------------------------------------------------- refused: exit 2
#: tracker and policy parameter values -> text the message must contain
PARAMETER_CASES = [
    ("jmpd:n_particles=0", "n_particles"),
    ("jmpd:n_particles=-5", "n_particles"),
    ("jmpd:n_particles=abc", "n_particles"),
    ("jmpd:n_particles=", "n_particles"),
    ("jmpd:n_particles=2.5", "n_particles"),
    ("jmpd:n_particles=1" + "0" * 400, "n_particles"),  # beyond float: was an OverflowError
    ("jmpd:birth_rate=1" + "0" * 400, "birth_rate"),
    ("jmpd:t_max=0", "t_max"),
    ("jmpd:proposal=bogus", "proposal"),
    ("jmpd:birth_rate=-1", "birth_rate"),
    ("jmpd:resample_threshold=2", "resample_threshold"),
    ("kfnn:association=bogus", "association"),
    ("kfnn:gate_probability=2", "gate_probability"),
    ("kfnn:false_track_probability=0", "false_track_probability"),
    ("kfnn:lost_track_probability=1", "lost_track_probability"),
    ("gpf:extraction=bogus", "extraction"),
    ("gpf:epsilon=abc", "epsilon"),
    ("gpf:epsilon=-1", "epsilon"),
    ("gpf:epsilon=nan", "epsilon"),
    ("gpf:max_combinations=0", "max_combinations"),
    ("gpf:max_particles=0", "max_particles"),
    ("gpf:births=yes", "births"),
]
POLICY_CASES = [
    ("renyi:alpha=0", "alpha"),
    ("renyi:alpha=-1", "alpha"),
    ("renyi:alpha=abc", "alpha"),
]


def _run(*extra: str, scenario: str = "default", trackers=("null",)) -> list[str]:
    small = SMALL[2:] if {"--seeds", "--seed-list"} & set(extra) else SMALL
    return ["run", "--scenarios", scenario, "--trackers", *trackers, *small, *extra]


def refused_cases(tmp: Path) -> list[tuple[str, list[str], str]]:
    """``(id, argv without --out, regex the one line must match)`` of every input that
    must be refused with exit status 2."""
    huge = scenario_file(tmp, "huge", _sub(r"^nx = \d+", "nx = 1000000"))
    huge = scenario_file(tmp, "huge", _sub(r"^ny = \d+", "ny = 1000000"),
                         text=huge.read_text())
    cases = [
        # command-line values
        ("c-inf", _run("--c", "inf"), r"--c inf .*finite number > 0"),
        ("c-nan", _run("--c", "nan"), r"--c nan .*finite number > 0"),
        ("c-zero", _run("--c", "0"), r"--c 0\.0 .*> 0"),
        ("p-inf", _run("--p", "inf"), r"--p inf .*finite number >= 1"),
        ("p-half", _run("--p", "0.5"), r"--p 0\.5 .*>= 1"),
        ("seed-huge", _run("--seed-list", str(2**64)), r"seed 18446744073709551616 .*2\*\*63"),
        ("seed-negative", _run("--seed-list", "-1"), r"seed -1 .*>= 0"),
        ("seeds-zero", _run("--seeds", "0"), r"--seeds 0 .*from 1"),
        ("seeds-too-many", _run("--seeds", str(10**9)), r"--seeds 1000000000 .*1000000"),
        ("steps-zero", _run("--steps", "0"), r"--steps 0"),
        ("workers-zero", _run("--workers", "0"), r"--workers 0"),
        ("looks-text", _run("--looks", "x"), r"--looks value 'x'"),
        ("looks-negative", _run("--looks", "-1"), r"--looks value -1"),
        ("compare-c-inf", ["compare", "--scenarios", "default", "--trackers", "null", *SMALL,
                           "--c", "inf"], r"--c inf"),
        # names
        ("unknown-tracker", _run(trackers=("nosuch",)), r"nosuch"),
        ("unknown-policy", _run("--policy", "wild"), r"wild"),
        ("unknown-scenario", _run(scenario="nowhere"), r"nowhere"),
        # lenient spellings: what is typed must be what runs
        ("policy-empty", _run("--policy", ""), r"policy: none given"),
        ("tracker-trailing-comma", _run(trackers=("gpf:epsilon=1e-3,",)),
         r"'gpf:epsilon=1e-3,': an empty item \(a trailing or doubled comma\)"),
        ("tracker-full-width-digits", _run(trackers=("gpf:epsilon=\uff10.\uff15",)),
         r"is not ASCII"),
        ("tracker-spaces", _run(trackers=("gpf: epsilon = 0.1",)), r"spaces in 'gpf: epsilon"),
        # scenario files
        ("grid-1e6", _run("--policy", "all", scenario=str(huge)),  # every cell looked at
         r"scenario 'default' \(1000000x1000000 grid.*needs about [\d.]+ TiB of memory.*more than "
         r"the [\d.]+ [GMT]iB"),
        ("snr-db-overflow", _run(scenario=str(scenario_file(
            tmp, "loud", _sub(r"^snr = .*$", "snr_db = 4000.0")))), r"snr_db = 4000\.0.*<= 30"),
        ("snr-underflow", _run(scenario=str(scenario_file(
            tmp, "loud2", _sub(r"^snr = .*$", "snr = 5000.0")))), r"snr = 5000\.0.*underflows"),
        ("cell-size-overflow", _run(scenario=str(scenario_file(
            tmp, "wide", _sub(r"^cell_size = .*$", "cell_size = 1e308")))), r"must be finite"),
        ("tau-overflow", _run(scenario=str(scenario_file(
            tmp, "slowtime", _sub(r"^tau = .*$", "tau = 1e200")))), r"tau = 1e\+200.*overflows"),
        ("name-newline", _run(scenario=str(scenario_file(
            tmp, "nl", text='name = "two\\nlines"\n' + dumps(scenarios.get("default"))
            .split("\n", 1)[1]))), r"name = 'two\\nlines'.*one line"),
        ("not-utf8", _run(scenario=str(_bytes(tmp / "latin.toml", "n_steps = 3 # é\n"
                                              .encode("latin-1")))), r"not UTF-8"),
        ("not-toml", _run(scenario=str(scenario_file(tmp, "junk", text="n_steps = = 3"))),
         r"not valid TOML"),
        ("bad-field", _run(scenario=str(scenario_file(
            tmp, "bad", _sub(r"^n_steps = .*$", 'n_steps = "many"')))), r"n_steps = 'many'"),
        ("missing-file", _run(scenario=str(tmp / "missing.toml")), r"No such file"),
        ("folder-named-toml", _run(scenario=str(_folder(tmp / "dir.toml"))),
         r"cannot read the file"),
    ]
    cases += [(f"tracker-{t}", _run(trackers=(t,)), re.escape(needle))
              for t, needle in PARAMETER_CASES]
    cases += [(f"policy-{t}", _run("--policy", t), re.escape(needle)) for t, needle in POLICY_CASES]
    return cases


def _bytes(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _folder(path: Path) -> Path:
    path.mkdir(exist_ok=True)
    return path


def _ids() -> list[str]:
    """The case ids (the cases themselves are built per test, in its tmp_path)."""
    with tempfile.TemporaryDirectory() as d:
        return [c[0] for c in refused_cases(Path(d))]


CASE_IDS = _ids()


@pytest.mark.parametrize("case_id", CASE_IDS)
def test_refused_with_one_line_and_earlier_results_intact(case_id, earlier, tmp_path, capsys):
    cases = {c[0]: c for c in refused_cases(tmp_path)}
    _, argv, pattern = cases[case_id]
    before = snapshot(earlier)
    capsys.readouterr()
    rc = main([*argv, "--out", str(earlier)])
    captured = capsys.readouterr()
    err = lines(captured.err)
    assert rc == 2, (rc, captured.err)
    assert len(err) == 1, captured.err
    assert "Traceback" not in captured.err and "Traceback" not in captured.out
    assert err[0].startswith(f"mttbench {argv[0]}: error: "), err[0]
    assert re.search(pattern, err[0]), (pattern, err[0])
    assert snapshot(earlier) == before


@pytest.mark.parametrize(("argv", "needle"), [
    (["--out", "{file}"], "exists and is not a folder"),
    (["--out", "{file}/below"], "Not a directory"),
])
def test_output_folder_that_cannot_be_made(argv, needle, earlier, capsys):
    target = earlier / "summary.csv"
    before = snapshot(earlier)
    capsys.readouterr()
    rc = main([*GOOD_RUN, *[a.format(file=target) for a in argv]])
    err = lines(capsys.readouterr().err)
    assert rc == 2 and len(err) == 1 and needle in err[0], err
    assert str(target) in err[0]
    assert snapshot(earlier) == before


def test_read_only_output_folder(tmp_path, capsys):
    if os.geteuid() == 0:  # root ignores permissions: use a file system that refuses
        target = Path("/sys/fs")
        if not target.is_dir() or _writable(target):
            pytest.skip("running as root and no read-only folder to try")
    else:
        target = tmp_path / "ro"
        target.mkdir()
        target.chmod(0o555)
    try:
        rc = main([*GOOD_RUN, "--out", str(target)])
    finally:
        if os.geteuid() != 0:
            target.chmod(0o755)
    err = lines(capsys.readouterr().err)
    assert rc == 2 and len(err) == 1, err
    assert re.search(r"cannot (write into|create) the output folder .*: "
                     r"(Permission denied|Operation not permitted|Read-only)", err[0]), err[0]


def _writable(folder: Path) -> bool:
    try:
        (folder / ".probe").write_bytes(b"")
    except OSError:
        return False
    (folder / ".probe").unlink()
    return True


def test_bad_memory_override_is_refused(monkeypatch, earlier, capsys):
    monkeypatch.setenv(resources.MEMORY_ENV, "lots")
    before = snapshot(earlier)
    assert main([*GOOD_RUN, "--out", str(earlier)]) == 2
    err = lines(capsys.readouterr().err)
    assert len(err) == 1 and resources.MEMORY_ENV in err[0], err
    assert snapshot(earlier) == before


def test_a_grid_too_large_for_the_memory_left(monkeypatch, tmp_path, capsys):
    """1e4 x 1e4 cells, every one looked at each step (the all policy): about 48 GiB of
    looks; refused under an 8 GiB limit (the limit is set, so the test means the same on
    any machine)."""
    monkeypatch.setenv(resources.MEMORY_ENV, "8")
    big = scenario_file(tmp_path, "big", _sub(r"^nx = \d+", "nx = 10000"))
    big = scenario_file(tmp_path, "big", _sub(r"^ny = \d+", "ny = 10000"), text=big.read_text())
    rc = main(["run", "--scenarios", str(big), "--trackers", "null", "--policy", "all",
               "--seeds", "2", "--workers", "2", "--no-progress", "--out", str(tmp_path / "never")])
    err = lines(capsys.readouterr().err)
    assert rc == 2 and len(err) == 1, err
    assert "more than the 4 GiB per worker (8 GiB available / 2 workers)" in err[0], err[0]
    assert not (tmp_path / "never").exists()


def test_compare_resume_without_out_and_nothing_to_resume(monkeypatch, tmp_path, capsys):
    monkeypatch.chdir(tmp_path)
    rc = main(["compare", "--scenarios", "default", "--trackers", "null", *SMALL, "--resume"])
    err = lines(capsys.readouterr().err)
    assert rc == 2 and len(err) == 1 and "no unfinished reports/compare-*" in err[0], err
    assert not (tmp_path / "reports").exists()


# ------------------------------------------------------- runs that fail: exit 1
def test_one_failing_tracker_exits_1_and_keeps_every_other_run(tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["run", "--scenarios", "default", "--trackers", "null", "crashing_tracker:Crash",
               "kfnn", "--seeds", "2", "--steps", "6", "--workers", "2", "--no-progress",
               "--out", str(out)])
    captured = capsys.readouterr()
    assert rc == 1, captured.err
    err = lines(captured.err)
    assert "Traceback" not in captured.err
    failed = [x for x in err if "runs failed" in x]
    assert len(failed) == 1 and err[-1] == failed[0], err
    assert failed[0] == (
        f"2 of 6 runs failed; first error: default/crashing_tracker:Crash/seed 0: "
        f"RuntimeError: deliberate failure at step 3 (step 3); see {out / 'summary.csv'}")
    df = pd.read_parquet(out / "results.parquet")
    ok = df[df["tracker_label"] != "crashing_tracker:Crash"]
    assert (ok["status"] == "ok").all() and len(ok) == 2 * 2 * 6
    crash = df[df["tracker_label"] == "crashing_tracker:Crash"]
    assert list(crash.groupby("seed")["status"].apply(list)) == [["ok"] * 3 + ["error"]] * 2
    summary = pd.read_csv(out / "summary.csv", keep_default_na=False, na_values=[""])
    assert dict(zip(summary["tracker_label"], summary["n_errors"], strict=True)) == {
        "crashing_tracker:Crash": 2, "kfnn": 0, "null": 0}


def test_disk_full_is_one_line_and_leaves_no_temp_file(monkeypatch, earlier, tmp_path,
                                                       capsys):
    # the earlier sweep, its runs to do again (--resume: a sweep's folder takes no other)
    earlier = Path(shutil.copytree(earlier, tmp_path / "out"))
    shutil.rmtree(earlier / "parts")
    before = snapshot(earlier)

    def full(self, path, *args, **kwargs):
        Path(path).write_bytes(b"PAR1 partial")  # a partial file, then the disk is full
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pd.DataFrame, "to_parquet", full)
    rc = main([*GOOD_RUN, "--out", str(earlier), "--resume"])
    err = lines(capsys.readouterr().err)
    assert rc == 1, err
    assert "Traceback" not in "\n".join(err)
    assert err[-1].startswith("mttbench run: error: ") and len(
        [x for x in err if "error" in x]) == 1, err
    assert re.search(r"parts/[0-9a-f]+\.parquet: No space left on device", err[-1]), err[-1]
    assert not temp_files(earlier)
    assert snapshot(earlier) == before


def test_interrupt_in_process_prints_the_resume_command(monkeypatch, tmp_path, capsys):
    """Ctrl-C once the ``null`` run has finished; the ``Slow`` run beside it waits at its
    first step for a gate opened only after the interrupt, so exactly one run is finished
    whatever the machine's load (three ``null`` runs on one worker once finished a third
    while the interrupt was on its way)."""
    from crashing_tracker import gate_env

    out = tmp_path / "out"
    gate = tmp_path / "gate"
    for name, value in gate_env(gate).items():
        monkeypatch.setenv(name, value)  # the forked workers inherit them
    real = executors.wait
    finished = []

    def interrupt_after_the_first_run(fs, timeout=None, return_when=None):
        # Ctrl-C in this process while it waits on its workers, once a run has finished
        if finished:
            raise KeyboardInterrupt
        done, pending = real(fs, timeout=timeout, return_when=return_when)
        finished.extend(done)
        return done, pending

    monkeypatch.setattr(executors, "wait", interrupt_after_the_first_run)
    argv = ["run", "--scenarios", "default", "--trackers", "null", "crashing_tracker:Slow",
            "--seeds", "1", "--steps", "2", "--workers", "2", "--no-progress", "--out", str(out)]
    rc = main(argv)
    err = lines(capsys.readouterr().err)
    assert rc == cli.EXIT_INTERRUPTED
    assert "Traceback" not in "\n".join(err)
    assert err[-1] == (f"mttbench run: interrupted; finished runs are kept in {out}/parts; "
                       f"resume with: mttbench {' '.join(argv[:])} --resume"), err
    assert len(list((out / "parts").glob("*.parquet"))) == 1 and not temp_files(out)
    monkeypatch.setattr(executors, "wait", real)
    gate.touch()
    assert main([*argv, "--resume"]) == 0
    assert len(pd.read_parquet(out / "results.parquet")) == 2 * 2


# ------------------------------------------------- accepted, and said clearly
def test_none_parses_as_none(tmp_path, capsys):
    rc = main(_run(trackers=("jmpd:birth_rate=None,n_particles=50",)) + ["--out", str(tmp_path)])
    assert rc == 0, capsys.readouterr().err
    df = pd.read_parquet(tmp_path / "results.parquet")
    assert (df["status"] == "ok").all()
    assert df["param_birth_rate"].isna().all()


def test_byte_order_mark_is_accepted(tmp_path, capsys):
    path = tmp_path / "bom.toml"
    path.write_text(dumps(scenarios.get("default")), encoding="utf-8-sig")
    assert path.read_bytes()[:3] == b"\xef\xbb\xbf"
    assert main(_run(scenario=str(path)) + ["--out", str(tmp_path / "o")]) == 0
    assert set(pd.read_parquet(tmp_path / "o" / "results.parquet")["status"]) == {"ok"}


def test_scenario_error_names_the_path_once(tmp_path, capsys):
    path = scenario_file(tmp_path, "bad", _sub(r"^n_steps = .*$", "n_steps = 0"))
    assert main(_run(scenario=str(path)) + ["--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count(str(path)) == 1 and "n_steps = 0" in err, err


def test_pipe_in_a_scenario_name_keeps_the_tables(tmp_path, capsys):
    path = tmp_path / "pipe.toml"
    text = dumps(scenarios.get("default")).replace('name = "default"', 'name = "a|b"')
    assert 'name = "a|b"' in text
    path.write_text(text)
    out = tmp_path / "o"
    assert main(["run", "--scenarios", str(path), "--trackers", "null", "kfnn", "--seeds", "2",
                 "--steps", "3", "--workers", "1", "--no-progress", "--out", str(out)]) == 0
    # the compare report's tables, without drawing its figures
    report.build_report(pd.read_parquet(out / "results.parquet"), out, reference="kfnn",
                        draw=False)
    for name in ("summary.md", "report.md"):
        tables, current = [], []
        for line in (out / name).read_text().splitlines() + [""]:
            if line.startswith("|"):
                current.append(line)
            elif current:
                tables.append(current)
                current = []
        assert len(tables) >= (1 if name == "summary.md" else 4), name
        named = 0
        for table in tables:  # an escaped pipe does not split a cell: every row as wide
            widths = {len(re.split(r"(?<!\\)\|", row)) for row in table}
            assert len(widths) == 1, table
            named += sum(row.startswith("| a\\|b |") for row in table)
        assert named >= 2, name


def test_looks_above_the_cell_count_are_recorded(tmp_path, capsys):
    # random looks at distinct cells, so at most the cell count is made (raster wraps
    # and repeats cells instead: tests/test_policies.py)
    out = tmp_path / "o"
    assert main(_run("--looks", "200", "24", "--policy", "random") + ["--out", str(out)]) == 0
    df = pd.read_parquet(out / "results.parquet")
    n_cells = scenarios.get("default").grid.n_cells
    made = df.groupby("looks_per_step")["n_looks"].unique().to_dict()
    assert {k: list(v) for k, v in made.items()} == {24: [24], 200: [n_cells]}
    md = (out / "summary.md").read_text()
    assert f"| 200 ({n_cells} made) |" in md and "| 24 |" in md, md
    summary = pd.read_csv(out / "summary.csv", keep_default_na=False, na_values=[""])
    assert sorted(summary["looks_made"]) == [24, n_cells]


def test_damaged_parts_are_recomputed_on_resume(tmp_path, capsys):
    out = tmp_path / "o"
    argv = _run("--seeds", "3") + ["--out", str(out)]
    assert main(argv) == 0
    reference = pd.read_parquet(out / "results.parquet").drop(columns=TIMING)
    parts = sorted((out / "parts").glob("*.parquet"))
    assert len(parts) == 3
    parts[0].write_bytes(parts[0].read_bytes()[:100])  # truncated
    parts[1].write_bytes(b"")  # empty
    mtime = parts[2].stat().st_mtime_ns
    capsys.readouterr()
    assert main([*argv, "--resume"]) == 0
    err = lines(capsys.readouterr().err)
    damaged = [x for x in err if "damaged part" in x]
    assert len(damaged) == 1 and damaged[0].startswith("2 damaged part file(s) will be "
                                                       "recomputed (first: "), err
    assert "Traceback" not in "\n".join(err)
    assert parts[2].stat().st_mtime_ns == mtime
    again = pd.read_parquet(out / "results.parquet").drop(columns=TIMING)
    pd.testing.assert_frame_equal(again, reference)


def test_stale_temp_files_are_removed_and_live_ones_kept(tmp_path, capsys):
    out = tmp_path / "o"
    (out / "parts").mkdir(parents=True)
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead_pid = int(gone.stdout)
    stale = [out / f".results.parquet.{dead_pid}.tmp",
             out / "parts" / f".abc.parquet.{dead_pid}.tmp"]
    live = out / "parts" / f".def.parquet.{os.getppid()}.tmp"
    other = out / "notes.tmp"
    for p in [*stale, live, other]:
        p.write_bytes(b"x")
    assert main(_run() + ["--out", str(out)]) == 0
    assert not any(p.exists() for p in stale)
    assert live.exists() and other.exists()


# ------------------------------------------------ refused before any run
def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def _symlink(path: Path, target: str) -> Path:
    path.symlink_to(target)
    return path


def _bad_csv(path: Path) -> Path:
    path.write_text("this,is\nnot,a numbers csv\n", encoding="utf-8")
    return path


def late_failure_cases(tmp: Path) -> list[tuple[str, list[str], str]]:
    """``(id, argv, regex the one line must match)``: values that passed validation and
    then overflowed, hung or failed after the work; ``{out}`` is the output
    folder, which must not be created."""
    file = _bytes(tmp / "a-file", b"x")
    tune = ["tune", "kfnn", "--scenarios", "default", "--steps", "2", "--trials", "2",
            "--tuning-seeds", "1", "--no-progress", "--out", "{out}"]
    paper = ["reproduce", "paper", "--reduced", "--no-progress", "--out", "{out}"]
    out = ["--out", "{out}"]
    return [
        ("p-overflows", [*_run("--p", "1000000"), *out], r"--c 2.0 with --p 1000000.0.*c \*\* p"),
        ("c-overflows", [*_run("--c", "1e308"), *out], r"--c 1e\+308 with --p 2.0"),
        ("compare-p-overflows", ["compare", "--trackers", "null", "--p", "1e6", *out],
         r"c \*\* p"),
        ("renyi-alpha-overflows", [*_run("--policy", "renyi:alpha=1e308"), *out],
         r"alpha=1e\+308.*a number in \(0, 100\]"),
        ("scenario-nx-2**70", [*_run(scenario=str(scenario_file(
            tmp, "wide70", _sub(r"^nx = \d+", f"nx = {2**70}")))), *out], r"nx \* ny <="),
        ("scenario-cell-size-1e307", [*_run(scenario=str(scenario_file(
            tmp, "cell307", _sub(r"^cell_size = .*$", "cell_size = 1e307")))), *out],
         r"cell_size = 1e\+307.*at most 1e\+100"),
        ("scenario-wna-1e308", [*_run(scenario=str(scenario_file(
            tmp, "wna308", _sub(r"^wna_intensity = .*$", "wna_intensity = 1e308")))), *out],
         r"process noise Q"),
        ("scenario-fifo", [*_run(scenario=str(_fifo(tmp / "fifo.toml"))), *out],
         r"fifo\.toml'?: not a regular file"),
        ("scenario-symlink-dev-zero", [*_run(scenario=str(_symlink(tmp / "zero.toml",
                                                                   "/dev/zero"))), *out],
         r"zero\.toml'?: not a regular file"),
        ("scenario-too-large", [*_run(scenario=str(_bytes(
            tmp / "large.toml", b"# padding\n" * 120_000))), *out], r"larger than 1048576 bytes"),
        ("out-name-too-long", _run("--out", str(tmp / ("x" * 300))),
         r"--out .* a name longer than the file system allows"),
        ("out-empty", _run("--out", ""), r"--out '' is not allowed"),
        ("trackers-empty", ["run", "--scenarios", "default", "--trackers", "", *SMALL, *out],
         r"--trackers: none given"),
        ("seed-list-empty", [*_run("--seed-list", ""), *out], r"seed: none given"),
        ("run-timeout-zero", [*_run("--run-timeout", "0"), *out], r"--run-timeout 0.0"),
        ("run-timeout-nan", [*_run("--run-timeout", "nan"), *out], r"--run-timeout nan"),
        ("tune-seed-negative", [*tune, "--seed", "-1"], r"--seed -1 is not allowed"),
        ("tune-seed-2**32", [*tune, "--seed", str(2**32)], r"--seed 4294967296"),
        ("tune-seed-start-2**64", [*tune, "--seed-start", str(2**64)],
         r"--seed-start 18446744073709551616 is not allowed"),
        ("tune-trials-1e9", [*tune, "--trials", "1000000000"], r"--trials 1000000000"),
        ("tune-batch-size-0", [*tune, "--batch-size", "0"], r"--batch-size 0"),
        ("tune-startup-trials-negative", [*tune, "--startup-trials", "-1"],
         r"--startup-trials -1 is not allowed"),
        ("tune-run-timeout-zero", [*tune, "--run-timeout", "0"], r"--run-timeout 0.0"),
        ("reproduce-run-timeout-nan", [*paper, "--run-timeout", "nan"], r"--run-timeout nan"),
        ("tune-tuned-dir-file", [*tune, "--tuned-dir", str(file)],
         r"--tuned-dir .*a-file exists and is not a folder"),
        ("compare-tuned-dir-missing", ["compare", "--trackers", "kfnn", "--tuned-dir",
                                       str(tmp / "missing"), *out],
         r"--tuned-dir .*missing: no such folder"),
        ("reproduce-cache-dir-file", [*paper, "--cache-dir", str(file)],
         r"--cache-dir .*a-file exists and is not a folder"),
        ("reproduce-reference-csv-malformed", [*paper, "--check", "--reference-csv",
                                               str(_bad_csv(tmp / "bad.csv"))],
         r"is not a numbers CSV"),
        ("reproduce-check-and-update-reference", [*paper, "--check", "--update-reference"],
         r"--check and --update-reference: give one"),
        ("dask-scheduler-not-a-url", [*_run("--executor", "dask", "--scheduler", "not a url"),
                                      *out], r"--scheduler 'not a url' is not allowed"),
        ("argparse-not-an-int", [*_run("--seeds", "many"), *out],
         r"^mttbench run: error: argument --seeds: invalid int value: 'many' \(see"),
        ("argparse-unknown-option", [*_run("--bogus"), *out],
         r"^mttbench: error: unrecognized arguments: --bogus \(see"),
        ("argparse-unknown-command", ["frobnicate"], r"^mttbench: error: argument COMMAND"),
    ]


def _late_failure_ids() -> list[str]:
    with tempfile.TemporaryDirectory() as d:
        return [c[0] for c in late_failure_cases(Path(d))]


@pytest.mark.parametrize("case_id", _late_failure_ids())
def test_late_failing_value_refused_before_any_run_in_one_line(case_id, tmp_path, capsys):
    cases = {c[0]: c for c in late_failure_cases(tmp_path)}
    _, argv, pattern = cases[case_id]
    out = tmp_path / "never"
    capsys.readouterr()
    rc = main([a.replace("{out}", str(out)) for a in argv])
    captured = capsys.readouterr()
    err = lines(captured.err)
    assert rc == 2, (rc, captured.err)
    assert len(err) == 1, captured.err
    assert "Traceback" not in captured.err and "Traceback" not in captured.out
    assert re.search(r"^mttbench( \w+)?: error: ", err[0]), err[0]
    assert re.search(pattern, err[0]), (pattern, err[0])
    assert not out.exists()
