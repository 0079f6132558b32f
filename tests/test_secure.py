"""Secure mode: a certificate authority, identities in certificates, mutual TLS, and a robot that
only its own processes steer.

The unit tests check what ``python -m ubf_async.secure init`` writes (keys 0600, the CA's key
apart), what ``export``/``rotate``/``revoke`` change, and what :func:`ubf_async.net.secure.apply`
refuses. The process tests share one robot in secure mode (``launch --secure DIR --listen
tls/…``, one set of certificates for the module): each refused connection is told why in one
line (no certificate, another CA's, expired, a name the robot's certificate does not carry,
plain ``tcp/`` against TLS, a rotated or revoked identity's old files); each identity is told,
before it acts, what its rights do not allow; separate processes speaking plain zenoh +
msgpack with valid certificates of the wrong role attack it while the configured teleop drives
and the inspector reads; and bytes captured by a proxy between a client and the robot hold
none of a sample's payload. The same attacker run against the robot in open mode shows every
attack landing there, so the secure run's silence is the ACL's doing.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import json
import os
import re
import shutil
import stat
import subprocess
import sys
import tarfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import zenoh

from tests.conftest import as_dict, eventually, free_port, read_until, repository_env
from ubf_async.access.policy import access_control
from ubf_async.access.setup import identities_for, init, revoke, rights
from ubf_async.assembly.robotfile import load_robot
from ubf_async.errors import ConfigurationError, NotAllowedError, RefusedError
from ubf_async.net import pki, tlsprobe
from ubf_async.net.options import ConnectionOptions, listening
from ubf_async.net.secure import apply, export, rotate, settings
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
# What init writes, what export, rotate and revoke change, what apply refuses


def test_init_writes_a_ca_and_private_certificates_and_a_default_deny_acl(tmp_path: Path
                                                                         ) -> None:
    robot = load_robot(robot_file(tmp_path, "sec"))
    d = tmp_path / "s"
    setup = init(d, robot=robot, devices=["camera/front"], hosts=["robot.local", "10.0.0.7"])
    assert list(setup.identities) == ["robot", "inspector", "operator", "teleop",
                                      "avoid_obstacles", "device-camera-front"]
    for path in [d, *d.rglob("*")]:
        mode = stat.S_IMODE(path.stat().st_mode)
        assert mode == (0o700 if path.is_dir() else 0o600), (path, oct(mode))
    ca = pki.read(d / "ca.pem", what="CA")
    ca_key = (d / "private" / "ca.key").read_bytes()
    assert not [f for f in d.rglob("*") if f.is_file() and f.read_bytes() == ca_key
                and f.parent.name != "private"]
    for name in setup.identities:
        cert = pki.read(d / "identities" / f"{name}.pem", what=name)
        assert pki.common_name(cert) == name and pki.signed_by(cert, ca)
        assert pki.own_certificate_problem(
            cert_path=d / "identities" / f"{name}.pem", key_path=d / "identities" / f"{name}.key",
            ca_path=d / "ca.pem", identity=name) is None
        assert pki.hosts_of(cert) == (["robot.local", "10.0.0.7"] if name == "robot" else [])
    creds = json.loads((d / "identities" / "teleop.json").read_text())
    assert creds["user"] == "teleop" and len(creds["password"]) >= 30
    lines = (d / "passwords.txt").read_text().splitlines()
    assert f"teleop:{creds['password']}" in lines and len(lines) == 6
    subjects = json.loads((d / "acl.json").read_text())["access_control"]["subjects"]
    assert {"id": "user-teleop", "cert_common_names": ["teleop"],
            "usernames": ["teleop"]} in subjects  # both factors must match
    with pytest.raises(ConfigurationError, match="already holds"):
        init(d, robot=robot)
    again = init(d, robot=robot, force=True)
    assert "device-camera-front" not in again.identities
    assert not (d / "identities" / "device-camera-front.pem").exists()
    assert not pki.signed_by(pki.read(d / "identities" / "teleop.pem", what="t"), ca)
    with pytest.raises(ConfigurationError, match="not a host name"):
        init(tmp_path / "bad", robot=robot, hosts=["no such host"])


def test_export_packs_one_hosts_files_rotate_and_revoke_touch_one_identity(tmp_path: Path
                                                                          ) -> None:
    d = tmp_path / "s"
    init(d, robot=load_robot(robot_file(tmp_path, "sec")))
    packed = export(d, ["teleop", "inspector"], tmp_path / "laptop.tar.gz")
    with tarfile.open(tmp_path / "laptop.tar.gz") as tar:
        names = set(tar.getnames())
        modes = {m.name: m.mode for m in tar.getmembers()}
    assert names == {"secure.json", "ca.pem", "identities", *(
        f"identities/{n}.{x}" for n in ("teleop", "inspector") for x in ("json", "pem", "key"))}
    assert set(packed) | {"identities"} == names
    assert all(mode == (0o700 if name == "identities" else 0o600) for name, mode in modes.items())
    with tarfile.open(tmp_path / "laptop.tar.gz") as tar:  # the laptop unpacks it and runs
        tar.extractall(tmp_path / "laptop", filter="data")
    apply(zenoh.Config(), directory=tmp_path / "laptop", identity="teleop", robot="sec",
          connect=["tls/127.0.0.1:1"])
    # An identity of the set-up whose files this host was not given: which it has, and how to
    # bring the other.
    with pytest.raises(ConfigurationError) as missing:
        apply(zenoh.Config(), directory=tmp_path / "laptop", identity="operator", robot="sec",
              connect=["tls/127.0.0.1:1"])
    assert str(missing.value) == (
        f"--identity operator: {tmp_path / 'laptop' / 'identities' / 'operator.json'}: no such "
        f"file: this host has the files of inspector, teleop only; on the set-up's host, "
        f"`python -m ubf_async.secure export DIR operator` packs operator's for this one "
        f"(docs/security.md)")
    with tarfile.open(export(d, ["robot"], tmp_path / "r.tar.gz") and tmp_path / "r.tar.gz") as t:
        assert {"passwords.txt", "acl.json", "identities/robot.key"} <= set(t.getnames())
        assert not any("private" in n or "ca.key" in n for n in t.getnames())

    def files(name: str) -> dict[str, bytes]:
        return {x: (d / "identities" / f"{name}.{x}").read_bytes() for x in ("json", "pem", "key")}

    teleop, inspector = files("teleop"), files("inspector")
    rotate(d, "teleop")
    assert all(files("teleop")[x] != teleop[x] for x in teleop) and files("inspector") == inspector
    rotate(d, "robot", hosts=["robot.lan"])
    assert pki.hosts_of(pki.read(d / "identities" / "robot.pem", what="r")) == ["robot.lan"]
    with pytest.raises(ConfigurationError, match="does not listen"):
        rotate(d, "teleop", hosts=["x"])
    revoke(d, "avoid_obstacles")
    acl = json.loads((d / "acl.json").read_text())["access_control"]
    assert "user-avoid_obstacles" not in {s["id"] for s in acl["subjects"]}
    assert not any(line.startswith("avoid_obstacles:")
                   for line in (d / "passwords.txt").read_text().splitlines())
    assert not list((d / "identities").glob("avoid_obstacles.*"))
    with pytest.raises(ConfigurationError, match="was revoked"):
        apply(zenoh.Config(), directory=d, identity="avoid_obstacles", robot="sec")
    with pytest.raises(ConfigurationError, match="cannot be revoked"):
        revoke(d, "robot")
    with pytest.raises(ConfigurationError, match="only on the host where the set-up was made"):
        rotate(tmp_path / "laptop", "teleop")


def test_secure_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``python -m ubf_async.secure``'s commands, through its ``main`` (in this process)."""
    from ubf_async.tools.secure import main

    d, path = tmp_path / "s", robot_file(tmp_path, "sec")
    assert main(["init", str(d), "--robot-file", str(path), "--host", "10.0.0.7"]) == 0
    made = capsys.readouterr().out
    assert "carries: 10.0.0.7" in made and f"--secure {d} --identity teleop" in made
    assert main(["show", str(d)]) == 0 and capsys.readouterr().out == made
    out = tmp_path / "t.tar.gz"
    assert main(["export", str(d), "teleop", "--output", str(out)]) == 0
    assert "identities/teleop.key" in capsys.readouterr().out and out.is_file()
    assert main(["rotate", str(d), "robot", "--host", "robot.lan"]) == 0
    assert "rotated 'robot'" in capsys.readouterr().out
    assert main(["revoke", str(d), "teleop"]) == 0
    assert main(["show", str(d)]) == 0 and "revoked: teleop" in capsys.readouterr().out
    assert main(["zenoh-override", str(d), "inspector", "-e", "tls/10.0.0.7:7447"]) == 0
    line = capsys.readouterr().out.strip()
    assert 'connect/endpoints=["tls/10.0.0.7:7447"]' in line and 'mode="client"' in line
    assert main(["show", str(tmp_path / "nope")]) == 2
    assert "no secure set-up there" in capsys.readouterr().err
    assert main(["zenoh-override", str(d), "inspector", "-e", "tcp/10.0.0.7:7447"]) == 2
    assert "use tls/10.0.0.7:7447" in capsys.readouterr().err


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
    assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
    assert json.loads(conf.get_json("transport/link/tls/verify_name_on_connect")) is True
    robot_conf = zenoh.Config()
    apply(robot_conf, directory=d, identity="robot", robot="sec", listen=["tls/127.0.0.1:1"])
    assert json.loads(robot_conf.get_json("access_control/default_permission")) == "deny"
    assert json.loads(robot_conf.get_json("transport/link/tls/listen_certificate")).endswith(
        "robot.pem")
    refusals: list[tuple[dict[str, Any], str]] = [
        ({"identity": None, "robot": "sec"}, "needs --identity"),
        ({"identity": "nobody", "robot": "sec"}, "has no such identity"),
        ({"identity": "teleop", "robot": "other"}, "is for robot 'sec'"),
        ({"identity": "teleop", "robot": "sec", "listen": ["tls/127.0.0.1:1"]},
         "may not --listen"),
        ({"identity": "robot", "robot": "sec", "listen": ["tcp/127.0.0.1:1"]},
         r"--listen tcp/127.0.0.1:1: secure mode speaks TLS only .*: use tls/127.0.0.1:1"),
        ({"identity": "teleop", "robot": "sec", "connect": ["tcp/10.0.0.7:7447"]},
         "use tls/10.0.0.7:7447"),
    ]
    for kwargs, message in refusals:
        with pytest.raises(ConfigurationError, match=message):
            apply(zenoh.Config(), directory=d, **kwargs)
    with pytest.raises(ConfigurationError, match=r"nodir: no secure set-up there .*secure init"):
        apply(zenoh.Config(), directory=tmp_path / "nodir", identity="robot", robot="sec")
    os.chmod(d / "identities" / "teleop.json", 0o644)
    with pytest.raises(ConfigurationError, match="readable by others"):
        apply(zenoh.Config(), directory=d, identity="teleop", robot="sec")
    os.chmod(d / "identities" / "teleop.json", 0o600)
    shutil.copy(d / "identities" / "operator.pem", d / "identities" / "teleop.pem")
    with pytest.raises(ConfigurationError, match="is the certificate of 'operator', not of"):
        apply(zenoh.Config(), directory=d, identity="teleop", robot="sec")
    with pytest.raises(ConfigurationError, match="needs --secure"):
        ConnectionOptions(robot="sec", identity="teleop").zenoh_config()


