"""The tolerant golden comparisons of ``tests/_golden.py`` accept build noise and nothing more."""

from __future__ import annotations

import pytest

from ._golden import assert_close, assert_text_close


def test_last_bits_pass_and_real_changes_fail():
    ref = {"a": [1.0, -2.5, 0.0], "b": {"s": "x", "n": 3, "ok": True, "none": None}}
    assert_close({"a": [1.0 + 3e-15, -2.5 * (1 + 2e-16), 1e-14], "b": {"s": "x", "n": 3, "ok": True, "none": None}}, ref)
    for bad in (
        {"a": [1.0 + 1e-6, -2.5, 0.0], "b": ref["b"]},
        {"a": [1.0, -2.5], "b": ref["b"]},
        {"a": [1.0, -2.5, 0.0], "b": {**ref["b"], "s": "y"}},
        {"a": [1.0, -2.5, 0.0], "b": {**ref["b"], "n": 4}},
        {"b": ref["b"], "a": ref["a"]},  # key order is part of the output
        {"a": [1.0, -2.5, float("nan")], "b": ref["b"]},
    ):
        with pytest.raises(AssertionError):
            assert_close(bad, ref)


def test_printed_numbers_within_one_last_digit():
    assert_text_close("p 0.125  rank 2.00\n", "p 0.124  rank 2.00\n")  # a value at a rounding edge
    with pytest.raises(AssertionError):
        assert_text_close("p 0.127  rank 2.00\n", "p 0.124  rank 2.00\n")
    with pytest.raises(AssertionError):
        assert_text_close("q 0.124  rank 2.00\n", "p 0.124  rank 2.00\n")
    with pytest.raises(AssertionError):
        assert_text_close("p 0.124\nmore\n", "p 0.124\n")
