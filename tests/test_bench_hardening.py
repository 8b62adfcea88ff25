"""bench carmen's harder runs (Hardening, harden_scans): the mapping pass kept, the query pass cut, started later
or reversed; the seed and odometry factor reach the pose filters; the JSON records the run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fingerloc.errors import FingerlocError
from fingerloc.experiments.carmen import Hardening, harden_scans, run_benchmark
from fingerloc.sensors import Scan

from ._cli import run_cli


def _scans(n):
    return [Scan(np.ones(3), np.array([-0.1, 0.0, 0.1]), pose=(float(i), 0.0, 0.0)) for i in range(n)]


def test_harden_scans_keeps_the_mapping_pass_and_changes_the_query_pass():
    scans = _scans(20)
    out, n_map = harden_scans(scans, Hardening())
    assert n_map == 10 and out == scans
    out, n_map = harden_scans(scans, Hardening(mapping_part=0.3))
    assert n_map == 6 and out == scans
    out, n_map = harden_scans(scans, Hardening(query_start=0.5))
    assert out[:10] == scans[:10] and [s.pose[0] for s in out[10:]] == [15.0, 16.0, 17.0, 18.0, 19.0]
    out, _ = harden_scans(scans, Hardening(query_cut=(0.2, 0.3)))
    assert [s.pose[0] for s in out[10:]] == [10.0, 11.0, 15.0, 16.0, 17.0, 18.0, 19.0]
    out, _ = harden_scans(scans, Hardening(reverse=True))
    assert [s.pose[0] for s in out[10:]] == list(np.arange(19.0, 9.0, -1.0))


def test_hardening_checks_and_json():
    for bad in ({"mapping_part": 1.0}, {"query_start": -0.1}, {"query_cut": (0.8, 0.3)}, {"seed": -1},
                {"odometry_error": -1.0}):  # fmt: skip
        with pytest.raises(FingerlocError):
            Hardening(**bad)
    assert Hardening().is_protocol() and not Hardening(seed=1).is_protocol()
    assert Hardening(query_cut=(0.1, 0.2)).to_json()["query_cut"] == [0.1, 0.2]


def test_a_hardened_run_seeds_the_pose_filter_and_is_recorded(rooms_log, tmp_path, capsys):
    from fingerloc.experiments.carmen import make_method

    m = Hardening(seed=4, odometry_error=2.0).apply(make_method("fingerprint-odometry-x2"))
    assert m.seed == 4 and m.odometry_error == 4.0  # the method's own factor times the run's
    assert Hardening(seed=4).apply(make_method("baseline-histogram")).name == "baseline-histogram"
    methods = ["baseline-histogram"]
    a = run_benchmark([rooms_log], methods).to_json()
    assert "hardening" not in a["protocol"]
    b = run_benchmark([rooms_log], methods, hardening=Hardening(seed=3, odometry_error=2.0, reverse=True)).to_json()
    assert b["protocol"]["hardening"]["seed"] == 3 and b["protocol"]["hardening"]["reverse"] is True
    assert b["logs"]["rooms"]["queries"] == a["logs"]["rooms"]["queries"]  # the same queries, in reverse order
    out = tmp_path / "h.json"
    code, _, err = run_cli(capsys, "bench", "carmen", str(rooms_log), "-m", "baseline-histogram", "--mapping-part", "0.4",
                           "--query-cut", "0.0", "0.5", "--json", str(out))  # fmt: skip
    assert code == 0, err
    js = json.loads(out.read_text())
    assert js["protocol"]["mapping"] == "index < floor(0.4 n)" and js["protocol"]["hardening"]["query_cut"] == [0.0, 0.5]
    code, _, err = run_cli(capsys, "bench", "carmen", str(rooms_log), "--mapping-part", "1.5")
    assert code == 2 and err.startswith("error:")