def test_each_identity_is_told_before_it_acts_what_the_acl_would_drop(tmp_path: Path) -> None:
    d = tmp_path / "s"
    init(d, robot=load_robot(robot_file(tmp_path, "sec")))

    def rights_of(identity: str) -> Any:
        return rights(ConnectionOptions(robot="sec", secure=d, identity=identity))

    rights_of("inspector").check("declare_subscriber", "ubf/sec/**")
    rights_of("teleop").check("put", "ubf/sec/vote/seek_pink_ball/teleop")
    rights_of("operator").check("query", "ubf/sec/tree")
    rights_of("robot").check("put", "ubf/sec/cmd/drive")
    refused = [
        ("inspector", "put", "ubf/sec/cmd/drive", "only the robot itself may"),
        ("inspector", "query", "ubf/sec/tree", "operator may .*: run it with --identity operator"),
        ("avoid_obstacles", "put", "ubf/sec/vote/seek_pink_ball/teleop",
         "teleop may .*--identity teleop"),
        ("teleop", "put", "ubf/sec/clock", "only the robot itself may"),
        ("operator", "liveliness_token", "ubf/sec/alive/teleop", ".*--identity teleop"),
    ]
    for identity, message, key, hint in refused:
        with pytest.raises(NotAllowedError, match=f"identity {identity!r} may not .* {key}: "
                                                   f"the robot's access control would drop it "
                                                   f"without a word; {hint}"):
            rights_of(identity).check(message, key)
    assert rights(ConnectionOptions(robot="sec")).allows("put", "ubf/sec/cmd/drive")


