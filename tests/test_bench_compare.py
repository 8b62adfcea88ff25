"""``fingerloc bench compare``: accuracy figures must agree, timings are listed apart."""

from __future__ import annotations

import json

from fingerloc.experiments.compare import compare_json, is_timing

from ._cli import run_cli


def _run(top1: float, ms: float) -> dict:
    return {"logs": {"a": {"methods": {"fp": {"top1": top1, "mean_rank": 1.5, "ms_per_query": ms, "learn_s": 2.0}}}},
            "pooled": {"fp": {"top1": top1}}, "wall_s": 3.0}  # fmt: skip


def test_compare_json_finds_the_figures_that_differ():
    assert compare_json(_run(0.5, 1.0), _run(0.5, 9.0)) == []
    diffs = compare_json(_run(0.5, 1.0), _run(0.6, 9.0))
    assert [d.path for d in diffs] == ["logs.a.methods.fp.top1", "pooled.fp.top1"]
    timed = compare_json(_run(0.5, 1.0), _run(0.5, 9.0), timings=True)
    assert [(d.path, d.ratio) for d in timed] == [("logs.a.methods.fp.ms_per_query", 9.0)]
    only = compare_json({"x": 1}, {"x": 1, "y": 2})
    assert [(d.path, d.first, d.second) for d in only] == [("y", None, 2)]
    assert compare_json({"v": float("nan")}, {"v": float("nan")}) == []
    assert is_timing("ms_per_query") and is_timing("learn_s") and is_timing("extract_cpu_ms") and not is_timing("top1")


def test_cli_exit_codes(tmp_path, capsys):
    a, b, c = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "c.json"
    a.write_text(json.dumps(_run(0.5, 1.0)))
    b.write_text(json.dumps(_run(0.5, 2.0)))
    c.write_text(json.dumps(_run(0.4, 1.0)))
    code, out, _ = run_cli(capsys, "bench", "compare", a, b)
    assert code == 0 and "identical figures" in out
    code, out, _ = run_cli(capsys, "bench", "compare", a, c)
    assert code == 1 and "logs.a.methods.fp.top1: 0.5 -> 0.4" in out and "2 figure(s) differ" in out
    code, out, _ = run_cli(capsys, "bench", "compare", a, b, "--timings")
    assert code == 0 and "x2.000" in out
    (tmp_path / "bad.json").write_text("{")
    code, _, err = run_cli(capsys, "bench", "compare", a, tmp_path / "bad.json")
    assert code == 2 and err.startswith("error: ") and "bad.json" in err
