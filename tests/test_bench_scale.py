"""``fingerloc bench scale``: its figures' fields, exactness against the linear scan, its argument checks."""

import json

import pytest

from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.scale import run_scale

from ._cli import run_cli


@pytest.mark.slow
def test_bench_scale_writes_every_figure_and_is_exact(tmp_path, capsys):
    out = tmp_path / "scale.json"
    code, text, err = run_cli(
        capsys, "bench", "scale", "--places", "30,60", "--preset", "laser2d", "--queries", "8",
        "--exact-queries", "8", "--repeat", "1", "--json", out,
    )  # fmt: skip
    assert code == 0, err
    res = json.loads(out.read_text())
    sizes = res["presets"]["laser2d"]["sizes"]
    assert sorted(sizes, key=int) == ["30", "60"]
    for n, f in sizes.items():
        for key in ("learn_s", "peak_rss_mb", "db_mb", "localize_ms", "localize_batched_ms", "top1", "exact", "size_wall_s"):
            assert key in f
        assert f["places"] == int(n)
        assert f["views"] == 3 * int(n)
        assert f["exact"] is True and f["exact_posterior"] is True
        assert f["exact_queries"] == 8
        assert f["index_used_by_localize"] is False  # below the size from which localize uses the index
        assert 1 <= f["mean_rank"] <= int(n)
    assert "laser2d" in text


def test_bench_scale_rejects_bad_sizes_and_presets(tmp_path, capsys):
    code, _, err = run_cli(capsys, "bench", "scale", "--places", "10,x")
    assert code == 2 and err.startswith("error: --places")
    code, _, err = run_cli(capsys, "bench", "scale", "--places", "10", "--preset", "nope")
    assert code == 2 and "unknown preset" in err
    with pytest.raises(InvalidParameterError):
        run_scale([1])
