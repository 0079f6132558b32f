"""Revocation that bites while the robot runs (issue 50, item 5), on real processes over TLS:
a stolen laptop's files — the teleop's and the obstacle avoider's, each driving the robot —
are cut off once ``secure rotate`` and ``secure revoke`` have run on the set-up's host, within
the stated bound and without restarting the robot; the teleop's new files drive it again."""

from __future__ import annotations

import asyncio
import re
import time
from pathlib import Path

import pytest

from tests.conftest import eventually, free_port
from tests.remote_robot import Process
from tests.test_secure import ROOT, observe, robot_file, spawn, stop, unpack
from ubf_async.access.setup import init, revoke
from ubf_async.assembly.robotfile import load_robot
from ubf_async.net.options import ConnectionOptions
from ubf_async.net.secure import export, rotate
from ubf_async.services.setupwatch import POLL_S, SETTLE_S

ROBOT = "revbot"
BOUND_S = POLL_S + SETTLE_S + 1.0
"""docs/security.md's bound: a poll, the settling read, and the swap (≈ 0.1-0.3 s measured)."""


@pytest.mark.slow
@pytest.mark.asyncio
async def test_a_rotated_and_a_revoked_identity_are_cut_off_while_the_robot_runs(
        tmp_path: Path) -> None:
    path = robot_file(tmp_path, ROBOT)
    setup = tmp_path / "secure"
    init(setup, robot=load_robot(path), hosts=["127.0.0.1"])
    # The laptop's files, as exported to it before it was stolen.
    stolen = unpack(export(setup, ["teleop", "avoid_obstacles", "inspector"],
                           tmp_path / "laptop.tar.gz") and tmp_path / "laptop.tar.gz",
                    tmp_path / "laptop")
    endpoint = f"tls/127.0.0.1:{free_port()}"
    robot = Process("-m", "ubf_async.launch", str(path), "--listen", endpoint, "--secure",
                    str(setup), "--status-period-s", "0.25")
    procs: list[asyncio.subprocess.Process] = []
    bus = None
    try:
        robot.wait_for_line("controller:", timeout_s=60)

        def options(identity: str, at: Path) -> ConnectionOptions:
            return ConnectionOptions(robot=ROBOT, mode="client", connect=[endpoint], secure=at,
                                     identity=identity)

        bus, seen = await observe(options("inspector", setup))
        old_teleop = await spawn(str(ROOT / "examples" / "teleop_override.py"), "--connect",
                                 endpoint, "--robot", ROBOT, "--secure", str(stolen), "--speed",
                                 "-30", "--turn", "50", "--quiet")
        old_avoid = await spawn(str(ROOT / "examples" / "avoid_obstacles.py"), "--connect",
                                endpoint, "--robot", ROBOT, "--secure", str(stolen))
        procs += [old_teleop, old_avoid]
        await eventually(lambda: (-30.0, 50.0, ("teleop",)) in seen.drives, timeout_s=30,
                         what="the stolen teleop files to take control")
        await eventually(lambda: "avoid_obstacles" in seen.remotes, timeout_s=30,
                         what="the stolen obstacle avoider to join")

        # On the set-up's host: the teleop rotated, the obstacle avoider revoked.
        changed = time.monotonic()
        rotate(setup, "teleop")
        revoke(setup, "avoid_obstacles")
        line = await asyncio.to_thread(robot.wait_for_match,
                                       r"the secure set-up changed \(.*\): the robot's session "
                                       r"was re-opened in [\d.]+ s", timeout_s=30)
        took = time.monotonic() - changed
        assert "revoked avoid_obstacles" in line and "rotated teleop" in line, line
        assert took <= BOUND_S * 3, took  # (×3: a busy machine; the figure is in the docs)
        swapped = float(re.search(r"re-opened in ([\d.]+) s", line)[1])  # type: ignore[index]

        # The inspector, whose files are still good, is back by itself; from then on the
        # stolen teleop never wins again and the robot ticks on its own tree.
        seen.drives.clear()
        await eventually(lambda: len(seen.drives) > 50, timeout_s=30,
                         what="the inspector back, seeing drive commands")
        assert not [d for d in seen.drives if "teleop" in d[2]], seen.drives[-5:]
        remotes_before = set(seen.remotes)
        seen.remotes.clear()
        await eventually(lambda: len(seen.drives) > 150, timeout_s=30,
                         what="more drive commands")
        assert not [d for d in seen.drives if "teleop" in d[2]]
        assert "avoid_obstacles" not in seen.remotes and "teleop" not in seen.remotes, (
            remotes_before, seen.remotes)

        # The teleop's new files work: the operator's laptop gets its control back.
        new_teleop = await spawn(str(ROOT / "examples" / "teleop_override.py"), "--connect",
                                 endpoint, "--robot", ROBOT, "--secure", str(setup), "--speed",
                                 "-20", "--turn", "10", "--quiet")
        procs.append(new_teleop)
        await eventually(lambda: (-20.0, 10.0, ("teleop",)) in seen.drives, timeout_s=30,
                         what="the rotated teleop's new files to take control")
        assert robot.proc.poll() is None  # never restarted: the same process throughout
        assert swapped < 5.0, swapped
    finally:
        for proc in procs:
            await stop(proc)
        if bus is not None:
            await bus.aclose()
        robot.kill()
    print(f"cut off {took:.2f} s after the change (the swap itself {swapped:.2f} s)")
