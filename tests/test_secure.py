"""Secure mode: generated credentials and ACL, and a robot that only its own processes steer.

The unit tests check what ``python -m ubf_async.secure init`` writes and what
:func:`ubf_async.net.secure.apply` refuses. The process tests launch the robot (``python -m
ubf_async.launch --secure DIR``) and attack it from separate processes that speak plain
zenoh + msgpack — without credentials, and with the read-only inspector's — while a
configured remote behaviour (the teleop example) and an inspector session keep working. The
same attacker run against the robot in open mode shows every attack landing there, so the
secure run's silence is the ACL's doing. A process the robot does not let in is told that the
connection was refused, not that nothing answered.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import stat
import subprocess
import sys
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio
import zenoh

from tests.conftest import as_dict, eventually, free_port, read_until
from ubf_async.assembly.robotfile import load_robot
from ubf_async.errors import ConfigurationError
from ubf_async.net.options import ConnectionOptions
from ubf_async.net.secure import access_control, apply, identities_for, init
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode

ROOT = Path(__file__).resolve().parent.parent
ROBOT_FILE = ROOT / "ubf_async" / "robots" / "mini-whegs.yaml"
def robot_file(tmp_path: Path, name: str) -> Path:
    """mini-whegs named ``name``: it has `remote:` slots for teleop (priority 10) and
    avoid_obstacles (3)."""
    text = ROBOT_FILE.read_text().replace("\nname: mini\n", f"\nname: {name}\n")
    assert "remote: teleop" in text
    path = tmp_path / "robot.yaml"
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------------------------
# What init writes, what apply refuses


def test_init_writes_private_credentials_and_a_default_deny_acl(tmp_path: Path) -> None:
    robot = load_robot(robot_file(tmp_path, "sec"))
    setup = init(tmp_path / "s", robot=robot, devices=["camera/front"])
    assert list(setup.identities) == ["robot", "inspector", "operator", "teleop",
                                      "avoid_obstacles", "device-camera-front"]
    for path in [tmp_path / "s", *(tmp_path / "s").rglob("*")]:
        mode = stat.S_IMODE(path.stat().st_mode)
        assert mode == (0o700 if path.is_dir() else 0o600), (path, oct(mode))
    creds = json.loads((tmp_path / "s" / "identities" / "teleop.json").read_text())
    assert creds["user"] == "teleop" and len(creds["password"]) >= 30
    lines = (tmp_path / "s" / "passwords.txt").read_text().splitlines()
    assert f"teleop:{creds['password']}" in lines and len(lines) == 6
    with pytest.raises(ConfigurationError, match="already holds"):
        init(tmp_path / "s", robot=robot)
    again = init(tmp_path / "s", robot=robot, force=True)
    assert "device-camera-front" not in again.identities
    assert json.loads((tmp_path / "s" / "identities" / "teleop.json").read_text()) != creds


def test_the_acl_gives_each_identity_only_its_own_keys(tmp_path: Path) -> None:
    robot = load_robot(robot_file(tmp_path, "sec"))
    acl = access_control("sec", identities_for(robot, devices=["motors/main"]))
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    granted: dict[str, set[tuple[str, str, str]]] = {}
    for policy in acl["policies"]:
        for subject in policy["subjects"]:
            for rule_id in policy["rules"]:
                rule = rules[rule_id]
                granted.setdefault(subject.removeprefix("user-"), set()).update(
                    (flow, message, key) for flow in rule["flows"]
                    for message in rule["messages"] for key in rule["key_exprs"])

    def ingress(who: str, message: str) -> set[str]:
        return {k for f, m, k in granted[who] if f == "ingress" and m == message}

    assert ingress("robot", "put") == {"ubf/sec/**"}
    assert ingress("teleop", "put") == {"ubf/sec/vote/seek_pink_ball/teleop",
                                        "ubf/sec/heartbeat/teleop"}
    assert ingress("teleop", "liveliness_token") == {"ubf/sec/alive/teleop"}
    assert ingress("inspector", "put") == set()
    assert ingress("inspector", "declare_subscriber") == {"ubf/sec/**"}
    assert ingress("inspector", "query") == set()
    assert ingress("operator", "query") == {"ubf/sec/tree"}
    assert ingress("device-motors-main", "put") == {
        "ubf/sec/sensor/motors/main", "ubf/sec/heartbeat/motors-main",
        "ubf/sec/status/motors-main", "ubf/sec/sim/pulses"}
    for who in granted:
        assert ("egress", "put", "ubf/sec/**") in granted[who]
        if who != "robot":
            assert not any(k.startswith(("ubf/sec/cmd", "ubf/sec/clock")) or k == "ubf/sec/**"
                           for k in ingress(who, "put")), who
            assert ingress(who, "declare_queryable") == set()


def test_identity_names_that_would_clash_are_refused(tmp_path: Path) -> None:
    path = robot_file(tmp_path, "sec")
    path.write_text(path.read_text().replace("remote: teleop", "remote: inspector"))
    with pytest.raises(ConfigurationError, match="built-in identity"):
        identities_for(load_robot(path))
    with pytest.raises(ConfigurationError, match="not a device"):
        identities_for(load_robot(robot_file(tmp_path, "sec")), devices=["lidar/top"])


def test_apply_refuses_what_would_silently_weaken_secure_mode(tmp_path: Path) -> None:
    init(tmp_path / "s", robot=load_robot(robot_file(tmp_path, "sec")))
    d = tmp_path / "s"
    conf = zenoh.Config()
    apply(conf, directory=d, identity="teleop", robot="sec")
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("transport/auth/usrpwd/user")) == "teleop"
    robot_conf = zenoh.Config()
    apply(robot_conf, directory=d, identity="robot", robot="sec", listen=["tcp/127.0.0.1:1"])
    assert json.loads(robot_conf.get_json("access_control/default_permission")) == "deny"
    refusals: list[tuple[dict[str, Any], str]] = [
        ({"identity": None, "robot": "sec"}, "needs --identity"),
        ({"identity": "nobody", "robot": "sec"}, "no such file"),
        ({"identity": "teleop", "robot": "other"}, "is for robot 'sec'"),
        ({"identity": "teleop", "robot": "sec", "listen": ["tcp/127.0.0.1:1"]},
         "may not --listen"),
    ]
    for kwargs, message in refusals:
        with pytest.raises(ConfigurationError, match=message):
            apply(zenoh.Config(), directory=d, **kwargs)
    os.chmod(d / "identities" / "teleop.json", 0o644)
    with pytest.raises(ConfigurationError, match="readable by others"):
        apply(zenoh.Config(), directory=d, identity="teleop", robot="sec")
    with pytest.raises(ConfigurationError, match="needs --secure"):
        ConnectionOptions(robot="sec", identity="teleop").zenoh_config()


def test_secure_cli_init_and_show(tmp_path: Path) -> None:
    path = robot_file(tmp_path, "sec")
    run = [sys.executable, "-m", "ubf_async.secure"]
    made = subprocess.run([*run, "init", str(tmp_path / "s"), "--robot-file", str(path)],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert made.returncode == 0, made.stderr
    assert "--identity teleop" in made.stdout
    shown = subprocess.run([*run, "show", str(tmp_path / "s")], capture_output=True,
                           text=True, cwd=ROOT, timeout=60)
    assert shown.stdout == made.stdout
    missing = subprocess.run([*run, "show", str(tmp_path / "nope")], capture_output=True,
                             text=True, cwd=ROOT, timeout=60)
    assert missing.returncode == 2 and "no such file" in missing.stderr


# ---------------------------------------------------------------------------------------------
# Separate processes: the robot, attackers, a configured remote behaviour, an inspector

ATTACKER = r'''
import json, sys, time, msgpack, zenoh
endpoint, robot, mode, user, password, seconds = sys.argv[1:7]
conf = zenoh.Config()
conf.insert_json5("mode", json.dumps(mode))
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
if user:
    conf.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
    conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
try:
    session = zenoh.open(conf)
except zenoh.ZError as exc:
    print("refused:", exc, flush=True)
    sys.exit(0)
p = f"ubf/{robot}"
now = [0]
def on_clock(sample):
    now[0] = max(now[0], msgpack.unpackb(sample.payload.to_bytes())["stamp_ns"])
session.declare_subscriber(f"{p}/clock", on_clock)
tokens = [session.liveliness().declare_token(f"{p}/alive/{n}") for n in ("teleop", "intruder")]
n = 0
def msg(schema, data, stamp):
    return msgpack.packb({"schema": schema, "v": 1, "stamp_ns": stamp, "seq": n, "data": data})
connected = bool(list(session.info.routers_zid()) or list(session.info.peers_zid()))
print("connected" if connected else "alone", flush=True)
end = time.monotonic() + float(seconds)
while time.monotonic() < end:
    n += 1
    stamp = now[0]
    vote = {"vote": 5.0, "speed": -100.0, "turn": 100.0, "priority": 1000000}
    session.put(f"{p}/cmd/drive", msg("drive", {"speed": -100.0, "turn": -100.0,
                                                "winners": ["attacker"]}, stamp))
    session.put(f"{p}/vote/seek_pink_ball/teleop", msg("vote", vote, stamp))
    session.put(f"{p}/vote/seek_pink_ball/intruder", msg("vote", vote, stamp))
    session.put(f"{p}/cmd/seek_color", msg("seek_color", {"lo": [1, 2, 3], "hi": [4, 5, 6]},
                                           stamp))
    session.put(f"{p}/sim/pulses", msg("sim.pulses", {"left_ms": 2.0, "right_ms": 2.0}, stamp))
    session.put(f"{p}/clock", msg("clock", {}, 2**62 + n))
    time.sleep(0.02)
print("sent", n, "clock seen", now[0] > 0, flush=True)
session.close()
'''

ATTACK_S = 4.0
FAR = 10**15  # no honest clock sample of these runs is anywhere near (a million seconds)


@dataclass
class Seen:
    """Everything the observer received under ``ubf/<robot>/``, decoded."""

    drives: list[tuple[float, float, tuple[str, ...]]] = field(default_factory=list)
    applied: list[tuple[float, float]] = field(default_factory=list)
    clock_max_ns: int = 0
    clock_samples: int = 0
    seek_colors: list[Any] = field(default_factory=list)
    pulses: int = 0
    remotes: set[str] = field(default_factory=set)

    def on_sample(self, key: str, payload: bytes, received_ns: int) -> None:
        m = decode(payload)
        tail = key.split("/", 2)[2]
        if tail == "cmd/drive":
            self.drives.append((m.data.speed, m.data.turn, tuple(m.data.winners)))
        elif tail == "sensor/motors/main":
            self.applied.append((m.data.speed, m.data.turn))
        elif tail == "clock":
            self.clock_samples += 1
            self.clock_max_ns = max(self.clock_max_ns, m.stamp_ns)
        elif tail == "cmd/seek_color":
            self.seek_colors.append(as_dict(m.data))
        elif tail == "sim/pulses":
            self.pulses += 1
        elif tail == "status/remotes":
            self.remotes.update(r["behavior"] for r in m.data["remotes"])

    def attacked(self) -> dict[str, bool]:
        """Which attacks show in what the observer saw."""
        return {
            "drive": (-100.0, -100.0, ("attacker",)) in self.drives,
            "motors": (-100.0, -100.0) in self.applied,
            "vote": any(d[:2] == (-100.0, 100.0) for d in self.drives) or (
                "intruder" in self.remotes),
            "clock": self.clock_max_ns >= FAR,
            "seek_color": {"lo": [1, 2, 3], "hi": [4, 5, 6]} in self.seek_colors,
            "pulses": self.pulses > 0,
        }


async def spawn(*argv: str) -> asyncio.subprocess.Process:
    return await asyncio.create_subprocess_exec(
        sys.executable, *argv, cwd=ROOT, stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})


async def output(proc: asyncio.subprocess.Process, timeout_s: float = 60.0) -> str:
    out, _ = await asyncio.wait_for(proc.communicate(), timeout_s)
    return out.decode()


async def stop(proc: asyncio.subprocess.Process) -> None:
    if proc.returncode is None:
        proc.terminate()
        try:
            await asyncio.wait_for(proc.wait(), 15)
        except TimeoutError:
            proc.kill()
            await proc.wait()


def attacker(endpoint: str, robot: str, mode: str, creds: dict[str, str] | None = None
             ) -> list[str]:
    user, password = (creds["user"], creds["password"]) if creds else ("", "")
    return ["-c", ATTACKER, endpoint, robot, mode, user, password, str(ATTACK_S)]


@pytest_asyncio.fixture
async def launched(request: pytest.FixtureRequest, tmp_path: Path, endpoint: str, robot: str
                   ) -> AsyncIterator[Callable[..., Any]]:
    """Start launch (``secure=True``: with ``--secure``) and an observer session; yields a
    function returning (setup dir, observer Seen)."""
    procs: list[asyncio.subprocess.Process] = []
    buses: list[Bus] = []

    async def start(*, secure: bool) -> tuple[Path, Seen]:
        path = robot_file(tmp_path, robot)
        setup = tmp_path / "secure"
        init(setup, robot=load_robot(path))
        extra = ["--secure", str(setup)] if secure else []
        proc = await spawn("-m", "ubf_async.launch", str(path), "--listen", endpoint,
                           "--quiet", *extra)
        procs.append(proc)
        await read_until(proc, "controller:", timeout_s=60)
        options = ConnectionOptions(robot=robot, connect=[endpoint], mode="client")
        if secure:
            options.secure, options.identity = setup, "inspector"
        bus = await Bus.open(options)
        buses.append(bus)
        seen = Seen()
        bus.subscribe(f"{bus.keys.prefix}/**", seen.on_sample, latest=False, max_queue=1 << 16)
        await eventually(lambda: len(seen.drives) > 20, timeout_s=30,
                         what="the observer to see drive commands")
        return setup, seen

    yield start
    for bus in buses:
        await bus.aclose()
    for proc in procs:
        await stop(proc)
        if proc.stdout is not None:
            await proc.stdout.read()  # drain


def creds_of(setup: Path, identity: str) -> dict[str, str]:
    data: dict[str, str] = json.loads((setup / "identities" / f"{identity}.json").read_text())
    return data


@pytest.mark.asyncio
async def test_open_mode_lets_every_attack_land(launched: Any, endpoint: str, robot: str
                                                ) -> None:
    """The control: without --secure, one plain zenoh process does it all."""
    _, seen = await launched(secure=False)
    proc = await spawn(*attacker(endpoint, robot, "client"))
    text = await output(proc)
    assert "connected" in text and "clock seen True" in text, text
    await eventually(lambda: all(seen.attacked().values()), timeout_s=10,
                     what=f"every attack to show (so far {seen.attacked()})")


@pytest.mark.asyncio
async def test_secure_mode_stops_outsiders_and_unauthorised_identities_and_says_refused(
    launched: Any, endpoint: str, robot: str, tmp_path: Path
) -> None:
    """One robot in secure mode: attacked from outside and by identities without the right
    (while a configured remote behaviour takes control), then asked for its state by
    processes it does not let in, which are told that it refused them."""
    setup, seen = await launched(secure=True)
    other = tmp_path / "other"  # a set-up for a robot of the same name: other passwords
    init(other, robot=load_robot(robot_file(tmp_path, robot)))

    async def state(*flags: str, at: str = endpoint) -> tuple[int | None, str]:
        proc = await spawn("-m", "ubf_async.inspector", "state", "--connect", at, "--robot",
                           robot, "--timeout", "3", *flags)
        text = await output(proc)
        return proc.returncode, text

    # Asked for its state, meanwhile, by those it does not let in (each waits its 3 s), and
    # where nothing listens.
    nobody = f"tcp/127.0.0.1:{free_port()}"
    refusals = asyncio.gather(
        state(), state("--mode", "peer"), state("--secure", str(other), "--identity", "inspector"),
        state(at=nobody))
    clock_before = seen.clock_max_ns
    attackers = [await spawn(*attacker(endpoint, robot, "client")),
                 await spawn(*attacker(endpoint, robot, "peer")),
                 await spawn(*attacker(endpoint, robot, "client", creds_of(setup, "inspector"))),
                 await spawn(*attacker(endpoint, robot, "client", creds_of(setup, "operator")))]
    teleop = await spawn(str(ROOT / "examples" / "teleop_override.py"), "--connect", endpoint,
                         "--robot", robot, "--secure", str(setup), "--speed", "-30",
                         "--turn", "50", "--quiet")
    try:
        # A configured remote behaviour with its own identity takes control meanwhile.
        await eventually(lambda: (-30.0, 50.0, ("teleop",)) in seen.drives, timeout_s=30,
                         what="the configured teleop to take control")
        texts = [await output(p) for p in attackers]
        client, peer, wrong, absent = await refusals
    finally:
        await stop(teleop)
        if not refusals.done():
            refusals.cancel()
            with contextlib.suppress(BaseException):
                await refusals
    no_creds_client, no_creds_peer, inspector, operator = texts
    assert no_creds_client.startswith("refused"), no_creds_client
    assert no_creds_peer.startswith("alone") and "sent" in no_creds_peer, no_creds_peer
    for text in (inspector, operator):  # authenticated, read the clock, sent for 4 s
        assert text.startswith("connected") and "clock seen True" in text, text
    assert seen.attacked() == dict.fromkeys(seen.attacked(), False), seen.attacked()
    # The robot's own processes kept working: simulator clock, controller, motors.
    assert clock_before < seen.clock_max_ns < FAR
    assert seen.applied and seen.drives[-1][2] != ("attacker",)
    assert "teleop" in seen.remotes

    # A refused connection is reported as refused, not as absence.
    refused = f"error: the robot at {endpoint} refused the connection: something listens " \
              f"there but did not let this process's zenoh session in, as a robot in secure " \
              f"mode does without valid credentials (docs/security.md); "
    # No credentials: as a client (the inspector's default), and as a peer, whose session
    # opens alone and never reaches the robot.
    for flags, (code, text) in ((), client), (("--mode", "peer"), peer):
        *before, last = text.strip().splitlines()
        assert code == 2 and last == refused + (
            "this process gave none: pass the robot's set-up with --secure DIR --identity "
            "NAME"), (flags, text)
        # A peer may have said so while it waited (its connect watch): refused, not absent.
        assert all("does not let this session in" in line for line in before), text
    # Credentials the robot's set-up does not have.
    code, text = wrong
    assert code == 2 and text.startswith(refused + f"this process gave identity 'inspector' "
                                         f"of {other}, which the robot's set-up does not "
                                         f"have"), text
    # Where nothing listens, absence is still reported as absence.
    code, text = absent
    assert code == 2 and f"no robot to connect to: nothing answered at {nobody}" in text, text
    # Its own: let in.
    code, text = await state("--secure", str(setup), "--identity", "inspector")
    assert code == 0 and "drive:" in text, text
