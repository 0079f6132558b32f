"""Issue 55, item 2: docs/protocol.md's field reference is generated from the types the robot
decodes with, so the page cannot drift from the wire; ``inspector schemas`` prints it."""

from __future__ import annotations

import argparse
import io
from pathlib import Path
from typing import Annotated

import msgpack
import msgspec.inspect as mi
import pytest
from msgspec import Meta

from ubf_async.tools.inspector import parser, program
from ubf_async.wire import reference, topics
from ubf_async.wire.protocol import ProtocolError, decode
from ubf_async.wire.topics import Data

ROOT = Path(__file__).resolve().parent.parent


def test_the_page_holds_the_reference_the_code_generates() -> None:
    page = (ROOT / "docs" / "protocol.md").read_text("utf-8")
    assert page.count(reference.BEGIN) == 1 and page.count(reference.END) == 1
    held = page.split(reference.BEGIN, 1)[1].split(reference.END, 1)[0]
    assert held == "\n\n" + reference.markdown() + "\n", (
        "docs/protocol.md's generated schemas differ from the code's: paste the output of "
        "`python -m ubf_async.inspector schemas` between its markers")


def test_every_field_of_every_schema_is_listed_and_required_as_the_decoder_requires() -> None:
    for topic in topics.TOPICS:
        rows = reference.field_rows(topic)
        assert [name.strip("`") for name, _, _ in rows] == list(topic.fields), topic.schema
        if not rows:
            continue
        required = {name.strip("`") for name, given, _ in rows if given == "required"}
        info = mi.type_info(topic.type)
        assert isinstance(info, mi.StructType)
        assert required == {f.encode_name for f in info.fields if f.required}
        if required:  # the empty map misses each of them: refused, as the page says
            empty = msgpack.packb({"schema": topic.schema, "v": 1, "stamp_ns": 1, "seq": 1,
                                   "data": {}})
            with pytest.raises(ProtocolError):
                decode(empty, topic=topic)


class Planted(Data, frozen=True, kw_only=True):
    count: Annotated[int, Meta(ge=1, le=8)]
    name: Annotated[str, Meta(max_length=12)] | None = None
    pair: tuple[Annotated[float, Meta(ge=-1.0, le=1.0)], bool] = (0.0, False)


@pytest.mark.parametrize(("field", "text"), [
    ("count", "int 1…8"),
    ("name", "str ≤ 12 or nil"),
    ("pair", "array [number −1…1, bool]"),
])
def test_a_type_is_described_by_its_limits(field: str, text: str) -> None:
    info = mi.type_info(Planted)
    assert isinstance(info, mi.StructType)
    (found,) = [f for f in info.fields if f.name == field]
    assert reference.type_text(found.type) == text


@pytest.mark.asyncio
async def test_the_inspector_prints_the_reference_without_a_robot() -> None:
    def run_args(*argv: str) -> argparse.Namespace:
        return parser.build_parser().parse_args(["schemas", *argv])

    out = io.StringIO()
    assert await program.run(run_args(), out) == 0  # no --connect, no robot: none is needed
    assert out.getvalue() == reference.markdown()
    out = io.StringIO()
    assert await program.run(run_args("heartbeat"), out) == 0
    assert out.getvalue().startswith("**`heartbeat`** on `heartbeat/<component>`")
    assert "| `leaving` | *opt*, default `false` | bool |" in out.getvalue()


def test_an_unknown_schema_is_named_with_the_nearest(capsys: pytest.CaptureFixture[str]
                                                     ) -> None:
    assert program.main(["schemas", "heartbat"]) == 2
    assert "no schema 'heartbat' (did you mean 'heartbeat'?)" in capsys.readouterr().err
