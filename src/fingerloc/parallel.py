"""Independent tasks, run serially or on a Dask cluster, with the same results in the same order.

Benchmarks and reproductions are lists of independent tasks: the trials of
Table I, the logs of ``bench carmen``, the trials of ``reproduce robot``, the
cells of a sweep over logs x seeds x presets. :func:`run_tasks` runs
``fn(task)`` for each of them:

* serially in this process (the default: nothing to install, nothing started);
* on a ``dask.distributed.LocalCluster`` of ``workers`` processes started for
  the call and closed after it (``--workers N`` on the command line);
* on an existing Dask cluster whose scheduler listens at ``scheduler``
  (``--scheduler tcp://host:8786``; dask-jobqueue, Kubernetes or a
  ``dask scheduler`` / ``dask worker`` pair started by hand).

The results come back as a list in task order, whichever worker finished
first, and equal the serial ones as long as each task carries everything
random about it (its own seed or generator state), which is the caller's
contract: a task must not draw from a generator shared with other tasks.
``fn`` and the tasks must be picklable (a module-level function, plain data),
as Dask ships them to other processes.

Dask (``distributed``) is imported only when a cluster is asked for.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, TypeVar

from .errors import FingerlocError, InvalidParameterError

__all__ = ["ClusterError", "check_cluster_options", "iter_tasks", "run_tasks"]

_T = TypeVar("_T")
_R = TypeVar("_R")


class ClusterError(FingerlocError):
    """Dask is missing, or the cluster could not be started or reached."""


def check_cluster_options(workers: int | None = None, scheduler: str | None = None) -> None:
    """Validate ``workers`` and ``scheduler`` before any work (the messages name the command-line flags).

    Raises
    ------
    InvalidParameterError
        ``workers`` not a positive int, ``scheduler`` empty, or both given.
    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InvalidParameterError(f"--workers: expected a positive number of worker processes, got {workers!r}")
    if scheduler is not None and (not isinstance(scheduler, str) or not scheduler.strip()):
        raise InvalidParameterError(
            f"--scheduler: expected a scheduler address like tcp://host:8786, got {scheduler!r}"
        )
    if workers is not None and scheduler is not None:
        raise InvalidParameterError(
            f"--workers {workers} and --scheduler {scheduler}: give one (a local cluster, or an existing one)"
        )


def run_tasks(
    fn: Callable[[_T], _R],
    tasks: Sequence[_T],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    processes: bool = True,
    on_done: Callable[[int], None] | None = None,
) -> list[_R]:
    """``[fn(t) for t in tasks]``, serially or on Dask; results in task order.

    Parameters
    ----------
    fn : callable
        A picklable function of one task (define it at module level).
    tasks : sequence
        Picklable task descriptions, each carrying its own seed.
    workers : int, optional
        Start a ``LocalCluster`` of this many single-threaded workers for the
        call. ``None`` (and no ``scheduler``): run serially in this process.
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``) to send
        the tasks to; the cluster is left running.
    processes : bool, default True
        Local workers as processes (True) or threads of this process (False:
        starts faster; fine for tests and for kernels that release the GIL).
    on_done : callable, optional
        Called with the number of tasks finished so far, after each one.

    Returns
    -------
    list
        ``fn(task)`` for each task, in the order of ``tasks``.

    Raises
    ------
    InvalidParameterError
        Bad ``workers`` / ``scheduler`` (see :func:`check_cluster_options`).
    ClusterError
        Dask is not installed, or the cluster could not be started or reached.
    Exception
        Whatever ``fn`` raised for the first failing task (re-raised here).
    """
    check_cluster_options(workers, scheduler)
    items = list(tasks)
    if workers is None and scheduler is None:
        out: list[_R] = []
        for i, task in enumerate(items):
            out.append(fn(task))
            if on_done is not None:
                on_done(i + 1)
        return out
    if not items:
        return []
    from distributed import as_completed

    with _client(workers, scheduler, processes) as client:
        futures = client.map(fn, items, pure=False)
        if on_done is not None:
            for done, _ in enumerate(as_completed(futures), start=1):
                on_done(done)
        return list(client.gather(futures))


@contextmanager
def _client(workers: int | None, scheduler: str | None, processes: bool) -> Iterator[Any]:
    """A Dask client: of a ``LocalCluster`` of ``workers`` single-threaded workers (closed after), or of ``scheduler``."""
    try:
        from distributed import Client, LocalCluster
    except ImportError as err:  # pragma: no cover - dask is a dependency
        raise ClusterError(
            "--workers/--scheduler need Dask's distributed package: pip install 'dask[distributed]'"
        ) from err
    cluster: Any = None
    try:
        if scheduler is not None:
            try:
                client = Client(scheduler, timeout="10s")
            except (OSError, TimeoutError) as err:
                raise ClusterError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({err})") from err
        else:
            try:
                cluster = LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=processes,
                    dashboard_address=None,
                    silence_logs=40,  # logging.ERROR
                )
            except (OSError, RuntimeError) as err:
                raise ClusterError(f"--workers {workers}: could not start a local Dask cluster ({err})") from err
            client = Client(cluster)
        with client:
            yield client
    finally:
        if cluster is not None:
            cluster.close()


def iter_tasks(
    fn: Callable[[_T], _R],
    tasks: Iterable[_T],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    processes: bool = True,
    in_flight: int | None = None,
) -> Iterator[_R]:
    """``fn(t)`` for each task, yielded in task order as they finish, serially or on Dask.

    Unlike :func:`run_tasks`, ``tasks`` may be a generator and results come
    back one at a time: at most ``in_flight`` tasks (default: twice the
    cluster's threads, at least 2) are submitted and not yet yielded, so the
    memory stays bounded however many tasks there are (``localize --workers``
    on a long file). Serially (no ``workers`` nor ``scheduler``) this is
    ``map(fn, tasks)``. Arguments and errors as :func:`run_tasks`.
    """
    check_cluster_options(workers, scheduler)
    if in_flight is not None and (isinstance(in_flight, bool) or not isinstance(in_flight, int) or in_flight < 1):
        raise InvalidParameterError(f"in_flight must be a positive integer, got {in_flight!r}")
    if workers is None and scheduler is None:
        for task in tasks:
            yield fn(task)
        return
    from collections import deque

    with _client(workers, scheduler, processes) as client:
        window = in_flight or max(2, 2 * sum(client.nthreads().values()))
        pending: deque[Any] = deque()
        for task in tasks:
            pending.append(client.submit(fn, task, pure=False))
            if len(pending) >= window:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
