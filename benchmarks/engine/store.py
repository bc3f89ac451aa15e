"""The result store: part files written atomically, read back and checked, and the table.

Every finished run is one Parquet part, ``<out>/parts/<job key>.parquet``, written to a
temp file ``.<name>.<pid>.tmp`` in the same folder and moved into place with
``os.replace``: a part is whole or absent, whatever stops the writer. The results table is
the parts concatenated in a deterministic order (:func:`sort_results`).
"""

from __future__ import annotations

import contextlib
import fcntl
import io
import json
import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path

import pandas as pd

from .errors import ConfigError
from .loop import COLUMNS, RUN_KEYS

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


#: the lock file of :func:`sweep_lock` and the manifest of :func:`check_sweep`
LOCK_FILE = ".mttbench.lock"
SWEEP_MANIFEST = "sweep.json"
#: folders this process holds the lock of: real path -> [fd, depth, pid]
_LOCKS: dict[str, list[int]] = {}


@contextlib.contextmanager
def sweep_lock(out_dir: str | Path) -> Iterator[None]:
    """Hold the output folder's advisory lock (``fcntl.flock`` on ``.mttbench.lock``)
    meanwhile: one writer per folder. Another process holding it raises
    :class:`ConfigError` (one line) at once; the same process may nest it."""
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
    try:
        fd = os.open(folder / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise ConfigError(f"cannot write into the output folder {folder}: "
                          f"{exc.strerror or exc}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise ConfigError(f"{folder} is in use by another mttbench process: wait for it to "
                          "end, or choose another --out") from None
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


def check_sweep(out_dir: str | Path, keys: list[str] | None, c: float, p: float,
                resume: bool, extend: bool = False) -> dict:
    """Check that the folder may take this sweep (job ``keys``, ``c``, ``p``); returns the
    manifest to write (:func:`write_sweep_manifest`). A folder holding another sweep's
    manifest, or this sweep's without ``resume``, or parts without a manifest and without
    ``resume``, raises :class:`ConfigError` (one line). ``extend``: a sweep that grows
    (tune's batches): its manifest gathers the keys of every batch; ``keys`` None checks
    the kind and ``c``, ``p`` only."""
    out = Path(out_dir)
    old = read_sweep_manifest(out)
    mine = sorted(set(keys or []))
    if old is None:
        parts = out / "parts"
        if not resume and parts.is_dir() and any(parts.glob("*.parquet")):
            raise ConfigError(f"{out} already holds the runs of a sweep: finish it with "
                              "--resume, or choose another --out")
        return {"format": 1, "extend": extend, "c": float(c), "p": float(p), "jobs": mine}
    same_kind = (bool(old.get("extend")) == extend and old.get("c") == float(c)
                 and old.get("p") == float(p))
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


