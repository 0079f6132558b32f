"""``python -m ubf_async.inspector`` against a robot and components in separate processes."""

from __future__ import annotations

import concurrent.futures
import json
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import msgpack
import pytest

from tests.cli_inprocess import run_main
from tests.conftest import free_port
from tests.remote_robot import ROOT, Process, start_robot
from ubf_async.tools.inspector.common import expected_schema, key_or_report, resolve_key
from ubf_async.tools.inspector.parser import build_parser
from ubf_async.tools.inspector.program import main as inspector_main
from ubf_async.tools.inspector.samples import format_sample
from ubf_async.tools.inspector.tree import tree_request_data
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import encode

EXAMPLES = ROOT / "examples"
ROBOT_COMPONENTS = ["aggregator", "camera-front", "controller", "remotes", "robot-time"]


def inspect(*args: str, timeout_s: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ubf_async.inspector", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout_s)


def until(
    check: Callable[[], object], *, timeout_s: float = 10.0, what: str = "condition"
) -> object:
    """Re-run ``check()`` (which runs the CLI) until it returns something truthy."""
    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        last = check()
        if last:
            return last
    raise AssertionError(f"timed out after {timeout_s}s waiting for {what}; last: {last!r}")


def robot_with_plain_sensor(endpoint: str, robot: str) -> Iterator[list[Process]]:
    """The robot helper plus a plain range sensor named "plain" (range 321 mm)."""
    procs = [start_robot(endpoint, robot)]
    try:
        procs.append(Process(str(EXAMPLES / "plain_range_sensor.py"), "--connect", endpoint,
                             "--robot", robot, "--name", "plain", "--range-mm", "321"))
        procs[-1].wait_for_line("publishing")
        yield procs
    finally:
        for p in procs:
            p.kill()


@pytest.fixture
def running_robot(endpoint: str, robot: str) -> Iterator[list[Process]]:
    """:func:`robot_with_plain_sensor`, for a test that adds components of its own."""
    yield from robot_with_plain_sensor(endpoint, robot)


@pytest.fixture(scope="module")
def watched_robot() -> Iterator[tuple[str, str]]:
    """:func:`robot_with_plain_sensor` that the tests only read (its endpoint, its name),
    shared by them."""
    endpoint, robot = f"tcp/127.0.0.1:{free_port()}", f"watched{free_port()}"
    for _ in robot_with_plain_sensor(endpoint, robot):
        yield endpoint, robot


def test_help_lists_commands_and_shared_flags(capfd: pytest.CaptureFixture[str]) -> None:
    top = inspect("--help")  # the real command; its commands' helps from its main, here
    assert top.returncode == 0
    for command in ("components", "keys", "echo", "state"):
        assert command in top.stdout

    def inspect_here(*argv: str) -> subprocess.CompletedProcess[str]:
        return run_main(inspector_main, argv, capfd, name="ubf_async.inspector")

    for command in ("components", "keys", "echo", "state"):
        out = inspect_here(command, "--help").stdout
        for flag in ("--connect", "--listen", "--mode", "--config", "--robot", "--timeout"):
            assert flag in out, (command, flag)
    assert "--count" in inspect_here("echo", "--help").stdout
    assert inspect().returncode == 2  # a command is required
    assert "tree" in top.stdout
    verbs = inspect_here("tree", "--help").stdout
    for verb in ("show", "set-arbiter", "set-child", "load"):
        assert verb in verbs
        out = inspect_here("tree", verb, "--help").stdout
        for flag in ("--connect", "--robot", "--timeout", "--json"):
            assert flag in out, (verb, flag)
    assert "--param" in inspect_here("tree", "set-arbiter", "--help").stdout
    # `tree` alone is `tree show` (issue 35: it was an error that named no verb), and the
    # usage lists the verbs.
    assert "{show,set-arbiter,set-child,load}" in verbs
    alone = build_parser().parse_args(["tree"])
    assert alone.tree_command == "show" and tree_request_data(alone) == {"op": "show"}
    bad_param = inspect_here("tree", "set-arbiter", "c", "MonteCarlo", "--param", "nokey")
    assert bad_param.returncode == 2 and "expected KEY=VALUE" in bad_param.stderr


def test_unreachable_robot_is_a_clear_error() -> None:
    proc = inspect("components", "--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "1")
    assert proc.returncode == 2
    assert proc.stderr.startswith("python -m ubf_async.inspector: error:") \
        and "Traceback" not in proc.stderr


def test_components_lists_exactly_the_live_ones(
    running_robot: list[Process], endpoint: str, robot: str
) -> None:
    second = Process(str(EXAMPLES / "plain_range_sensor.py"), "--connect", endpoint,
                     "--robot", robot, "--name", "second", "--range-mm", "800")
    try:
        second.wait_for_line("publishing")

        def listing() -> list[str]:
            proc = inspect("components", "--connect", endpoint, "--robot", robot)
            assert proc.returncode == 0, proc.stderr
            return proc.stdout.split()

        with_both = sorted([*ROBOT_COMPONENTS, "plain", "second"])
        until(lambda: listing() == with_both, what=f"components == {with_both}")
        assert listing() == with_both  # stable, and the inspector itself is not listed
        second.kill()
        without = sorted([*ROBOT_COMPONENTS, "plain"])
        until(lambda: listing() == without, what="the killed component to disappear")
        rows: dict[str, str] = {}

        def long_listing() -> list[str]:
            # (Like the short listing, retried: a liveliness query made while a loaded
            # machine's session is still learning the robot's tokens may come back short.)
            long = inspect("components", "--long", "--connect", endpoint, "--robot", robot,
                           "--heartbeat-s", "0.7")
            assert long.returncode == 0, long.stderr
            rows.clear()
            rows.update(line.split(None, 1) for line in long.stdout.splitlines())
            return sorted(rows)

        until(lambda: long_listing() == without, what="the long listing")
        assert rows["controller"].startswith("healthy")
        assert rows["plain"].startswith("token only: no heartbeat")  # plain zenoh
    finally:
        second.kill()


def test_echo_decodes_samples_and_reports_malformed_ones(
    running_robot: list[Process], endpoint: str, robot: str
) -> None:
    proc = inspect("echo", "sensor/range/plain", "--count", "3", "--connect", endpoint,
                   "--robot", robot)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == f"# echo ubf/{robot}/sensor/range/plain"
    assert len(lines) == 4
    for line in lines[1:]:
        assert line.startswith(f"ubf/{robot}/sensor/range/plain range #")
        assert '"range_mm": 321' in line and '"status": "ok"' in line
    drive = inspect("echo", f"ubf/{robot}/cmd/drive", "-n", "2", "--json", "--connect",
                    endpoint, "--robot", robot)
    samples = [json.loads(line) for line in drive.stdout.splitlines()]
    assert len(samples) == 2
    assert all(s["schema"] == "drive" and s["data"]["winners"] == ["chase"] for s in samples)
    assert samples[1]["seq"] > samples[0]["seq"]

    # A publisher of junk on a sensor key: echo shows it as an error and goes on.
    junk = Process("-c", JUNK_PUBLISHER, endpoint, robot)
    try:
        junk.wait_for_line("publishing")
        echo = inspect("echo", "sensor/junk/*", "--count", "4", "--connect", endpoint,
                       "--robot", robot)
    finally:
        junk.kill()
    assert echo.returncode == 0, echo.stderr
    lines = echo.stdout.splitlines()[1:]
    assert len(lines) == 4
    errors = [line for line in lines if " ERROR " in line]
    good = [line for line in lines if " range #" in line]
    assert errors and good and len(errors) + len(good) == 4
    assert any("not a valid msgpack payload" in e or "range_mm" in e for e in errors)


JUNK_PUBLISHER = """
import json, sys, time, msgpack, zenoh
endpoint, robot = sys.argv[1:3]
conf = zenoh.Config()
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
with zenoh.open(conf) as session:
    pub = session.declare_publisher(f"ubf/{robot}/sensor/junk/a")
    print("publishing", flush=True)
    seq = 0
    while True:
        seq += 1
        pub.put(b"\\xc1\\xff garbage")
        pub.put(msgpack.packb({"schema": "range", "v": 1, "stamp_ns": 1, "seq": seq,
                               "data": {"range_mm": "near", "status": "ok"}}))
        pub.put(msgpack.packb({"schema": "range", "v": 1, "stamp_ns": 1, "seq": seq,
                               "data": {"range_mm": 5, "status": "ok"}}))
        time.sleep(0.02)
"""


def test_state_shows_sources_with_ages_and_the_explanation(
    watched_robot: tuple[str, str]
) -> None:
    endpoint, robot = watched_robot

    def state() -> str | None:
        proc = inspect("state", "--connect", endpoint, "--robot", robot)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout if "range/plain" in proc.stdout else None

    out = until(state, what="range/plain in the controller's state")
    assert f"robot {robot!r}, controller: periodic mode" in out
    assert "drive: speed +40 turn +0  won by: chase" in out
    source_lines = [line for line in out.splitlines() if " age " in line]
    assert {line.split()[0] for line in source_lines} == {"camera/front", "range/plain"}
    assert all(line.split()[2].isdigit() and "ms" in line for line in source_lines)
    explanation = out[out.index("last tick"):]
    assert "* chase [p=1 w=1]: speed=+40 turn=+0 vote=1" in explanation
    assert "search [p=2 w=1]: abstain" in explanation
    as_json = json.loads(inspect("state", "--json", "--connect", endpoint, "--robot",
                                 robot).stdout)
    assert as_json["status"]["winners"] == ["chase"]


def test_keys_lists_keys_with_rates(watched_robot: tuple[str, str]) -> None:
    endpoint, robot = watched_robot
    proc = inspect("keys", "--seconds", "1", "--connect", endpoint, "--robot", robot)
    assert proc.returncode == 0, proc.stderr
    rows = {line.split()[0]: line.split()[1:] for line in proc.stdout.splitlines()[1:]}
    prefix = f"ubf/{robot}/"
    assert {f"{prefix}cmd/drive", f"{prefix}sensor/range/plain", f"{prefix}sensor/camera/front",
            f"{prefix}heartbeat/controller", f"{prefix}status/controller"} <= set(rows)
    count, rate, schema = rows[f"{prefix}cmd/drive"][:3]
    assert int(count) >= 30 and schema == "drive" and 30 <= float(rate.removesuffix("Hz")) <= 60
    assert rows[f"{prefix}sensor/range/plain"][2] == "range"
    assert 10 <= float(rows[f"{prefix}sensor/range/plain"][1].removesuffix("Hz")) <= 25


def test_conform_checks_real_components_against_the_protocol(
        watched_robot: tuple[str, str]) -> None:
    """Issue 55, item 3, on real processes: the plain-zenoh range finder (no heartbeat: its
    key named) and a ubf_async component (its keys announced) conform; without a key to check
    the plain one is a deviation (exit status 1), and says how to name one."""
    endpoint, robot = watched_robot
    flags = ("--connect", endpoint, "--robot", robot, "--seconds", "2")
    with concurrent.futures.ThreadPoolExecutor(3) as pool:  # each listens 2 s: side by side
        plain, camera, unnamed = pool.map(lambda argv: inspect(*argv, *flags), [
            ("conform", "plain", "--key", "sensor/range/plain"), ("conform", "camera-front"),
            ("conform", "plain")])
    assert plain.returncode == 0, plain.stdout + plain.stderr
    assert f"ok    liveliness token ubf/{robot}/alive/plain" in plain.stdout
    assert re.search(rf"ok    ubf/{robot}/sensor/range/plain \(no pub\): \d+ valid range "
                     r"samples", plain.stdout), plain.stdout
    assert camera.returncode == 0, camera.stdout + camera.stderr
    # Its heartbeats seen and valid: in 2 s, one a second, a busy machine may deliver too few
    # to judge their period (tests/test_conform.py judges periods, planted deviations too).
    assert re.search(r"ok    ubf/\S+/heartbeat/camera-front: (heartbeats every|[1-9]\d* "
                     r"heartbeats, too few to judge)", camera.stdout), camera.stdout
    assert f"ubf/{robot}/sensor/camera/front (pub" in camera.stdout
    assert unnamed.returncode == 1, unnamed.stdout + unnamed.stderr
    assert "FAIL  no keys to check: plain announces none" in unnamed.stdout
    assert unnamed.stdout.rstrip().endswith("1 deviation(s)")


def test_tree_request_data_from_the_command_line(tmp_path: Path) -> None:
    def data(*argv: str) -> dict[str, object]:
        return tree_request_data(build_parser().parse_args(["tree", *argv]))

    assert data("show") == {"op": "show"}
    assert data("set-arbiter", "c", "HighestPriority") == {
        "op": "set_arbiter", "composite": "c", "arbiter": "HighestPriority"}
    assert data("set-arbiter", "c", "MonteCarlo", "-p", "hold_ticks=5", "-p", "seed=2") == {
        "op": "set_arbiter", "composite": "c",
        "arbiter": {"type": "MonteCarlo", "params": {"hold_ticks": 5, "seed": 2}}}
    assert data("set-child", "c", "x", "--weight", "0.5") == {
        "op": "set_child", "composite": "c", "child": "x", "weight": 0.5}
    fragment = tmp_path / "t.yaml"
    fragment.write_text("name: a\n", encoding="utf-8")
    assert data("load", str(fragment)) == {"op": "load", "tree": "name: a\n"}
    fragment.write_text("#" * 5000, encoding="utf-8")
    assert data("load", str(fragment))["tree"] == b"#" * 5000  # too long for a string


def test_formatting_helpers() -> None:
    keys = Keys("r")
    assert resolve_key(keys, "sensor/range/front") == "ubf/r/sensor/range/front"
    assert resolve_key(keys, "ubf/other/cmd/drive") == "ubf/other/cmd/drive"
    assert expected_schema(keys, "ubf/r/cmd/drive") == "drive"
    assert expected_schema(keys, "ubf/r/vote/a/b") == "vote"
    assert expected_schema(keys, "ubf/r/sensor/range/x") == "range"
    assert expected_schema(keys, "ubf/r/sensor/sonar/x") is None  # a kind not declared
    # A drive key only takes drive payloads, as on the robot.
    wrong = encode("range", {"range_mm": 1, "status": "ok"}, stamp_ns=1, seq=1)
    assert "ERROR" in format_sample(keys, "ubf/r/cmd/drive", wrong, raw=False, as_json=False)
    assert "RAW" in format_sample(keys, "ubf/r/cmd/drive", wrong, raw=True, as_json=False)
    raw_junk = format_sample(keys, "k", b"\xc1", raw=True, as_json=True)
    assert "error" in json.loads(raw_junk)
    with_bytes = msgpack.packb({"schema": "blob", "v": 1, "stamp_ns": 1, "seq": 1,
                                "data": {"b": b"\x01\x02"}})
    assert json.loads(format_sample(keys, "k", with_bytes, raw=False,
                                    as_json=True))["data"] == {"b": "0102"}


def test_a_key_that_does_not_resolve_is_reported(capsys: pytest.CaptureFixture[str]) -> None:
    keys = Keys("r")
    assert key_or_report(keys, "cmd/drive") == "ubf/r/cmd/drive"
    assert capsys.readouterr().err == ""
    assert key_or_report(keys, " / ") is None
    assert capsys.readouterr().err == "python -m ubf_async.inspector: error: empty key\n"


def test_state_shows_refusals_and_quarantined_behaviours() -> None:
    from ubf_async.tools.inspector.state import format_state

    status = {
        "mode": "periodic", "sources": [
            {"source": "camera/front", "age_s": 0.05, "stale": False, "schema": "camera",
             "refused": 3},
            {"source": "range/front", "age_s": 0.01, "stale": False, "schema": "range",
             "refused": 0},
        ],
        "refused": {"future": 3, "out_of_order": 0, "malformed": 2},
        "quarantined": ["root/flaky"],
    }
    text = format_state(status, robot="mini", controller="controller", status_age_s=None)
    camera, range_line = (line for line in text.splitlines() if line.startswith("  ")
                          and ("camera/" in line or "range/" in line))
    assert camera.endswith("refused 3") and "refused" not in range_line
    assert "refused: future 3, malformed 2" in text and "out_of_order" not in text
    assert "quarantined (failing tick after tick, cut off): root/flaky" in text
