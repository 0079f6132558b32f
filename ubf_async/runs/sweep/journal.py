"""A sweep's journal: ``DIR/journal.jsonl``, one JSON line per finished run, appended and
flushed as each run finishes, so a sweep killed at any moment loses only the runs in flight.

The first line says what the file is; each other line is a
:class:`~ubf_async.runs.sweep.execution.RunRecord`. A run found more than once counts as its
last line. A kill while a line is being written leaves it without its newline: reading ignores
it, and appending starts by cutting it off.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import BinaryIO

import msgspec

from ubf_async.errors import JournalError
from ubf_async.runs.sweep.execution import RunRecord

__all__ = ["HEADER", "JOURNAL", "Journal", "read_journal"]

JOURNAL = "journal.jsonl"
HEADER = {"journal": "ubf_async.sweep", "format": 1}


def _complete(data: bytes) -> bytes:
    """``data`` up to the end of its last complete line."""
    return data[:data.rfind(b"\n") + 1]


def read_journal(path: Path) -> dict[str, RunRecord]:
    """Every run of the journal at ``path``, by id (none if there is no such file). Raises
    :class:`JournalError` for a file that is not a sweep's journal or a line that is not a
    record (but a last line without its newline is ignored: cut short by a kill)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return {}
    lines = _complete(data).splitlines()
    if not lines:
        return {}
    try:
        header = json.loads(lines[0])
    except ValueError:
        header = None
    if header != HEADER:
        raise JournalError(f"{path}:1: not a sweep's journal (its first line is not "
                           f"{json.dumps(HEADER)})")
    records: dict[str, RunRecord] = {}
    decoder = msgspec.json.Decoder(RunRecord)
    for number, line in enumerate(lines[1:], start=2):
        try:
            record = decoder.decode(line)
        except msgspec.DecodeError as exc:
            raise JournalError(f"{path}:{number}: not a run's record: {exc}") from None
        records[record.id] = record
    return records


class Journal:
    """The journal at ``path`` opened for appending (created with its first line if new)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        file: BinaryIO = path.open("a+b")
        file.seek(0)
        data = file.read()
        if _complete(data) != data:  # a line cut short: its run is run again
            file.truncate(len(_complete(data)))
        if not _complete(data):
            file.write(json.dumps(HEADER).encode() + b"\n")
            file.flush()
        self._file = file
        self._encoder = msgspec.json.Encoder()

    def append(self, record: RunRecord) -> None:
        """Add ``record`` and flush it to the system: once this returns, a kill of this process
        does not lose it."""
        self._file.write(self._encoder.encode(record) + b"\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
