"""The two hosts of tests/hosts.py: linked to each other and to nothing else, each with its own
processes, gone without a trace at the end; skipped with the reason where they cannot be made,
failed instead where CI requires them."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from tests import hosts
from tests.hosts import hosts_or_skip

SERVE = """\
import socket, sys
with socket.create_server((sys.argv[1], 7447)) as server:
    print("listening", flush=True)
    connection, (peer, _) = server.accept()
    with connection:
        connection.sendall(peer.encode())
"""
ASK = """\
import socket, sys
with socket.create_connection((sys.argv[1], 7447), timeout=5) as connection:
    print(connection.recv(100).decode())
"""


def namespaces() -> str:
    return subprocess.run(["ip", "netns", "list"], capture_output=True, text=True,
                          check=False).stdout


def test_two_hosts_reach_each_other_see_their_own_processes_and_leave_nothing() -> None:
    with hosts_or_skip() as (a, b):
        assert a.netns in namespaces() and b.netns in namespaces()
        server = a.popen([sys.executable, "-c", SERVE, a.address], stdout=subprocess.PIPE,
                         text=True)
        try:
            assert server.stdout is not None and server.stdout.readline() == "listening\n"
            asked = b.run([sys.executable, "-c", ASK, a.address], timeout=10)
            assert asked.stdout == f"{b.address}\n"  # from b's own address, over the link
            assert server.wait(10) == 0
        finally:
            if server.poll() is None:
                server.kill()
                server.wait()
            assert server.stdout is not None
            server.stdout.close()
        # Each host sees its own processes: its PID 1 and the ps asking.
        seen = b.run(["ps", "-eo", "pid=,comm="]).stdout.split()
        assert seen[:2] == ["1", "python3"] or seen[:2] == ["1", "python"], seen
        assert len(seen) == 4, seen
        sleeper = a.popen(["sleep", "600"])
        deadline = time.monotonic() + 10
        while "sleep" not in a.run(["ps", "-eo", "comm="]).stdout.split():
            assert time.monotonic() < deadline, "sleep never started on host a"
            time.sleep(0.02)
        a.kill()  # the machine goes down: everything on it ends
        assert sleeper.wait(10) != 0 and not a.alive
        a.restart()
        assert a.alive and a.run(["true"]).returncode == 0
    assert a.netns not in namespaces() and b.netns not in namespaces()
    assert not a.root.exists()


def test_hosts_that_cannot_be_made_skip_with_the_reason(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(hosts.os, "geteuid", lambda: 1000)
    monkeypatch.delenv(hosts.REQUIRE, raising=False)
    with pytest.raises(pytest.skip.Exception, match=r"no network namespaces here: network "
                                                    r"namespaces need root"), hosts_or_skip():
        pass
    monkeypatch.setenv(hosts.REQUIRE, "1")
    with pytest.raises(pytest.fail.Exception, match=r"need root \(ip netns add\) "
                                                    r"\(UBF_REQUIRE_NETNS is set\)"), \
            hosts_or_skip():
        pass