# ---------------------------------------------------------------------------------------------
# One robot in secure mode over TLS, shared by the module

ATTACKER = r'''
import json, sys, time, msgpack, zenoh
endpoint, robot, mode, settings, seconds = sys.argv[1:6]
conf = zenoh.Config()
conf.insert_json5("mode", json.dumps(mode))
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
for path, value in json.loads(settings).items():
    if path != "mode":
        conf.insert_json5(path, json.dumps(value))
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
        tail = key.split("/", 2)[2]
        if tail.startswith("marker"):
            return
        m = decode(payload)
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
        stderr=asyncio.subprocess.STDOUT, env=repository_env())


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


def attacker(endpoint: str, robot: str, mode: str, zenoh_settings: dict[str, Any] | None = None
             ) -> list[str]:
    return ["-c", ATTACKER, endpoint, robot, mode, json.dumps(zenoh_settings or {}),
            str(ATTACK_S)]


async def observe(options: ConnectionOptions) -> tuple[Bus, Seen]:
    """A session seeing everything under the robot's keys, once it sees drive commands."""
    bus = await Bus.open(options)
    seen = Seen()
    bus.subscribe(f"{bus.keys.prefix}/**", seen.on_sample, latest=False, max_queue=1 << 16)
    await eventually(lambda: len(seen.drives) > 20, timeout_s=30,
                     what="the observer to see drive commands")
    return bus, seen


@pytest.mark.asyncio
async def test_open_mode_lets_every_attack_land(tmp_path: Path, endpoint: str, robot: str
                                                ) -> None:
    """The control: without --secure, one plain zenoh process does it all."""
    proc = await spawn("-m", "ubf_async.launch", str(robot_file(tmp_path, robot)), "--listen",
                       endpoint, "--quiet")
    bus = None
    try:
        await read_until(proc, "controller:", timeout_s=60)
        bus, seen = await observe(ConnectionOptions(robot=robot, connect=[endpoint],
                                                    mode="client"))
        text = await output(await spawn(*attacker(endpoint, robot, "client")))
        assert "connected" in text and "clock seen True" in text, text
        await eventually(lambda: all(seen.attacked().values()), timeout_s=10,
                         what=f"every attack to show (so far {seen.attacked()})")
    finally:
        if bus is not None:
            await bus.aclose()
        await stop(proc)


ROBOT = "tlsbot"


@dataclass
class TlsRobot:
    """The module's robot in secure mode, and the files made around it."""

    setup: Path
    endpoint: str
    port: int
    banner: str
    stale: Path
    """The teleop's and avoid_obstacles' files from before teleop was rotated and
    avoid_obstacles revoked."""
    other: Path
    """A set-up of its own for a robot of the same name: another CA."""
    expired: Path
    """The setup's inspector files, its certificate expired."""

    def options(self, identity: str | None, *, at: str | None = None,
                setup: Path | None = None) -> ConnectionOptions:
        return ConnectionOptions(robot=ROBOT, mode="client", connect=[at or self.endpoint],
                                 secure=(setup or self.setup) if identity else None,
                                 identity=identity)


def unpack(archive: Path, into: Path) -> Path:
    with tarfile.open(archive) as tar:
        tar.extractall(into, filter="data")
    return into


@pytest.fixture(scope="module")
def tls_robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TlsRobot]:
    folder = tmp_path_factory.mktemp("tls")
    path = robot_file(folder, ROBOT)
    setup = folder / "secure"
    # Its certificate carries 127.0.0.1 only: a client dialling "localhost" must be told.
    init(setup, robot=load_robot(path), hosts=["127.0.0.1"])
    stale = unpack(export(setup, ["teleop", "avoid_obstacles"], folder / "old.tar.gz")
                   and folder / "old.tar.gz", folder / "stale")
    rotate(setup, "teleop")
    revoke(setup, "avoid_obstacles")
    other = folder / "other"
    init(other, robot=load_robot(path), hosts=["127.0.0.1"])
    expired = unpack(export(setup, ["inspector"], folder / "i.tar.gz") and folder / "i.tar.gz",
                     folder / "expired")
    ca = pki.Issued((setup / "private" / "ca.key").read_bytes(), (setup / "ca.pem").read_bytes())
    old = pki.issue(ca, "inspector", days=1, not_before=datetime.datetime.now(datetime.UTC)
                    - datetime.timedelta(days=30))
    (expired / "identities" / "inspector.pem").write_bytes(old.cert_pem)
    pki.write_private(expired / "identities" / "inspector.key", old.key_pem)
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    proc = subprocess.Popen([sys.executable, "-m", "ubf_async.launch", str(path), "--listen",
                             endpoint, "--secure", str(setup)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=repository_env())
    assert proc.stdout is not None
    banner = ""
    for line in proc.stdout:
        banner += line
        if "controller:" in line:
            break
    drain = threading.Thread(target=proc.stdout.read, daemon=True)
    drain.start()
    try:
        yield TlsRobot(setup=setup, endpoint=endpoint, port=port, banner=banner, stale=stale,
                       other=other, expired=expired)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        drain.join(timeout=10)
        proc.stdout.close()


def test_the_robot_says_it_is_in_secure_mode_and_how_to_attach(tls_robot: TlsRobot) -> None:
    assert (f"secure mode: mutual TLS with the set-up in {tls_robot.setup} (identity 'robot'; "
            f"the certificate names 127.0.0.1)") in tls_robot.banner, tls_robot.banner
    assert (f"attach with: --connect {tls_robot.endpoint} --robot {ROBOT} --secure "
            f"{tls_robot.setup} --identity NAME") in tls_robot.banner, tls_robot.banner


def zenoh_opens(conf_settings: dict[str, Any], endpoint: str) -> bool:
    """Whether a plain zenoh client with these settings gets a session to ``endpoint``."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    for path, value in conf_settings.items():
        conf.insert_json5(path, json.dumps(value))
    try:
        zenoh.open(conf).close()
        return True
    except zenoh.ZError:
        return False


@pytest.mark.asyncio
async def test_each_refused_connection_is_told_why_in_one_line(tls_robot: TlsRobot) -> None:
    """In this process, as every entry point opens its session (``Bus.open``)."""
    r = tls_robot
    ep = r.endpoint
    cases: list[tuple[ConnectionOptions, str]] = [
        (r.options(None),  # no certificate at all
         f"the robot at {ep} is in secure mode and asks for a certificate: this process gave "
         f"none: pass --secure DIR --identity NAME"),
        (r.options(None, at=f"tcp/127.0.0.1:{r.port}"),  # plain tcp against TLS
         f"the robot at tcp/127.0.0.1:{r.port} speaks TLS (secure mode), not plain tcp/: "
         f"connect to {ep} with --secure DIR --identity NAME"),
        (r.options("inspector", setup=r.other),  # another set-up: another CA
         f"the robot at {ep} has a certificate not signed by this set-up's CA ({r.other}/ca.pem)"
         f": this host's files come from another set-up"),
        (r.options("inspector", at=f"tls/localhost:{r.port}"),  # a name it does not carry
         f"the robot's certificate at tls/localhost:{r.port} does not carry the name dialled, "
         f"'localhost' (it carries: 127.0.0.1): dial one of those, or on the set-up's host run "
         f"`python -m ubf_async.secure rotate DIR robot --host localhost …`"),
        (r.options("teleop", setup=r.stale),  # rotated since these files were made
         f"the robot at {ep} accepted this process's certificate but not identity 'teleop''s "
         f"password: it was rotated or revoked"),
        (r.options("avoid_obstacles", setup=r.stale),  # revoked since
         f"the robot at {ep} accepted this process's certificate but not identity "
         f"'avoid_obstacles''s password: it was rotated or revoked"),
    ]
    for options, expected in cases:
        with pytest.raises(RefusedError) as refused:
            bus = await Bus.open(options)
            await bus.aclose()
        assert str(refused.value).startswith(expected), (options, str(refused.value))
        assert "\n" not in str(refused.value)
    # An expired certificate is told before anything connects.
    with pytest.raises(ConfigurationError, match=r"the certificate of identity 'inspector' .* "
                                                 r"expired on .*: on the set-up's host run "
                                                 r"`python -m ubf_async.secure rotate DIR "
                                                 r"inspector`"):
        await Bus.open(r.options("inspector", setup=r.expired))

    # The robot itself refuses them (a plain zenoh client, no check of ours on the way) …
    def inspector_settings(setup: Path, **over: Path) -> dict[str, Any]:
        ours = settings(directory=setup, identity="inspector", robot=ROBOT)
        return ours | {f"transport/link/tls/connect_{k}": str(v) for k, v in over.items()}

    good = inspector_settings(r.setup)
    ca_only = {k: v for k, v in good.items() if "connect_" not in k}
    other_ca_cert = inspector_settings(r.setup, certificate=r.other / "identities/inspector.pem",
                                       private_key=r.other / "identities/inspector.key")
    expired = inspector_settings(r.setup, certificate=r.expired / "identities/inspector.pem",
                                 private_key=r.expired / "identities/inspector.key")
    opens = await asyncio.gather(*(asyncio.to_thread(zenoh_opens, s, ep) for s in (
        good, ca_only, other_ca_cert, expired)))
    assert opens == [True, False, False, False]
    # … and says which (the alert the probe reads).
    found = [await asyncio.to_thread(tlsprobe.probe, "127.0.0.1", r.port, ca=r.setup / "ca.pem",
                                     cert=cert, key=key) for cert, key in (
        (None, None),
        (r.other / "identities/inspector.pem", r.other / "identities/inspector.key"),
        (r.expired / "identities/inspector.pem", r.expired / "identities/inspector.key"))]
    assert [f.kind if f else None for f in found] == [
        "client-required", "client-unknown-ca", "client-expired"]


@pytest.mark.asyncio
async def test_roles_tell_before_they_act(tls_robot: TlsRobot) -> None:
    """As a new user would: each is told at once, exit status 2, nothing sent."""
    r = tls_robot
    flags = ["--connect", r.endpoint, "--robot", ROBOT, "--secure", str(r.setup)]
    procs = await asyncio.gather(
        spawn("-m", "ubf_async.inspector", "pub", "cmd/drive", "{speed: 50, turn: 0}", *flags,
              "--identity", "inspector"),
        spawn("-m", "ubf_async.inspector", "tree", "set-arbiter", "seek_pink_ball",
              "HighestPriority", *flags, "--identity", "inspector"),
        spawn(str(ROOT / "examples" / "teleop_override.py"), *flags, "--identity", "operator"),
    )
    texts = [await output(p) for p in procs]
    assert [p.returncode for p in procs] == [2, 2, 2], texts
    pub, tree, teleop = (t.strip().splitlines()[-1] for t in texts)
    assert pub == (f"python -m ubf_async.inspector: error: identity 'inspector' may not publish "
                   f"on ubf/{ROBOT}/cmd/drive: the robot's access control would drop it without "
                   f"a word; only the robot itself may (its launch process) "
                   f"(docs/security.md)"), texts[0]
    assert tree.endswith(f"identity 'inspector' may not query ubf/{ROBOT}/tree: the robot's "
                         f"access control would drop it without a word; operator may (and the "
                         f"robot): run it with --identity operator (docs/security.md)"), texts[1]
    assert "sent" not in texts[0] and "no robot" not in texts[1]
    assert teleop.endswith(f"identity 'operator' may not publish on ubf/{ROBOT}/vote/"
                           f"seek_pink_ball/teleop: the robot's access control would drop it "
                           f"without a word; teleop may (and the robot): run it with "
                           f"--identity teleop (docs/security.md)"), texts[2]
    assert "votes in" not in texts[2]  # refused before it connected


@pytest.mark.asyncio
async def test_over_tls_the_teleop_drives_the_inspector_reads_wrong_roles_change_nothing(
    tls_robot: TlsRobot
) -> None:
    """Attacked by processes with valid certificates of the wrong role (the inspector's, the
    operator's) while the configured teleop, with its own, takes control; the inspector's
    ``state`` reads it all."""
    r = tls_robot
    bus, seen = await observe(r.options("inspector"))
    clock_before = seen.clock_max_ns
    attackers = [await spawn(*attacker(r.endpoint, ROBOT, "client", settings(
        directory=r.setup, identity=who, robot=ROBOT))) for who in ("inspector", "operator")]
    teleop = await spawn(str(ROOT / "examples" / "teleop_override.py"), "--connect",
                         r.endpoint, "--robot", ROBOT, "--secure", str(r.setup), "--speed",
                         "-30", "--turn", "50", "--quiet")
    try:
        await eventually(lambda: (-30.0, 50.0, ("teleop",)) in seen.drives, timeout_s=30,
                         what="the configured teleop to take control")
        texts = [await output(p) for p in attackers]
        state = await spawn("-m", "ubf_async.inspector", "state", "--connect", r.endpoint,
                            "--robot", ROBOT, "--secure", str(r.setup), "--identity",
                            "inspector")
        shown = await output(state)
    finally:
        await stop(teleop)
        await bus.aclose()
    for text in texts:  # authenticated, read the clock, sent for 4 s
        assert text.startswith("connected") and "clock seen True" in text, text
    assert seen.attacked() == dict.fromkeys(seen.attacked(), False), seen.attacked()
    # The robot's own processes kept working: simulator clock, controller, motors.
    assert clock_before < seen.clock_max_ns < FAR
    assert seen.applied and seen.drives[-1][2] != ("attacker",)
    assert "teleop" in seen.remotes
    assert state.returncode == 0 and "drive:" in shown and "won by" in shown, shown


async def relay(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                captured: bytearray) -> None:
    with contextlib.suppress(ConnectionError, asyncio.CancelledError):
        while data := await reader.read(65536):
            captured += data
            writer.write(data)
            await writer.drain()
    writer.close()


@pytest.mark.asyncio
async def test_nothing_crosses_the_network_in_clear(tls_robot: TlsRobot) -> None:
    """A raw socket proxy between a client and the robot records every byte both ways: a
    sample that crossed it is nowhere in the capture, nor the client's password."""
    r = tls_robot
    captured = bytearray()
    tasks: list[asyncio.Task[None]] = []

    async def on_client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", r.port)
        tasks.extend([asyncio.ensure_future(relay(reader, up_writer, captured)),
                      asyncio.ensure_future(relay(up_reader, writer, captured))])

    proxy = await asyncio.start_server(on_client, "127.0.0.1", 0)
    proxy_port = proxy.sockets[0].getsockname()[1]
    marker = b"MARKER-" + os.urandom(8).hex().encode()
    observer = await Bus.open(r.options("inspector"))
    got: list[bytes] = []
    observer.subscribe(f"ubf/{ROBOT}/vote/seek_pink_ball/teleop",
                       lambda k, payload, t: got.append(payload), latest=False)
    client = await Bus.open(r.options("teleop", at=f"tls/127.0.0.1:{proxy_port}"))
    try:
        publisher = client.raw_publisher(f"ubf/{ROBOT}/vote/seek_pink_ball/teleop")
        await eventually(lambda: publisher._out.has_remote_subscribers(), timeout_s=10,
                         what="the robot's subscription to reach the client")
        for _ in range(20):
            publisher.put(marker)
            await asyncio.sleep(0.01)
        await eventually(lambda: marker in got, timeout_s=10,
                         what="the marker to cross the proxy to the observer")
    finally:
        await client.aclose()
        await observer.aclose()
        proxy.close()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    password = json.loads((r.setup / "identities" / "teleop.json").read_text())["password"]
    assert len(captured) > 2000
    assert marker not in captured and password.encode() not in captured
    assert b"MARKER" not in captured


# ---------------------------------------------------------------------------------------------
# A fleet over a TLS router

FLEET = """world: {scenario: ball-in-sight, speed: 4, duration_s: 2}
router: tcp/127.0.0.1:PORT
robots:
  - {name: r1, robot_file: mini-whegs, start: {x_m: 0.0, y_m: 0.0, heading_deg: 0}}
"""


@pytest.mark.asyncio
async def test_a_fleet_runs_over_a_tls_router_that_holds_its_access_control(tmp_path: Path
                                                                           ) -> None:
    """``fleet --secure DIR``: the router listens on tls/ with the fleet's ACL; the world,
    the controller and the launcher each join it with their own certificate. Meanwhile a
    process without one, or over plain tcp/, is told why it is refused, and a fleet's robot
    may not publish under another robot's keys."""
    port = free_port()
    fleet_file = tmp_path / "fleet.yaml"
    fleet_file.write_text(FLEET.replace("PORT", str(port)))
    setup = tmp_path / "fs"
    from ubf_async.tools.secure import main as secure_main

    assert secure_main(["init", str(setup), "--fleet-file", str(fleet_file), "--host",
                        "127.0.0.1"]) == 0
    proc = await spawn("-m", "ubf_async.fleet", str(fleet_file), "--secure", str(setup),
                       "--quiet", "--log-dir", str(tmp_path / "logs"), "--summary",
                       str(tmp_path / "summary.json"))
    try:
        await read_until(proc, "fleet: 1 robots on the router at "
                               f"tls/127.0.0.1:{port}", timeout_s=60)
        await eventually(lambda: listening(f"tls/127.0.0.1:{port}", timeout_s=0.5),
                         timeout_s=30, what="the router to listen")
        for options, expected in (
            (ConnectionOptions(robot="r1", mode="client", connect=[f"tls/127.0.0.1:{port}"]),
             "is in secure mode and asks for a certificate"),
            (ConnectionOptions(robot="r1", mode="client", connect=[f"tcp/127.0.0.1:{port}"]),
             "speaks TLS (secure mode), not plain tcp/"),
        ):
            with pytest.raises(RefusedError, match=re.escape(expected)):
                await Bus.open(options)
        text = await output(proc, timeout_s=120)
    finally:
        await stop(proc)
    assert proc.returncode == 0, text
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["robots"]["r1"]["ticks"] > 50, summary
    acl = json.loads((setup / "acl.json").read_text())["access_control"]
    assert {"id": "user-r1", "cert_common_names": ["r1"], "usernames": ["r1"]} in acl["subjects"]
    r1 = rights(ConnectionOptions(robot="r1", secure=setup, identity="r1"))
    r1.check("put", "ubf/r1/cmd/drive")
    with pytest.raises(NotAllowedError, match="identity 'r1' may not publish on "
                                              "ubf/r2/cmd/drive"):
        r1.check("put", "ubf/r2/cmd/drive")
    with pytest.raises(ConfigurationError, match="is for the fleet's robot 'r1', not 'r2'"):
        settings(directory=setup, identity="r1", robot="r2")
