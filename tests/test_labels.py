"""Labels CSV of a photo tour (``features --labels``, ``bench panorama --labels``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from fingerloc.errors import DataFormatError
from fingerloc.io.labels import PhotoLabel, match_labels, read_labels


def test_rows_with_and_without_positions(tmp_path):
    f = tmp_path / "labels.csv"
    f.write_text("\ufeffplace,file,x,y,note\nhall,hall/1.jpg,0,1.5,first\n\nkitchen,k\\2.jpg,,,\n")
    rows = read_labels(f)
    assert rows == [PhotoLabel("hall/1.jpg", "hall", (0.0, 1.5)), PhotoLabel("k/2.jpg", "kitchen", None)]
    f.write_text("file,place\na.jpg,x\n")
    assert read_labels(f) == [PhotoLabel("a.jpg", "x", None)]


@pytest.mark.parametrize(
    ("text", "where", "what"),
    [
        ("", "", "empty"),
        ("name,place\na.jpg,x\n", ":1", "file and place"),
        ("file,place\na.jpg,\n", ":2", "a file and a place"),
        ("file,place\na.jpg,x\na.jpg,y\n", ":3", "listed twice"),
        ("file,place,x,y\na.jpg,x,1,north\n", ":2", "must be numbers"),
        ("file,place,x,y\na.jpg,x,inf,0\n", ":2", "finite"),
        ("file,place\n\n", "", "no photo"),
    ],
)
def test_malformed_labels_name_the_line(tmp_path, text, where, what):
    f = tmp_path / "labels.csv"
    f.write_text(text)
    with pytest.raises(DataFormatError, match=what) as err:
        read_labels(f)
    assert f"labels.csv{where}" in str(err.value)


def test_photos_are_matched_by_path_then_by_name(tmp_path):
    (tmp_path / "hall").mkdir()
    rows = [PhotoLabel("hall/1.jpg", "hall"), PhotoLabel("2.jpg", "kitchen"), PhotoLabel("x/3.jpg", "a"),
            PhotoLabel("y/3.jpg", "b")]  # fmt: skip
    got = match_labels([tmp_path / "hall" / "1.jpg", Path("elsewhere/2.jpg")], rows, tmp_path)
    assert [r.place for r in got] == ["hall", "kitchen"]
    with pytest.raises(DataFormatError, match="2 rows have its file name"):
        match_labels([Path("z/3.jpg")], rows, tmp_path)
    with pytest.raises(DataFormatError, match="no row names it"):
        match_labels([Path("4.jpg")], rows, tmp_path)
    with pytest.raises(DataFormatError, match="no such file"):
        read_labels(tmp_path / "missing.csv")


def test_features_gives_each_photo_its_place_in_one_call(tmp_path, capsys):
    import json

    import numpy as np
    from PIL import Image

    from ._cli import run_cli

    rng = np.random.default_rng(0)
    for name in ("a.png", "b.png", "c.png"):  # a few coloured walls with vertical edges (noise would give thousands)
        cols = np.repeat(rng.integers(0, 255, (8, 3), dtype=np.uint8), 32, axis=0)
        Image.fromarray(np.repeat(cols[None, :, :], 128, axis=0)).save(tmp_path / name)
    (tmp_path / "labels.csv").write_text("file,place\na.png,hall\nb.png,kitchen\n")
    out = tmp_path / "o.jsonl"
    code, _, err = run_cli(capsys, "features", tmp_path / "a.png", tmp_path / "b.png", "--labels",
                           tmp_path / "labels.csv", "--json", out)  # fmt: skip
    assert code == 0, err
    assert [json.loads(x)["place"] for x in out.read_text().splitlines()] == ["hall", "kitchen"]
    out2 = tmp_path / "o2.jsonl"
    code, _, err = run_cli(capsys, "features", tmp_path / "a.png", tmp_path / "c.png", "--labels",
                           tmp_path / "labels.csv", "--json", out2)  # fmt: skip
    assert code == 2 and "c.png" in err and "no row names it" in err and not out2.exists()
    code, _, err = run_cli(capsys, "features", tmp_path / "a.png", "--labels", tmp_path / "labels.csv",
                           "--place", "x")  # fmt: skip
    assert code == 2 and "not both" in err
