"""``fingerloc demo``: the report folder (quick size)."""

import json

import pytest
from PIL import Image

from fingerloc.cli import main
from fingerloc.experiments.report import FIGURES, QUERY_FIGURE
from tests._browser import assert_page_ok


def test_demo_writes_report(tmp_path, capsys):
    out = tmp_path / "report"
    code = 0
    try:
        main(["demo", "--quick", "--workers", "1", "--out", str(out)])
    except SystemExit as e:
        code = int(e.code or 0)
    stdout = capsys.readouterr().out
    assert code == 0
    assert "Table III" in stdout and "Table IV" in stdout and "report:" in stdout
    # the first screen (25 lines) tells the story: what reproduces over 20 trials, then this trial's findings
    head = "\n".join(stdout.splitlines()[:25])
    assert "What the reproduction shows over 20 trials" in head
    for claim in (
        "Table II, features per measurement: CALIBRATED",
        "Table III, string matching alone: CALIBRATED",
        "Table IV, the Bayesian program: PREDICTED",
        "global alignment beats minimum energy: holds",
        "more mixture components help VE: not shown",
        "the full program beats VE & Ex: holds",
        "no one world gives both tables",
        "This trial alone",
    ):
        assert claim in head, claim
    page = (out / "index.md").read_text()
    for name in FIGURES:
        assert (out / name).exists(), name
        assert f"]({name})" in page
        with Image.open(out / name) as im:
            assert im.format == "PNG" and im.size[0] > 200 and im.size[1] > 150
    assert "Table II" in page and "paper" in page
    assert (out / "results.json").exists()
    # one query explained: its posterior, its fingerprint against the true place's and the answer's, why
    assert (out / QUERY_FIGURE).exists() and f"]({QUERY_FIGURE})" in page
    js = json.loads((out / "results.json").read_text())
    q = js["explained_query"]
    assert sum(q["posterior"].values()) == pytest.approx(1.0)
    assert q["truth"] in page and q["answer"] in page and q["fingerprint"] in page
    assert q["nearest_training_fingerprint"]["truth"]["letters"] in page
    assert ("Why it failed" in page) == (q["truth"] != q["answer"])
    assert "95" in page and "[" in page  # confidence intervals beside the figures
    assert js["ci95"]["table4"]["VE+Ex+Fp"]["3"]["top1"] is not None
    assert js["table4"]["VE+Ex+Fp"]["3"]["ci95"] == js["ci95"]["table4"]["VE+Ex+Fp"]["3"]
    assert "What reproduces, and what does not" in page and "The paper's findings" in page
    # last: the same page as HTML in a real browser (where none can run, the test is skipped after the checks above)
    assert_page_ok(out / "index.html", min_images=len(FIGURES))


def test_demo_help(capsys):
    code = 0
    try:
        main(["demo", "--help"])
    except SystemExit as e:
        code = int(e.code or 0)
    assert code == 0 and "--out" in capsys.readouterr().out
