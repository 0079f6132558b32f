"""The in-process transport's key-expression matching, checked against zenoh's own."""

from __future__ import annotations

import itertools

import pytest
import zenoh

from ubf_async.errors import KeyExprError
from ubf_async.net.keyexpr import intersects, key_chunks

CASES = [
    ("a/b", "a/b"), ("a/b", "a/c"), ("a/*", "a/b"), ("a/*", "a"), ("a/**", "a"),
    ("a/**", "a/b/c"), ("**", "a"), ("*/b", "a/*"), ("a/*/c", "a/**"), ("a/**/c", "a/c"),
    ("a/**/c", "a/b/d/c"), ("a/**/c", "a/b/d"), ("**/c", "a/**"), ("@a/b", "*/b"),
    ("@a/b", "**/b"), ("@a/b", "@a/*"), ("a/@b", "a/**"), ("a/**/@b", "a/@b"), ("**", "@a"),
    ("a/*", "a/*/b"), ("*", "**"), ("a/**/b/**/c", "a/x/b/c"), ("a/**/b/**/c", "a/b/x/y"),
    ("*/**", "a"), ("*/**", "a/b/c"), ("a/*/**", "a"),
    # the keys ubf_async itself uses
    ("ubf/mini/sensor/**", "ubf/mini/sensor/range/front"),
    ("ubf/mini/sensor/*/*", "ubf/mini/sensor/range/front"),
    ("ubf/mini/sensor/*", "ubf/mini/sensor/range/front"),
    ("ubf/mini/alive/*", "ubf/mini/alive/controller"),
    ("ubf/*/alive/*", "ubf/other/alive/x"),
    ("ubf/mini/vote/*/*", "ubf/mini/vote/seek/teleop"),
    ("ubf/mini/vote/**", "ubf/mini2/vote/seek/teleop"),
    ("ubf/mini/**", "ubf/mini"),
]


@pytest.mark.parametrize(("a", "b"), CASES)
def test_intersects_agrees_with_zenoh_both_ways(a: str, b: str) -> None:
    expected = zenoh.KeyExpr(a).intersects(zenoh.KeyExpr(b))
    assert intersects(a, b) is expected
    assert intersects(b, a) is expected


def test_every_pair_of_a_small_alphabet_agrees_with_zenoh() -> None:
    """All pairs of expressions of up to three chunks over {x, y, *, **, @v}."""
    chunks = ["x", "y", "*", "**", "@v"]
    exprs = []
    for n in (1, 2, 3):
        for combo in itertools.product(chunks, repeat=n):
            text = "/".join(combo)
            try:
                zenoh.KeyExpr(text)
            except zenoh.ZError:
                continue  # zenoh refuses it (non-canonical): so does key_chunks, below
            exprs.append(text)
    assert len(exprs) > 80
    for a, b in itertools.product(exprs, repeat=2):
        assert intersects(a, b) is zenoh.KeyExpr(a).intersects(zenoh.KeyExpr(b)), (a, b)


@pytest.mark.parametrize("bad", ["", "a//b", "/a", "a/", "a/b*", "a/**/**", "**/**", "a/**/*",
                                 "a/#", "a?b"])
def test_expressions_zenoh_refuses_are_refused(bad: str) -> None:
    with pytest.raises(zenoh.ZError):
        zenoh.KeyExpr(bad)
    with pytest.raises(KeyExprError):
        key_chunks(bad)


def test_sub_chunk_wildcards_are_refused_clearly() -> None:
    """zenoh accepts ``$*``; the in-process transport does not implement it and says so."""
    zenoh.KeyExpr("a/b$*")
    with pytest.raises(KeyExprError, match=r"\$"):
        key_chunks("a/b$*")
