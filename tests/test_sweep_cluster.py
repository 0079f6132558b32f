"""A sweep on a Ray cluster of two machines, as docs/experiments.md "On a Ray cluster" says it
(issue 54): the page's commands, quoted from it and run as written on two hosts
(tests/hosts.py: network namespaces linked as a LAN) with token authentication on; a sweep
whose runs Ray placed on both machines, by Ray's own record of its tasks, into the same
``runs.csv`` as one local worker's, byte for byte; the second machine killed mid-sweep, and
``--resume`` completing the same table; and the one line the sweep says for each reason it
cannot join a cluster.

Ray is started once, for the one test of the cluster. What the test changes in the page's
commands, and only that: ``HEAD_IP`` is the head host's address, each ``ray start`` gives its
node one CPU (the machine's two cores are the two hosts'), the sweep's SPEC is a small one (8
runs of 2 simulated s) and ``out/arbiters`` a folder of the test's; the head's Ray checks its
nodes' health every 0.5 s (by default it sees a node gone some 15 s after its processes were
killed, and a minute after its link went down). Skipped where network namespaces cannot be
made (not root), unless ``UBF_REQUIRE_NETNS`` is set (CI).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.conftest import REPOSITORY, repository_env
from tests.hosts import Host, hosts_or_skip
from ubf_async.errors import ClusterError, RunsLostError
from ubf_async.runs.sweep import cluster as joining
from ubf_async.runs.sweep import execution
from ubf_async.runs.sweep.execution import RunRecord
from ubf_async.runs.sweep.journal import JOURNAL, read_journal
from ubf_async.runs.sweep.spec import RunTask

PAGE = REPOSITORY / "docs" / "experiments.md"
SECTION = "## On a Ray cluster"
SHOWN_SPEC = "examples/sweeps/arbiters.yaml"
SHOWN_OUT = "out/arbiters"
SPEC = """\
robots: [mini-whegs]
overrides:
  tree.arbiter: [PriorityMerge, UtilityFusion]
scenarios: [ball-in-sight]
seeds: [1, 2, 3, 4]
duration_s: 2
figures: [ball_distance_m]
"""
RUNS = 8
WAIT_S = 120.0  # for a sweep or a node to start, on a loaded machine
HEALTH = {"RAY_health_check_period_ms": "500", "RAY_health_check_timeout_ms": "500",
          "RAY_health_check_failure_threshold": "2"}
"""The head's checks of its nodes, often: a killed machine is seen gone within seconds."""
WHERE_RUNS_RAN = """\
import json, sys, time
from ray.util.state import list_nodes, list_tasks
deadline = time.monotonic() + 30
while True:  # a worker reports its tasks' ends every second or so
    tasks = list_tasks(filters=[("name", "=", "PoolActor.run_batch")], limit=10000, detail=True)
    finished = sum(task.state == "FINISHED" for task in tasks)
    if finished >= int(sys.argv[1]) or time.monotonic() > deadline:
        break
    time.sleep(0.2)
ips = {node.node_id: node.node_ip for node in list_nodes(limit=100)}
print(json.dumps([[task.job_id, task.state, ips.get(task.node_id)] for task in tasks]))
"""
"""Ray's record of the pool's tasks (one per run), once ``argv[1]`` of them are finished: job,
state, and the address of the node that ran it (the state API, as ``ray list tasks`` reads
it)."""
GONE = """\
import sys, time
from ray.util.state import list_nodes
deadline = time.monotonic() + float(sys.argv[2])
while time.monotonic() < deadline:
    if any(node.node_ip == sys.argv[1] and node.state == "DEAD" for node in list_nodes()):
        sys.exit(0)
    time.sleep(0.2)
sys.exit(1)
"""
"""Wait until Ray marks the node at ``argv[1]`` dead (what ``ray status`` shows)."""


# -- the page's commands ----------------------------------------------------------------------

def shell_blocks() -> list[str]:
    """The shell blocks of the page's Ray section, in order."""
    text = PAGE.read_text("utf-8")
    section = text[text.index(SECTION):]
    section = section[:section.find("\n## ", len(SECTION))]
    return re.findall(r"^```sh\n(.*?)^```", section, re.M | re.S)


def block_with(line: str) -> str:
    [block] = [b for b in shell_blocks() if line in b.splitlines()]
    return block


HEAD_BLOCK = block_with("ray start --head")
NODE_BLOCK = block_with("ray start --address=HEAD_IP:6379")
[SWEEP_AUTO, SWEEP_CLIENT] = block_with(
    f"python -m ubf_async.sweep {SHOWN_SPEC} --out {SHOWN_OUT} --executor ray --address auto"
).splitlines()
CLIENT_SHOWN = "ray://HEAD_IP:10001"


