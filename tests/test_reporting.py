"""Report folders (fingerloc.reporting): page building, figures' data, CLI --report, and a real browser."""

from __future__ import annotations

import json
import math
import re
import time

import numpy as np
import pytest
from PIL import Image

from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.report_bench import run_report_bench, synthetic_report_data
from fingerloc.reporting import (
    FeatureView,
    alignment_rows,
    check_report_dir,
    detect_jumps,
    draw_view_thumbnail,
    ellipsize_middle,
    markdown_to_html,
    most_confused,
    recoveries_after,
    write_localize_report,
    write_map_report,
    write_panorama_report,
    write_track_report,
)
from tests._browser import assert_page_ok
from tests._cli import run_cli

# ----------------------------------------------------------------------------- small pieces


def test_markdown_subset_to_html():
    md = (
        "# Title\n\nSome **bold** and `a<b>` code, [a link](r.json).\n\n"
        "1. one\n2. two\n\n| a | b |\n|---|---:|\n| x | 1.5 |\n\n![map](map.png)\n"
    )
    html = markdown_to_html(md)
    assert "<h1>Title</h1>" in html
    assert "<strong>bold</strong>" in html and "<code>a&lt;b&gt;</code>" in html
    assert '<a href="r.json">a link</a>' in html
    assert "<ol><li>one</li><li>two</li></ol>" in html
    assert "<th>a</th><th>b</th>" in html and '<td class="num">1.5</td>' in html
    assert '<img src="map.png" alt="map">' in html


def test_markdown_escapes_text_outside_markup():
    assert "&lt;script&gt;" in markdown_to_html("a <script>alert(1)</script> b")


@pytest.mark.parametrize(
    ("text", "width", "expected"),
    [("office-12", 20, "office-12"), ("abcdefghijkl", 7, "abc…jkl"), ("abcdefghijkl", 6, "ab…jkl")],
)
def test_ellipsize_middle_keeps_both_ends(text, width, expected):
    out = ellipsize_middle(text, width)
    assert out == expected and len(out) <= width


