"""The Dask executor of ``drake-estop campaign`` and ``drake-estop sweep``.

:func:`dask_client` opens a ``dask.distributed`` ``LocalCluster`` (one
single-threaded worker process per core by default) or connects to an
existing scheduler; :func:`run_tasks` submits one task per item and hands
each result to a callback as soon as it finishes, with a tqdm progress bar
(rate and ETA).

Each worker runs one task at a time and its numerical libraries on one
thread: ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``, ``MKL_NUM_THREADS``
and ``NUMBA_NUM_THREADS`` are 1 in the workers' environment (set before
they start, through Dask's ``distributed.nanny.pre-spawn-environ``) and in
the run processes they start (:data:`PINNED_THREADS`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings

from drake_estop.campaign.config import ConfigError

#: Environment of every worker and run process: one thread for BLAS, OpenMP and numba.
PINNED_THREADS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                  "NUMBA_NUM_THREADS": "1"}
#: Seconds to wait for an existing scheduler before giving up (exit status 2).
CONNECT_TIMEOUT = 3.0


def pinned_environment(base: dict | None = None) -> dict:
    """``base`` (default ``os.environ``) with the thread pins of :data:`PINNED_THREADS`."""
    return {**(os.environ if base is None else base), **PINNED_THREADS}


def _connect(scheduler: str, timeout: float):
    from distributed import Client

    try:
        return Client(scheduler, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as error:
        raise ConfigError(f"--scheduler: cannot reach {scheduler!r} within {timeout:g} s ({error})") from None


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None, *, timeout: float = CONNECT_TIMEOUT):
    """A ``distributed.Client``: on ``scheduler`` (``tcp://host:port``), or on a new ``LocalCluster``.

    Parameters
    ----------
    workers : int, optional
        Worker processes of the local cluster, one thread each (default: every core).
    scheduler : str, optional
        Address of an existing Dask scheduler; ``workers`` must then be None.
    timeout : float
        Seconds to wait for ``scheduler`` [s].

    Raises
    ------
    ConfigError
        ``workers`` < 1, both given, or ``scheduler`` unreachable within ``timeout``.
    """
    import dask
    from distributed import Client, LocalCluster

    if scheduler is not None and workers is not None:
        raise ConfigError("--workers and --scheduler: give one (the cluster's workers are its own)")
    if scheduler is not None:
        client = _connect(scheduler, timeout)
        try:
            yield client
        finally:
            client.close()
        return
    if workers is None:
        workers = os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"--workers: needs a whole number >= 1, got {workers!r}")
    environ = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), **PINNED_THREADS}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}), warnings.catch_warnings():
        # the scheduler's HTTP server (health routes; no dashboard) moves off a busy default port: not a problem
        warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
    try:
        with Client(cluster, set_as_default=False) as client:
            yield client
    finally:
        cluster.close()


def run_tasks(client, function, items, *, on_result, progress: bool = True, desc: str = "runs",
              total: int | None = None, initial: int = 0):
    """Run ``function(item)`` for every item on ``client``; call ``on_result(index, value, error)`` per finish.

    Results are handed over in completion order, as soon as each finishes;
    ``index`` is the item's position in ``items``, ``value`` is the task's return value and ``error`` None, or ``value``
    None and ``error`` the exception the task (or its lost worker) raised.
    The progress bar counts from ``initial`` to ``total`` (default
    ``initial + len(items)``) and shows the rate and ETA.
    """
    from distributed import as_completed
    from tqdm import tqdm

    items = list(items)
    futures = {client.submit(function, item, pure=False): index for index, item in enumerate(items)}
    total = initial + len(items) if total is None else total
    with tqdm(total=total, initial=initial, desc=desc, unit="run", disable=not progress, smoothing=0.1) as bar:
        for future in as_completed(futures, loop=client.loop):
            index = futures.pop(future)
            try:
                value, error = future.result(), None
            except Exception as failure:  # noqa: BLE001 - handed to on_result, which records it
                value, error = None, failure
            on_result(index, value, error)
            future.release()
            bar.update(1)


def map_tasks(function, items, *, workers: int | None = None, scheduler: str | None = None,
              progress: bool = True, desc: str = "runs") -> list:
    """``[function(item) for item in items]`` on Dask, in the order of ``items``; a task's exception is raised."""
    items = list(items)
    results = [None] * len(items)

    def keep(index, value, error):
        if error is not None:
            raise error
        results[index] = value

    with dask_client(workers, scheduler) as client:
        run_tasks(client, function, items, on_result=keep, progress=progress, desc=desc)
    return results