def as_run(block: str, head: Host) -> str:
    """A block of the page as the test runs it: ``HEAD_IP`` the head's address, a CPU for
    each node."""
    lines = [line + " --num-cpus=1" if line.startswith("ray start") else line
             for line in block.replace("HEAD_IP", head.address).splitlines()]
    return "\n".join(lines)


def sweep_command(line: str, head: Host, spec: Path) -> str:
    return line.replace("HEAD_IP", head.address).replace(SHOWN_SPEC, str(spec))


def host_env(host: Host, **extra: str) -> dict[str, str]:
    """A shell's environment on ``host``: this checkout's code, this venv's commands first, no
    Ray settings of this machine's, no usage reports from Ray (they would try the network)."""
    base = {name: value for name, value in repository_env().items()
            if not name.startswith("RAY_")}
    env = host.env(base, RAY_USAGE_STATS_ENABLED="0", **extra)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    return env


def bash(host: Host, script: str, cwd: Path | None = None, *, timeout: float = WAIT_S,
         **extra: str) -> subprocess.CompletedProcess[str]:
    """``script`` run by bash on ``host`` (stopping at its first failing command)."""
    return host.run(["bash", "-euc", script], env=host_env(host, **extra), cwd=cwd,
                    timeout=timeout)


# -- the cluster --------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Cluster:
    head: Host
    node: Host
    spec: Path
    reference: Path
    """The local one-worker sweep's folder."""


@contextlib.contextmanager
def started_cluster(folder: Path) -> Iterator[Cluster]:
    """The head and the other machine started with the page's commands, and the local
    one-worker sweep run meanwhile; all stopped at the end (the hosts' every process)."""
    spec = folder / "spec.yaml"
    spec.write_text(SPEC)
    reference = folder / "reference"
    # The local one-worker sweep, on this machine while the cluster starts.
    local = subprocess.Popen(
        [sys.executable, "-m", "ubf_async.sweep", str(spec), "--out", str(reference),
         "--workers", "1"], cwd=REPOSITORY, env=repository_env(), stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT)
    try:
        with hosts_or_skip() as (head, node):
            said = bash(head, as_run(HEAD_BLOCK, head), **HEALTH)
            assert "Ray runtime started." in said.stdout + said.stderr, said
            # The token, copied to the other machine as the page says (scp -p there).
            (node.home / ".ray").mkdir(mode=0o700)
            shutil.copy2(head.home / ".ray" / "auth_token", node.home / ".ray" / "auth_token")
            said = bash(node, as_run(NODE_BLOCK, head))
            assert "Ray runtime started." in said.stdout + said.stderr, said
            out = local.communicate(timeout=WAIT_S)[0].decode()
            assert local.returncode == 0 and f"{RUNS} runs: {RUNS} ok" in out, out
            yield Cluster(head=head, node=node, spec=spec, reference=reference)
    finally:
        if local.poll() is None:
            local.kill()
            local.wait()


def where_runs_ran(cluster: Cluster) -> list[tuple[str, str, str]]:
    said = cluster.head.run(["python", "-c", WHERE_RUNS_RAN, str(RUNS)],
                            env=host_env(cluster.head, RAY_AUTH_MODE="token"))
    return [tuple(task) for task in json.loads(said.stdout)]


@pytest.mark.slow
def test_a_sweep_on_two_machines_as_the_page_says(tmp_path: Path) -> None:
    # One test for one Ray: pytest-xdist's worksteal could give tests of one module to two
    # workers, each then starting a cluster of its own. The steps go in this order: the
    # second machine is killed in the second, and is outside the cluster in the third.
    with started_cluster(tmp_path) as cluster:
        for step in (runs_on_both_machines, a_machine_lost_mid_sweep, says_why_it_cannot_join):
            folder = tmp_path / step.__name__
            folder.mkdir()
            step(cluster, folder)


def runs_on_both_machines(cluster: Cluster, here: Path) -> None:
    """The sweep with ``auto`` on the head: Ray runs it on both machines, into the local
    table."""
    head, node = cluster.head, cluster.node
    done = bash(head, sweep_command(SWEEP_AUTO, head, cluster.spec), here,
                RAY_AUTH_MODE="token")
    assert f"running {RUNS} runs on Ray (auto): a worker per CPU" in done.stdout, done
    assert f"{RUNS} runs: {RUNS} ok, 0 failed" in done.stdout, done
    out = here / SHOWN_OUT
    assert (out / "runs.csv").read_bytes() == (cluster.reference / "runs.csv").read_bytes()
    assert (out / "cells.csv").read_bytes() == (cluster.reference / "cells.csv").read_bytes()
    # Where Ray ran them: a task of the pool's per run, finished, on either machine.
    [ran] = _by_job(where_runs_ran(cluster)).values()  # the one sweep so far
    assert sorted(state for state, _ in ran) == ["FINISHED"] * RUNS, ran
    assert {ip for _, ip in ran} == {head.address, node.address}, ran


