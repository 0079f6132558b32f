"""A busy machine on demand: one busy loop per chosen core, at normal priority.

``python -m bench.cpu_hog [--cpus 0,1] -- COMMAND ...`` runs ``COMMAND`` while a busy loop
spins on each chosen core (default: every core this process may use), stops them when it ends
and exits with its status — e.g. the whole suite on a loaded machine::

    python -m bench.cpu_hog -- python -m pytest

From Python, :func:`hogs` is a context manager that does the same around a block (the
lockstep tests run a launch pinned beside one). Each hog is a child process pinned to its core
(``os.sched_setaffinity``, what ``taskset -c`` does); they are killed when the block or the
command ends, however it ends.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import signal
import subprocess
import sys
from collections.abc import Iterable, Iterator

from ubf_async.cli import ending

BUSY_LOOP = "while True: pass"


def available_cpus() -> list[int]:
    """The cores this process may run on."""
    return sorted(os.sched_getaffinity(0))


def pin_to(cpus: Iterable[int]) -> None:
    """Pin the calling process to ``cpus`` (a ``preexec_fn`` for a child to run pinned)."""
    os.sched_setaffinity(0, set(cpus))


def hog_preexec(cpu: int) -> None:
    """A busy loop's set-up: pinned to ``cpu``, and killed by the kernel when its parent dies
    (however it dies: a hog left spinning would load the machine for hours unnoticed)."""
    pin_to([cpu])
    ending.die_with_parent()


@contextlib.contextmanager
def hogs(cpus: Iterable[int] | None = None) -> Iterator[list[subprocess.Popen[bytes]]]:
    """One busy loop per core of ``cpus`` (default: every available core) for the block."""
    chosen = list(cpus) if cpus is not None else available_cpus()
    procs: list[subprocess.Popen[bytes]] = []
    try:
        for cpu in chosen:
            procs.append(subprocess.Popen([sys.executable, "-c", BUSY_LOOP],
                                          preexec_fn=functools.partial(hog_preexec, cpu)))
        yield procs
    finally:
        for proc in procs:
            proc.kill()
        for proc in procs:
            proc.wait()


def parse_cpus(text: str) -> list[int]:
    try:
        cpus = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected core numbers like 0,1, got {text!r}") from None
    unknown = sorted(set(cpus) - set(available_cpus()))
    if not cpus or unknown:
        raise argparse.ArgumentTypeError(
            f"cores {unknown or text!r} are not available; this process may use "
            f"{available_cpus()}")
    return cpus


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.cpu_hog",
        description="Run COMMAND beside one busy loop per core (a loaded machine).")
    parser.add_argument("--cpus", type=parse_cpus, default=None, metavar="0,1",
                        help="the cores to load (default: every core available)")
    parser.add_argument("command", nargs=argparse.REMAINDER,
                        help="the command to run, after --")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command to run after --")
    # SIGTERM ends the command's wait like Ctrl-C, so the hogs are stopped on the way out.
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    with hogs(args.cpus) as procs:
        print(f"bench.cpu_hog: {len(procs)} busy loop(s) on cores "
              f"{args.cpus or available_cpus()}", file=sys.stderr, flush=True)
        try:
            return subprocess.call(command)
        except KeyboardInterrupt:
            return 130


if __name__ == "__main__":
    raise SystemExit(main())
