"""Runs read line by line: CARMEN and JSON Lines streams, followed files, bad lines, no-return codes."""

from __future__ import annotations

import gzip
import io
import json
import threading
import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fingerloc.errors import DataFormatError, InvalidParameterError
from fingerloc.io.carmen import LaserRecord, parse_line
from fingerloc.io.stream import (
    NoReturnCodes,
    StreamReader,
    detect_stream_kind,
    follow_lines,
    iter_stream,
    open_lines,
)
from fingerloc.pipeline.readers import load_log_scans

from ._logs import rooms_path
from .features_world import CARMEN_DIR


def _numbered(lines):
    return list(enumerate(lines, start=1))


def _flaser(ranges, pose=(1.0, 2.0, 0.5), odom=(0.0, 0.0, 0.0), t=10.0):
    r = " ".join(str(v) for v in ranges)
    return f"FLASER {len(ranges)} {r} {pose[0]} {pose[1]} {pose[2]} {odom[0]} {odom[1]} {odom[2]} {t} host {t}"


SHARED = sorted(CARMEN_DIR.glob("*.log.gz")) if CARMEN_DIR.is_dir() else []


@pytest.mark.skipif(not SHARED, reason="the shared CARMEN logs are not beside the project")
@pytest.mark.parametrize("name", ["aces", "csail", "freiburg-101", "intel"])
def test_a_streamed_shared_log_gives_the_scans_of_the_file_reader(name):
    path = CARMEN_DIR / f"{name}-corrected.log.gz"
    offline, _ = load_log_scans(path)
    items = list(iter_stream(path))
    scans = [it.scan for it in items]
    assert len(scans) == len(offline)
    for a, b in zip(scans, offline, strict=True):
        assert a is not None
        np.testing.assert_array_equal(a.ranges, b.ranges)  # the same beams are no return (inf)
        np.testing.assert_array_equal(a.bearings, b.bearings)
        assert a.pose == b.pose
        assert a.timestamp == b.timestamp
        assert a.sensor_offset == b.sensor_offset


def test_each_item_comes_before_the_next_line_is_read(rooms_log):
    read = []

    def lines():
        for n, text in enumerate(rooms_log.read_text().splitlines(keepends=True), start=1):
            read.append(n)
            yield n, text

    k = 0
    for item in StreamReader(lines(), source="rooms"):
        assert read[-1] == item.line  # nothing past the item's own line was read
        assert item.name == f"rooms:{item.line} FLASER"
        k += 1
    assert k == len(rooms_path())


def test_carmen_items_carry_pose_odometry_and_stamp():
    lines = [
        "# a log",
        "PARAM robot_front_laser_max 30 nohost 0",
        _flaser([1.0, 2.0, 3.0], odom=(0.1, 0.2, 0.3), t=5.5),
    ]
    lines.append("ODOM 0.5 0.6 0.7 0 0 0 6.0 host 6.0")
    (item,) = StreamReader(_numbered(lines))
    assert item.pose == (1.0, 2.0, 0.5) and item.odometry == (0.1, 0.2, 0.3) and item.stamp == 5.5
    assert item.item is item.scan and item.observation is None
    both = list(StreamReader(_numbered(lines), odometry_lines=True))
    assert [it.name for it in both] == ["stdin:3 FLASER", "stdin:4 ODOM"]
    assert both[1].odometry == (0.5, 0.6, 0.7) and both[1].item is None


def test_the_first_front_laser_line_fixes_the_laser():
    rl = "ROBOTLASER1 0 -1.5707963 3.1415926 0.0174533 80 0.01 0 3 1 2 3 0 0 0 0 0 0 0 0 0 0.5 0.5 0 7.0 host 7.0"
    assert isinstance(parse_line(rl), LaserRecord)
    items = list(StreamReader(_numbered([_flaser([1.0, 2.0, 3.0]), rl, _flaser([2.0, 2.0, 2.0])])))
    assert [it.name.split()[1] for it in items] == ["FLASER", "FLASER"]
    items = list(StreamReader(_numbered([rl, _flaser([1.0, 2.0, 3.0]), rl])))
    assert [it.name.split()[1] for it in items] == ["ROBOTLASER1", "ROBOTLASER1"]
    assert len(list(StreamReader(_numbered([rl, _flaser([1.0, 2.0, 3.0])]), messages=["FLASER"]))) == 1


