"""The result store: part files written atomically, read back and checked, and the table.

Every finished run is one Parquet part, ``<out>/parts/<job key>.parquet``, written to a
temp file ``.<name>.<pid>.tmp`` in the same folder and moved into place with
``os.replace``: a part is whole or absent, whatever stops the writer. The results table is
the parts concatenated in a deterministic order (:func:`sort_results`).

The batched **dataset** (docs/result_store.md) is the layout of very large
sweeps: ``<out>/dataset/scenario=<s>/tracker=<t>/batch-<hash>.parquet``, each file the runs
of one worker task with a ``run_key`` column and its runs listed in its metadata
(:func:`batch_frame`), checked on resume run by run (:func:`check_batch`), indexed by
``dataset/manifest.json`` and summarised one file at a time (:func:`dataset_runs`,
:func:`runs_of`). Readers load either layout with :func:`load_results` (every row) or
:func:`load_runs` (one row per run).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import io
import json
import os
import re
import sys
import urllib.parse
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from .errors import ConfigError
from .loop import COLUMNS, RUN_KEYS
from .metrics import metric_columns, run_metric_columns
from .track_series import series_columns

#: temporary file of :func:`_write_parquet`: ``.<name>.<pid of the writer>.tmp``
_TEMP_FILE = re.compile(r"^\..+\.(\d+)\.tmp$")


def _write_parquet(df: pd.DataFrame, path: Path) -> None:
    """Write atomically: a temp file ``.<name>.<pid>.tmp`` in the same folder, then
    ``os.replace``. On any failure (disk full, read-only folder, an interrupt) the temp
    file is removed and ``path`` is left as it was; an ``OSError`` is re-raised naming
    ``path`` (``exc.filename``)."""
    _write_atomic(path, lambda tmp: df.to_parquet(tmp, index=False))


#: a part's identity (:func:`part_identity`): its key in the table's ``attrs``, which
#: pandas keeps in the Parquet schema metadata
PART_META_KEY = "mttbench.part"


def part_identity(df: pd.DataFrame, key: str) -> dict[str, object]:
    """What a part file says about itself: its job ``key``, its number of ``rows`` and the
    run's ``status`` (``error`` if a row failed, else ``unsupported`` or ``ok``); checked
    on read (:func:`_read_part`)."""
    return {"key": str(key), "rows": int(len(df)), "status": _run_status(df)}


def _run_status(df: pd.DataFrame) -> str:
    statuses = set(df["status"]) if "status" in df.columns else set()
    return "error" if "error" in statuses else "unsupported" if "unsupported" in statuses \
        else "ok"


def _with_identity(df: pd.DataFrame, key: str) -> pd.DataFrame:
    """``df`` (a shallow copy) whose ``attrs`` hold its identity: pandas stores them in
    the Parquet file's schema metadata (``PANDAS_ATTRS``) and restores them on read."""
    out = df.copy(deep=False)
    out.attrs = {PART_META_KEY: part_identity(df, key)}
    return out


def _write_part(df: pd.DataFrame, path: Path) -> None:
    """Write a run's part like :func:`_write_parquet`, with its identity in the file's
    metadata (:func:`part_identity`; the job key is the file's name)."""
    path = Path(path)
    _write_parquet(_with_identity(df, path.stem), path)


def _parquet_bytes(df: pd.DataFrame, key: str) -> bytes:
    """The bytes :func:`_write_part` writes for ``df``, the rows of job ``key`` (a part
    file, made where the job ran)."""
    buffer = io.BytesIO()
    _with_identity(df, key).to_parquet(buffer, index=False)
    return buffer.getvalue()


def _write_bytes(path: Path, data: bytes) -> None:
    """Write a part's bytes (:func:`_parquet_bytes`) like :func:`_write_part`."""
    _write_atomic(Path(path), lambda tmp: tmp.write_bytes(data))


