"""The command line's executor options (``--executor``, ``--scheduler``, ``--retries``,
``--no-worker-timeout``) and the executor they choose, current while a command runs."""

from __future__ import annotations

import argparse
import contextlib
import os
from collections.abc import Iterator

from ..engine.dask_watch import NO_WORKER_FLOOR_S
from ..engine.executors import (
    DEFAULT_RETRIES,
    EXECUTORS,
    DaskExecutor,
    Executor,
    LocalExecutor,
    check_no_worker_timeout,
    check_retries,
    use_executor,
)
from .usage import UsageError


def add_executor_arguments(parser: argparse.ArgumentParser, workers: bool = False) -> None:
    """``--executor``, ``--scheduler`` and ``--retries`` (and ``--workers`` if asked: the
    run, compare and reproduce commands have their own)."""
    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help="where the runs go: local processes (default) or a Dask "
                             "cluster (pip install 'mttbench[dask]')")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="with --executor dask: an existing cluster's scheduler, "
                             "tcp://HOST:PORT (default: a LocalCluster of --workers "
                             "processes on this machine)")
    parser.add_argument("--retries", type=int, default=DEFAULT_RETRIES, metavar="N",
                        help="times a run lost with its worker process is run again "
                             f"before it counts as failed (default {DEFAULT_RETRIES})")
    parser.add_argument("--no-worker-timeout", type=float, default=None, metavar="SECONDS",
                        help="with --executor dask: when the cluster has had no worker for "
                             "this long while runs wait, they get error rows and the sweep "
                             "ends, keeping its finished runs for --resume (default: the "
                             f"--run-timeout, at least {NO_WORKER_FLOOR_S:g} s)")
    if workers:
        parser.add_argument("--workers", type=int, default=None, metavar="N",
                            help="parallel worker processes (default: the number of CPUs)")


def executor_from_args(args: argparse.Namespace) -> Executor:
    """The executor the options ask for (:class:`UsageError` on a bad combination or a
    missing ``distributed``); ``--workers`` None means the number of CPUs."""
    workers = getattr(args, "workers", None)
    retries = getattr(args, "retries", DEFAULT_RETRIES)
    scheduler = getattr(args, "scheduler", None)
    no_worker = getattr(args, "no_worker_timeout", None)
    check_retries(retries)
    check_no_worker_timeout(no_worker)
    if getattr(args, "executor", "local") == "dask":
        return DaskExecutor(scheduler=scheduler, workers=workers, retries=retries,
                            no_worker_timeout=no_worker)
    if scheduler:
        raise UsageError("--scheduler needs --executor dask")
    if no_worker is not None:
        raise UsageError("--no-worker-timeout needs --executor dask")
    return LocalExecutor(workers or os.cpu_count() or 1, retries=retries)


@contextlib.contextmanager
def executor_scope(args: argparse.Namespace) -> Iterator[Executor | None]:
    """For a command with :func:`add_executor_arguments`: its executor, current while
    the command runs and closed after; other commands: nothing."""
    if not hasattr(args, "executor"):
        yield None
        return
    with use_executor(executor_from_args(args)) as executor:
        yield executor