def _by_job(tasks: list[tuple[str, str, str]]) -> dict[str, list[tuple[str, str]]]:
    jobs: dict[str, list[tuple[str, str]]] = {}
    for job, state, ip in tasks:
        jobs.setdefault(job, []).append((state, ip))
    return jobs


def a_machine_lost_mid_sweep(cluster: Cluster, here: Path) -> None:
    """The second machine killed mid-sweep: its runs are told lost, and ``--resume``
    completes the same table on the head."""
    head, node = cluster.head, cluster.node
    sweep = head.popen(["bash", "-euc", sweep_command(SWEEP_AUTO, head, cluster.spec)],
                       env=host_env(head, RAY_AUTH_MODE="token"), cwd=here,
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # The second machine goes down while it runs one of the sweep's runs: Ray titles
        # an actor's process with the task it runs.
        deadline = time.monotonic() + WAIT_S
        while "PoolActor.run_batch" not in node.run(["ps", "-eo", "args"]).stdout:
            assert sweep.poll() is None, sweep.communicate()
            assert time.monotonic() < deadline, "no run started on the second machine"
            time.sleep(0.05)
        node.kill()
        out, err = sweep.communicate(timeout=WAIT_S)
    finally:
        if sweep.poll() is None:
            sweep.kill()
            sweep.communicate()
    assert sweep.returncode == 2, (out, err)
    lines = err.splitlines()
    assert re.fullmatch(r"python -m ubf_async\.sweep: error: \d+ runs? lost with the Ray worker "
                        rf"that held (it|them) \(a node that died\? .*\): \d+ of {RUNS} runs done, "
                        r"kept in out/arbiters/journal\.jsonl\. Resume with \(once `ray "
                        r"status` no longer counts the lost node as active\):", lines[-2]), err
    resume = lines[-1].strip()
    assert resume == f"python -m ubf_async.sweep {cluster.spec} --out {SHOWN_OUT} --resume " \
                     f"--executor ray --address auto", err
    kept = read_journal(here / SHOWN_OUT / JOURNAL)
    assert 0 < len(kept) < RUNS
    # Once Ray has seen the machine gone, the resume runs the lost runs on the head alone.
    head.run(["python", "-c", GONE, node.address, str(WAIT_S)],
             env=host_env(head, RAY_AUTH_MODE="token"))
    done = bash(head, resume, here, RAY_AUTH_MODE="token")
    assert f"resuming {SHOWN_OUT}: {len(kept)} runs done already" in done.stdout, done
    assert f"{RUNS} runs: {RUNS} ok, 0 failed" in done.stdout, done
    out_dir = here / SHOWN_OUT
    assert (out_dir / "runs.csv").read_bytes() == (cluster.reference / "runs.csv").read_bytes()
    assert (out_dir / "cells.csv").read_bytes() == (cluster.reference / "cells.csv").read_bytes()


CANNOT_JOIN = {
    # case: (address, environment, the line's cause and fix); {head}: the head's address
    "nothing answers": (
        "ray://{head}:10009", {"RAY_AUTH_MODE": "token"},
        "nothing answers there within 3 s: is the head started (ray start --head), and its "
        "Ray Client port reachable from this machine?"),
    "no token": (
        "ray://{head}:10001", {"RAY_AUTH_MODE": "token", "HOME": "{empty}"},
        "RAY_AUTH_MODE is 'token' but this machine has no token: copy the head's "
        "~/.ray/auth_token to this machine's ~/.ray/auth_token (or set RAY_AUTH_TOKEN)"),
    "another token": (
        "ray://{head}:10001", {"RAY_AUTH_MODE": "token",
                                "RAY_AUTH_TOKEN": "0123456789abcdef0123456789abcdef"},
        "the head refused this machine's token (not the head's): copy the head's "
        "~/.ray/auth_token to this machine's ~/.ray/auth_token (or set RAY_AUTH_TOKEN)"),
    "no token sent": (
        "ray://{head}:10001", {},
        "the head requires a token and this machine sends none (RAY_AUTH_MODE is not 'token' "
        "here): export RAY_AUTH_MODE=token, and copy the head's ~/.ray/auth_token to this "
        "machine's ~/.ray/auth_token (or set RAY_AUTH_TOKEN)"),
    "not a node": (
        "{head}:6379", {"RAY_AUTH_MODE": "token"},
        "this machine is not a node of that cluster (a HOST:PORT address is for its nodes): "
        "connect through the head's Ray Client port (--address ray://HOST:10001), or make "
        "this machine a node first (ray start --address={head}:6379)"),
    "no cluster here": (
        "auto", {"RAY_AUTH_MODE": "token", "TMPDIR": "{empty}"},
        "no Ray cluster runs on this machine: start its head here (ray start --head) or join "
        "one (ray start --address=HEAD_IP:6379), or give the head's address (--address "
        "ray://HEAD_IP:10001)"),
}


def says_why_it_cannot_join(cluster: Cluster, here: Path) -> None:
    """From a machine outside the cluster, each reason the sweep cannot join it: one line."""
    head, node = cluster.head, cluster.node
    node.restart()  # a machine that is not a node of the cluster (any more), with the token
    empty = here / "empty"
    empty.mkdir()
    started = {}
    for case, (address, extra, _) in CANNOT_JOIN.items():
        env = host_env(node, **{name: value.format(empty=empty)
                                for name, value in extra.items()})
        if "RAY_AUTH_MODE" not in extra:
            env.pop("RAY_AUTH_MODE", None)
        # The page's command from another machine, its address the case's.
        command = sweep_command(SWEEP_CLIENT.replace(CLIENT_SHOWN, address.format(
            head=head.address)), head, cluster.spec)
        (here / case).mkdir()
        started[case] = node.popen(["bash", "-euc", command], env=env, cwd=here / case,
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for case, proc in started.items():
        address, _, said = CANNOT_JOIN[case]
        err = proc.communicate(timeout=WAIT_S)[1]
        assert proc.returncode == 2, (case, err)
        assert err == (f"python -m ubf_async.sweep: error: cannot join Ray at "
                       f"{address.format(head=head.address)}: {said.format(head=head.address)} "
                       f"(docs/experiments.md, On a Ray cluster)\n"), case
        assert not (here / case / SHOWN_OUT / JOURNAL).exists()


# -- without a cluster --------------------------------------------------------------------------

class FakeRay:
    """What :func:`ubf_async.runs.sweep.cluster.join` uses of Ray's module, its ``init``
    raising each of ``failures`` in turn."""

    class exceptions:  # as Ray names its module of them
        AuthenticationError = type("AuthenticationError", (Exception,), {})

    def __init__(self, failures: list[Exception]) -> None:
        self.failures = failures
        self.inits = self.shutdowns = 0

    def init(self, **_: object) -> None:
        self.inits += 1
        if self.failures:
            raise self.failures.pop(0)

    def shutdown(self) -> None:
        self.shutdowns += 1


CLIENT_SERVER_DIED = ConnectionAbortedError(
    "Initialization failure from server:\nTraceback (most recent call last):\n  File "
    "\"proxier.py\", line 772, in Datapath\n    raise RuntimeError(\nRuntimeError: Starting "
    "Ray client server failed. See ray_client_server_23000.err for detailed logs.")
"""What Ray Client says when the head's server for it died at its start (Ray 2.60)."""


def test_ray_clients_head_is_asked_again_when_its_server_for_the_sweep_dies(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(joining, "_probe", lambda address: None)  # a head that answers
    ray = FakeRay([CLIENT_SERVER_DIED, CLIENT_SERVER_DIED])
    joining.join("ray://head:10001", ray, {})
    assert (ray.inits, ray.shutdowns) == (joining.CLIENT_ATTEMPTS, 2)
    ray = FakeRay([CLIENT_SERVER_DIED] * joining.CLIENT_ATTEMPTS)
    with pytest.raises(ClusterError) as told:
        joining.join("ray://head:10001", ray, {})
    assert str(told.value) == (
        "cannot join Ray at ray://head:10001: Initialization failure from server: "
        "RuntimeError: Starting Ray client server failed (docs/experiments.md, On a Ray "
        "cluster)")


def test_the_runs_of_a_lost_worker_are_told_once_the_others_are_done() -> None:
    records = [RunRecord(id="a", status="ok", key={}), RuntimeError("The actor died."),
               RunRecord(id="b", status="ok", key={})]

    class RaysPool:  # Ray's pool gives a lost run's error in place of its record
        def imap_unordered(self, func: object, iterable: object,
                           chunksize: int = 1) -> Iterator[object]:
            return iter(records)

    pool = execution._LossesTold(RaysPool())
    done = []
    tasks: list[RunTask] = []
    with pytest.raises(RunsLostError) as told:
        for record in pool.imap_unordered(execution.run_task, tasks):
            done.append(record.id)
    assert done == ["a", "b"]
    assert str(told.value) == ("1 run lost with the Ray worker that held it (a node that "
                               "died? RuntimeError: The actor died)")
