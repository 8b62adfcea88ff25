"""The ``localize`` section of ``fingerloc bench speed``: its synthetic case, and a quick run (slow)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fingerloc.experiments.speed_localize import localize_figures, write_case


def test_case_is_the_issue_generator(tmp_path):
    train, q = write_case(tmp_path, places=5, views=3, queries=7, seed=0)
    rows = [json.loads(line) for line in train.read_text(encoding="utf-8").splitlines()]
    assert len(rows) == 15 and [r["place"] for r in rows[:4]] == ["p0", "p0", "p0", "p1"]
    assert all(len(r["features"]["VE"]) == 6 and len(r["features"]["Ex"]) == 3 and len(r["features"]["c"]) == 3 for r in rows)
    assert all(r["features"]["c"] == [round(v, 3) for v in r["features"]["c"]] for r in rows)
    queries = q.read_text(encoding="utf-8").splitlines()
    assert len(queries) == 7
    again = tmp_path / "again"
    again.mkdir()
    _, q2 = write_case(again, places=5, views=3, queries=7, seed=0)
    assert q2.read_text(encoding="utf-8").splitlines() == queries  # seeded: anyone gets the same files


@pytest.mark.slow
def test_section_quick():
    figs = localize_figures(places=30, queries=300, small=100, repeat=1)
    assert figs["steady_obs_per_cpu_s"] > 0 and figs["fixed_cpu_s"] < figs["small_cpu_s"]
    assert figs["json_bytes_per_record"] > 1000 and figs["peak_rss_mb"] > 10


def test_peak_memory_is_the_childs_own(tmp_path):
    """The bench's peak resident size is the command's, not the bigger parent's (ru_maxrss survives fork + exec)."""
    import numpy as np

    from fingerloc.experiments.speed_localize import _fingerloc

    if not Path("/proc/self/status").exists():
        pytest.skip("needs /proc")
    big = np.ones(40_000_000)  # 320 MB resident in this process
    _, _, peak_mb = _fingerloc(["--version"], tmp_path)
    assert big.sum() > 0 and peak_mb < 200