def test_check_report_dir(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(InvalidParameterError, match=r"--report: .*file exists and is not a folder"):
        check_report_dir(f)
    with pytest.raises(InvalidParameterError, match="is not a folder"):
        check_report_dir(f / "sub")
    assert check_report_dir(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"


def test_most_confused_against_a_loop():
    rng = np.random.default_rng(3)
    m = rng.integers(0, 4, (9, 9)) * (rng.random((9, 9)) < 0.3)
    np.fill_diagonal(m, 7)
    k = 4
    # oracle: wrong answers per place, as true place or as answer, by loops
    score = [sum(m[i, j] for j in range(9) if j != i) + sum(m[j, i] for j in range(9) if j != i) for i in range(9)]
    expected = sorted(sorted(range(9), key=lambda i: (-score[i], i))[:k])
    expected = [i for i in expected if score[i] > 0]
    assert most_confused(m, k).tolist() == expected


def test_detect_jumps_and_recoveries():
    poses = np.column_stack([np.r_[np.arange(10.0) * 0.5, 40 + np.arange(10.0) * 0.5], np.zeros(20)])
    assert detect_jumps(poses).tolist() == [10]
    right = np.array([1] * 10 + [0, -1, 0, 1, 0, 1, -1, 1, 1, 1])
    # the last wrong step after the jump is 14: recovered at 15, and it stays right
    assert recoveries_after([10], right).tolist() == [15]
    assert recoveries_after([10], np.r_[np.ones(10), np.zeros(10)]).tolist() == [-1]


def _dark_top_and_left(path):
    """Mean darkness of small windows at the top, left, bottom and right of a thumbnail."""
    a = 255 - np.asarray(Image.open(path).convert("L"), dtype=np.float64)
    n = a.shape[0]
    w = slice(n // 2 - 6, n // 2 + 6)
    edge = slice(2, 14)
    return {
        "top": a[edge, w].mean(),
        "left": a[w, edge].mean(),
        "bottom": a[-14:-2, w].mean(),
        "right": a[w, -14:-2].mean(),
    }


def test_thumbnail_draws_bearing_zero_up_and_ninety_left(tmp_path):
    ahead = _dark_top_and_left(draw_view_thumbnail(FeatureView({"VE": [0.0]}), tmp_path / "a.png"))
    left = _dark_top_and_left(draw_view_thumbnail(FeatureView({"VE": [math.pi / 2]}), tmp_path / "b.png"))
    assert ahead["top"] > 3 * max(ahead["left"], ahead["bottom"], ahead["right"])
    assert left["left"] > 3 * max(left["top"], left["bottom"], left["right"])


def test_feature_view_checks_hues():
    with pytest.raises(InvalidParameterError, match="hues_deg"):
        FeatureView({"CP": [0.1, 0.2]}, [10.0])


# ----------------------------------------------------------------------------- writers


def _img_srcs(html):
    return re.findall(r'<img src="([^"]+)" alt="([^"]*)"', html)


def _all_images_exist(index):
    html = index.read_text()
    # plain and offline: no script, nothing fetched from elsewhere
    assert "<script" not in html.lower() and not re.search(r'(src|href)="(https?:)?//', html)
    srcs = _img_srcs(html)
    assert srcs
    for src, alt in srcs:
        assert (index.parent / src).is_file(), src
        assert alt.strip(), src
    return html


def test_localize_report_numbers_match_an_independent_count(tmp_path):
    d = synthetic_report_data(40, 200, seed=1)["localize"]
    index = write_localize_report(tmp_path / "loc", **d)
    html = _all_images_exist(index)
    js = json.loads((tmp_path / "loc" / "report.json").read_text())
    logp, truth = d["log_proba"], d["truth"]
    best = logp.argmax(axis=1)
    assert js["top1"] == pytest.approx(np.mean(best == truth))
    ranks = [1 + sum(logp[i, j] > logp[i, truth[i]] for j in range(40)) for i in range(200)]
    assert js["mean_rank"] == pytest.approx(np.mean(ranks))
    # the most frequent mistake counted by hand
    pairs: dict[tuple[int, int], int] = {}
    for t, b in zip(truth, best, strict=True):
        if t != b:
            pairs[(t, b)] = pairs.get((t, b), 0) + 1
    assert js["mistakes"][0][2] == max(pairs.values())
    assert "Only the 25 places with the most wrong answers" in html
    assert len(js["worst"]) == 12 and all(w["rank_of_true"] > 1 for w in js["worst"])


def test_localize_report_without_posterior(tmp_path):
    index = write_localize_report(
        tmp_path / "r", classes=["a", "b", "c"], truth=[0, 1, 2, 2], predicted=[0, 2, 2, 1], ranks=[1, 2, 1, 3]
    )
    js = json.loads((tmp_path / "r" / "report.json").read_text())
    assert js["top1"] == pytest.approx(0.5) and js["mean_rank"] == pytest.approx(7 / 4)
    assert [w["query"] for w in js["worst"]] == ["query 4", "query 2"]
    _all_images_exist(index)


def test_writers_reject_bad_shapes(tmp_path):
    with pytest.raises(InvalidParameterError, match="centres"):
        write_map_report(tmp_path, place_names=["a", "b"], centres=np.zeros((3, 2)), radius=1.0)
    with pytest.raises(InvalidParameterError, match="log_proba"):
        write_localize_report(tmp_path, classes=["a", "b"], log_proba=np.zeros((4, 3)))
    with pytest.raises(InvalidParameterError, match="kidnaps"):
        write_track_report(tmp_path, classes=["a"], log_posterior=np.zeros((3, 1)), kidnaps=[5])
    assert not (tmp_path / "index.html").exists()


def test_scaled_down_reports_fit_their_budget(tmp_path):
    # a tenth of the acceptance scale (1,000 places, 5,000 queries: < 30 s, < 50 MB; see docs/RESULTS.md)
    t0 = time.process_time()
    res = run_report_bench(tmp_path, n_places=100, n_queries=500)
    cpu = time.process_time() - t0
    assert res["total_bytes"] < 5e6, res
    assert cpu < 9.0, (cpu, res)
    for name in ("map", "localize", "track"):
        _all_images_exist(tmp_path / name / "index.html")
    # one thumbnail per place on the map page
    assert len(list((tmp_path / "map" / "places").glob("*.png"))) == 100


def _panorama(tmp_path):
    h, w = 40, 360
    img = np.full((h, w, 3), 0.8)
    img[:, 90:95] = 0.1  # a dark stripe: columns 90..95
    img[5:15, 200:215] = [0.9, 0.1, 0.1]
    ref = np.roll(img, -30, axis=1)  # the same place seen from a heading 30 columns = 30 deg away
    col = lambda c: np.deg2rad(-c)  # clockwise panorama, offset 0: bearing of column c  # noqa: E731
    return write_panorama_report(
        tmp_path / "pano",
        img,
        edges=[col(90), col(95)],
        patches=[col(207)],
        patch_hues_deg=[0.0],
        reference_image=ref,
        reference_edges=[col(60), col(65)],
        reference_patches=[col(177)],
        reference_hues_deg=[0.0],
        heading=np.deg2rad(-30.0),
    )


def test_panorama_report(tmp_path):
    index = _panorama(tmp_path)
    _all_images_exist(index)
    js = json.loads((tmp_path / "pano" / "report.json").read_text())
    assert js["heading_deg"] == pytest.approx(330.0)


# ----------------------------------------------------------------------------- command line


def _jsonl_session(tmp_path):
    from fingerloc.io.jsonl import write_observations
    from fingerloc.map.database import save_model
    from fingerloc.model import PlaceModel
    from fingerloc.observation import Observation

    rng = np.random.default_rng(0)
    names = ["office-with-a-rather-long-name-number-1", "b", "c", "d"]
    centres = {n: rng.uniform(0, 360, 4) for n in names}

    def obs(lab, x):
        return Observation.from_degrees(
            {"VE": (centres[lab] + rng.normal(0, 4, 4)).tolist(), "c": [float(rng.uniform(0, 360))]},
            label=lab,
            pose=[x, 0.0, 0.0],
        )

    walk = [n for n in names for _ in range(3)]
    train = [obs(lab, 2.0 * names.index(lab) + 0.1 * i) for i, lab in enumerate(walk)]
    db = tmp_path / "p.sqlite"
    save_model(PlaceModel(n_components=2, terms=("VE", "Fp")).fit(train), db)
    tr = tmp_path / "train.jsonl"
    write_observations(tr, train)
    # a run along the places, then a jump far away and back through them
    seq = ["office-with-a-rather-long-name-number-1", "b", "c", "d", "b", "c"]
    xs = [0.0, 2.0, 4.0, 6.0, 60.0, 62.0]
    q = tmp_path / "q.jsonl"
    write_observations(q, [obs(lab, x) for lab, x in zip(seq, xs, strict=True)])
    return db, tr, q


def test_cli_localize_report_and_quiet(tmp_path, capsys):
    db, _, q = _jsonl_session(tmp_path)
    out = tmp_path / "loc"
    code, text, err = run_cli(capsys, "localize", q, "--db", db, "--quiet", "--report", out)
    assert code == 0, err
    assert text.startswith("right classification:") and text.count("\n") == 1  # the summary only
    assert "index.html" in err
    html = _all_images_exist(out / "index.html")
    assert "office-with-a-rather-long-name-number-1" in html
    # without --quiet, the table folds long names onto the next lines instead of cutting them
    code, text, _ = run_cli(capsys, "localize", q, "--db", db)
    assert code == 0 and "…" not in text
    rows = [ln.split("│")[1:-1] for ln in text.splitlines() if ln.startswith("│")]
    end = next((k for k, r in enumerate(rows[1:], 1) if r[0].strip()), len(rows))
    true_cell = "".join(r[1].strip() for r in rows[:end])
    assert true_cell == "office-with-a-rather-long-name-number-1"


def test_cli_report_path_is_checked_before_anything_is_written(tmp_path, capsys):
    db, tr, q = _jsonl_session(tmp_path)
    bad = tmp_path / "a-file"
    bad.write_text("x")
    before = db.stat().st_mtime_ns
    code, _, err = run_cli(capsys, "track", q, "--db", db, "--graph-from", tr, "--report", bad)
    assert code == 2 and err.startswith("error: --report:") and "a-file" in err and err.count("\n") == 1
    assert db.stat().st_mtime_ns == before  # --graph-from would have stored the graph


def test_cli_track_report_marks_the_jump(tmp_path, capsys):
    db, tr, q = _jsonl_session(tmp_path)
    out = tmp_path / "trk"
    code, _, err = run_cli(capsys, "track", q, "--db", db, "--graph-from", tr, "-q", "--report", out)
    assert code == 0, err
    _all_images_exist(out / "index.html")
    js = json.loads((out / "report.json").read_text())
    assert js["kidnaps"] == [4] and js["steps"] == 6
    assert (out / "trajectory.png").exists()


def test_confusion_omitted_line_is_one_whole_line(tmp_path, capsys):
    from fingerloc.io.jsonl import write_observations
    from fingerloc.map.database import save_model
    from fingerloc.model import PlaceModel
    from fingerloc.observation import Observation

    rng = np.random.default_rng(1)
    obs = [Observation.from_degrees({"VE": rng.uniform(0, 360, 3).tolist()}, label=f"p{j}") for j in range(32)]
    db = tmp_path / "m.sqlite"
    save_model(PlaceModel(n_components=1, terms=("VE",), n_init=1).fit(obs), db)
    q = tmp_path / "q.jsonl"
    write_observations(q, obs)
    code, text, _ = run_cli(capsys, "localize", q, "--db", db)
    assert code == 0
    lines = [ln for ln in text.splitlines() if "omitted" in ln]
    assert lines == ["(confusion matrix omitted: 32 places, more than 30; --report DIR draws the most confused ones)"]


# ----------------------------------------------------------------------------- in a real browser


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    root = tmp_path_factory.mktemp("reports")
    d = synthetic_report_data(30, 120, seed=2)
    return {
        "map": write_map_report(root / "map", **d["map"]),
        "localize": write_localize_report(root / "localize", **d["localize"]),
        "track": write_track_report(root / "track", **d["track"]),
        "panorama": _panorama(root),
    }


@pytest.mark.parametrize("name", ["map", "localize", "track", "panorama"])
def test_report_opens_in_a_browser(reports, name):
    page = assert_page_ok(reports[name], min_images=2)
    assert page.title.startswith("fingerloc")


def test_browser_check_catches_a_missing_image(tmp_path):
    (tmp_path / "index.html").write_text('<!DOCTYPE html><html><body><img src="gone.png" alt="x"></body></html>')
    with pytest.raises(AssertionError):
        assert_page_ok(tmp_path / "index.html")


@pytest.mark.slow
def test_bench_carmen_report_on_a_shared_log(tmp_path, capsys):
    from pathlib import Path

    log = Path(__file__).resolve().parents[2] / "shared" / "data" / "carmen" / "aces-corrected.log.gz"
    if not log.exists():
        pytest.skip(f"{log} not found (the shared CARMEN logs sit beside the project)")
    out = tmp_path / "bench"
    code, _, err = run_cli(capsys, "bench", "carmen", log, "-m", "fingerprint", "--report", out)
    assert code == 0, err
    html = (out / "index.html").read_text()
    assert 'href="log1/map/index.html"' in html and 'href="log1/localize/index.html"' in html
    js = json.loads((out / "log1" / "map" / "report.json").read_text())
    assert len(js["places"]) == 61  # the protocol's count for aces (docs/RESULTS.md)
    for page in ("index.html", "log1/map/index.html", "log1/localize/index.html"):
        assert_page_ok(out / page, min_images=0 if page == "index.html" else 2)


def test_map_report_edges_by_name_and_json(tmp_path):
    index = write_map_report(
        tmp_path / "m",
        place_names=["hall", "lab", "office"],
        centres=[[0, 0], [3, 0], [3, 4]],
        radius=[1.0, 1.0, 0.5],
        edges=[("hall", "lab"), (1, 2), ("lab", "lab")],  # a self-loop draws nothing
        trajectory=[[0, 0, 0], [1.5, 0, 0], [3, 0, 0], [3, 2, 1.57], [3, 4, 1.57]],
        views_per_place=[2, 3, 1],
        place_views=[FeatureView({"c": [0.5]}, fingerprint="cnnn"), None, FeatureView({"VE": [1.0, -1.0]})],
    )
    js = json.loads((tmp_path / "m" / "report.json").read_text())
    assert js["edges"] == [["hall", "lab"], ["lab", "office"]]
    assert [p["views"] for p in js["places"]] == [2, 3, 1] and js["places"][0]["fingerprint"] == "cnnn"
    assert js["places"][2]["radius_m"] == 0.5
    html = _all_images_exist(index)
    assert len(list((tmp_path / "m" / "places").glob("*.png"))) == 2 and "3 views" in html
    with pytest.raises(InvalidParameterError, match="'kitchen'"):
        write_map_report(tmp_path / "x", place_names=["a"], centres=[[0, 0]], radius=1, edges=[("a", "kitchen")])


def test_map_report_adapter_from_a_learned_database(tmp_path, capsys):
    from fingerloc.cli.reports import map_report
    from fingerloc.io.jsonl import read_observations
    from fingerloc.map.database import load_model

    db, tr, _ = _jsonl_session(tmp_path)
    model = load_model(db)
    train = read_observations(tr)
    centres = {c: np.mean([o.pose[:2] for o in train if o.label == c], axis=0) for c in model.classes_}
    map_report(tmp_path / "map", model=model, centres=centres, radius=0.5, edges={("b", "c"): 2},
               trajectory=np.array([o.pose for o in train]), data=tr, db=db)  # fmt: skip
    js = json.loads((tmp_path / "map" / "report.json").read_text())
    assert [p["views"] for p in js["places"]] == [3, 3, 3, 3]
    assert js["edges"] == [["b", "c"]]
    assert all(p["fingerprint"] for p in js["places"])
    _all_images_exist(tmp_path / "map" / "index.html")
    assert "index.html" in capsys.readouterr().err


@pytest.mark.parametrize(("a", "b"), [("vnncnnb", "vncnnnbA"), ("", "cc"), ("ffv", "ffv"), ("vbc", "")])
def test_alignment_rows_spell_both_strings_and_count_the_cost(a, b):
    from fingerloc.align import global_alignment

    cost, path = global_alignment(a, b, return_alignment=True)
    top, mid, bottom = alignment_rows(a, b, path)
    assert top.replace("-", "") == a and bottom.replace("-", "") == b
    assert len(top) == len(mid) == len(bottom)
    # unit costs: one per substitution and per gap
    assert cost == mid.count(".") + mid.count(" ")


def test_importing_the_report_modules_loads_no_plotting_library():
    import subprocess
    import sys

    code = (
        "import sys, fingerloc.reporting, fingerloc.cli.reports, fingerloc.experiments.report_bench; "
        "print(sorted(m for m in ('matplotlib', 'PIL') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_localize_report_without_labels_shows_the_least_confident(tmp_path):
    logp = np.log(np.array([[0.9, 0.1], [0.55, 0.45], [0.2, 0.8]]))
    index = write_localize_report(tmp_path / "u", classes=["a", "b"], log_proba=logp, query_views=[None] * 3)
    html = index.read_text()
    js = json.loads((tmp_path / "u" / "report.json").read_text())
    assert "top1" not in js and js["labelled"] == 0
    assert "Least confident answers" in html
    assert [w["query"] for w in js["worst"]] == ["query 2", "query 3", "query 1"]


def test_map_report_from_the_command(rooms_log, tmp_path, capsys):
    """``fingerloc map LOG --db DB --report DIR`` writes the map report and checks DIR first."""
    out, db = tmp_path / "r1", tmp_path / "m.sqlite"
    code, _, err = run_cli(capsys, "map", rooms_log, "--db", db, "--no-calibration", "--report", out)
    assert code == 0, err
    html = (out / "index.html").read_text()
    assert "map.png" in html and (out / "map.png").stat().st_size > 1000
    from fingerloc.map.database import load_model

    assert html.count(" views</div>") == len(load_model(db).classes_)  # a card per place
    code, _, err = run_cli(capsys, "map", rooms_log, "--db", tmp_path / "n.sqlite", "--report", db)
    assert code == 2 and "--report" in err and not (tmp_path / "n.sqlite").exists()


def test_track_report_on_a_map_database(rooms_log, tmp_path, capsys):
    """``fingerloc track LOG --db MAP --report DIR``: trajectory with the map's places."""
    db, out = tmp_path / "m.sqlite", tmp_path / "r2"
    assert run_cli(capsys, "map", rooms_log, "--db", db, "--no-calibration")[0] == 0
    code, _, err = run_cli(capsys, "track", rooms_log, "--db", db, "--filter", "pose", "-q", "--report", out)
    assert code == 0, err
    assert (out / "trajectory.png").stat().st_size > 1000 and "trajectory.png" in (out / "index.html").read_text()