def test_no_return_codes_are_learned_line_by_line():
    codes = NoReturnCodes()

    def thr(ranges):
        return codes.threshold(parse_line(_flaser(ranges)))

    assert thr([1.0, 4.4, 4.4, 4.4]) is None  # a repeated reading is no code
    assert thr([1.0, 81.91, 2.0]) == 81.91
    assert thr([1.0, 32.76, 2.0]) == 81.91  # a smaller code is a reading once a larger one is known
    assert thr([81.83, 1.0, 2.0]) == 81.83  # lowered within 0.5 %, as the file reader does
    assert NoReturnCodes(max_range=20.0).threshold(parse_line(_flaser([50.0, 1.0]))) == 20.0
    items = list(StreamReader(_numbered([_flaser([1.0, 50.0, 2.0]), _flaser([50.0, 3.0, 32.76])])))
    np.testing.assert_array_equal(items[0].scan.ranges, [1.0, np.inf, 2.0])
    np.testing.assert_array_equal(items[1].scan.ranges, [np.inf, 3.0, 32.76])


def test_json_lines_observations_scans_and_odometry():
    obs = {"features": {"VE": [10.0, 200.0]}, "pose": [1, 2, 90], "timestamp": 3.0, "odometry": [0.5, 0, -90]}
    scan = {"scan": {"bearings": [-10, 0, 10], "ranges": [1.5, None, 2.5]}, "pose": [4, 5, 0], "timestamp": 4.0}
    odo = {"odometry": [1, 1, 0], "timestamp": 4.5}
    lines = _numbered([json.dumps(obs), "", json.dumps(scan), json.dumps(odo)])
    a, b = StreamReader(lines)
    assert a.observation is not None and a.pose == pytest.approx((1.0, 2.0, np.pi / 2))
    assert a.odometry == pytest.approx((0.5, 0.0, -np.pi / 2)) and a.stamp == 3.0
    np.testing.assert_allclose(b.scan.bearings, np.deg2rad([-10, 0, 10]))
    np.testing.assert_array_equal(b.scan.ranges, [1.5, np.inf, 2.5])
    assert b.scan.max_range == 3.5 and b.stamp == 4.0 and b.name == "stdin:3"
    c = list(StreamReader(lines, odometry_lines=True))[2]
    assert c.item is None and c.odometry == (1.0, 1.0, 0.0) and c.stamp == 4.5


@pytest.mark.parametrize(
    ("line", "kind"),
    [("{}", "jsonl"), ('  {"a": 1}', "jsonl"), ("# comment", "carmen"), ("PARAM x 1", "carmen"), ("", None)],
)
def test_detect_stream_kind(line, kind):
    assert detect_stream_kind(line) == kind


def test_a_line_of_neither_format_is_an_error_naming_it():
    with pytest.raises(DataFormatError, match=r"^stdin:2: neither a CARMEN line nor a JSON Lines record: 'hello'"):
        list(StreamReader(_numbered(["", "hello", "FLASER 2 1 1 0 0 0 0 0 0 1 h 1"])))


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        ("FLASER 3 1 2 0 0 0 0 0 0 1 h 1", "FLASER line has 13 fields, expected 14"),
        ("FLASER 3 1 2 x 0 0 0 0 0 0 1 h 1", "must be numbers, got 'x'"),
    ],
)
def test_a_bad_carmen_line_stops_the_stream_or_is_skipped_with_its_name(bad, match):
    lines = _numbered([_flaser([1.0, 2.0, 3.0]), bad, _flaser([2.0, 2.0, 2.0], t=11.0)])
    with pytest.raises(DataFormatError, match=rf"^robot\.log:2: .*{match}"):
        list(StreamReader(lines, source="robot.log"))
    seen = []
    reader = StreamReader(lines, source="robot.log", skip_bad=True, on_error=seen.append)
    assert [it.stamp for it in reader] == [10.0, 11.0]
    assert [str(e) for e in seen] == [str(seen[0])] and str(seen[0]).startswith("robot.log:2: ")
    assert reader.stats.skipped == 1 and reader.stats.scans == 2


