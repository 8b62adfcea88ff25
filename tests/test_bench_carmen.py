import json
import math

import numpy as np
import pytest

from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.carmen import (
    DEFAULT_METHODS,
    METHODS,
    HistogramBaseline,
    ScanContextBaseline,
    log_name,
    make_method,
    make_split,
    plot_benchmark,
    rank_metrics,
    register_method,
    run_benchmark,
    true_place_ranks,
)

from ._cli import run_cli as _run_cli
from ._logs import ROOMS, box_scan
from ._logs import write_log as _write_log

# ---- protocol ------------------------------------------------------------------------------------

# Ten scans: 0..4 map, 5..9 query.
TRAJ = [
    (0.0, 0.0),  # 0: first scan -> place 0 at (0, 0); trains place 0
    (1.4, 1.0),  # 1: 1.72 m from place 0: no place; 1.49 m from both... not within R: dropped
    (2.0, 0.0),  # 2: exactly D from place 0: NOT a new place (strictly farther needed); 0.5 m from place 1
    (2.5, 0.0),  # 3: 2.5 m > D -> place 1 at (2.5, 0)
    (0.5, 0.0),  # 4: trains place 0
    (0.0, 1.0),  # 5: query, exactly R from place 0: included (inclusive), true place 0
    (3.5, 0.0),  # 6: query, exactly R from place 1: true place 1
    (10.0, 10.0),  # 7: far from every place: not a query
    (1.25, 0.0),  # 8: 1.25 m from both: outside R, not a query
    (2.4, 0.1),  # 9: query, place 1
]


def test_split_known_trajectory():
    sp = make_split(TRAJ)
    assert sp.n_scans == 10 and sp.n_mapping == 5
    assert np.allclose(sp.centres, [[0, 0], [2.5, 0]])
    assert sp.centre_scans.tolist() == [0, 3]
    # scan 2 is 2.0 m from place 0 and 0.5 m from place 1 (created after it): trains place 1
    assert sp.train_idx.tolist() == [0, 2, 3, 4]
    assert sp.train_labels.tolist() == [0, 1, 1, 0]
    assert sp.query_idx.tolist() == [5, 6, 9]
    assert sp.query_labels.tolist() == [0, 1, 1]
    assert (sp.n_places, sp.n_train, sp.n_queries) == (2, 4, 3)


def test_split_odd_length_maps_the_floor_half():
    sp = make_split([*TRAJ, (0.0, 0.0)])
    assert sp.n_mapping == 5 and sp.query_idx.tolist() == [5, 6, 9, 10]


def test_split_mapping_scans_never_query():
    # A mapping scan right at a centre is training only; query scans never create places.
    sp = make_split([(0, 0), (0, 0), (50, 50), (0, 0.5)])
    assert sp.n_places == 1
    assert sp.train_idx.tolist() == [0, 1] and sp.query_idx.tolist() == [3]


def test_split_every_place_has_its_creator_as_training_scan():
    rng = np.random.default_rng(3)
    pos = np.cumsum(rng.normal(0, 0.7, size=(400, 2)), axis=0)
    sp = make_split(pos)
    assert set(sp.centre_scans.tolist()) <= set(sp.train_idx.tolist())
    assert set(sp.train_labels.tolist()) == set(range(sp.n_places))
    c = sp.centres
    d = np.hypot(*(c[:, None, :] - c[None, :, :]).transpose(2, 0, 1))
    assert np.all(d[~np.eye(len(c), dtype=bool)] > 2.0)


