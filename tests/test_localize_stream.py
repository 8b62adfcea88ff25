"""Streaming ``localize``: the same answers as before, serially and on Dask workers.

``tests/data/localize_golden`` holds two place databases (the paper preset,
and the same with ``--cyclic --costs feature`` for the headings), 300 query
lines (labelled, unlabelled, an unknown label, partial fields of view, colour
patches, beacons, integer bearings, empty features, blank lines: two chunks
of 256) and the output of ``fingerloc localize q.jsonl --db DB --json OUT``
(and its table on stdout) written by the plain one-at-a-time code. The
stream, the JSON Lines fast path and the faster kernels must give these
answers again (within the last bits a numpy / numba build may change:
``tests/_golden.py``).
"""

from __future__ import annotations

import gzip
import json
import shutil
from pathlib import Path

import pytest

from ._cli import run_cli
from ._golden import assert_close, assert_text_close

GOLDEN = Path(__file__).parent / "data" / "localize_golden"


@pytest.fixture
def golden(tmp_path):
    for name in ("q.jsonl", "paper.sqlite", "cyclic.sqlite"):
        shutil.copy(GOLDEN / name, tmp_path / name)
    return tmp_path


def _expected(db: str) -> tuple[str, str]:
    js = gzip.decompress((GOLDEN / f"{db}.json.gz").read_bytes()).decode("utf-8")
    txt = gzip.decompress((GOLDEN / f"{db}.txt.gz").read_bytes()).decode("utf-8")
    return js, txt


@pytest.mark.parametrize("db", ["paper", "cyclic"])
def test_localize_gives_the_answers_of_before(golden, capsys, db):
    out = golden / "out.json"
    code, stdout, err = run_cli(capsys, "localize", golden / "q.jsonl", "--db", golden / f"{db}.sqlite", "--json", out)
    assert code == 0, err
    js, txt = _expected(db)
    assert_close(json.loads(out.read_text(encoding="utf-8")), json.loads(js))
    assert_text_close(stdout, txt)


def test_quiet_summary_and_no_output_left_on_a_bad_line(golden, capsys):
    code, stdout, err = run_cli(capsys, "localize", golden / "q.jsonl", "--db", golden / "paper.sqlite", "-q")
    assert code == 0, err
    summary = json.loads(_expected("paper")[0])["summary"]
    assert f"of {sum(1 for r in json.loads(_expected('paper')[0])['observations'] if r['rank_of_true'])} labelled" in stdout
    assert f"mean rank of the true place: {summary['mean_rank']:.2f}" in stdout
    # a malformed line in the second chunk: one error line naming it, and no --json file (nor temporary file)
    lines = (golden / "q.jsonl").read_text(encoding="utf-8").splitlines()
    lines[290] = '{"features": {"VE": [1, "x"]}}'
    bad = golden / "bad.jsonl"
    bad.write_text("\n".join(lines) + "\n", encoding="utf-8")
    out = golden / "o.json"
    code, stdout, err = run_cli(capsys, "localize", bad, "--db", golden / "paper.sqlite", "-q", "--json", out)
    assert code == 2
    assert err.strip().splitlines() == [err.strip()] and "bad.jsonl:291" in err and err.startswith("error: ")
    assert not out.exists() and not list(golden.glob("*.tmp"))


@pytest.fixture(scope="module")
def cluster_address():
    distributed = pytest.importorskip("distributed")
    # threads, not processes: a process start costs seconds (imports, numba caches) on a loaded CI machine
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None, silence_logs=40
    ) as cluster:
        yield cluster.scheduler_address


@pytest.mark.parametrize("db", ["paper", "cyclic"])
def test_localize_on_two_dask_workers_equals_the_serial_run(golden, capsys, cluster_address, db):
    out = golden / "dask.json"
    code, stdout, err = run_cli(
        capsys, "localize", golden / "q.jsonl", "--db", golden / f"{db}.sqlite", "--json", out, "--scheduler", cluster_address
    )
    assert code == 0, err
    js, txt = _expected(db)
    assert_close(json.loads(out.read_text(encoding="utf-8")), json.loads(js))
    assert_text_close(stdout, txt)


