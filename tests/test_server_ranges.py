"""Sans-I/O parts of the server: the Range parser and conditional-request rules."""

from __future__ import annotations

import time

from hypothesis import given
from hypothesis import strategies as st

from tsog_stream.container.ranges import ByteRange
from tsog_stream.server.conditional import (
    Outcome,
    evaluate,
    http_date,
    if_range_allows,
    parse_etags,
)
from tsog_stream.server.ranges import (
    MAX_RANGES,
    Ignore,
    Serve,
    Unsatisfiable,
    content_range,
    parse_range,
    unsatisfied_range,
)

LEN = 1000


def spans(value: str, length: int = LEN) -> list[tuple[int, int]]:
    """The served spans of a header, failing when the verdict is not Serve."""
    verdict = parse_range(value, length)
    assert isinstance(verdict, Serve), verdict
    return [(r.start, r.end) for r in verdict.ranges]


def test_single_open_and_suffix_ranges() -> None:
    assert spans("bytes=0-0") == [(0, 1)]
    assert spans("bytes=10-19") == [(10, 20)]
    assert spans("bytes=990-5000") == [(990, 1000)]
    assert spans("bytes=500-") == [(500, 1000)]
    assert spans("bytes=-10") == [(990, 1000)]
    assert spans("bytes=-5000") == [(0, 1000)]
    assert spans("BYTES = 1-2") == [(1, 3)]


def test_multiple_ranges_sorted_and_coalesced() -> None:
    assert spans("bytes=0-9, 20-29") == [(0, 10), (20, 30)]
    assert spans("bytes=20-29,0-9") == [(0, 10), (20, 30)]
    assert spans("bytes=0-9,5-14") == [(0, 15)]
    assert spans("bytes=0-9,10-19") == [(0, 20)]
    assert spans("bytes=0-9,,  ,50-59") == [(0, 10), (50, 60)]
    assert spans("bytes=0-9,2000-3000") == [(0, 10)]


def test_unsatisfiable() -> None:
    for value in ("bytes=1000-", "bytes=-0", "bytes=5000-6000", "bytes=1000-1000,-0"):
        assert parse_range(value, LEN) == Unsatisfiable(), value
    assert parse_range("bytes=-5", 0) == Unsatisfiable()
    assert parse_range("bytes=0-", 0) == Unsatisfiable()


def test_ignored_headers() -> None:
    for value in (
        None,
        "",
        "bytes=",
        "bytes=abc",
        "bytes=5-2",
        "bytes=1-2-3",
        "bytes=-",
        "items=0-5",
        "bytes 0-5",
        "bytes=0-5;x",
        "bytes=\u0661-\u0662",
        "bytes=é-1",
        "bytes=+1-2",
    ):
        assert isinstance(parse_range(value, LEN), Ignore), value


def test_range_cap() -> None:
    assert len(spans(",".join(["bytes=0-0"] + [f"{2 * i}-{2 * i}" for i in range(1, 32)]))) == 32
    too_many = "bytes=" + ",".join(f"{2 * i}-{2 * i}" for i in range(MAX_RANGES + 1))
    assert isinstance(parse_range(too_many, LEN), Ignore)
    ten_thousand = "bytes=" + ",".join("0-0" for _ in range(10_000))
    assert isinstance(parse_range(ten_thousand, LEN), Ignore)


def test_huge_numbers() -> None:
    assert parse_range("bytes=" + "9" * 5000 + "-", LEN) == Unsatisfiable()
    assert spans("bytes=0-" + "9" * 5000) == [(0, 1000)]
    assert spans("bytes=-" + "9" * 5000) == [(0, 1000)]
    assert spans("bytes=" + "0" * 50 + "7-8") == [(7, 9)]


def test_header_formatting() -> None:
    assert content_range(ByteRange(0, 10), 100) == "bytes 0-9/100"
    assert unsatisfied_range(100) == "bytes */100"


