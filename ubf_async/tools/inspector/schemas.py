"""``schemas``: every schema's fields as the robot checks them (no robot needed) — the table
``docs/protocol.md`` holds, for whoever writes a component in another language."""

from __future__ import annotations

import argparse
import difflib
from typing import Any, TextIO

from ubf_async.tools.inspector import common
from ubf_async.wire import reference, topics

__all__ = ["add_schemas_parser", "cmd_schemas"]


def add_schemas_parser(sub: Any) -> None:
    """``schemas``: print the schemas' fields (offline: it takes no connection flags)."""
    schemas = sub.add_parser(
        "schemas", help="print every schema's fields, types and limits (no robot needed)",
        description="Print each schema's key, fields, whether a sender must give them (or "
                    "the value taken when absent), and their types and limits — drawn from "
                    "the types the robot decodes with, as docs/protocol.md shows them "
                    "(Markdown). No robot needed.")
    schemas.add_argument("names", nargs="*", metavar="SCHEMA",
                         help="only these schemas (e.g. heartbeat range); default: all")


def cmd_schemas(args: argparse.Namespace, out: TextIO) -> int:
    unknown = [name for name in args.names if name not in topics.BY_SCHEMA]
    if unknown:
        name = unknown[0]
        near = difflib.get_close_matches(name, list(topics.BY_SCHEMA), n=1, cutoff=0.6)
        common.say_error(f"no schema {name!r}" + (f" (did you mean {near[0]!r}?)" if near
                                                  else "") + "; the schemas: "
                         + ", ".join(topics.BY_SCHEMA))
        return 2
    chosen = [topics.BY_SCHEMA[name] for name in args.names] or list(topics.TOPICS)
    out.write(reference.markdown(chosen))
    return 0
