"""Two hosts for the tests that cross machines: network namespaces joined by a veth pair.

Each :class:`Host` is a machine as far as its programs can tell: a network of its own (``lo``
and ``eth0``, its address on 10.232.0.0/24, its own ports — a server there takes no port of
this machine's or of the other host's), processes of their own (a PID namespace: they see
only each other, so a ``ray stop`` there stops that host's Ray and no one else's, and
:meth:`Host.kill` ends all of them at once, as a machine that goes down), and its own ``HOME``
and ``TMPDIR``. The rest of the file system is this machine's: the checkout, the venv and a
test's ``tmp_path`` are the same paths on both.

The addresses are the project's own test hosts, inside this sandbox. Each host's default
route is the link to the other one, which forwards nothing: a program that asks the kernel
which of its addresses faces outwards (Ray does, for the address a node announces) gets the
host's own, and nothing goes beyond the pair.

Making them needs root and iproute2's ``ip``, util-linux's ``unshare`` and ``nsenter``.
:func:`two_hosts` raises :class:`HostsUnavailable` where they cannot be made;
:func:`hosts_or_skip` turns that into a skip with the reason — or a failure where
``UBF_REQUIRE_NETNS`` is set, as CI sets it, so that a machine that should run these tests
cannot pass by skipping them.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from ubf_async.cli import ending

__all__ = ["ADDRESSES", "PREFIX_LENGTH", "REQUIRE", "Host", "HostsUnavailable",
           "hosts_or_skip", "two_hosts"]

ADDRESSES = ("10.232.0.1", "10.232.0.2")
PREFIX_LENGTH = 24
REQUIRE = "UBF_REQUIRE_NETNS"
"""Set (CI sets it): hosts that cannot be made fail the test instead of skipping it."""
TOOLS = ("ip", "unshare", "nsenter")
SETUP_S = 10.0
"""For a step of making a host (a namespace, a link, its first process)."""

# PID 1 of a host's processes: it adopts whatever a program leaves running when it exits
# (Ray's daemons, started by a `ray start` that returns) and reaps it when it ends, as a
# machine's init does; a zombie would still look alive to Ray's checks of its processes.
REAPER = """\
import os, time
while True:
    try:
        os.wait()
    except ChildProcessError:
        time.sleep(0.5)
"""


class HostsUnavailable(Exception):
    """The hosts cannot be made on this machine; the message says why."""


@dataclass(slots=True)
class Host:
    """One host: its network namespace, its address, its folder (``home/``, ``tmp/``) and the
    process that holds its PID namespace (what :meth:`kill` ends, :meth:`restart` makes anew)."""

    name: str
    netns: str
    address: str
    root: Path
    holder: subprocess.Popen[bytes]
    """``unshare`` in the host's network namespace; its child is the host's PID 1."""
    init_pid: int
    """The host's PID 1, as this machine numbers it."""

    @property
    def home(self) -> Path:
        return self.root / "home"

    @property
    def tmp(self) -> Path:
        return self.root / "tmp"

    def env(self, base: Mapping[str, str] | None = None, **extra: str) -> dict[str, str]:
        """``base`` (default: this process's environment) as this host's: its ``HOME`` and
        ``TMPDIR``, then ``extra``."""
        env = dict(os.environ if base is None else base)
        env.update(HOME=str(self.home), TMPDIR=str(self.tmp))
        env.update(extra)
        return env

    def argv(self, command: Sequence[str], cwd: str | Path | None = None) -> list[str]:
        """``command`` as run on this host, in ``cwd`` (default: this process's)."""
        return ["nsenter", f"--target={self.init_pid}", "--net", "--pid", "--mount",
                f"--wd={cwd or os.getcwd()}", "--", *command]

    def run(self, command: Sequence[str], *, env: Mapping[str, str] | None = None,
            cwd: str | Path | None = None, timeout: float = 120.0,
            check: bool = True) -> subprocess.CompletedProcess[str]:
        """Run ``command`` on this host to its end (in this host's environment, :meth:`env`,
        when ``env`` is not given): its output and error as text."""
        done = subprocess.run(self.argv(command, cwd), env=self.env() if env is None else env,
                              capture_output=True, text=True, timeout=timeout, check=False)
        if check and done.returncode:
            raise AssertionError(f"on host {self.name}: {' '.join(command)} exited "
                                 f"{done.returncode}:\n{done.stdout}\n{done.stderr}")
        return done

    def popen(self, command: Sequence[str], *, env: Mapping[str, str] | None = None,
              cwd: str | Path | None = None, **kwargs: Any) -> subprocess.Popen[bytes]:
        """Start ``command`` on this host (``kwargs``: :class:`subprocess.Popen`'s)."""
        return subprocess.Popen(self.argv(command, cwd),
                                env=self.env() if env is None else env, **kwargs)

    def kill(self) -> None:
        """End every process of this host at once (SIGKILL to its PID 1: the kernel ends the
        rest), as a machine that goes down. Its network, its address and its files stay."""
        namespace = _pid_namespace(self.init_pid)
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.init_pid, signal.SIGKILL)
        _ended(self.holder, namespace)

    def restart(self) -> None:
        """Kill this host (:meth:`kill`) and start it again with no process running: a machine
        rebooted, its files as they were."""
        self.kill()
        self.holder, self.init_pid = _boot(self.netns)

    @property
    def alive(self) -> bool:
        return self.holder.poll() is None


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=SETUP_S,
                          check=False)
    if done.returncode:
        raise HostsUnavailable(f"ip {' '.join(args)}: {done.stderr.strip() or done.returncode}")