def test_bad_json_records_name_the_line():
    lines = _numbered(
        ['{"features": {}}', '{"features": ', '{"pose": [1, 2, 3]}', '{"scan": {"bearings": [1], "ranges": []}}']
    )
    seen = []
    items = list(StreamReader(lines, skip_bad=True, on_error=seen.append))
    assert len(items) == 1
    assert [e.line for e in seen] == [2, 3, 4]
    assert (
        "malformed JSON" in str(seen[0]) and '"features"' in str(seen[1]) and "1 bearings but 0 ranges" in str(seen[2])
    )


@given(st.lists(st.binary(max_size=60).map(lambda b: b.replace(b"\n", b" ")), max_size=8))
def test_garbage_lines_raise_only_data_format_errors_or_are_skipped(chunks):
    data = b"".join(c + b"\n" for c in chunks)
    try:
        list(StreamReader(open_lines("-", stdin=io.BufferedReader(io.BytesIO(data)))))
    except DataFormatError:
        pass  # the only error a line may cause
    reader = StreamReader(open_lines("-", stdin=io.BufferedReader(io.BytesIO(data))), skip_bad=True)
    if data.startswith(b"\x1f\x8b"):  # gzip magic: a corrupt gzip stream is an error, not a bad line
        with pytest.raises(DataFormatError, match="gzip"):
            list(reader)
        return
    list(reader)
    assert reader.stats.lines == len(chunks)


def test_standard_input_plain_or_gzip(rooms_log):
    raw = rooms_log.read_bytes()
    for data in (raw, gzip.compress(raw)):
        items = list(StreamReader(open_lines("-", stdin=io.BufferedReader(io.BytesIO(data)))))
        assert len(items) == len(rooms_path())


def test_a_gzip_file_streams_but_cannot_be_followed(tmp_path, rooms_log):
    gz = tmp_path / "r.log.gz"
    gz.write_bytes(gzip.compress(rooms_log.read_bytes()))
    assert len(list(iter_stream(gz))) == len(rooms_path())
    with pytest.raises(InvalidParameterError, match="cannot be followed"):
        iter_stream(gz, follow=True)
    with pytest.raises(DataFormatError, match="cannot read"):
        iter_stream(tmp_path / "missing.log")


def test_a_followed_file_gives_each_line_once_it_is_complete(tmp_path):
    path = tmp_path / "growing.log"
    path.write_bytes(b"")
    got: list[tuple[float, int, str]] = []

    def read():
        for n, text in follow_lines(path, poll_s=0.01, idle_timeout_s=1.0):
            got.append((time.monotonic(), n, text))

    th = threading.Thread(target=read)
    th.start()
    with open(path, "ab") as fh:
        fh.write(b"first\nsec")
        fh.flush()
        time.sleep(0.3)
        assert [g[2] for g in got] == ["first\n"]  # the half-written line waits
        fh.write(b"ond\nthird")
        fh.flush()
    th.join(timeout=5.0)
    assert not th.is_alive()
    assert [(n, t) for _, n, t in got] == [(1, "first\n"), (2, "second\n"), (3, "third")]


def test_a_followed_file_that_shrinks_is_an_error(tmp_path):
    path = tmp_path / "g.log"
    path.write_bytes(b"one\ntwo\n")
    lines = follow_lines(path, poll_s=0.01, idle_timeout_s=2.0)
    assert next(lines) == (1, "one\n") and next(lines) == (2, "two\n")
    path.write_bytes(b"")
    with pytest.raises(DataFormatError, match="shrank"):
        next(lines)


def test_stream_options_are_checked():
    with pytest.raises(InvalidParameterError, match="kind must be one of auto, carmen, jsonl"):
        StreamReader([], kind="bag")
    with pytest.raises(InvalidParameterError, match="unknown CARMEN laser message 'LASER3'"):
        StreamReader([], messages=["LASER3"])
    with pytest.raises(InvalidParameterError, match="max_range"):
        StreamReader([], max_range=-1.0)