def test_split_brute_force_oracle():
    rng = np.random.default_rng(7)
    pos = np.round(np.cumsum(rng.normal(0, 0.6, size=(120, 2)), axis=0), 1)
    sp = make_split(pos)
    n = len(pos)
    centres = []
    for i in range(n // 2):
        if all(math.dist(pos[i], c) > 2.0 for c in centres):
            centres.append(tuple(pos[i]))

    def nearest(p):
        d = [math.dist(p, c) for c in centres]
        j = min(range(len(d)), key=d.__getitem__)
        return j, d[j]

    tr = [(i, nearest(pos[i])[0]) for i in range(n // 2) if nearest(pos[i])[1] <= 1.0]
    q = [(i, nearest(pos[i])[0]) for i in range(n // 2, n) if nearest(pos[i])[1] <= 1.0]
    assert np.allclose(sp.centres, centres)
    assert list(zip(sp.train_idx.tolist(), sp.train_labels.tolist(), strict=True)) == tr
    assert list(zip(sp.query_idx.tolist(), sp.query_labels.tolist(), strict=True)) == q


def test_split_bad_input():
    with pytest.raises(InvalidParameterError, match="shape"):
        make_split(np.zeros((4, 3)))
    with pytest.raises(InvalidParameterError, match="place_spacing"):
        make_split(TRAJ, place_spacing=0)


# ---- metrics -------------------------------------------------------------------------------------


def test_ranks_ties_count_against():
    s = [[1.0, 1.0, 0.0], [0.0, 0.5, 0.2], [3.0, 2.0, 1.0], [0.0, 0.0, 0.0]]
    assert true_place_ranks(s, [0, 1, 2, 2]).tolist() == [2, 1, 3, 3]


def test_ranks_nan_is_worst():
    s = [[np.nan, 0.0], [np.nan, np.nan], [-np.inf, 1.0]]
    assert true_place_ranks(s, [0, 0, 1]).tolist() == [2, 2, 1]


def test_ranks_bad_shapes():
    with pytest.raises(InvalidParameterError):
        true_place_ranks(np.zeros((2, 3)), [0])
    with pytest.raises(InvalidParameterError, match="place indices"):
        true_place_ranks(np.zeros((1, 3)), [3])


def test_rank_metrics():
    m = rank_metrics([1, 2, 1, 6, 5])
    assert m == {"top1": 0.4, "mean_rank": 3.0, "recall5": 0.8}
    assert math.isnan(rank_metrics([])["top1"])


# ---- methods -------------------------------------------------------------------------------------


def _room_data(seed=0):
    rng = np.random.default_rng(seed)
    train, labels, queries, qlab = [], [], [], []
    for j, (w, h) in enumerate(ROOMS):
        for _ in range(3):
            train.append(box_scan(w, h, w / 2, h / 2, rng.uniform(-3, 3), noise=0.01, rng=rng))
            labels.append(j)
        queries.append(box_scan(w, h, w / 2 + 0.1, h / 2, rng.uniform(-3, 3), noise=0.01, rng=rng))
        qlab.append(j)
    return train, np.array(labels), queries, np.array(qlab)


@pytest.mark.parametrize("name", ["baseline-scancontext", "baseline-histogram"])
def test_baselines_tell_rooms_apart(name):
    train, labels, queries, qlab = _room_data()
    m = make_method(name)
    m.fit(train, labels)
    s = m.score(queries)
    assert s.shape == (3, 3)
    assert true_place_ranks(s, qlab).tolist() == [1, 1, 1]


def test_scancontext_union_vs_intersection_score():
    sc = ScanContextBaseline()
    a = box_scan(6.0, 4.0, 3.0, 2.0, 0.0)
    sc.fit([a], [0])
    assert sc.score([a])[0, 0] == pytest.approx(1.0)  # a scan matches itself fully at shift 0
    # the same spot seen the other way: the two half-grids overlap at their edges only
    b = box_scan(6.0, 4.0, 3.0, 2.0, math.pi)
    u = sc.score([b])[0, 0]
    orig = ScanContextBaseline(normalise="intersection").fit([a], [0]).score([b])[0, 0]
    assert u < orig
    with pytest.raises(InvalidParameterError, match="normalise"):
        ScanContextBaseline(normalise="mean").fit([a], [0])


def test_histogram_is_heading_free():
    h = HistogramBaseline()
    a = box_scan(6.0, 6.0, 3.0, 3.0, 0.0, n=180)
    b = box_scan(6.0, 6.0, 3.0, 3.0, math.pi / 2, n=180)
    assert np.allclose(h.descriptor(a), h.descriptor(b))
    assert h.descriptor(a)[-1] == pytest.approx(1.0)


def test_fit_input_checks():
    train, labels, _, _ = _room_data()
    with pytest.raises(InvalidParameterError, match="one label per scan"):
        HistogramBaseline().fit(train, labels[:-1])
    with pytest.raises(InvalidParameterError, match=r"0 \.\. n_places - 1"):
        HistogramBaseline().fit(train, labels + 1)


def test_registry():
    assert {"baseline-scancontext", "baseline-histogram", "fingerprint"} <= set(DEFAULT_METHODS)
    assert "baseline-scancontext-original" in METHODS and "baseline-scancontext-original" not in DEFAULT_METHODS
    with pytest.raises(InvalidParameterError, match="unknown method 'nope'"):
        make_method("nope")
    with pytest.raises(InvalidParameterError, match="method name"):
        register_method("Bad Name")


def test_log_name():
    assert log_name("/x/intel-corrected.log.gz") == "intel"
    assert log_name("freiburg-101-corrected.log.gz") == "freiburg-101"
    assert log_name("run.log") == "run" and log_name("a.clf") == "a"


# ---- end to end on a synthetic CARMEN log --------------------------------------------------------


def _rooms_path():
    out = []
    for _ in range(2):
        for w, h in ROOMS:
            for dx in (-0.3, 0.0, 0.3):
                out.append((w, h, w / 2 + dx, h / 2, 0.3 * dx))
    return out


def test_run_benchmark_end_to_end(tmp_path):
    p1 = _write_log(tmp_path / "rooms-corrected.log", _rooms_path())
    p2 = _write_log(tmp_path / "other.log", _rooms_path()[::-1])
    run = run_benchmark([p1, p2], ["baseline-histogram", "baseline-scancontext"])
    js = json.loads(json.dumps(run.to_json()))
    assert set(js["logs"]) == {"rooms", "other"}
    lg = js["logs"]["rooms"]
    assert (lg["places"], lg["train"], lg["queries"], lg["scans"]) == (3, 9, 9, 18)
    for m in ("baseline-histogram", "baseline-scancontext"):
        f = lg["methods"][m]
        assert set(f) == {"top1", "mean_rank", "recall5", "ms_per_query", "learn_s"}
        assert f["top1"] == 1.0 and f["mean_rank"] == 1.0
    pooled = js["pooled"]
    assert pooled["queries"] == 18 and pooled["places"] == 6
    assert pooled["methods"]["baseline-histogram"]["top1"] == 1.0
    out = tmp_path / "map.png"
    plot_benchmark(run, out, method="baseline-histogram")
    assert out.stat().st_size > 1000 and out.read_bytes()[:4] == b"\x89PNG"


def test_run_benchmark_errors(tmp_path):
    with pytest.raises(InvalidParameterError, match="at least one log"):
        run_benchmark([])
    p = _write_log(tmp_path / "r.log", _rooms_path())
    with pytest.raises(InvalidParameterError, match="unknown method"):
        run_benchmark([p], ["baseline-nope"])



def test_cli_bench_carmen(tmp_path, capsys):
    p = _write_log(tmp_path / "rooms-corrected.log", _rooms_path())
    out = tmp_path / "b.json"
    png = tmp_path / "b.png"
    code, text, _ = _run_cli(
        capsys, "bench", "carmen", str(p), "-m", "baseline-histogram", "--json", str(out), "--plot", str(png)
    )
    assert code == 0
    assert "rooms" in text and "pooled" in text and "baseline-histogram" in text
    js = json.loads(out.read_text())
    assert js["logs"]["rooms"]["methods"]["baseline-histogram"]["top1"] == 1.0
    assert png.read_bytes()[:4] == b"\x89PNG"
    code, _, err = _run_cli(capsys, "bench", "carmen", str(tmp_path / "missing.log"))
    assert code == 2 and "missing.log" in err and err.startswith("error:")
    code, _, err = _run_cli(capsys, "bench", "carmen", str(p), "-m", "nope")
    assert code == 2 and "unknown method 'nope'" in err
    code, text, _ = _run_cli(capsys, "bench", "carmen", "--list-methods")
    assert code == 0 and "baseline-scancontext-original  (run only when named)" in text


def test_speed_section_quick():
    from fingerloc.experiments.carmen import _speed_section

    figs = _speed_section(True)
    assert figs["carmen_read_scans_per_s"] > 0
    assert {"baseline-scancontext_ms_per_query_20_train", "baseline-histogram_ms_per_query_20_train"} <= set(figs)


def test_benchmark_on_two_dask_workers_matches_the_serial_run(tmp_path):
    """One task per log on a 2-worker thread cluster gives the serial run's figures."""
    pytest.importorskip("distributed")
    from fingerloc.experiments.carmen import run_benchmark

    from ._logs import rooms_path

    logs = [_write_log(tmp_path / f"r{k}-corrected.log", rooms_path()) for k in range(2)]
    serial = run_benchmark(logs, ["baseline-histogram", "fingerprint"]).to_json()
    import fingerloc.parallel as par

    real = par.run_tasks
    try:  # thread workers: they start in a second, and the figures must not depend on where a task ran
        par.run_tasks = lambda fn, tasks, **kw: real(fn, tasks, **{**kw, "processes": False})  # type: ignore[assignment]
        dask = run_benchmark(logs, ["baseline-histogram", "fingerprint"], workers=2).to_json()
    finally:
        par.run_tasks = real
    for js in (serial, dask):  # timings differ from run to run
        for lg in js["logs"].values():
            for m in lg["methods"].values():
                m.pop("ms_per_query", None)
                m.pop("learn_s", None)
        for m in js["pooled"]["methods"].values():
            m.pop("ms_per_query", None)
            m.pop("learn_s", None)
    assert dask == serial
