"""``reproduce robot`` on Dask: one task per trial, the serial run's JSON."""

import json

import pytest

from fingerloc.experiments.robot import run_robot, small_protocol

from ._cli import run_cli


@pytest.fixture(scope="module")
def cluster_address():
    distributed = pytest.importorskip("distributed")
    # threads, not processes: a process start costs seconds (imports, numba caches) on a loaded CI machine
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None, silence_logs=40
    ) as cluster:
        yield cluster.scheduler_address


def _tiny():
    return small_protocol(n_offices=2, n_train=2, n_test=1, random_heading=False, omni_size=(160, 120),
                          panorama_width=180, n_beams=360)  # fmt: skip


def test_robot_on_two_dask_workers_equals_the_serial_run(cluster_address):
    serial = run_robot(trials=2, seed=3, protocol=_tiny(), workers=1)
    done: list[int] = []
    dist = run_robot(trials=2, seed=3, protocol=_tiny(), scheduler=cluster_address, on_trial=done.append)
    assert done == [1, 2]
    assert json.dumps(dist.to_json(), sort_keys=True) == json.dumps(serial.to_json(), sort_keys=True)
    # the comparison can fail: the two trials (two seeds) differ, and a trial's figures are in the JSON
    assert serial.trials[0].features != serial.trials[1].features
    swapped = run_robot(trials=1, seed=3, protocol=_tiny(), workers=1)
    assert swapped.trials[0].features == dist.trials[0].features


def test_reproduce_robot_cluster_options(capsys):
    code, _, err = run_cli(capsys, "reproduce", "robot", "--quick", "--trials", "2", "--workers", "2",
                           "--scheduler", "tcp://h:1")  # fmt: skip
    assert code == 2 and err.startswith("error: --workers 2 and --scheduler tcp://h:1")
    code, _, err = run_cli(capsys, "reproduce", "robot", "--quick", "--trials", "1", "--workers", "0")
    assert code == 2 and "--workers" in err and len(err.strip().splitlines()) == 1
    code, _, err = run_cli(capsys, "reproduce", "robot", "--quick", "--trials", "1", "--scheduler", " ")
    assert code == 2 and "--scheduler" in err


def test_reproduce_robot_help_lists_the_cluster_options(capsys):
    for cmd in ("robot", "table1"):
        code, text, _ = run_cli(capsys, "reproduce", cmd, "--help")
        assert code == 0 and "--workers" in text and "--scheduler" in text
