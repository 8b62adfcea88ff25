import json

import numpy as np
import pytest

from fingerloc import Observation
from fingerloc.errors import DataFormatError, EmptyInputError
from fingerloc.io import read_observations, write_observations


def _write(tmp_path, lines, name="obs.jsonl"):
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def test_read_design_example(tmp_path):
    rec = {
        "place": "office-3",
        "pose": [1.0, 2.0, 90.0],
        "fov": [[-90, 90]],
        "features": {"VE": [12.5, 80.0], "CP": [{"bearing": 40.0, "hue": 130.0}], "Ex": [5], "c": [-30], "B": [181]},
    }
    (obs,) = read_observations(_write(tmp_path, [json.dumps(rec)]))
    assert obs.label == "office-3"
    assert np.allclose(np.rad2deg(obs.ve), [12.5, 80.0])
    assert np.allclose(obs.cp_hue, [130.0])
    assert np.allclose(np.rad2deg(obs.c), [-30.0])
    assert np.allclose(np.rad2deg(obs.b), [-179.0])  # wrapped to [-180, 180)
    assert obs.pose is not None and np.isclose(obs.pose[2], np.pi / 2)
    assert not obs.full_fov
    assert np.isclose(obs.fov_coverage(), 0.5)


def test_roundtrip(tmp_path):
    a = Observation.from_degrees(
        {"VE": [1, 2], "CP": [(3, 4.5)], "c": [300], "B": [10], "Ex": [20]},
        fov=[[-90, 90], [100, 120]],
        label="x",
        pose=[1, 2, 30],
        timestamp=3.5,
    )
    b = Observation.from_degrees({}, label=None)
    p = tmp_path / "out.jsonl"
    assert write_observations(p, [a, b]) == 2
    a2, b2 = read_observations(p)
    for n in ("ve", "cp", "cp_hue", "c", "b", "ex"):
        assert np.allclose(getattr(a, n), getattr(a2, n), atol=1e-9)
    assert np.allclose(np.array(a.fov), np.array(a2.fov), atol=1e-9)
    assert a2.label == "x" and a2.timestamp == 3.5
    assert b2 == b


def test_full_circle_fov_forms(tmp_path):
    p = _write(tmp_path, [json.dumps({"fov": [[0, 360]], "features": {}}), json.dumps({"features": {}})])
    a, b = read_observations(p)
    assert a.full_fov and b.full_fov


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ('{"features": {"VE": [1, 2}', r"obs\.jsonl:2: malformed JSON"),
        ('{"features": {"VE": ["abc"]}}', r"obs\.jsonl:2: bearing in features\.VE must be a number, got 'abc'"),
        ('{"features": {"VE": [NaN]}}', r"obs\.jsonl:2: bearing in features\.VE must be finite, got nan"),
        ('{"features": {"VE": [Infinity]}}', r"obs\.jsonl:2: .*finite, got inf"),
        ('{"features": {"XX": [1]}}', r"obs\.jsonl:2: unknown feature type 'XX'"),
        ('{"features": {"CP": [{"bearing": 1, "hue": 360}]}}', r"obs\.jsonl:2: hue must be in \[0, 360\).*360"),
        ('{"features": {"CP": [{"bearing": 1, "hue": -1}]}}', r"obs\.jsonl:2: hue.*-1"),
        ('{"place": "a"}', r'obs\.jsonl:2: missing key "features"'),
        ("[1, 2]", r"obs\.jsonl:2: a record must be a JSON object"),
        ('{"fov": [[10, 10]], "features": {}}', r"obs\.jsonl:2: fov: empty range"),
        ('{"pose": [1, 2], "features": {}}', r'obs\.jsonl:2: "pose" must be'),
    ],
)
def test_bad_lines(tmp_path, line, match):
    p = _write(tmp_path, ['{"features": {"VE": [1]}}', line])
    with pytest.raises(DataFormatError, match=match):
        read_observations(p)


def test_empty_file(tmp_path):
    p = _write(tmp_path, ["", "   "])
    with pytest.raises(EmptyInputError, match="empty"):
        read_observations(p)


def test_missing_file(tmp_path):
    with pytest.raises(DataFormatError, match="cannot read"):
        read_observations(tmp_path / "nope.jsonl")


def test_walls_and_scan_roundtrip(tmp_path):
    import dataclasses

    a = Observation.from_degrees({"W": [{"bearing": 10, "length": 2.5, "range": 1.2}, (-30, 0.4, 3.0)], "Ex": [5]})
    a = dataclasses.replace(a, ranges=np.array([1.0, np.inf, 2.5]), range_bearings=np.deg2rad([-10.0, 0.0, 10.0]))
    p = tmp_path / "w.jsonl"
    write_observations(p, [a])
    (b,) = read_observations(p)
    assert np.allclose(b.w, a.w) and np.allclose(b.w_length, a.w_length) and np.allclose(b.w_range, a.w_range)
    assert b.ranges is not None and np.isinf(b.ranges[1]) and np.allclose(b.ranges[[0, 2]], [1.0, 2.5])
    assert '"ranges": [1.0, null, 2.5]' in p.read_text()


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ('{"features": {"W": [{"bearing": 1, "length": 0, "range": 2}]}}', "must be > 0"),
        ('{"features": {"W": [{"bearing": 1}]}}', "each wall"),
        ('{"features": {}, "scan": {"bearings": [1, 2], "ranges": [1]}}', "one range per bearing"),
        ('{"features": {}, "scan": {"bearings": [1], "ranges": [-1]}}', ">= 0"),
    ],
)
def test_bad_wall_and_scan(tmp_path, line, match):
    with pytest.raises(DataFormatError, match=match):
        read_observations(_write(tmp_path, [line]))