def write_text_atomic(path: Path, text: str) -> None:
    """Write a text file (UTF-8) like :func:`_write_parquet`: all or nothing."""
    _write_atomic(Path(path), lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _write_atomic(path: Path, write: Callable[[Path], object]) -> None:
    """``write`` a temp file in the same folder, then ``os.replace`` it onto ``path``;
    on any failure remove the temp file and re-raise (an ``OSError`` naming ``path``)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise


def prepare_out_dir(out_dir: str | Path, parts: bool = True) -> Path:
    """Create the output folder (and its ``parts/`` unless ``parts=False``) and check
    that files can be written there, before any run; a problem (the path is a file, a
    parent is a file, no permission, a read-only file system) raises
    :class:`~mttbench.benchmarks.engine.specs.ConfigError` in one line."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"output folder {out} exists and is not a folder")
    for folder in (out, out / "parts") if parts else (out,):
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"cannot create the output folder {folder}: "
                             f"{exc.strerror or exc}") from None
        probe = folder / f".write-test.{os.getpid()}.tmp"
        try:
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise ConfigError(f"cannot write into the output folder {folder}: "
                             f"{exc.strerror or exc}") from None
    return out


#: the two layouts of a sweep's results (``sweep.json``'s ``store``): one Parquet part
#: per run (``parts/``), or runs batched per worker task into a dataset (``dataset/``)
STORE_PARTS, STORE_DATASET = "parts", "dataset"
STORES = (STORE_PARTS, STORE_DATASET)
DATASET_DIR = "dataset"
#: the environment variable that chooses the layout when the caller does not
#: (``store=None``): ``parts`` or ``dataset`` (e.g. ``MTTBENCH_STORE=dataset mttbench run``)
STORE_ENV = "MTTBENCH_STORE"
#: the lock file of :func:`sweep_lock` and the manifest of :func:`check_sweep`
LOCK_FILE = ".mttbench.lock"
SWEEP_MANIFEST = "sweep.json"
#: folders this process holds the lock of: real path -> [fd, depth, pid]
_LOCKS: dict[str, list[int]] = {}


def release_inherited_locks() -> None:
    """In a forked child (a pool worker): close the lock files inherited from its parent,
    without unlocking them (``flock`` belongs to the open file, which the parent still
    holds), so that a worker left running after its parent died holds no folder."""
    for ident, (fd, _, pid) in list(_LOCKS.items()):
        if pid != os.getpid():
            _LOCKS.pop(ident, None)
            with contextlib.suppress(OSError):
                os.close(fd)


