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


# -- the fast path of observation_from_record: the same observations bit for bit -----------------

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from fingerloc.io import jsonl as _jsonl  # noqa: E402

from .conftest import fuzz_examples  # noqa: E402

_FIELDS = ("ve", "cp", "cp_hue", "ex", "c", "b", "w", "w_length", "w_range")


def _validating(record):
    """observation_from_record with the fast path switched off."""
    saved = _jsonl._fast_observation
    _jsonl._fast_observation = lambda r: None
    try:
        return _jsonl.observation_from_record(record)
    finally:
        _jsonl._fast_observation = saved


def _identical(a, b):
    for n in _FIELDS:
        x, y = getattr(a, n), getattr(b, n)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), n
        assert not x.flags.writeable and not y.flags.writeable
    for n in ("ranges", "range_bearings", "appearance", "fov", "label", "pose", "timestamp", "source"):
        assert repr(getattr(a, n)) == repr(getattr(b, n)), n


_number = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.floats(-1e4, 1e4),
    st.integers(-(2**60), 2**60),
    st.booleans(),
    st.just(-0.0),
    st.just(1e-300),
)
_value = st.one_of(_number, st.text(max_size=3), st.none(), st.lists(_number, max_size=3))
_record = st.fixed_dictionaries(
    {"features": st.one_of(
        st.dictionaries(st.sampled_from(["VE", "Ex", "c", "B", "CP", "W", "X"]),
                        st.one_of(st.lists(_number, max_size=6), _value), max_size=4),
        _value)},
    optional={
        "place": st.one_of(st.text(max_size=4), st.just("\ud800"), _value),
        "pose": st.one_of(st.lists(_number, min_size=2, max_size=4), _value),
        "fov": st.one_of(st.lists(st.lists(_number, min_size=1, max_size=3), max_size=3), _value),
        "timestamp": _value,
        "source": st.one_of(st.text(max_size=3), _value),
        "extra": _value,
    },
)  # fmt: skip


@settings(max_examples=fuzz_examples(300), deadline=None)
@given(_record)
def test_fast_path_builds_what_the_validating_path_builds(record):
    fast = _jsonl._fast_observation(record)
    try:
        slow = _validating(record)
    except DataFormatError:
        assert fast is None  # the fast path never accepts what the checks refuse
        return
    if fast is not None:
        _identical(fast, slow)


def test_fast_path_takes_plain_records_and_leaves_the_rest():
    plain = {"place": "a", "pose": [1, 2.5, 90], "fov": [[-90, 90], [100, 120]], "timestamp": 3, "source": "s",
             "features": {"VE": [359.9999, -0.0, 1e-300, 720], "Ex": [5], "c": [], "B": [181.25]}}  # fmt: skip
    fast = _jsonl._fast_observation(plain)
    assert fast is not None
    _identical(fast, _validating(plain))
    assert fast == _jsonl.observation_from_record(plain)
    for other in (
        {**plain, "features": {"CP": [{"bearing": 1, "hue": 2}]}},
        {**plain, "scan": {"bearings": [0], "ranges": [1]}},
        {**plain, "appearance": [1.0]},
        {**plain, "features": {"VE": [True]}},
        {**plain, "features": {"VE": [float("nan")]}},
        {**plain, "place": "\ud800"},
        {**plain, "fov": [[10, 10]]},
        {**plain, "pose": [2e9, 0, 0]},
    ):
        assert _jsonl._fast_observation(other) is None


def test_parse_record_keeps_json_loads_errors():
    with pytest.raises(DataFormatError, match="BOM"):
        _jsonl.parse_record('\ufeff{"features": {}}')
    with pytest.raises(DataFormatError, match="40"):
        _jsonl.parse_record('{"features": {"VE": [' + "1" * 41 + "]}}")
    assert _jsonl.parse_record(b'{"features": {}}') == {"features": {}}