@given(st.text(max_size=200), st.integers(min_value=0, max_value=10**6))
def test_any_header_gives_a_verdict(value: str, length: int) -> None:
    verdict = parse_range(value, length)
    assert isinstance(verdict, Serve | Ignore | Unsatisfiable)
    if isinstance(verdict, Serve):
        assert 1 <= len(verdict.ranges) <= MAX_RANGES
        for r in verdict.ranges:
            assert 0 <= r.start < r.end <= length


@given(
    st.lists(
        st.tuples(st.integers(0, 3000), st.integers(0, 3000)) | st.integers(0, 3000),
        min_size=1,
        max_size=40,
    ),
    st.integers(min_value=0, max_value=2000),
)
def test_generated_range_sets(items: list[tuple[int, int] | int], length: int) -> None:
    parts = [f"{min(x)}-{max(x)}" if isinstance(x, tuple) else f"-{x}" for x in items]
    verdict = parse_range("bytes=" + ",".join(parts), length)
    if len(parts) > MAX_RANGES:
        assert isinstance(verdict, Ignore)
        return
    assert isinstance(verdict, Serve | Unsatisfiable)
    wanted: set[int] = set()
    for x in items:
        lo, hi = (min(x), max(x) + 1) if isinstance(x, tuple) else (length - x, length)
        wanted.update(range(max(lo, 0), min(hi, length)))
    if isinstance(verdict, Unsatisfiable):
        assert not wanted
        return
    served = [i for r in verdict.ranges for i in range(r.start, r.end)]
    assert served == sorted(wanted)
    for a, b in zip(verdict.ranges, verdict.ranges[1:], strict=False):
        assert a.end < b.start


def test_etag_lists() -> None:
    assert parse_etags("*") is None
    assert parse_etags('"a", W/"b", junk, "c') == ['"a"', 'W/"b"']


def test_preconditions() -> None:
    tag, mtime = '"abc"', 1_700_000_000.5
    assert evaluate("GET", {}, tag, mtime) is Outcome.PROCEED
    assert evaluate("GET", {"If-Match": '"x", "abc"'}, tag, mtime) is Outcome.PROCEED
    assert evaluate("GET", {"If-Match": "*"}, tag, mtime) is Outcome.PROCEED
    assert evaluate("GET", {"If-Match": 'W/"abc"'}, tag, mtime) is Outcome.FAILED
    assert evaluate("GET", {"If-Match": '"x"'}, tag, mtime) is Outcome.FAILED
    assert evaluate("GET", {"If-None-Match": 'W/"abc"'}, tag, mtime) is Outcome.NOT_MODIFIED
    assert evaluate("HEAD", {"If-None-Match": "*"}, tag, mtime) is Outcome.NOT_MODIFIED
    assert evaluate("POST", {"If-None-Match": '"abc"'}, tag, mtime) is Outcome.FAILED
    assert evaluate("GET", {"If-None-Match": '"x"'}, tag, mtime) is Outcome.PROCEED
    same, before = http_date(mtime), http_date(mtime - 10)
    assert evaluate("GET", {"If-Modified-Since": same}, tag, mtime) is Outcome.NOT_MODIFIED
    assert evaluate("GET", {"If-Modified-Since": before}, tag, mtime) is Outcome.PROCEED
    assert evaluate("GET", {"If-Modified-Since": "garbage"}, tag, mtime) is Outcome.PROCEED
    both = {"If-None-Match": '"x"', "If-Modified-Since": same}
    assert evaluate("GET", both, tag, mtime) is Outcome.PROCEED  # INM wins over IMS
    assert evaluate("GET", {"If-Unmodified-Since": before}, tag, mtime) is Outcome.FAILED
    assert evaluate("GET", {"If-Unmodified-Since": same}, tag, mtime) is Outcome.PROCEED


def test_if_range() -> None:
    tag, mtime = '"abc"', time.time()
    assert if_range_allows(None, tag, mtime)
    assert if_range_allows('"abc"', tag, mtime)
    assert not if_range_allows('"abd"', tag, mtime)
    assert not if_range_allows('W/"abc"', tag, mtime)
    assert if_range_allows(http_date(mtime), tag, mtime)
    assert not if_range_allows(http_date(mtime - 1), tag, mtime)
    assert not if_range_allows("not a date", tag, mtime)