def _boot(netns: str) -> tuple[subprocess.Popen[bytes], int]:
    """A PID namespace in ``netns`` whose PID 1 reaps (:data:`REAPER`): ``unshare``, and that
    PID 1 as this machine numbers it."""
    holder = subprocess.Popen(
        ["ip", "netns", "exec", netns, "unshare", "--pid", "--fork", "--mount-proc",
         "--kill-child", sys.executable, "-c", REAPER],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        preexec_fn=ending.die_with_parent)  # a test process killed outright ends its hosts too
    deadline = time.monotonic() + SETUP_S
    children = Path(f"/proc/{holder.pid}/task/{holder.pid}/children")
    while time.monotonic() < deadline and holder.poll() is None:
        with contextlib.suppress(OSError, ValueError, IndexError):  # not there yet
            pid = int(children.read_text().split()[0])
            # Ready once it runs the reaper: unshare mounts the host's /proc before that.
            if Path(f"/proc/{pid}/cmdline").read_bytes().endswith(REAPER.encode() + b"\0"):
                return holder, pid
        time.sleep(0.02)
    holder.kill()
    said = holder.communicate(timeout=SETUP_S)[1].decode(errors="replace").strip()
    raise HostsUnavailable(f"unshare --pid --fork: {said or 'no PID namespace'}")


def _pid_namespace(pid: int) -> str | None:
    """Which PID namespace ``pid`` is in (``pid:[INODE]``), ``None`` if it is gone."""
    try:
        return os.readlink(f"/proc/{pid}/ns/pid")
    except OSError:
        return None


def _ended(holder: subprocess.Popen[bytes], namespace: str | None) -> None:
    """``unshare`` ended, and with it (``--kill-child``) the host's PID 1 and every process:
    returns once no process of the host's PID ``namespace`` is left (the kernel ends them after
    their PID 1, not at once)."""
    if holder.poll() is None:
        holder.kill()
    with contextlib.suppress(subprocess.TimeoutExpired):
        holder.wait(SETUP_S)
    deadline = time.monotonic() + SETUP_S
    while namespace is not None and time.monotonic() < deadline and any(
            _pid_namespace(int(entry.name)) == namespace
            for entry in Path("/proc").iterdir() if entry.name.isdigit()):
        time.sleep(0.02)  # polling /proc: the kernel tells no one
    if holder.stderr is not None:
        holder.stderr.close()


@contextlib.contextmanager
def two_hosts() -> Iterator[tuple[Host, Host]]:
    """Hosts ``a`` (10.232.0.1) and ``b`` (10.232.0.2), linked, each with its processes and
    its folder; all torn down at the end, or at once when a step fails. Raises
    :class:`HostsUnavailable` (why) where they cannot be made."""
    if os.geteuid() != 0:
        raise HostsUnavailable("network namespaces need root (ip netns add)")
    missing = [tool for tool in TOOLS if shutil.which(tool) is None]
    if missing:
        raise HostsUnavailable(f"not installed: {', '.join(missing)} (iproute2, util-linux)")
    # Names of this process: a test run elsewhere on the machine makes its own. A short
    # folder: Ray's sockets live under a host's TMPDIR, and a socket's path has 107 bytes.
    tag = f"ubf{os.getpid()}"
    with contextlib.ExitStack() as undo:
        folder = Path(tempfile.mkdtemp(prefix="ubfh"))
        undo.callback(shutil.rmtree, folder, ignore_errors=True)
        names = [f"{tag}{x}" for x in "ab"]
        for netns in names:
            _ip("netns", "add", netns)
            undo.callback(subprocess.run, ["ip", "netns", "del", netns], capture_output=True,
                          check=False)
        # Made here, each end then moved into its host, where it is eth0.
        _ip("link", "add", names[0], "type", "veth", "peer", "name", names[1])
        undo.callback(subprocess.run, ["ip", "link", "del", names[0]], capture_output=True,
                      check=False)  # still here if a move failed; gone with its netns if not
        hosts = []
        for index, (netns, address) in enumerate(zip(names, ADDRESSES, strict=True)):
            peer = ADDRESSES[1 - index]
            _ip("link", "set", netns, "netns", netns)
            _ip("-n", netns, "link", "set", netns, "name", "eth0")
            _ip("-n", netns, "addr", "add", f"{address}/{PREFIX_LENGTH}", "dev", "eth0")
            _ip("-n", netns, "link", "set", "lo", "up")
            _ip("-n", netns, "link", "set", "eth0", "up")
            _ip("-n", netns, "route", "add", "default", "via", peer)
            root = folder / "ab"[index]
            for sub in ("home", "tmp"):
                (root / sub).mkdir(parents=True)
            holder, init_pid = _boot(netns)
            host = Host(name="ab"[index], netns=netns, address=address, root=root,
                        holder=holder, init_pid=init_pid)
            undo.callback(host.kill)
            hosts.append(host)
        a, b = hosts
        yield a, b


@contextlib.contextmanager
def hosts_or_skip() -> Iterator[tuple[Host, Host]]:
    """:func:`two_hosts` for a test: skipped with the reason where they cannot be made,
    failed instead where ``UBF_REQUIRE_NETNS`` is set."""
    with contextlib.ExitStack() as stack:
        try:
            hosts = stack.enter_context(two_hosts())
        except HostsUnavailable as exc:
            reason = f"no network namespaces here: {exc}"
            if os.environ.get(REQUIRE):
                pytest.fail(f"{reason} ({REQUIRE} is set)")
            pytest.skip(reason)
        yield hosts
