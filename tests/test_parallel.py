"""fingerloc.parallel: serial and Dask runs give the same results, in task order."""

from __future__ import annotations

import time

import numpy as np
import pytest

from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.table1 import run_table1
from fingerloc.parallel import check_cluster_options, run_tasks
from tests._cli import run_cli


def seeded_task(task: tuple[int, float]) -> list[float]:
    """A seeded task whose later items finish first (so completion order differs from task order)."""
    seed, delay = task
    time.sleep(delay)
    return np.random.default_rng(seed).normal(size=3).tolist()


@pytest.fixture(scope="module")
def cluster_address():
    distributed = pytest.importorskip("distributed")
    # threads, not processes: a process start costs seconds (imports, numba caches) on a loaded CI machine
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None, silence_logs=40
    ) as cluster:
        yield cluster.scheduler_address


def test_serial_is_a_plain_loop():
    tasks = [(s, 0.0) for s in range(5)]
    done: list[int] = []
    assert run_tasks(seeded_task, tasks, on_done=done.append) == [seeded_task(t) for t in tasks]
    assert done == [1, 2, 3, 4, 5]
    assert run_tasks(seeded_task, []) == []


def test_two_workers_same_results_in_task_order(cluster_address):
    tasks = [(s, 0.05 * (6 - s)) for s in range(6)]
    done: list[int] = []
    dist = run_tasks(seeded_task, tasks, scheduler=cluster_address, on_done=done.append)
    assert dist == run_tasks(seeded_task, tasks)
    assert done == [1, 2, 3, 4, 5, 6]


def test_table1_on_two_workers_equals_serial(cluster_address):
    kw = {"trials": 3, "seed": 4, "ks": (3, 5), "ns": (5, 15)}
    serial = run_table1(**kw)
    dist = run_table1(scheduler=cluster_address, **kw)
    np.testing.assert_array_equal(dist.per_trial, serial.per_trial)
    assert dist.to_json() == serial.to_json()


def test_task_errors_reach_the_caller(cluster_address):
    with pytest.raises(InvalidParameterError, match="trials"):
        run_tasks(_fails, [1, 2], scheduler=cluster_address)


def _fails(x: int) -> int:
    if x == 2:
        raise InvalidParameterError("trials: bad task 2")
    return x


@pytest.mark.parametrize(
    ("workers", "scheduler", "match"),
    [(0, None, "--workers"), (True, None, "--workers"), (None, " ", "--scheduler"), (2, "tcp://h:8786", "give one")],
)
def test_cluster_options_are_checked(workers, scheduler, match):
    with pytest.raises(InvalidParameterError, match=match):
        check_cluster_options(workers, scheduler)
    with pytest.raises(InvalidParameterError, match=match):
        run_tasks(seeded_task, [(1, 0.0)], workers=workers, scheduler=scheduler)


def test_cli_rejects_bad_cluster_options(capsys):
    code, _, err = run_cli(capsys, "reproduce", "table1", "--trials", "1", "--workers", "2", "--scheduler", "tcp://h:1")
    assert code == 2 and err.startswith("error: --workers 2 and --scheduler tcp://h:1")
    code, _, err = run_cli(capsys, "reproduce", "table1", "--trials", "1", "--workers", "0")
    assert code == 2 and "--workers" in err and "0" in err and len(err.strip().splitlines()) == 1