def _process_start(pid: int) -> str | None:
    """When process ``pid`` started (clock ticks since boot, ``/proc/<pid>/stat``), so a
    reused pid is not taken for the holder; None where ``/proc`` cannot say. ``"Z"`` for a
    zombie (dead, not yet reaped)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rfind(")") + 2:].split()
    return "Z" if fields[0] in ("Z", "X") else fields[19]


def _owner_line() -> str:
    pid = os.getpid()
    return f"{pid} {os.uname().nodename} {_process_start(pid) or '-'}\n"


def _owner_gone(fd: int) -> int | None:
    """The pid recorded in the lock file ``fd`` (:func:`_owner_line`) if that process is
    gone (this host, not running, or running with another start time: a reused pid), else
    None (alive, another host's, or not recorded: the lock is respected)."""
    try:
        pid_text, host, start = os.pread(fd, 4096, 0).decode().split()
        pid = int(pid_text)
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if host != os.uname().nodename or pid <= 0:
        return None
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return pid
    except OSError:
        return None
    now = _process_start(pid)
    return pid if now == "Z" or (start != "-" and now is not None and now != start) else None


def _take_over(path: Path, stale_ino: int) -> bool:
    """Unlink the stale lock file ``path`` (inode ``stale_ino``) under a guard lock, so
    that of two processes taking it over at once one replaces it; False if another
    process is at it or has replaced it already."""
    guard = path.with_name(path.name + ".takeover")
    gfd = os.open(guard, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(gfd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(gfd)
        return False
    try:
        try:
            if os.stat(path).st_ino != stale_ino:
                return False
        except FileNotFoundError:
            return False
        path.unlink()
        return True
    finally:
        os.close(gfd)


def _acquire(folder: Path) -> int:
    """The file descriptor of the folder's lock file, locked (see :func:`sweep_lock`)."""
    path = folder / LOCK_FILE
    for _ in range(5):
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise ConfigError(f"cannot write into the output folder {folder}: "
                              f"{exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            gone, ino = _owner_gone(fd), os.fstat(fd).st_ino
            os.close(fd)
            if gone is None:
                raise ConfigError(f"{folder} is in use by another mttbench process: wait "
                                  "for it to end, or choose another --out") from None
            if _take_over(path, ino):
                print(f"{path}: its holder (pid {gone}) is gone; taking its lock over (a "
                      "leftover worker of it may still be running)", file=sys.stderr)
            continue
        try:  # the path may have been replaced since it was opened (a take-over)
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if not same:
            os.close(fd)
            continue
        os.ftruncate(fd, 0)
        os.pwrite(fd, _owner_line().encode(), 0)
        return fd
    raise ConfigError(f"{folder} is in use by another mttbench process: wait for it to "
                      "end, or choose another --out")


@contextlib.contextmanager
def sweep_lock(out_dir: str | Path) -> Iterator[None]:
    """Hold the output folder's advisory lock (``fcntl.flock`` on ``.mttbench.lock``)
    meanwhile: one writer per folder. Another process holding it raises
    :class:`ConfigError` (one line) at once; the same process may nest it.

    The file records its holder (pid, host, start time). A lock held though its holder
    is gone (a worker process of a killed sweep that outlived it, with the lock file
    inherited) is stale: the file is replaced by a new one, with a one-line notice on
    stderr (the leftover keeps a lock on the old file, which no one reads)."""
    folder = Path(out_dir)
    ident = os.path.realpath(folder)
    held = _LOCKS.get(ident)
    if held is not None and held[2] == os.getpid():
        held[1] += 1
        try:
            yield
        finally:
            held[1] -= 1
        return
    fd = _acquire(folder)
    _LOCKS[ident] = [fd, 1, os.getpid()]
    try:
        yield
    finally:
        _LOCKS.pop(ident, None)
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def read_sweep_manifest(out_dir: str | Path) -> dict | None:
    """The folder's ``sweep.json`` (None if absent); :class:`ConfigError` if unreadable."""
    path = Path(out_dir) / SWEEP_MANIFEST
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(data, dict) or not isinstance(data.get("jobs"), list):
            raise ValueError("not a sweep manifest")
    except (OSError, ValueError) as exc:
        raise ConfigError(f"cannot read {path} ({type(exc).__name__}: "
                          f"{' '.join(str(exc).split())}): remove it, or choose another "
                          "--out") from None
    return data


def resolve_store(out_dir: str | Path, store: str | None, extend: bool = False) -> str:
    """The results layout of a sweep into ``out_dir``: ``store`` if given; else the
    environment's :data:`STORE_ENV` (an ``extend`` sweep, tune's, keeps ``parts``); else
    the layout of the sweep the folder holds (its ``sweep.json``); else ``parts``.
    :class:`ConfigError` for an unknown name."""
    if store is None and os.environ.get(STORE_ENV):
        store = STORE_PARTS if extend else os.environ[STORE_ENV]
    if store is None:
        old = read_sweep_manifest(out_dir) if (Path(out_dir) / SWEEP_MANIFEST).exists() \
            else None
        store = STORE_PARTS if old is None else str(old.get("store", STORE_PARTS))
    if store not in STORES:
        raise ConfigError(f"store {store!r} is not one of {', '.join(STORES)}")
    return store


def check_sweep(out_dir: str | Path, keys: list[str] | None, c: float, p: float,
                resume: bool, extend: bool = False, store: str | None = None) -> dict:
    """Check that the folder may take this sweep (job ``keys``, ``c``, ``p``, results
    layout ``store``, None: :func:`resolve_store`); returns the manifest to write
    (:func:`write_sweep_manifest`). A
    folder holding another sweep's manifest, or this sweep's without ``resume``, or parts
    or batches without a manifest and without ``resume``, raises :class:`ConfigError`
    (one line). ``extend``: a sweep that grows (tune's batches): its manifest gathers the
    keys of every batch; ``keys`` None checks the kind and ``c``, ``p`` only."""
    out = Path(out_dir)
    store = resolve_store(out, store, extend)
    old = read_sweep_manifest(out)
    mine = sorted(set(keys or []))
    if old is None:
        parts, dataset = out / "parts", out / DATASET_DIR
        if not resume and ((parts.is_dir() and any(parts.glob("*.parquet"))) or (
                dataset.is_dir() and any(dataset.rglob("batch-*.parquet")))):
            raise ConfigError(f"{out} already holds the runs of a sweep: finish it with "
                              "--resume, or choose another --out")
        manifest = {"format": 1, "extend": extend, "c": None if c is None else float(c),
                    "p": float(p),
                    "jobs": mine}
        if store != STORE_PARTS:  # a parts sweep's manifest stays as it was
            manifest["store"] = store
        return manifest
    same_kind = (bool(old.get("extend")) == extend
                 and old.get("c") == (None if c is None else float(c))
                 and old.get("p") == float(p) and old.get("store", STORE_PARTS) == store)
    if not same_kind or (not extend and keys is not None and sorted(old["jobs"]) != mine):
        raise ConfigError(f"{out} holds another sweep ({SWEEP_MANIFEST}): resume that one "
                          "with its own options and --resume, or choose another --out")
    if not resume:
        raise ConfigError(f"{out} already holds this sweep: finish it with --resume, or "
                          "choose another --out")
    return {**old, "jobs": sorted({*old["jobs"], *mine})}


def write_sweep_manifest(out_dir: str | Path, manifest: dict) -> None:
    write_text_atomic(Path(out_dir) / SWEEP_MANIFEST,
                      json.dumps(manifest, indent=1, sort_keys=True) + "\n")


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # this process writes nothing before the sweep starts
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process
        return True
    return True


def remove_stale_temp_files(folder: Path) -> list[Path]:
    """Remove the temp files of :func:`_write_parquet` left in ``folder`` by processes
    that are gone (a killed sweep); returns them. A live process's file is kept."""
    removed = []
    try:
        candidates = [p for p in folder.iterdir() if _TEMP_FILE.match(p.name)]
    except OSError:
        return removed
    for path in candidates:
        if not _pid_alive(int(_TEMP_FILE.match(path.name).group(1))):
            with contextlib.suppress(OSError):
                path.unlink()
                removed.append(path)
    return removed


def _read_part(path: Path, key: str | None = None,
               n_steps: int | None = None) -> pd.DataFrame:
    """A part file as a table; ``ValueError`` (one line) if it is damaged, not a part, or
    (given the job's ``key`` and ``n_steps``) not this job's whole rows: its identity
    (:func:`part_identity`) must name ``key``, its row count and status must match its
    rows, and its steps must be ``0..n_steps-1`` (ok), ``-1`` (unsupported) or ``0..k-1``
    then the error row at ``k`` (failed)."""
    try:
        df = pd.read_parquet(path)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises many types for a bad file
        first = (str(exc).strip().splitlines() or [""])[0].replace(f" '{path}'", "")
        raise ValueError(f"{type(exc).__name__}: {first}") from None
    missing = [c for c in (*RUN_KEYS, "step", "status") if c not in df.columns]
    if df.empty or missing:
        raise ValueError("no rows" if df.empty else f"not a results part (no {missing[0]})")
    ident = df.attrs.get(PART_META_KEY)
    df.attrs = {}
    if key is None:
        return df
    if not isinstance(ident, dict):
        raise ValueError("no job identity in its metadata (not written by this sweep)")
    if ident.get("key") != key:
        raise ValueError(f"holds the rows of another run (job {ident.get('key')!r})")
    if ident.get("rows") != len(df) or ident.get("status") != _run_status(df):
        raise ValueError(f"incomplete: {len(df)} rows ({_run_status(df)}), its metadata "
                         f"says {ident.get('rows')} ({ident.get('status')})")
    if n_steps is not None:
        steps = [int(k) for k in df["step"]]
        status = list(df["status"])
        if ident["status"] == "ok":
            good = steps == list(range(int(n_steps)))
        elif ident["status"] == "unsupported":
            good = steps == [-1]
        else:
            k = steps[-1]
            good = (steps == [*range(k), k] and k < int(n_steps) and status[-1] == "error"
                    and "error" not in status[:-1])
        if not good:
            raise ValueError(f"incomplete: {len(df)} rows for a {ident['status']} run of "
                             f"{n_steps} steps")
    return df


def sort_results(df: pd.DataFrame) -> pd.DataFrame:
    """Deterministic row order: by run keys, tracker parameters and step."""
    keys = [*RUN_KEYS, "tracker_params", "policy_params", "step"]
    return df.sort_values(keys, kind="stable").reset_index(drop=True)


def _concat(frames: list[pd.DataFrame]) -> pd.DataFrame:
    df = pd.concat(frames, ignore_index=True)
    df.attrs = {}
    params = sorted(c for c in df.columns if c.startswith("param_"))
    extra = [c for c in df.columns if c not in COLUMNS and c not in params]
    df = df[COLUMNS + params + extra]
    for col in params:
        # two trackers may share a parameter name with different value types
        values = df[col].dropna()
        if df[col].dtype == object and values.map(type).nunique() > 1:
            df[col] = df[col].map(lambda v: None if v is None else str(v))
    return sort_results(df)




# ------------------------------------------------------------ the batched dataset
#: the dataset's index (:func:`write_dataset_manifest`): its files and the runs each holds
DATASET_MANIFEST = "manifest.json"
#: the per-run table of a dataset sweep (:func:`runs_of`), next to ``sweep.json``
RUNS_FILE = "runs.parquet"
#: a batch's identity in its ``attrs`` (the Parquet schema metadata, like a part's)
BATCH_META_KEY = "mttbench.batch"
#: the column of a batch that names each row's run (its job key)
RUN_KEY = "run_key"
#: a batch file's name: ``batch-<name>.parquet``
_BATCH_FILE = re.compile(r"^batch-([0-9a-f]+)\.parquet$")


def _path_value(value: object) -> str:
    """A partition value as a safe folder name component (``scenario=<it>``): percent-
    encoded, never ``.``/``..``, long names cut with a hash of the whole."""
    text = urllib.parse.quote(str(value), safe="")
    if text.startswith("."):
        text = "%2E" + text[1:]
    if len(text) > 96:
        text = text[:72] + "-" + hashlib.sha256(text.encode()).hexdigest()[:16]
    return text


def batch_name(keys: Sequence[str]) -> str:
    """The name of the batch of runs ``keys`` (their job keys, in order): a hash of them,
    so a batch re-made of the same runs (a resumed sweep) lands on the same file."""
    return hashlib.sha256("\n".join(keys).encode()).hexdigest()[:24]


def batch_path(out_dir: str | Path, scenario: str, tracker: str, name: str) -> Path:
    """``<out>/dataset/scenario=<s>/tracker=<t>/batch-<name>.parquet`` (Hive-style folders:
    one partition per scenario and tracker name)."""
    return (Path(out_dir) / DATASET_DIR / f"scenario={_path_value(scenario)}"
            / f"tracker={_path_value(tracker)}" / f"batch-{name}.parquet")


def batch_frame(runs: Sequence[tuple[str, pd.DataFrame]], name: str,
                replaces: Sequence[str] = ()) -> pd.DataFrame:
    """The rows of the runs ``(job key, rows)`` of batch ``name``, in order, with a
    ``run_key`` column; its ``attrs`` hold the batch's identity (written in the Parquet
    schema metadata): ``{"batch": name, "runs": [[key, rows, status], ...]}`` with each
    run's :func:`part_identity`, and ``replaces``: the names of the checkpoint batches of
    these runs that :func:`write_batch` removes. A run's rows are contiguous, in the
    order listed."""
    frames = []
    for key, df in runs:
        frame = df.copy(deep=False)
        frame.attrs = {}
        frame[RUN_KEY] = key
        frames.append(frame)
    out = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=[RUN_KEY])
    ident: dict = {"batch": name, "runs": [
        [key, int(len(df)), _run_status(df)] for key, df in runs]}
    if replaces:
        ident["replaces"] = list(replaces)
    out.attrs = {BATCH_META_KEY: ident}
    return out


def _remove_replaced(path: Path) -> None:
    """Remove the checkpoint batches that the batch file ``path`` lists as ``replaces``
    (each holds some of its runs), from its folder."""
    with contextlib.suppress(Exception):
        attrs = json.loads((pq.read_metadata(path).metadata or {}).get(b"PANDAS_ATTRS",
                                                                       b"{}"))
        for name in attrs[BATCH_META_KEY].get("replaces", []):
            if re.fullmatch(r"[0-9a-f]+", str(name)) and name != _batch_stem(path):
                (path.parent / f"batch-{name}.parquet").unlink(missing_ok=True)


def _batch_stem(path: Path) -> str | None:
    match = _BATCH_FILE.match(Path(path).name)
    return None if match is None else match.group(1)


def write_batch(df: pd.DataFrame, path: Path) -> None:
    """Write a batch like :func:`_write_parquet`, then remove its checkpoints."""
    _write_parquet(df, path)
    _remove_replaced(Path(path))


def write_batch_bytes(path: Path, data: bytes) -> None:
    """Write a batch's bytes (:func:`frame_bytes`), then remove its checkpoints."""
    _write_bytes(Path(path), data)
    _remove_replaced(Path(path))


def frame_bytes(df: pd.DataFrame, key: str) -> bytes:
    """``df`` (its ``attrs`` included) as Parquet bytes (a batch made where it ran)."""
    buffer = io.BytesIO()
    df.to_parquet(buffer, index=False)
    return buffer.getvalue()


def read_batch_identity(path: Path) -> dict:
    """A batch file's identity (:func:`batch_frame`) from its footer alone; ``ValueError``
    (one line) if the file is damaged, is not a batch, is not the batch its name says, or
    holds another number of rows than its identity lists (a torn or partial batch)."""
    try:
        meta = pq.read_metadata(path)
        attrs = json.loads((meta.metadata or {}).get(b"PANDAS_ATTRS", b"{}"))
    except Exception as exc:  # noqa: BLE001 - pyarrow raises many types for a bad file
        first = (str(exc).strip().splitlines() or [""])[0].replace(f" '{path}'", "")
        raise ValueError(f"{type(exc).__name__}: {first}") from None
    ident = attrs.get(BATCH_META_KEY) if isinstance(attrs, dict) else None
    match = _BATCH_FILE.match(Path(path).name)
    if not isinstance(ident, dict) or not isinstance(ident.get("runs"), list):
        raise ValueError("no batch identity in its metadata (not written by this sweep)")
    if match is None or ident.get("batch") != match.group(1):
        raise ValueError(f"holds another batch ({ident.get('batch')!r})")
    try:
        runs = [(str(k), int(n), str(s)) for k, n, s in ident["runs"]]
    except (TypeError, ValueError):
        raise ValueError("its identity lists malformed runs") from None
    if sum(n for _, n, _ in runs) != meta.num_rows:
        raise ValueError(f"incomplete: {meta.num_rows} rows, its identity lists "
                         f"{sum(n for _, n, _ in runs)}")
    return {"batch": ident["batch"], "runs": runs}


def _rows_fit(steps: np.ndarray, status: np.ndarray, run_status: str, n_steps: int) -> bool:
    """A run's rows are whole (:func:`_read_part`'s rule): steps ``0..n_steps-1`` all ok,
    or the one row ``-1`` (unsupported, or an error before the first step), or ``0..k-1``
    ok then the error row at ``k < n_steps``."""
    if run_status == "ok":
        return (len(steps) == n_steps and np.array_equal(steps, np.arange(n_steps))
                and bool((status == "ok").all()))
    if run_status == "unsupported":
        return len(steps) == 1 and steps[0] == -1 and status[0] == "unsupported"
    if run_status != "error" or not len(steps):
        return False
    k = int(steps[-1])
    head = np.arange(k) if k >= 0 else np.arange(0)
    return (k < n_steps and np.array_equal(steps[:-1], head) and status[-1] == "error"
            and bool((status[:-1] == "ok").all()))


def check_batch(path: Path, n_steps: Callable[[str], int | None]
                ) -> tuple[list[str], int, str]:
    """The runs of batch file ``path`` that are whole, and why the others are not.

    The identity (:func:`read_batch_identity`) must hold; then the file's ``run_key``,
    ``step`` and ``status`` columns are read, and each listed run must own its rows
    (contiguous, in the listed order) and fit its status with ``n_steps(key)`` steps
    (:func:`_rows_fit`); ``n_steps(key)`` None means the run is not this sweep's (skipped,
    not reported). Returns ``(good keys, number of runs listed, first problem or "")``;
    ``ValueError`` if the file itself is damaged."""
    ident = read_batch_identity(path)
    try:
        table = pq.read_table(path, columns=[RUN_KEY, "step", "status"])
    except Exception as exc:  # noqa: BLE001
        raise ValueError(f"{type(exc).__name__}: {' '.join(str(exc).split())}") from None
    keys = table.column(RUN_KEY).to_numpy(zero_copy_only=False)
    steps = table.column("step").to_numpy(zero_copy_only=False)
    status = table.column("status").to_numpy(zero_copy_only=False)
    good, problem, start = [], "", 0
    for key, rows, run_status in ident["runs"]:
        seg = slice(start, start + rows)
        start += rows
        want = n_steps(key)
        if want is None:
            continue
        if not (keys[seg] == key).all():
            problem = problem or f"run {key}: its rows name another run"
        elif not _rows_fit(steps[seg], status[seg], run_status, int(want)):
            problem = problem or (f"run {key}: incomplete ({rows} rows for a {run_status} "
                                  f"run of {want} steps)")
        else:
            good.append(key)
    return good, len(ident["runs"]), problem


def write_dataset_manifest(out_dir: str | Path, files: Sequence[tuple[Path, list[str],
                                                                        int]]) -> None:
    """The dataset's index, ``dataset/manifest.json``: each file (relative path), the runs
    of the sweep it holds (``runs``; a file's other rows are not the sweep's) and whether
    those are all its runs (``whole``). Readers (:func:`iter_dataset`) go by it."""
    root = Path(out_dir) / DATASET_DIR
    entries = [{"path": Path(path).relative_to(root).as_posix(), "runs": list(keys),
                "whole": len(keys) == n_runs}
               for path, keys, n_runs in sorted(files, key=lambda f: str(f[0]))]
    write_text_atomic(root / DATASET_MANIFEST,
                      json.dumps({"format": 1, "files": entries}, separators=(",", ":")) + "\n")


def iter_dataset(out_dir: str | Path, columns: Sequence[str] | None = None
                 ) -> Iterator[pd.DataFrame]:
    """The rows of a dataset sweep, one batch file at a time (with its ``run_key``
    column), as listed by its manifest: only the runs it lists (a file's other rows are
    dropped). ``columns``: those of them the file has (``run_key`` always).
    :class:`ConfigError` if the folder has no finished dataset."""
    root = Path(out_dir) / DATASET_DIR
    try:
        manifest = json.loads((root / DATASET_MANIFEST).read_text(encoding="utf-8"))
        entries = list(manifest["files"])
    except (OSError, ValueError, KeyError, TypeError):
        raise ConfigError(f"{out_dir} holds no finished results dataset ({DATASET_DIR}/"
                          f"{DATASET_MANIFEST}): finish the sweep with --resume") from None
    for entry in entries:
        path = root / entry["path"]
        cols = None
        if columns is not None:
            have = set(pq.read_schema(path).names)
            cols = [c for c in dict.fromkeys([*columns, RUN_KEY]) if c in have]
        df = pd.read_parquet(path, columns=cols)
        df.attrs = {}
        if not entry.get("whole", False):
            df = df[df[RUN_KEY].isin(set(entry["runs"]))]
        yield df


def load_results(out_dir: str | Path) -> pd.DataFrame:
    """The step-level results table of a sweep's folder, whatever its layout:
    ``results.parquet`` (the per-run parts' table) or the batched dataset concatenated
    (its rows in :func:`sort_results` order, without ``run_key``). The dataset of a very
    large sweep may not fit in memory: use :func:`load_runs`, or :func:`iter_dataset`."""
    out = Path(out_dir)
    if (out / "results.parquet").is_file():
        return pd.read_parquet(out / "results.parquet")
    frames = [df.drop(columns=[RUN_KEY]) for df in iter_dataset(out)]
    return _concat(frames) if frames else pd.DataFrame(columns=COLUMNS)


def load_runs(out_dir: str | Path) -> pd.DataFrame:
    """One row per run (:func:`runs_of`) of a sweep's folder: ``runs.parquet`` of a
    dataset sweep, else computed from ``results.parquet``."""
    out = Path(out_dir)
    if (out / RUNS_FILE).is_file():
        return pd.read_parquet(out / RUNS_FILE)
    return runs_of(load_results(out))


#: columns carried into the per-run table (constant within a run), and the run times
_RUN_CARRY = ["tracker", "policy", "tracker_uses_truth", "policy_uses_truth"]
RUN_TIMES = ["tracker_wall_s", "tracker_wall_p95_s", "tracker_wall_max_s", "tracker_cpu_s",
             "select_wall_s", "peak_rss_mb"]


def runs_columns() -> list[str]:
    """The columns of a step table that :func:`runs_of` reads (those it has)."""
    series = set(series_columns())
    return list(dict.fromkeys([
        *RUN_KEYS, *_RUN_CARRY, "status", "error", *metric_columns(display=True),
        *(c for c in run_metric_columns() if c not in series), "tracker_wall_s",
        "tracker_cpu_s", "select_wall_s", "peak_rss_mb", "n_looks", RUN_KEY]))


def runs_of(results: pd.DataFrame) -> pd.DataFrame:
    """One row per run of a step table, grouped with vectorised (``groupby``) statistics:
    the same table as the app's ``summary.per_run`` (its definitions: step metrics the
    NaN-aware mean over the run's ok steps, run-level metrics the run's value if every
    step was ok, else NaN; ``tracker_wall_s``/``tracker_cpu_s`` the median ok step,
    ``tracker_wall_p95_s`` the 95th percentile with linear interpolation (numpy's
    default), ``tracker_wall_max_s`` the slowest ok step, ``select_wall_s`` the mean,
    ``peak_rss_mb`` the maximum, ``status`` ``ok`` if every step was ok else
    ``unsupported`` if one was else ``error``, ``error`` the first message,
    ``n_steps`` the ok steps, ``looks_made`` the mean ``n_looks`` of ok steps), sorted by
    the run keys. Means are pandas' group sums over counts, so they may differ from
    numpy's pairwise mean in the last bits (tests/test_result_store.py compares them)."""
    if RUN_KEY in results.columns:
        key = results[RUN_KEY]
    else:
        key = pd.Series(pd.MultiIndex.from_frame(results[RUN_KEYS].astype(str)).to_flat_index()
                        .map("\x1f".join), index=results.index)
    steps = [c for c in metric_columns(display=True) if c in results.columns]
    series = set(series_columns())  # per-step series: their run values are listed already
    track = [c for c in run_metric_columns() if c in results.columns and c not in series]
    carry = [c for c in _RUN_CARRY if c in results.columns]
    groups = results.groupby(key, sort=False)
    out = groups[[*RUN_KEYS, *carry]].first()
    is_ok = results["status"].eq("ok")
    all_ok = is_ok.groupby(key, sort=False).all()
    unsupported = results["status"].eq("unsupported").groupby(key, sort=False).any()
    out["status"] = np.where(all_ok, "ok", np.where(unsupported, "unsupported", "error"))
    bad = results.loc[~is_ok]
    out["error"] = bad.groupby(key[~is_ok], sort=False)["error"].first().reindex(
        out.index).fillna("").astype(str)
    ok = results.loc[is_ok]
    ok_groups = ok.groupby(key[is_ok], sort=False)
    out["n_steps"] = ok_groups.size().reindex(out.index).fillna(0).astype("int64")
    if steps:
        out[steps] = ok_groups[steps].mean().reindex(out.index)
    if track:
        values = ok_groups[track].first().reindex(out.index)
        out[track] = values.where(out["status"].eq("ok"), axis=0)
    wall = ok_groups["tracker_wall_s"]
    out["tracker_wall_s"] = wall.median().reindex(out.index)
    out["tracker_wall_p95_s"] = wall.quantile(0.95).reindex(out.index)
    out["tracker_wall_max_s"] = wall.max().reindex(out.index)
    out["tracker_cpu_s"] = ok_groups["tracker_cpu_s"].median().reindex(out.index)
    out["select_wall_s"] = ok_groups["select_wall_s"].mean().reindex(out.index)
    out["peak_rss_mb"] = groups["peak_rss_mb"].max()
    cols = [*RUN_KEYS, *carry, "status", "error", "n_steps", *steps, *track, *RUN_TIMES]
    if "n_looks" in results.columns:
        out["looks_made"] = ok_groups["n_looks"].mean().reindex(out.index)
        cols.append("looks_made")
    for c in [*steps, *track, *RUN_TIMES, *(["looks_made"] if "looks_made" in out else [])]:
        out[c] = out[c].astype("float64")
    out = out[cols].sort_values(RUN_KEYS, kind="stable").reset_index(drop=True)
    return out


def dataset_runs(out_dir: str | Path, extra: Sequence[pd.DataFrame] = ()) -> pd.DataFrame:
    """:func:`runs_of` over a dataset sweep, streamed: one batch file at a time (only the
    columns it needs), so memory holds one batch's rows and the per-run table; ``extra``
    step tables (the error rows of lost runs) are added. A run's rows are all in one
    batch, so grouping file by file is the whole group-by."""
    parts = [runs_of(df) for df in iter_dataset(out_dir, columns=runs_columns())]
    parts.extend(runs_of(df) for df in extra if len(df))
    if not parts:
        return runs_of(pd.DataFrame(columns=[*COLUMNS, RUN_KEY]))
    runs = pd.concat(parts, ignore_index=True)
    return runs.sort_values(RUN_KEYS, kind="stable").reset_index(drop=True)