def test_dask_errors_are_one_line(golden, capsys, cluster_address):
    bad = golden / "bad.jsonl"
    bad.write_text('{"features": {}}\n{"features": {"VE": [NaN]}}\n', encoding="utf-8")
    code, _, err = run_cli(capsys, "localize", bad, "--db", golden / "paper.sqlite", "-q", "--scheduler", cluster_address)
    assert code == 2 and err.startswith("error: ") and "bad.jsonl:2" in err and len(err.strip().splitlines()) == 1
    other = golden / "other.sqlite"
    shutil.copy(golden / "cyclic.sqlite", other)
    code, _, err = run_cli(capsys, "localize", golden / "q.jsonl", "--db", other, "-q", "--workers", "2", "--report", golden / "r")
    assert code == 2 and "--report" in err
    code, _, err = run_cli(capsys, "localize", golden / "q.jsonl", "--db", other, "--workers", "0")
    assert code == 2 and "--workers" in err


def test_worker_refuses_another_database(golden):
    from fingerloc.cli._localize import LinesTask, answer_lines

    task = LinesTask(str(golden / "paper.sqlite"), "0" * 64, str(golden / "q.jsonl"), 0, [(1, '{"features": {}}')], 3, False, False)
    res = answer_lines(task)
    assert isinstance(res, tuple) and res[0] == "error" and "differs from the client's" in res[1]


def test_records_with_non_finite_numbers_are_encoded_as_before(monkeypatch):
    """Non-finite terms (a place a term rules out: -inf; NaN, +inf) become null, listed under "nulls" as before."""
    import numpy as np

    from fingerloc.cli._localize import answer_chunk, encode_record, parse_lines
    from fingerloc.metrics import rank_scores
    from fingerloc.model import normalise_log
    from fingerloc.pipeline.placemap import load_map

    model = load_map(GOLDEN / "paper.sqlite").model
    lines = (GOLDEN / "q.jsonl").read_text(encoding="utf-8").splitlines()
    obs = parse_lines(GOLDEN / "q.jsonl", [(k + 1, ln) for k, ln in enumerate(lines) if ln.strip()][:40])
    real = model.term_log_likelihoods
    terms = real(obs)
    terms["Fp"][3, 1] = -np.inf
    terms["Fp"][5, :] = -np.inf  # every place ruled out: the uniform posterior
    terms["VE"][7, 2] = np.nan
    terms["Ex"][8, 0] = np.inf
    monkeypatch.setattr(model, "term_log_likelihoods", lambda o: {t: v.copy() for t, v in terms.items()})
    got = answer_chunk(model, obs, [f"q:{i}" for i in range(len(obs))], 10, 3, table=False, records=True)
    # the records as the plain one-at-a-time code built them, through the generic strict encoder
    classes = [str(c) for c in model.classes_]
    logp = normalise_log(model.combine(terms))
    ranks = rank_scores(logp)
    best = np.argmax(logp, axis=1)
    post = np.exp(logp)
    for i, o in enumerate(obs):
        col = classes.index(o.label) if o.label in classes else -1
        rec = {
            "index": 10 + i, "name": f"q:{i}", "place": o.label, "best": classes[best[i]],
            "posterior": dict(zip(classes, post[i].tolist(), strict=True)),
            "rank_of_true": int(ranks[i, col]) if col >= 0 else None,
            "terms": {t: dict(zip(classes, ll[i].tolist(), strict=True)) for t, ll in terms.items()},
            "heading_deg": None, "heading_ref": None,
        }  # fmt: skip
        text, nulls = encode_record(rec)
        assert got.records[i] == text
        assert got.nulls[i] == nulls
    assert got.nulls[3] == {"/terms/Fp/room 1": "not a finite number: -inf"}
    assert got.nulls[5] == {f"/terms/Fp/room {j}": "not a finite number: -inf" for j in range(6)}
    assert got.nulls[7] == {"/terms/VE/room 2": "not a finite number: nan"}  # its row is dead: a uniform posterior
    assert got.nulls[8] == {"/terms/Ex/room 0": "not a finite number: inf"}
