"""The result store: part files written atomically, read back and checked, and the table.

Every finished run is one Parquet part, ``<out>/parts/<job key>.parquet``, written to a
temp file ``.<name>.<pid>.tmp`` in the same folder and moved into place with
``os.replace``: a part is whole or absent, whatever stops the writer. The results table is
the parts concatenated in a deterministic order (:func:`sort_results`).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
from collections.abc import Callable
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


def _parquet_bytes(df: pd.DataFrame) -> bytes:
    """The bytes :func:`_write_parquet` writes for ``df`` (a part file, made where the job
    ran)."""
    buffer = io.BytesIO()
    df.to_parquet(buffer, index=False)
    return buffer.getvalue()


def _write_bytes(path: Path, data: bytes) -> None:
    """Write a part's bytes (:func:`_parquet_bytes`) like :func:`_write_parquet`."""
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


def _read_part(path: Path) -> pd.DataFrame:
    """A part file as a table; ``ValueError`` (one line) if it is damaged or not a part."""
    try:
        df = pd.read_parquet(path)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises many types for a bad file
        first = (str(exc).strip().splitlines() or [""])[0].replace(f" '{path}'", "")
        raise ValueError(f"{type(exc).__name__}: {first}") from None
    missing = [c for c in (*RUN_KEYS, "step", "status") if c not in df.columns]
    if df.empty or missing:
        raise ValueError("no rows" if df.empty else f"not a results part (no {missing[0]})")
    return df


def sort_results(df: pd.DataFrame) -> pd.DataFrame:
    """Deterministic row order: by run keys, tracker parameters and step."""
    keys = [*RUN_KEYS, "tracker_params", "policy_params", "step"]
    return df.sort_values(keys, kind="stable").reset_index(drop=True)


def _concat(frames: list[pd.DataFrame]) -> pd.DataFrame:
    df = pd.concat(frames, ignore_index=True)
    params = sorted(c for c in df.columns if c.startswith("param_"))
    extra = [c for c in df.columns if c not in COLUMNS and c not in params]
    df = df[COLUMNS + params + extra]
    for col in params:
        # two trackers may share a parameter name with different value types
        values = df[col].dropna()
        if df[col].dtype == object and values.map(type).nunique() > 1:
            df[col] = df[col].map(lambda v: None if v is None else str(v))
    return sort_results(df)


