"""Every command README.md and docs/*.md show, run (issue 28).

tests/test_docs.py checks that each command shown parses with its entry point's real parser;
here each one runs, through its real entry point, as a subprocess, and the test asserts what
the page says it does (an exit status and a line of its output, a file it writes, another
process seeing it). docs/your-robot.md is run whole by tests/test_tutorial.py, and
docs/your-device.md by tests/test_your_device.py.

A command shown is a simple command of a shell code block, or of an inline code span starting
with ``python`` that is not a form with placeholders (:func:`a_form`: ``secure init DIR
--robot-file FILE``). Each test names the
commands it runs (:func:`runs`); a command that cannot run here says why in :data:`NOT_RUN`.
:func:`test_every_command_shown_is_run_or_says_why_not` fails for a command added to a page
that neither covers, and for one that a test runs but no page shows any more — so a command
edited on a page is noticed, and run as edited.

What a test changes in a command, and only that:

* the documented endpoint (``tcp/127.0.0.1:7447``, ``tcp/192.168.1.10:7447``, a Foxglove port)
  becomes a free loopback port, and a command that relies on the default endpoint is given
  that port explicitly (``--listen`` for a robot, ``--connect`` for a tool);
* a command that runs until stopped is stopped with Ctrl-C (SIGINT) once the test has seen
  what it waits for, or is bounded with its own ``--duration`` (a scenario: 4 simulated s);
  a ``--duration`` shown is shortened the same way, with one given after it (a scenario's to
  4 simulated s, a recorder's to 2 s: the replays of their recordings are as short);
* ``~`` is a temporary folder, a placeholder (``DIR``, ``...``) what the page says it stands
  for, and each page's commands run in a temporary folder of their own (``examples/`` linked
  in, a fleet file's router on a free port).

Commands that attach to a robot share one: the quick start's (:func:`robot`).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import functools
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import pytest

from tests.conftest import free_port, repository_env
from tests.foxglove_client import FoxgloveClient
from tests.test_docs import DOCS, ROOT, shell_texts, tokens
from tests.test_late_join import readme_tools_join_late

TUTORIAL = ROOT / "docs" / "your-robot.md"
DEVICE_GUIDE = ROOT / "docs" / "your-device.md"
DOCUMENTED_ENDPOINTS = ("tcp/127.0.0.1:7447", "tcp/192.168.1.10:7447", "tcp/0.0.0.0:7447",
                        "tls/192.168.1.10:7447")
ROBOT_FILE = ROOT / "ubf_async" / "robots" / "mini-whegs.yaml"
WAIT_S = 90.0  # for a line of output: generous, for a loaded machine
STOP_S = 30.0  # for a process to end once stopped (the bound is 5 s; a loaded machine is slow)


# -- the commands the pages show --------------------------------------------------------------

def simple_commands(text: str) -> Iterator[list[str]]:
    """The simple commands of a shell text (split at ``&&``, ``&``, ``;``, ``|``), comments
    dropped."""
    command: list[str] = []
    for token in [*tokens(text), ";"]:
        if token and set(token) <= set("();<>|&"):
            if command:
                yield command
            command = []
        else:
            command.append(token)


@functools.cache
def shown(*, inline: bool = True) -> dict[str, list[str]]:
    """Every simple command of the pages' shell blocks and (``inline``) of their inline code
    spans that start with ``python`` (its words joined by spaces) → where it is shown."""
    found: dict[str, list[str]] = {}
    for doc in DOCS:
        if doc in (TUTORIAL, DEVICE_GUIDE):  # each executed whole by a test of its own
            continue
        for line, text in shell_texts(doc.read_text("utf-8"), inline=inline):
            for command in simple_commands(text):
                found.setdefault(" ".join(command), []).append(f"{doc.relative_to(ROOT)}:{line}")
    return found


PLACEHOLDER = re.compile(r"[A-Z][A-Z_]+(?:\.\w+)?|.*[…<>].*|\[.*|.*\]")


def a_form(command: str) -> bool:
    """An inline mention that shows the form of a command rather than a command to run: a
    placeholder (``FILE``, ``DIR``, ``[--quick]``, ``…``), or a piece of
    ``components.<device>``."""
    words = command.split(" ")
    if words[0] != "python" or words[-1].endswith("."):
        return True
    return any(PLACEHOLDER.fullmatch(word) for word in words)


RUN: dict[str, str] = {}
"""Command shown → the test that runs it."""

F = TypeVar("F", bound=Callable[..., object])


def runs(*commands: str) -> Callable[[F], F]:
    """Declare the commands shown that the decorated test runs."""
    def declare(test: F) -> F:
        for command in commands:
            RUN[command] = test.__name__
        return test
    return declare


BOARD = "a Raspberry Pi–class board's set-up (root, apt, systemd as PID 1)"
ROS_MACHINE = ("a ROS 2 installation with rmw_zenoh (none here): test_ros2_sees_the_robot_"
               "through_a_router does what it does with tests/ros2_side.py, an rmw_zenoh "
               "implementation independent of ubf_async.services.ros2")

EVOLVE = "python -m ubf_async.evolve examples/evolve/mini-whegs.yaml --out out/evolve --workers 2"
EVOLVE_WHY = ("the worked evolution, 16 × 10 generations: about 12 minutes on 2 cores, past the "
              "doc tests' budget; tests/test_evolve.py runs the same command (its main) on a "
              "tiny SPEC: its outputs, --resume after a kill, 1 against 2 workers")
TUNE_WHY = ("the worked study, 30 trials: minutes on 2 cores; tests/test_evolve.py runs the same "
            "command (its main) on a tiny SPEC, resuming a study kept in SQLite")

CLUSTER_RUN = ("run as written, quoted from docs/experiments.md, on two hosts (network "
               "namespaces) by tests/test_sweep_cluster.py::test_a_sweep_on_two_machines_as_the_"
               "page_says")
PIONEER_WHY = ("the library call, byte for byte a launch (tests/test_experiment.py), runs each of "
               "the four: tests/test_bodies.py::test_the_pioneer_passes_the_thesis_scenarios_"
               "scaled (flat out)")

NOT_RUN = {
    **{f"python -m ubf_async.launch examples/robots/pioneer.yaml --scenario "
       f"examples/scenarios/pioneer/{name}.json --speed max": PIONEER_WHY
       for name in ("ball-in-sight", "ball-behind", "keep-away", "dance")},
    "ssh -L 8770:127.0.0.1:8770 pi@robot.local":
        "a tunnel to another host (test_the_tree_is_served_to_browsers_and_changed_live serves "
        "the page on loopback, where the tunnel ends)",
    "python -m ubf_async.inspector conform my_ir --key sensor/range/my_ir":
        "the page's own sensor snippet, not a file here: tests/test_clock_domain.py runs the "
        "same check on examples/plain_range_sensor.py (conform plain --key sensor/range/plain)",
    "python3 -m venv .venv":
        "the quick start's installation: .ci/run does it from a clean clone (a test cannot "
        "install the project's build dependencies without the network)",
    ". .venv/bin/activate": "the quick start's installation (see python3 -m venv)",
    "pip install -e .[all]": "the quick start's installation (see python3 -m venv)",
    "pip install -r requirements/test.txt -e .[test]":
        "the test command's installation of the lock and the test extra: .ci/run does it "
        "from a clean clone (tests/test_docs.py checks that it installs the same)",
    "python .ci/deps.py latest":
        "a fresh venv of every newest release and the whole suite in it: a maintainer's "
        "command (tests/test_gate.py checks the lock it is compared with)",
    "python .ci/deps.py lock --upgrade":
        "resolves the lock against the package index: a maintainer's command, which changes "
        "requirements/test.txt",
    "python .ci/deps.py lowest":
        "a fresh venv of the ranges' lower bounds and the whole suite in it: a maintainer's "
        "command",
    "python .ci/deps.py lock": "resolves the lock against the package index (see lock "
                               "--upgrade)",
    "bash .ci/run": "CI itself, from a clean clone: the suite this test is part of",
    "python -m pytest": "the test suite this test is part of (.ci/run runs it)",
    "python -m pytest tests/test_latency.py": "part of the test suite this test is part of",
    "pip install -e .[hardware]":
        "installs gpiozero and smbus2 into the environment running the tests (they are test "
        "dependencies here; the gpio check below runs on them)",
    "sudo apt install python3-lgpio": "root, and a Raspberry Pi's packages",
    "sudo apt install python3-venv python3-lgpio": BOARD,
    "python3 -m venv --system-site-packages ~/ubf-venv": BOARD,
    ". ~/ubf-venv/bin/activate": BOARD,
    "sudo cp ubf-robot-mini.service /etc/systemd/system/": BOARD,
    "sudo systemctl daemon-reload": BOARD,
    "sudo systemctl enable --now ubf-robot-mini": BOARD,
    "journalctl -u ubf-robot-mini -f": BOARD,
    "python -m components.motors --backend gpio --check --robot-file my-robot.yaml":
        "real GPIO motors (tests/test_hw_launch.py runs the check on gpiozero's mock pins)",
    "python -m ubf_async.inspector robots --connect tls/192.168.1.10:7447 --secure "
    "~/.ubf/mini --identity inspector":
        "a robot on another host of the LAN: tests/test_secure.py reads a TLS robot with the "
        "inspector's identity on loopback",
    "sudo usermod -aG gpio,i2c $USER": "root, and a Raspberry Pi's groups",
    "sudo raspi-config nonint do_i2c 0": "root, and a Raspberry Pi's configuration tool",
    "ls -l /dev/gpiochip* /dev/i2c-1": "a Raspberry Pi's GPIO and I²C device files",
    "i2cdetect -y 1": "a Raspberry Pi's I²C bus with the rangers and the ADC on it",
    "python -m ubf_async.launch examples/robots/pi-whegs.yaml":
        "a real robot: its motors and encoders need GPIO pins and its rangers /dev/i2c-1; "
        "test_the_pi_robot_file_checks runs it with --check (tests/test_hw_launch.py runs it "
        "on gpiozero's mock pins and a test I²C bus)",
    "python -m bench.latency":
        "about 4 minutes, past the doc tests' time budget: test_the_latency_bench_explains_"
        "itself runs its --help; tests/test_latency.py runs its sections in short runs",
    "python -m bench.latency --quick": "about 45 s (see python -m bench.latency)",
    "python -m bench.latency --json out.json": "the full run (see python -m bench.latency)",
    "python -m bench.latency --only reflex obstacle":
        "146 s measured here (see python -m bench.latency)",
    "python -m bench.latency --only loops":
        "each event loop in interleaved rounds: minutes (see python -m bench.latency)",
    "python -m bench.latency --only loops --rounds 12":
        "each event loop, 12 interleaved rounds: minutes (see python -m bench.latency)",
    "python -m bench.latency --only reflex dora":
        "4 rounds of the reflex and 3 of dora's benchmark: about 2.5 minutes (see python -m "
        "bench.latency); tests/test_latency.py runs the pieces",
    "python -m bench.latency --only reflex dora --baseline ../ubf-base":
        "the same with a second checkout (see python -m bench.latency --only reflex dora)",
    "python -m bench.realtime --runs 5 --duration 20":
        "five runs of 20 simulated s, each also without the camera and flat out: minutes",
    "python -m ubf_async.inspector echo ubf/pi-whegs/sensor/encoders/wheels":
        "a running pi-whegs robot: real GPIO encoders",
    "python -m components.motors --backend gpio":
        "real GPIO motors (tests/test_hw_launch.py runs it on gpiozero's mock pins)",
    "python -m bench.fleet_scaling --search":
        "fleets of 1, 2, 4 and 8 robots for 90 simulated s each, twice: many minutes",
    "python -m bench.tick": "13 s measured here, past the doc tests' time budget",
    "python -m bench.handoff": "49 s measured here, past the doc tests' time budget",
    "python -m bench.margins": "37 s measured here, past the doc tests' time budget",
    "python -m bench.flood": "25 s measured here, past the doc tests' time budget",
    "python -m bench.visitors": "a flood, four visits and 100 000 malformed messages against "
                                "the default robot: minutes",
    "python -m bench.shm_visits": "eight visiting processes: 15 s measured here, past the doc "
                                  "tests' time budget",
    "python -m bench.realtime": "several runs of the simulated robot at --speed 5: minutes",
    "python -m bench.soak": "an hour of simulated time flat out (--sim-s 3600)",
    "python -m bench.fleet_scaling":
        "fleets of 1 to 8 robots through the fleet launcher: minutes",
    "python -m ubf_async.fleet":
        "the program's name (it needs a fleet file): its runs shown with one run above",
    "python -m ubf_async.inspector":
        "the program's name (it needs a command): the inspector commands shown run above",
    "python -m ubf_async.record":
        "the program's name in prose: the recorder commands shown with arguments run above",
    "python -m components.camera":
        "the program's name in prose (a device in a process of its own): components.range, "
        "shown with arguments, runs above",
    "python -m components.range":
        "the program's name in prose (docs/protocol.md): shown with arguments, it runs above",
    "export RMW_IMPLEMENTATION=rmw_zenoh_cpp": ROS_MACHINE,
    'export ZENOH_CONFIG_OVERRIDE=connect/endpoints=["tcp/ROBOT_HOST:7447"]': ROS_MACHINE,
    "export ZENOH_ROUTER_CHECK_ATTEMPTS=-1": ROS_MACHINE,
    "ros2 node list": ROS_MACHINE,
    "ros2 topic list -t": ROS_MACHINE,
    "ros2 topic echo /mini/odom": ROS_MACHINE,
    "ros2 run teleop_twist_keyboard teleop_twist_keyboard --ros-args -r "
    "cmd_vel:=/mini/cmd_vel_in": ROS_MACHINE,
    "python -m ubf_async.inspector echo":
        "the inspector's echo named in prose (it needs a KEY): echo with one runs above",
    "python -m ubf_async.inspector tree":
        "the inspector's tree named in prose: docs/your-robot.md runs tree show and "
        "set-arbiter (tests/test_tutorial.py); tests/test_inspector_verbs.py runs it alone",
    "python -m bench.ros2": "the bridge's latency, 300 samples each way: past the time budget",
    "python -m ubf_async.fleet fleet.yaml --world-only":
        "what the fleet launcher starts as its own process: every fleet run here runs it",
    "pip install -e .[cluster]": "an installation (Ray): the test extra installs it",
    "python -m ubf_async.sweep examples/sweeps/eyes.yaml --out out/eyes --workers 2":
        "660 runs, 14 minutes on 2 cores: past the doc tests' budget; tests/test_eyes.py runs "
        "each of its robots in process, and the sweep's machinery is tests/test_sweep.py's",
    "export RAY_AUTH_MODE=token": CLUSTER_RUN,
    "ray get-auth-token --generate": CLUSTER_RUN,
    "ray start --head": CLUSTER_RUN,
    "ray start --address=HEAD_IP:6379": CLUSTER_RUN,
    "python -m ubf_async.sweep examples/sweeps/arbiters.yaml --out out/arbiters --executor ray "
    "--address auto": CLUSTER_RUN,
    "python -m ubf_async.sweep examples/sweeps/arbiters.yaml --out out/arbiters --executor ray "
    "--address ray://HEAD_IP:10001":
        "run by tests/test_sweep_cluster.py from a machine outside the cluster for each refusal "
        "of the page's table; not to a finished sweep: Ray Client's per-client server dies at "
        "its start now and then on a busy head (ray-project/ray#63202)",
    "export RAY_AUTH_MODE=disabled":
        "the opt-out: a second cluster without tokens, past the budget; tests/test_sweep_"
        "cluster.py's 'no token sent' case runs with RAY_AUTH_MODE unset",
    EVOLVE: EVOLVE_WHY,
    EVOLVE + " --resume": EVOLVE_WHY,
    "python -m ubf_async.evolve examples/evolve/mini-whegs.yaml --out out/evolve --resume "
    "--compare out/tune/best.yaml": EVOLVE_WHY,
    "python -m ubf_async.launch out/evolve/best.yaml --scenario ball-behind --speed 5":
        "the evolution's robot file (see python -m ubf_async.evolve): tests/test_evolve.py "
        "loads the best.yaml of its tiny evolution as launch does",
    "python -m ubf_async.tune examples/evolve/mini-whegs.yaml --out out/tune --workers 2":
        TUNE_WHY,
    "python -m ubf_async.tune examples/evolve/mini-whegs.yaml --out out/tune --storage "
    "sqlite:///out/tune.db --workers 2": TUNE_WHY,
}


def test_every_command_shown_is_run_or_says_why_not() -> None:
    in_blocks = set(shown(inline=False))
    inline = {c for c in set(shown()) - in_blocks if not a_form(c)}
    assert in_blocks - set(RUN) - set(NOT_RUN) == set(), "shown, neither run nor said why not"
    assert inline - set(RUN) - set(NOT_RUN) == set(), "shown, neither run nor said why not"
    assert set(RUN) - set(shown()) == set(), "run here, but no page shows it (any more)"
    assert set(NOT_RUN) - set(shown()) == set(), "said why not run, but no page shows it"
    assert set(RUN) & set(NOT_RUN) == set()


def test_what_is_a_form_and_what_a_command() -> None:
    assert not a_form("python -m bench.codec")
    assert a_form("python -m ubf_async.secure init DIR --robot-file FILE")
    assert a_form("python -m bench.latency [--quick] [--json FILE]")
    assert a_form("python -m ubf_async.fleet FLEET.yaml --controllers-only r1,r2 …")
    assert a_form("python -m components.") and a_form("device")
    assert not a_form("python -m ubf_async.launch --help")
    assert not a_form("python -m ubf_async.record --no-live-channels")


# -- running them --------------------------------------------------------------------------

def environment(home: Path) -> dict[str, str]:
    """This repository's code (tests.conftest.repository_env), the console scripts of the
    environment running the tests on PATH, ``~`` a temporary folder."""
    env = repository_env()
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env["HOME"] = str(home)
    return env


def argv(command: str, *, endpoint: str | None = None, home: Path | None = None,
         add: tuple[str, ...] = (), replace: dict[str, list[str]] | None = None) -> list[str]:
    """The command shown (a key of :func:`shown`) as arguments to run: ``python`` is this
    interpreter, the documented endpoint ``endpoint``, ``~`` ``home``, an optional part
    (``[--speed 5]``) taken, a word in ``replace`` its words; ``add`` appended."""
    assert command in shown(), f"no page shows {command!r}"
    words: list[str] = []
    for word in command.split(" "):
        if word.startswith("[-"):
            word = word[1:]
        if word.endswith("]") and "[" not in word:
            word = word[:-1]
        if replace and word in replace:
            words += replace[word]
            continue
        if word == "python":
            word = sys.executable
        elif word in DOCUMENTED_ENDPOINTS:
            assert endpoint is not None, command
            word = endpoint
        elif word.startswith("~/"):
            assert home is not None, command
            word = str(home / word[2:])
        words.append(word)
    return [*words, *add]


class Proc:
    """A command running in the background, its output (stdout and stderr) read line by line
    on a thread: :meth:`wait_for` a line, :meth:`interrupt` it as Ctrl-C does."""

    def __init__(self, args: list[str], *, cwd: Path, env: dict[str, str]) -> None:
        self.args = args
        self.popen = subprocess.Popen(args, cwd=cwd, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True, bufsize=1,
                                      start_new_session=True)
        self.lines: list[str] = []
        self.ended = False
        self.changed = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        with self.popen.stdout:
            for line in self.popen.stdout:
                with self.changed:
                    self.lines.append(line.rstrip("\n"))
                    self.changed.notify_all()
        with self.changed:
            self.ended = True
            self.changed.notify_all()

    @property
    def output(self) -> str:
        with self.changed:
            return "\n".join(self.lines)

    def __str__(self) -> str:
        return f"$ {' '.join(self.args)}\n{self.output}"

    def wait_for(self, pattern: str, *, after: int = 0, timeout_s: float = WAIT_S
                 ) -> re.Match[str]:
        """The first line (from line ``after`` on) in which ``pattern`` is found, waiting for
        it as long as the process prints; fails if it ends or ``timeout_s`` passes first."""
        deadline = time.monotonic() + timeout_s
        compiled = re.compile(pattern)
        seen = after
        with self.changed:
            while True:
                for line in self.lines[seen:]:
                    if match := compiled.search(line):
                        return match
                seen = len(self.lines)
                assert not self.ended, f"ended without a line like {pattern!r}:\n{self}"
                left = deadline - time.monotonic()
                assert left > 0, f"no line like {pattern!r} within {timeout_s} s:\n{self}"
                self.changed.wait(left)

    def finish(self, *, timeout_s: float = WAIT_S) -> int:
        """Its exit status, once it has ended by itself (and its output is all read)."""
        code = self.popen.wait(timeout_s)
        with self.changed:
            self.changed.wait_for(lambda: self.ended, timeout_s)
        return code

    def interrupt(self, *, timeout_s: float = STOP_S) -> int:
        """Ctrl-C: SIGINT, then its exit status."""
        self.popen.send_signal(signal.SIGINT)
        return self.finish(timeout_s=timeout_s)

    def kill(self) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.popen.pid, signal.SIGKILL)
        self.popen.wait()


@dataclass
class Page:
    """Where a page's commands run: a folder of their own, ``examples/`` linked in."""

    cwd: Path
    home: Path
    env: dict[str, str]
    procs: list[Proc]

    def start(self, command: str, *, endpoint: str | None = None, add: tuple[str, ...] = (),
              replace: dict[str, list[str]] | None = None, env: dict[str, str] | None = None
              ) -> Proc:
        proc = Proc(argv(command, endpoint=endpoint, home=self.home, add=add, replace=replace),
                    cwd=self.cwd, env={**self.env, **(env or {})})
        self.procs.append(proc)
        return proc

    def run(self, command: str, *, endpoint: str | None = None, add: tuple[str, ...] = (),
            replace: dict[str, list[str]] | None = None, env: dict[str, str] | None = None,
            status: int = 0) -> str:
        """Run it to its end; it must exit with ``status``. Its output."""
        return ended(self.start(command, endpoint=endpoint, add=add, replace=replace, env=env),
                     status=status)


def ended(proc: Proc, *, status: int = 0) -> str:
    """``proc``'s output once it has ended by itself with ``status``."""
    code = proc.finish()
    assert code == status, f"exit status {code}, not {status}:\n{proc}"
    return proc.output


def stopped(proc: Proc) -> str:
    """Ctrl-C: ``proc`` stops, exits 0, and says it stopped. Its output."""
    code = proc.interrupt()
    assert code == 0, f"exit status {code} after Ctrl-C:\n{proc}"
    assert "stopping (press Ctrl-C again to quit at once)" in proc.output, proc
    return proc.output


@contextlib.contextmanager
def page(tmp: Path) -> Iterator[Page]:
    """A :class:`Page` in ``tmp``; whatever it started is killed when the block ends."""
    cwd = tmp / "work"
    (cwd / "examples").mkdir(parents=True)
    for item in (ROOT / "examples").iterdir():
        if item.name != "fleets":
            (cwd / "examples" / item.name).symlink_to(item)
    fleets = cwd / "examples" / "fleets"
    fleets.mkdir()
    for fleet in (ROOT / "examples" / "fleets").glob("*.yaml"):
        text = fleet.read_text("utf-8")
        assert "router: tcp/127.0.0.1:7447\n" in text, fleet
        (fleets / fleet.name).write_text(
            text.replace("router: tcp/127.0.0.1:7447\n", f"router: tcp/127.0.0.1:{free_port()}\n"))
    home = tmp / "home"
    home.mkdir()
    here = Page(cwd, home, environment(home), [])
    try:
        yield here
    finally:
        for proc in here.procs:
            proc.kill()


def together(*steps: Callable[[], object]) -> None:
    """Run ``steps`` at the same time (each on a thread); fail as the first that fails."""
    with concurrent.futures.ThreadPoolExecutor(len(steps)) as pool:
        for future in [pool.submit(step) for step in steps]:
            future.result()


def loopback() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


# -- README.md: the quick start, and what to try while that robot runs --------------------------

QUICK_START = "python -m ubf_async.launch"
RANGE = "python -m components.range --connect tcp/127.0.0.1:7447 --name left --yaw-deg 45"
ECHO = "python -m ubf_async.inspector echo ubf/mini/sensor/range/left --count 3"
AVOID = "python examples/avoid_obstacles.py --connect tcp/127.0.0.1:7447"
TELEOP = "python examples/teleop_override.py --connect tcp/127.0.0.1:7447 --speed 30 --turn 0"
AVOID_BARE = "python examples/avoid_obstacles.py"  # (docs/protocol.md: the default endpoint)
TELEOP_BACK = "python examples/teleop_override.py --speed -30 --turn 50"
COMPONENTS = "python -m ubf_async.inspector components"
STATE = "python -m ubf_async.inspector state --watch"
HZ = "python -m ubf_async.inspector hz cmd/drive"
STATE_ONCE = "python -m ubf_async.inspector state"
ROS2_BRIDGE = "python -m ubf_async.ros2 --connect tcp/127.0.0.1:7447 --distro jazzy"


@dataclass
class Robot:
    endpoint: str
    proc: Proc
    page: Page
    started: float
    """``time.monotonic()`` when it was launched."""

    def tool(self) -> tuple[str, str]:
        """What a tool shown without ``--connect`` (the documented default) is given."""
        return ("--connect", self.endpoint)


@pytest.fixture(scope="class")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Robot]:
    """The README's quick start (on a free port instead of 7447): the robot every command
    shown "while a robot runs" attaches to. Stopped with Ctrl-C at the end."""
    endpoint = loopback()
    with page(tmp_path_factory.mktemp("readme")) as here:
        started = time.monotonic()
        proc = here.start(QUICK_START, add=("--listen", endpoint))
        proc.wait_for(r"^\[mini\] [\d.]+s \| drive .* \| tick [\d.]+Hz")
        yield Robot(endpoint, proc, here, started)
        stopped(proc)
        assert proc.lines[-1] == "ubf_async: stopped", proc
        assert "saving the run's results" not in proc.output  # none asked for (issue 35)


LIVEVIEW = "python -m ubf_async.liveview --connect tcp/127.0.0.1:7447"
LIVEVIEW_PORT = "python -m ubf_async.liveview --connect tcp/127.0.0.1:7447 --port 8765"
FOXGLOVE = "python -m ubf_async.launch --scenario ball-behind --foxglove"


def served_to_foxglove(proc: Proc, port: int) -> None:
    """``proc`` serves the robot at ``ws://127.0.0.1:PORT``: a Foxglove client gets the drive
    command from it, and ``proc`` says so when stopped."""
    proc.wait_for(rf"ws://127\.0\.0\.1:{port}\b")
    with FoxgloveClient(f"ws://127.0.0.1:{port}") as client:
        client.wait_for_topics({"/ubf/cmd/drive"})
        client.subscribe({"/ubf/cmd/drive"})
        [drive] = client.collect({"/ubf/cmd/drive"})["/ubf/cmd/drive"][:1]
    assert {"speed", "winners"} <= set(drive.decoded["data"]), drive.decoded


RECORD = "python -m ubf_async.record --connect tcp/127.0.0.1:7447 --out rec/ --duration 10"
RECORD_PROGRESS = ("python -m ubf_async.record --connect tcp/127.0.0.1:7447 --out rec/ "
                   "--progress")
REPLAY_REC = "python -m ubf_async.replay rec/mini.mcap --speed 2"
RECORD_RUN = ("python -m ubf_async.launch --scenario ball-in-sight --speed 5 --duration 20 "
              "--record out/")
FRESH_CONTROLLER = "python -m ubf_async.launch --no-sim --sim-time"
REPLAY_OUT = "python -m ubf_async.replay out/mini.mcap --speed 2"
RECORD_ORIGINALS = "python -m ubf_async.record --no-live-channels"


RECORDING = ("--duration", "2")  # the recorder's: wall-clock seconds


def fresh_controller(here: Page) -> tuple[Proc, str]:
    """docs/recording.md's fresh controller (same tree, no simulator), on a free port."""
    endpoint = loopback()
    return here.start(FRESH_CONTROLLER, add=("--listen", endpoint)), endpoint


def replayed(here: Page, replay: str, controller: tuple[Proc, str]) -> None:
    """``replay`` (its file recorded by now) into a fresh ``controller``: it replays every
    message, and the controller decides on them."""
    proc, endpoint = controller
    proc.wait_for(rf"listening on {endpoint}")
    since = len(proc.lines)
    out = here.run(replay, add=("--connect", endpoint))
    assert re.search(r"replaying \S+mini\.mcap onto robot 'mini' \(2x", out), out
    # How far behind it fell (said only past 10 ms) depends on the machine, not on the docs.
    assert re.search(r": [1-9]\d* messages replayed(, at worst \d+ ms behind|$)", out,
                     re.MULTILINE), out
    # the controller ticked on the recorded clock and inputs: a status line with a source
    proc.wait_for(r"^\[mini\] [\d.]+s \| drive .*\| camera/front \d+ms", after=since)
    stopped(proc)


class TestWhileTheQuickStartRobotRuns:
    """README.md's "Things to try" while a robot runs, each attaching to the quick start's
    robot (:func:`robot`, one for the class: stopped once these tests are done)."""

    @pytest.mark.slow
    @runs(QUICK_START)
    def test_the_quick_start_prints_its_endpoint_tree_and_status_line(
            self, robot: Robot) -> None:
        printed = robot.proc.output
        assert f"listening on {robot.endpoint}" in printed
        assert f"attach with: --connect {robot.endpoint} --robot mini" in printed
        assert "    seek_pink_ball <PriorityMerge>" in printed  # the tree
        # the status line: tick rate, a source with its age, the drive and who won, the sim's pace
        robot.proc.wait_for(r"^\[mini\] .*\| drive [-+]\d+/[-+]\d+ \(.+\) \| tick [\d.]+Hz.* \| "
                            r"sim [\d.]+s x[\d.]+ \| .*camera/front \d+ms")

    @pytest.mark.slow
    @runs(RANGE, ECHO)
    def test_a_second_range_finder_attaches_and_echo_shows_three_of_its_samples(
            self, robot: Robot) -> None:
        ranger = robot.page.start(RANGE, endpoint=robot.endpoint)
        echoed = robot.page.run(ECHO, add=robot.tool())
        samples = [line for line in echoed.splitlines()
                   if line.startswith("ubf/mini/sensor/range/left range #")]
        assert len(samples) == 3, echoed
        assert all('"model": "ir-10-80"' in line for line in samples), echoed
        stopped(ranger)

    @pytest.mark.slow
    @runs(AVOID, TELEOP, AVOID_BARE, TELEOP_BACK)
    def test_obstacle_avoidance_and_teleop_attach_and_teleop_outranks_the_tree(
            self, robot: Robot) -> None:
        since = len(robot.proc.lines)
        avoid = robot.page.start(AVOID, endpoint=robot.endpoint)
        teleop = robot.page.start(TELEOP, endpoint=robot.endpoint)
        teleop.wait_for(r"^\[teleop\] votes \d+: speed=\+30 turn=\+0 .*\| robot drive \+30/\+0 "
                        r"\(teleop\)")
        robot.proc.wait_for(r"\| drive \+30/\+0 \(teleop\) \|", after=since)
        avoid.wait_for(r"^\[avoid_obstacles\] votes \d+: .*\| robot drive ")
        for proc in (teleop, avoid):
            assert "clock: simulated time (ubf/mini/clock)" in proc.output, proc
            stopped(proc)
        # docs/protocol.md's forms of the two, on the default endpoint (given explicitly here)
        since = len(robot.proc.lines)
        avoid = robot.page.start(AVOID_BARE, add=robot.tool())
        back = robot.page.start(TELEOP_BACK, add=robot.tool())
        robot.proc.wait_for(r"\| drive -30/\+50 \(teleop\) \|", after=since)
        avoid.wait_for(r"^\[avoid_obstacles\] votes \d+: .*\| robot drive ")
        for proc in (back, avoid):
            stopped(proc)

    @pytest.mark.slow
    @runs(COMPONENTS, STATE, HZ, STATE_ONCE)
    def test_the_inspector_lists_components_watches_state_and_measures_drive_rates(
            self, robot: Robot) -> None:
        watch = robot.page.start(STATE, add=robot.tool())
        hz = robot.page.start(HZ, add=robot.tool())
        once = robot.page.start(STATE_ONCE, add=robot.tool())
        listed = robot.page.run(COMPONENTS, add=robot.tool()).splitlines()
        assert {"aggregator", "controller", "camera-front", "motors-main", "sim"} <= set(listed)
        watch.wait_for(r"^robot 'mini', controller: periodic mode, tick [\d.]+Hz")
        watch.wait_for(r"^  camera/front +age +\d+ ms")  # sources with their ages
        watch.wait_for(r"^last tick \('\*' = won")  # and why the robot did what it did
        hz.wait_for(r"^ubf/mini/cmd/drive: average rate [\d.]+ Hz")
        hz.wait_for(r"^  ticked by clock: average rate [\d.]+ Hz")
        state = ended(once)
        assert re.search(r"^robot 'mini', controller: periodic mode", state, re.M), once
        assert re.search(r"^drive: speed [-+]\d+ turn [-+]\d+  won by: ", state, re.M), once
        assert "\n# " not in state  # once: a single block
        stopped(watch)
        stopped(hz)

    @pytest.mark.slow
    @runs(LIVEVIEW, LIVEVIEW_PORT, FOXGLOVE)
    def test_the_robot_is_served_live_to_a_foxglove_client(
            self, robot: Robot, tmp_path: Path) -> None:
        # The README's liveview has the default port (8765), docs/liveview.md names it: each a
        # free port here, given with --port.
        ports = [free_port() for _ in range(3)]
        with page(tmp_path) as here:
            launched = here.start(FOXGLOVE, add=(str(ports[2]), "--listen", loopback()))
            # one at a time: each is a component named 'foxglove' on the robot
            for command, port in ((LIVEVIEW, ports[0]), (LIVEVIEW_PORT, ports[1])):
                view = robot.page.start(command, endpoint=robot.endpoint,
                                        add=() if "--port" in command else ("--port", str(port)),
                                        replace={"8765": [str(port)]})
                served_to_foxglove(view, port)
                assert re.search(r"\d+ of \d+ messages converted went to 1 Foxglove client",
                                 stopped(view)), view
            served_to_foxglove(launched, ports[2])
            assert re.search(r"live view: \d+ of \d+ messages converted went to 1 Foxglove client",
                             stopped(launched)), launched

    @pytest.mark.slow
    @runs(RECORD, RECORD_PROGRESS, REPLAY_REC, RECORD_RUN, FRESH_CONTROLLER, REPLAY_OUT,
          RECORD_ORIGINALS)
    def test_recordings_made_of_the_bus_replay_into_a_fresh_controller(
            self, robot: Robot, tmp_path: Path) -> None:
        with page(tmp_path) as recording_md:  # docs/recording.md's commands, in a folder of theirs
            controllers = [fresh_controller(robot.page), fresh_controller(recording_md)]

            def readme() -> None:  # record from another process, then replay
                # One recorder at a time: each is a component named 'recorder' on the robot.
                progress = recording_md.start(RECORD_PROGRESS, endpoint=robot.endpoint)
                progress.wait_for(r"^recorded [1-9]\d* messages \(0 dropped, \d+ queued\) to "
                                  r"rec/mini\.mcap$")
                assert re.search(r": [1-9]\d* messages and \d+ in the live view's Foxglove "
                                 r"channels in rec/mini\.mcap$", stopped(progress)), progress
                originals = recording_md.start(RECORD_ORIGINALS, add=robot.tool())
                originals.wait_for(r"recording robot 'mini' to recordings/mini\.mcap$")
                # only the original messages, none of the live view's channels
                assert re.search(r": [1-9]\d* messages in recordings/mini\.mcap$",
                                 stopped(originals)), originals
                out = robot.page.run(RECORD, endpoint=robot.endpoint, add=RECORDING)
                assert re.search(r": [1-9]\d* messages and \d+ in the live view's Foxglove "
                                 r"channels in rec/mini\.mcap$", out), out
                replayed(robot.page, REPLAY_REC, controllers[0])

            def recording() -> None:  # launch --record, then replay
                endpoint = loopback()
                run = recording_md.start(RECORD_RUN, add=(*SHORT_RUN, "--listen", endpoint))
                # launch --record's recorder is 'recorder' too: another needs another --name.
                # Its session is open: the second recorder waits for the robot, whose
                # recorder is alive before it (and for the run's 4 simulated s after it).
                run.wait_for(rf"^  attach with: --connect {endpoint} --robot mini$")
                second = recording_md.run(RECORD_PROGRESS, endpoint=endpoint, status=2)
                assert "a component named 'recorder' is already alive on robot 'mini'" in second
                assert "give this recorder another --name" in second
                out = ended(run)
                assert re.search(r"^\[mini\] [\d.]+s \| drive ", out, re.M), out
                assert "  expected: turns to the ball, approaches and stops" in out, out
                assert re.search(r"^  recorded [1-9]\d* messages and \d+ in the live view's "
                                 r"Foxglove channels to out/mini\.mcap$", out, re.M), out
                replayed(recording_md, REPLAY_OUT, controllers[1])

            together(readme, recording)

    @pytest.mark.slow
    @pytest.mark.asyncio
    async def test_readme_tools_joining_late_work_within_3_s(self, robot: Robot) -> None:
        """Issue 28, item 1 (tests/test_late_join.py): the README's teleop, obstacle avoidance
        and range finder, and the radio, joining this robot 10 s and more after its launch,
        each at work within 3 s."""
        await readme_tools_join_late(robot.endpoint, launched=robot.started)

    @pytest.mark.slow
    @runs(ROS2_BRIDGE)
    def test_the_ros2_bridge_attaches_to_the_running_robot(self, robot: Robot) -> None:
        # its status line sooner than every 5 s
        bridge = robot.page.start(ROS2_BRIDGE, endpoint=robot.endpoint,
                                  add=("--status-period-s", "0.5"))
        bridge.wait_for(r"^ROS 2 bridge of robot 'mini': node /mini/ubf_bridge, domain 0, "
                        r"jazzy; clock: ")
        bridge.wait_for(r"^\[ros2\] sent: .*/mini/odom [1-9]\d*.* \| cmd_vel_in: 0 taken, "
                        r"refused: none$")
        stopped(bridge)
        # It ends as the other tools do: a closing line with what it did (issue 35).
        assert re.fullmatch(r"python -m ubf_async\.ros2: stopped; sent: .*/mini/odom [1-9]\d*"
                            r".* \| cmd_vel_in: 0 taken, refused: none", bridge.lines[-1]), bridge


# -- docs/monitor.md: the tree in a browser; docs/protocol.md: live tree changes ----------------

MONITOR = "python -m ubf_async.monitor --connect tcp/127.0.0.1:7447"
MONITOR_LAUNCH = "python -m ubf_async.launch --scenario ball-behind --monitor"
MONITOR_ANY_PORT = "python -m ubf_async.launch --scenario keep-away --monitor 0"
MONITOR_READ_ONLY = ("python -m ubf_async.monitor --connect tcp/ROBOT_HOST:7447 --port 8771 "
                     "--read-only")
MONITOR_LISTEN = "python -m ubf_async.monitor --listen tcp/127.0.0.1:7450"
REPLAY_ALL = "python -m ubf_async.replay rec/mini.mcap --only ** --connect tcp/127.0.0.1:7450"
TREE_SHOW = "python -m ubf_async.inspector tree show"
TREE_ARBITER = ("python -m ubf_async.inspector tree set-arbiter seek_pink_ball MonteCarlo "
                "--param hold_ticks=5")
TREE_CHILD = ("python -m ubf_async.inspector tree set-child seek_pink_ball chase --priority 3 "
              "--weight 0.5")
TREE_LOAD = "python -m ubf_async.inspector tree load my-tree.yaml"
MY_TREE = """name: seek_pink_ball
arbiter: HighestPriority
children:
  - {behavior: search, priority: 2}
  - {behavior: chase, priority: 1}
"""
"""``my-tree.yaml`` for TREE_LOAD: the shipped tree without flee (a fragment: the tree's value)."""


def monitor_frame(port: int) -> tuple[dict, dict]:
    """The page of the monitor serving on ``port``, as a browser gets it: its ``hello`` and the
    first frame with a tick's trace."""
    import urllib.request

    import websockets.sync.client

    with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=WAIT_S) as response:
        assert "monitor.js" in response.read().decode()
    with websockets.sync.client.connect(f"ws://127.0.0.1:{port}/ws",
                                        open_timeout=WAIT_S) as ws:
        hello = json.loads(ws.recv(WAIT_S))
        assert hello["type"] == "hello", hello
        while True:
            message = json.loads(ws.recv(WAIT_S))
            if message["type"] == "frame" and message["trace"]:
                return hello, message


def served_to_browsers(proc: Proc, port: int) -> dict:
    """``proc`` serves the tree at ``http://127.0.0.1:PORT/`` to a page: its hello."""
    proc.wait_for(rf"http://127\.0\.0\.1:{port}/")
    hello, frame = monitor_frame(port)
    assert frame["trace"]["nodes"][0]["name"] == "seek_pink_ball", frame
    return hello


@pytest.mark.slow
@runs(MONITOR, MONITOR_LAUNCH, MONITOR_ANY_PORT, MONITOR_READ_ONLY, MONITOR_LISTEN, REPLAY_ALL,
      TREE_SHOW, TREE_ARBITER, TREE_CHILD, TREE_LOAD)
def test_the_tree_is_served_to_browsers_and_changed_live(tmp_path: Path) -> None:
    ports = [free_port() for _ in range(4)]
    with page(tmp_path) as here:
        (here.cwd / "my-tree.yaml").write_text(MY_TREE)

        def launched() -> None:  # launch --monitor, the tool on it, and protocol.md's verbs
            endpoint = loopback()
            robot = here.start(MONITOR_LAUNCH, add=(str(ports[0]), "--duration", "30",
                                                    "--listen", endpoint))
            assert served_to_browsers(robot, ports[0])["allow_changes"] is True
            view = here.start(MONITOR, endpoint=endpoint, add=("--port", str(ports[1])))
            served_to_browsers(view, ports[1])
            remote = here.start(MONITOR_READ_ONLY, replace={
                "tcp/ROBOT_HOST:7447": [endpoint], "8771": [str(ports[2])]})
            assert served_to_browsers(remote, ports[2])["allow_changes"] is False
            tool = ("--connect", endpoint)
            assert "seek_pink_ball <PriorityMerge>" in here.run(TREE_SHOW, add=tool)
            assert "seek_pink_ball <MonteCarlo(hold_ticks=5)>" in here.run(TREE_ARBITER, add=tool)
            assert re.search(r"chase \(Chase\) \[p=3 w=0\.5\]", here.run(TREE_CHILD, add=tool))
            loaded = here.run(TREE_LOAD, add=tool)
            assert "seek_pink_ball <HighestPriority>" in loaded and "flee" not in loaded, loaded
            robot.wait_for(r"\| tree changed 3 \|")
            for proc in (view, remote):
                stopped(proc)
            # a run whose tree was changed live ends with status 3 (README)
            assert robot.interrupt() == 3, robot

        def any_port() -> None:
            robot = here.start(MONITOR_ANY_PORT, add=(*SHORT_RUN, "--listen", loopback()))
            port = int(robot.wait_for(r"the tree live in a browser on "
                                      r"http://127\.0\.0\.1:(\d+)/")[1])
            served_to_browsers(robot, port)
            ended(robot)

        def replayed_to_it() -> None:  # a recording of its own, replayed whole to a monitor
            subprocess.run([sys.executable, "-m", "ubf_async.launch", "--scenario",
                            "ball-in-sight", "--speed", "max", "--duration", "2", "--quiet",
                            "--listen", "tcp/127.0.0.1:0", "--record", "rec/"],
                           cwd=here.cwd, env=here.env, check=True, capture_output=True,
                           timeout=WAIT_S)
            endpoint = {"tcp/127.0.0.1:7450": [loopback()]}
            monitor = here.start(MONITOR_LISTEN, replace=endpoint, add=("--port", str(ports[3])))
            monitor.wait_for(r"http://127\.0\.0\.1:\d+/")
            out = here.run(REPLAY_ALL, replace=endpoint)
            assert re.search(r"\*\*: \d+ keys", out) and "messages replayed" in out, out
            # the replayed run's last tick is on the page (no tree service: from the traces)
            _, frame = monitor_frame(ports[3])
            assert frame["trace"]["nodes"][0]["name"] == "seek_pink_ball"
            assert frame["ticks"] and frame["trace"]["t"] > 1.5, frame["trace"]["t"]
            stopped(monitor)

        together(launched, any_port, replayed_to_it)


# -- launch: the scenarios and robot files shown (README.md, scenarios.md, recording.md,
#    robot-file.md) ------------------------------------------------------------------------

KEEP_AWAY = ("python -m ubf_async.launch --scenario keep-away --speed 5 --summary "
             "out/summary.json --record out/")
KEEP_AWAY_MAX = ("python -m ubf_async.launch --scenario keep-away --speed max --summary "
                 "out/summary.json")
KEEP_AWAY_RECORDED = "python -m ubf_async.launch --scenario keep-away --speed 5 --record out/"
SYNC = "python -m ubf_async.launch --tick sync"
MY_ROBOT = "python -m ubf_async.launch my_robot.yaml"
MY_ROBOT_SCENARIO = "python -m ubf_async.launch my_robot.yaml [--scenario keep-away] [--speed 5]"
MY_ROBOT_CHECK = "python -m ubf_async.launch my_robot.yaml --check"
ROBOTFILE_CHECK = "python -m ubf_async.robotfile check my_robot.yaml"
PLUGINS = "python -m ubf_async.robotfile plugins"
SHORT_RUN = ("--duration", "4")  # simulated seconds: the scenarios run 60 s and more
WALL_FIELDS = {"wall_time_s", "real_time_factor", "real_time_factor_windows", "speed_requested",
               "warnings", "command_line", "recording"}
WALL_TICK_FIGURE = re.compile(r"tick_us_|periodic_jitter_ms_")  # not _robot_ms: robot time


@pytest.mark.slow
@runs(KEEP_AWAY, KEEP_AWAY_MAX, KEEP_AWAY_RECORDED, SYNC)
def test_the_scenarios_run_with_summary_pictures_and_recording_the_same_at_any_speed(
        tmp_path: Path) -> None:
    with (page(tmp_path / "readme") as readme, page(tmp_path / "flat-out") as flat_out,
          page(tmp_path / "recording") as recording_md):
        quiet = ("--listen", "tcp/127.0.0.1:0")
        runs_ = [readme.start(KEEP_AWAY, add=(*SHORT_RUN, *quiet)),
                 flat_out.start(KEEP_AWAY_MAX, add=(*SHORT_RUN, *quiet)),
                 recording_md.start(KEEP_AWAY_RECORDED, add=(*SHORT_RUN, *quiet)),
                 readme.start(SYNC, add=("--duration", "2", *quiet))]
        for run in runs_:
            out = ended(run)
            assert out.splitlines()[-1] == "ubf_async: stopped", run
        keep_away, max_, recorded, sync = (run.output for run in runs_)
        assert "controller: sync on each camera/front sample (the thesis's loop" in sync, sync
        assert re.search(r"^\[mini\] .*\| sync [\d.]+Hz \(camera/front\)", sync, re.M), sync
        for out in (keep_away, max_, recorded):
            assert "scenario 'keep-away'" in out
            assert "  expected: keeps turning the way it last saw the ball" in out
        for here in (readme, recording_md):  # the MCAP recording of the bus, and pictures
            assert (here.cwd / "out" / "mini.mcap").stat().st_size > 0
            assert list((here.cwd / "out").glob("frame_*.png"))
            assert (here.cwd / "out" / "trajectory.png").exists()
        assert "summary written to out/summary.json" in keep_away
        assert "summary written to out/summary.json" in max_
        assert not (recording_md.cwd / "out" / "summary.json").exists()
        # "the same run, byte for byte": all but the wall-clock figures
        summaries = [json.loads((here.cwd / "out" / "summary.json").read_text())
                     for here in (readme, flat_out)]
        assert summaries[0]["sim_time_s"] == 4.0
        for summary in summaries:
            for key in WALL_FIELDS:
                summary.pop(key, None)
            for key in [k for k in summary["ticks"] if WALL_TICK_FIGURE.match(k)]:
                summary["ticks"].pop(key)  # what a tick costs: CPU time
        assert summaries[0] == summaries[1]


@pytest.mark.slow
@runs(MY_ROBOT, MY_ROBOT_SCENARIO, MY_ROBOT_CHECK, ROBOTFILE_CHECK, PLUGINS)
def test_a_robot_file_is_checked_and_launched(tmp_path: Path) -> None:
    with page(tmp_path) as here:
        shutil.copy(ROBOT_FILE, here.cwd / "my_robot.yaml")  # a robot file of one's own
        robot = here.start(MY_ROBOT, add=("--listen", loopback()))
        scenario = here.start(MY_ROBOT_SCENARIO, add=(*SHORT_RUN, "--listen", "tcp/127.0.0.1:0"))
        checked = here.run(MY_ROBOT_CHECK)
        assert checked.splitlines()[0] == "my_robot.yaml: robot 'mini' — OK", checked
        assert "seek_pink_ball <PriorityMerge>" in checked  # the tree
        assert here.run(ROBOTFILE_CHECK).startswith("my_robot.yaml: robot 'mini', 6 device(s) ")
        plugins = here.run(PLUGINS)
        assert re.search(r"^ubf_async\.behaviors:", plugins, re.M), plugins
        assert re.search(r"\bchase\b", plugins), plugins
        robot.wait_for(r"^\[mini\] [\d.]+s \| drive .* \| tick [\d.]+Hz")
        assert "(my_robot.yaml)" in robot.output
        stopped(robot)
        out = ended(scenario)
        assert "scenario 'keep-away'" in out and "5x real time" in out, scenario


# -- fleets (README.md, fleet.md) ---------------------------------------------------------

ROUTER = "python -m ubf_async.router"
R1 = "python -m ubf_async.launch --robot r1 --mode client --connect tcp/127.0.0.1:7447"
R2 = "python -m ubf_async.launch --robot r2 --mode client --connect tcp/127.0.0.1:7447"
ROBOTS = "python -m ubf_async.inspector robots --connect tcp/127.0.0.1:7447"
PAIR = "python -m ubf_async.fleet examples/fleets/pair.yaml --summary fleet.json"
SEARCH = "python -m ubf_async.fleet examples/fleets/search.yaml --summary search.json"


@pytest.mark.slow
@runs(ROUTER, R1, R2, ROBOTS)
def test_two_robots_meet_at_a_router_and_the_inspector_lists_both(tmp_path: Path) -> None:
    endpoint = loopback()
    with page(tmp_path) as here:
        router = here.start(ROUTER, add=("--listen", endpoint))
        router.wait_for(rf"^router: listening on {endpoint}$")
        robots = [here.start(R1, endpoint=endpoint), here.start(R2, endpoint=endpoint)]
        for name, robot in zip(("r1", "r2"), robots, strict=True):
            robot.wait_for(rf"a client of the router at {endpoint}$")
            robot.wait_for(rf"^  attach with: --mode client --connect {endpoint} --robot {name}$")
        router.wait_for(r"robots alive: r1 \(11 components\), r2 \(11 components\)")
        listed = here.run(ROBOTS, endpoint=endpoint).splitlines()
        assert listed[0].split() == ["ROBOT", "COMPONENTS", "PERIODIC", "Hz", "ALL", "TICKS",
                                     "Hz", "MODE", "WINNING"], listed
        assert [row.split()[:2] for row in listed[1:]] == [["r1", "11"], ["r2", "11"]], listed
        assert all(" periodic " in row for row in listed[1:]), listed
        for proc in (*robots, router):
            stopped(proc)


@pytest.mark.slow
@runs(PAIR, SEARCH)
def test_fleets_run_in_one_world_and_write_their_summary_when_stopped(tmp_path: Path) -> None:
    # The fleet files run 30 s and 90 s at 1x: stopped with Ctrl-C once every robot ticks,
    # which writes the summary as the world's end does.
    with page(tmp_path) as here:
        often = ("--status-period-s", "0.5")  # the first status line sooner
        fleets = {"fleet.json": (here.start(PAIR, add=often), ["r1", "r2"]),
                  "search.json": (here.start(SEARCH, add=often), ["s1", "s2", "s3", "s4"])}
        for proc, names in fleets.values():
            proc.wait_for(r"^fleet t=[\d.]+s" + "".join(rf" \| {n} \d+Hz \S+" for n in names))
        for summary, (proc, names) in fleets.items():
            out = stopped(proc)
            for name in names:
                assert re.search(rf"^  {name}: \d+ ticks, ", out, re.M), proc
            written = json.loads((here.cwd / summary).read_text())
            assert sorted(written["robots"]) == names
            assert all(r["ticks"] > 0 for r in written["robots"].values()), written
            assert written["sim_time_s"] > 0


# -- sweeps (README.md, experiments.md) -----------------------------------------------------

SWEEP = "python -m ubf_async.sweep examples/sweeps/arbiters.yaml --out out/arbiters"
SWEEP_CHECK = "python -m ubf_async.sweep examples/sweeps/arbiters.yaml --check"
SWEEP_RESUME = "python -m ubf_async.sweep examples/sweeps/arbiters.yaml --out out/arbiters --resume"
ARBITERS = ROOT / "examples" / "sweeps" / "arbiters.yaml"


@pytest.mark.slow
@runs(SWEEP_CHECK, SWEEP, SWEEP_RESUME)
def test_the_arbiters_sweep_checks_runs_shortened_and_resumes(tmp_path: Path) -> None:
    # The sweep shown runs 40 runs, a minute on 2 cores: here one seed of 2 simulated s.
    with page(tmp_path) as here:
        checked = here.run(SWEEP_CHECK)
        assert checked.splitlines()[0] == (
            "examples/sweeps/arbiters.yaml: 40 runs: 2 values of tree.arbiter × 2 scenarios × "
            "10 seeds — OK"), checked
        spec = ARBITERS.read_text("utf-8")
        assert "seeds: {first: 1, last: 10}\n" in spec
        (here.cwd / "short.yaml").write_text(
            spec.replace("seeds: {first: 1, last: 10}\n", "seeds: [1]\nduration_s: 2\n"))
        short = {"examples/sweeps/arbiters.yaml": ["short.yaml"]}
        ran = here.run(SWEEP, replace=short)
        assert re.search(r"^running 4 runs on \d+ local worker process", ran, re.M), ran
        assert "4 runs: 4 ok, 0 failed;" in ran, ran
        out = here.cwd / "out" / "arbiters"
        for name in ("runs.csv", "cells.csv", "ball_distance_m.png", "journal.jsonl"):
            assert (out / name).is_file(), name
        table = (out / "runs.csv").read_bytes()
        resumed = here.run(SWEEP_RESUME, replace=short)
        assert "resuming out/arbiters: 4 runs done already" in resumed, resumed
        assert "running" not in resumed
        assert (out / "runs.csv").read_bytes() == table


# -- evolution (evolve.md) ----------------------------------------------------------------

EVOLVE_CHECK = "python -m ubf_async.evolve examples/evolve/mini-whegs.yaml --check"


@runs(EVOLVE_CHECK)
def test_the_worked_evolution_spec_checks(tmp_path: Path) -> None:
    with page(tmp_path) as here:
        checked = here.run(EVOLVE_CHECK).splitlines()
    assert checked[0] == ("examples/evolve/mini-whegs.yaml: population 16 × 10 generations "
                          "from mini-whegs.yaml (seed 1)"), checked
    assert checked[1] == ("  training: 6 scenarios × 2 seeds, 12 s each = 12 runs per "
                          "individual; held out: 10 scenarios × 2 seeds, 20 s each"), checked
    assert checked[-1] == "  — OK", checked


# -- secure mode (security.md) --------------------------------------------------------------

SECURE_INIT = ("python -m ubf_async.secure init ~/.ubf/mini-secure --robot-file my-robot.yaml "
               "--host 192.168.1.10 --host mini.local")
SECURE_SHOW = "python -m ubf_async.secure show ~/.ubf/mini-secure"
SECURE_EXPORT = ("python -m ubf_async.secure export ~/.ubf/mini-secure teleop inspector "
                 "--output laptop.tar.gz")
SECURE_ROBOT = ("python -m ubf_async.launch my-robot.yaml --listen tls/192.168.1.10:7447 "
                "--secure ~/.ubf/mini-secure")
SECURE_MKDIR = "mkdir -m 700 -p ~/.ubf/mini"
SECURE_UNPACK = "tar xzf laptop.tar.gz -C ~/.ubf/mini"
SECURE_TELEOP = ("python examples/teleop_override.py --connect tls/192.168.1.10:7447 --robot mini "
                 "--secure ~/.ubf/mini")
SECURE_INSPECTOR = ("python -m ubf_async.inspector components --connect tls/192.168.1.10:7447 "
                    "--robot mini --secure ~/.ubf/mini --identity inspector")


@pytest.mark.slow
@runs(SECURE_INIT, SECURE_SHOW, SECURE_EXPORT, SECURE_ROBOT, SECURE_MKDIR, SECURE_UNPACK,
      SECURE_TELEOP, SECURE_INSPECTOR)
def test_the_secure_set_up_step_by_step(tmp_path: Path) -> None:
    # The robot's address (192.168.1.10) is a free loopback port here, over TLS; its
    # certificate carries 127.0.0.1 instead.
    endpoint = f"tls/127.0.0.1:{free_port()}"
    host = {"192.168.1.10": ["127.0.0.1"]}
    with page(tmp_path) as here:
        shutil.copy(ROBOT_FILE, here.cwd / "my-robot.yaml")  # it has the remote slot teleop
        made = here.run(SECURE_INIT, replace=host)
        shown_ = here.run(SECURE_SHOW)
        secure = here.home / ".ubf" / "mini-secure"
        assert "the robot's certificate carries: 127.0.0.1, mini.local" in made, made
        for identity in ("robot", "inspector", "operator", "teleop"):
            assert f"--secure {secure} --identity {identity}" in made
            assert f"--secure {secure} --identity {identity}" in shown_
            assert (secure / "identities" / f"{identity}.key").stat().st_mode & 0o077 == 0
        assert {"acl.json", "passwords.txt", "secure.json", "ca.pem", "private"} <= {
            p.name for p in secure.iterdir()}
        here.run(SECURE_EXPORT)
        robot = here.start(SECURE_ROBOT, endpoint=endpoint)
        robot.wait_for(r"^\[mini\] [\d.]+s \| drive ")
        assert any(f"attach with: --connect {endpoint} --robot mini --secure {secure} "
                   f"--identity NAME" in line for line in robot.lines), robot.output
        here.run(SECURE_MKDIR)
        here.run(SECURE_UNPACK)
        laptop = here.home / ".ubf" / "mini"
        assert {p.name for p in (laptop / "identities").iterdir()} == {
            f"{n}.{x}" for n in ("teleop", "inspector") for x in ("json", "pem", "key")}
        assert not (laptop / "private").exists() and not (laptop / "passwords.txt").exists()
        since = len(robot.lines)
        teleop = here.start(SECURE_TELEOP, endpoint=endpoint)
        robot.wait_for(r"\| drive \+\d+/\+0 \(teleop\) \|", after=since)
        listed = here.run(SECURE_INSPECTOR, endpoint=endpoint).splitlines()
        assert {"controller", "motors-main", "teleop"} <= set(listed), listed
        stopped(teleop)
        stopped(robot)


# -- a real robot's commands (README.md, hardware.md), on gpiozero's mock pins -------------

MOTORS_CHECK = ("python -m components.motors --backend gpio --check --robot-file "
                "examples/robots/pi-whegs.yaml")
MOTORS_HELP = "python -m components.motors --help"
MOCK_PINS = {"GPIOZERO_PIN_FACTORY": "mock", "GPIOZERO_MOCK_PIN_CLASS": "mockpwmpin"}


@pytest.mark.slow
@runs(MOTORS_CHECK)
def test_the_wiring_check_runs_on_mock_pins_where_no_wheel_turns(tmp_path: Path) -> None:
    """The check needs a lifted robot with motors and encoders: on gpiozero's mock pins it
    runs every step, pulses the motors' pins, and reports — rightly — that no encoder saw a
    wheel turn. (tests/test_hw_launch.py checks the pulses on the pins.)"""
    with page(tmp_path) as here:
        out = here.run(MOTORS_CHECK, env=MOCK_PINS, status=1)
        assert "checking the wiring of examples/robots/pi-whegs.yaml: each wheel 1 s" in out
        for step in ("left forward", "left reverse", "right forward", "right reverse"):
            assert re.search(rf"^{step}: [\d.]+ ms for 1 s", out, re.M), out
        assert out.count("FAIL: the left encoder saw 0 edges") == 2, out
        assert out.splitlines()[-1] == "4 of 4 steps failed", out


PI_LAUNCH = "python -m ubf_async.launch examples/robots/pi-whegs.yaml"


def test_the_pi_robot_file_checks(tmp_path: Path) -> None:
    """``launch examples/robots/pi-whegs.yaml`` needs a Raspberry Pi's GPIO and I²C (see
    NOT_RUN): its file loads and checks, as launch does before anything starts."""
    with page(tmp_path) as here:
        out = here.run(PI_LAUNCH, add=("--check",))
        assert out.splitlines()[0] == "examples/robots/pi-whegs.yaml: robot 'pi-whegs' — OK", out


DEPLOY = ("python -m ubf_async.deploy my-robot.yaml --secure ~/.ubf/mini-secure --out "
          "ubf-robot-mini.service")
DEPLOY_README = ("python -m ubf_async.deploy examples/robots/pi-whegs.yaml --out "
                 "ubf-robot-pi-whegs.service")
SECURE_INIT = ("python -m ubf_async.secure init ~/.ubf/mini-secure --robot-file my-robot.yaml "
               "--host 192.168.1.10 --host mini.local")
BOARD_CHECK = "python -m ubf_async.launch my-robot.yaml --check"


BRINGUP = "python -m components.bringup examples/robots/pi-whegs.yaml --out bringup"
BRINGUP_MY = "python -m components.bringup my-robot.yaml"


@runs(BRINGUP, BRINGUP_MY)
def test_bring_up_off_a_board_says_what_each_device_needs(tmp_path: Path) -> None:
    """docs/hardware.md's bring-up, here where there is no GPIO, no I²C bus and no camera:
    every device fails on its own line saying what to do, the motors are left to their check,
    gpiozero's fallbacks are in the encoders' one line (not four warnings), exit status 1."""
    with page(tmp_path) as here:
        (here.cwd / "my-robot.yaml").write_text((ROOT / "examples" / "robots" /
                                                 "pi-whegs.yaml").read_text("utf-8"))
        for command in (BRINGUP, BRINGUP_MY):
            out = here.run(command, status=1)
            lines = dict(line.split(": ", 1) for line in out.splitlines() if ": " in line
                         and line[:4] in ("ok  ", "FAIL", "--  "))
            assert set(lines) == {"--    motors/main", "FAIL  encoders/wheels",
                                  "FAIL  range/front", "FAIL  range/left",
                                  "FAIL  camera/front", "FAIL  leds/panel"}, out
            assert "cannot open /dev/i2c-1" in lines["FAIL  range/front"]
            assert "(tried lgpio: " in lines["FAIL  encoders/wheels"]
            assert "PinFactoryFallback" not in out
            assert "(tried lgpio: " in lines["FAIL  leds/panel"]
            assert out.rstrip().endswith("5 of 6 devices failed")


CALIBRATE_COLOR = "python -m components.camera.calibrate my-robot.yaml --camera"
CALIBRATE_COLOR_RECT = ("python -m components.camera.calibrate my-robot.yaml --frames "
                        "calibration/frame-*.png --rect 493,650,294,294")
CALIBRATE_COLOR_DRY = CALIBRATE_COLOR_RECT + " --dry-run"


@runs(CALIBRATE_COLOR, CALIBRATE_COLOR_DRY, CALIBRATE_COLOR_RECT)
def test_the_cameras_colour_is_calibrated_as_shown(tmp_path: Path) -> None:
    """docs/hardware.md's colour calibration on the Pi robot file (as ``my-robot.yaml``) whose
    camera is a video of the simulated ball 45 cm ahead, at the page's rectangle: the frames
    are saved, the dry run writes nothing, the run writes the camera's seek_color and the
    file still checks."""
    import cv2

    from components.sim.world.config import Lighting
    from tests.test_calibrate_color import rendered

    scene = rendered(Lighting(), tmp_path / "rendered")
    assert str(scene.rect) == "493,650,294,294"  # the page's rectangle is the ball's
    with page(tmp_path) as here:
        video = here.cwd / "ball.avi"
        writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0,
                                 (1280, 1024))
        for frame in scene.frames:
            writer.write(cv2.imread(str(frame)))
        writer.release()
        robot_file = here.cwd / "my-robot.yaml"
        robot_file.write_text((ROOT / "examples" / "robots" / "pi-whegs.yaml").read_text(
            "utf-8").replace('source: "0"', "source: ball.avi"), "utf-8")
        assert "camera/front: 5 frames 1280×1024 saved: " in here.run(CALIBRATE_COLOR)
        frames = {"calibration/frame-*.png": [f"calibration/frame-{i}.png" for i in range(1, 6)]}
        before = robot_file.read_text("utf-8")
        out = here.run(CALIBRATE_COLOR_DRY, replace=frames)
        assert "+    params: {latency_s: 0.11, seek_color: {lo: [" in out
        assert robot_file.read_text("utf-8") == before
        out = here.run(CALIBRATE_COLOR_RECT, replace=frames)
        assert "written: my-robot.yaml (devices[4].params.seek_color: {lo: [" in out
        assert (here.cwd / "calibration" / "seek-color-front.png").is_file()
        assert "my-robot.yaml: robot 'pi-whegs' — OK" in here.run(BOARD_CHECK)


@runs(DEPLOY, DEPLOY_README, BOARD_CHECK)
def test_the_deploy_page_writes_units_systemd_accepts(tmp_path: Path) -> None:
    """docs/deploy.md's and the README's units, written as shown by a normal user (``pi``) for
    the Pi robot file (as ``my-robot.yaml``, with the page's secure set-up), check as launch
    does and pass ``systemd-analyze verify`` without a word (where it is installed)."""
    with page(tmp_path) as here:
        (here.cwd / "my-robot.yaml").write_text((ROOT / "examples" / "robots" /
                                                 "pi-whegs.yaml").read_text("utf-8"))
        assert "my-robot.yaml: robot 'pi-whegs' — OK" in here.run(BOARD_CHECK)
        here.run(SECURE_INIT)
        user = {"USER": "pi", "LOGNAME": "pi"}
        assert "unit written to ubf-robot-mini.service" in here.run(DEPLOY, env=user)
        here.run(DEPLOY_README, env=user)
        for unit in ("ubf-robot-mini.service", "ubf-robot-pi-whegs.service"):
            text = (here.cwd / unit).read_text("utf-8")
            assert "User=pi" in text and "SupplementaryGroups=gpio i2c video" in text
            if shutil.which("systemd-analyze") is not None:
                verified = subprocess.run(["systemd-analyze", "verify", unit], cwd=here.cwd,
                                          capture_output=True, text=True, timeout=60)
                assert (verified.returncode, verified.stdout + verified.stderr) == (0, ""), \
                    verified.stderr
        assert "--secure" in (here.cwd / "ubf-robot-mini.service").read_text("utf-8")


# -- benchmarks and tools shown --------------------------------------------------------------

LATENCY_HELP = "python -m bench.latency --help"
CPU_HOG = "python -m bench.cpu_hog -- python -m pytest ..."
CALIBRATE = "python -m components.sim.render.calibrate --update-doc docs/scenarios.md"


@runs(LATENCY_HELP)
def test_the_latency_bench_explains_itself(tmp_path: Path) -> None:
    with page(tmp_path) as here:
        out = here.run(LATENCY_HELP)
    assert "usage: python -m bench.latency [-h] [--quick] [--json FILE]" in out
    for section in ("floor", "reflex", "periodic", "obstacle", "camera", "peers"):
        assert section in out.split("--only", 1)[1]


@pytest.mark.slow
@runs(CPU_HOG, CALIBRATE)
def test_tests_run_beside_a_busy_loop_per_core_and_the_calibration_table_is_current(
        tmp_path: Path) -> None:
    with page(tmp_path) as here:
        (here.cwd / "docs").mkdir()
        shutil.copy(ROOT / "docs" / "scenarios.md", here.cwd / "docs")
        out = here.run(CALIBRATE)
        assert "updated the calibration table in docs/scenarios.md" in out
        # the table shown is the one the simulator renders now
        assert ((here.cwd / "docs" / "scenarios.md").read_text("utf-8")
                == (ROOT / "docs" / "scenarios.md").read_text("utf-8"))
        # `...`: a test of its own (the suite's own tests would take the busy machine long),
        # its pytest without the plug-ins installed here (hypothesis alone imports for 1.4 s,
        # many times that beside the hogs); after the calibration, which the hogs would only
        # slow down, with every other test running beside this one
        (here.cwd / "test_under_load.py").write_text(
            "import os\n\ndef test_the_cores_are_busy():\n    assert os.cpu_count()\n")
        hogged = here.start(CPU_HOG, replace={
            "...": ["test_under_load.py", "-q", "-p", "no:cacheprovider", "--rootdir", "."]},
            env={"PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1"})
        assert re.search(r"^1 passed", ended(hogged), re.M), hogged


LAUNCH_HELP = "python -m ubf_async.launch --help"
SCHEMA = "python -m ubf_async.robotfile schema"
SOAK_HELP = "python -m bench.soak --help"


@pytest.mark.slow
@runs(LAUNCH_HELP, SCHEMA, SOAK_HELP, MOTORS_HELP)
def test_the_helps_shown_list_what_the_pages_say_and_the_schema_is_the_shipped_one(
        tmp_path: Path) -> None:
    with page(tmp_path) as here:
        procs = [here.start(c) for c in (LAUNCH_HELP, SCHEMA, SOAK_HELP, MOTORS_HELP)]
        launch, schema, soak, motors = (ended(proc) for proc in procs)
    for option in ("--scenario", "--speed", "--summary", "--record", "--foxglove", "--tick",
                   "--duration", "--check", "--secure"):
        assert option in launch
    assert schema == (ROOT / "ubf_async" / "robot-file.schema.json").read_text("utf-8").rstrip()
    for option in ("--sim-s", "--warmup-s", "--record", "--limit-mib"):  # resources.md
        assert option in soak
    assert "--check" in motors.split("wiring check", 1)[1]  # hardware.md


CODEC = "python -m bench.codec"
SEEKCOLOR = "python -m bench.seekcolor"
SIM_CALIBRATE = "python -m components.sim.render.calibrate"
SIMSECOND = "python -m bench.simsecond"
TRACK_CALIBRATE = "python -m components.encoders.calibrate"


@pytest.mark.slow
@runs(CODEC, SEEKCOLOR, SIM_CALIBRATE, TRACK_CALIBRATE, SIMSECOND)
def test_the_quick_benchmarks_and_the_calibrations_shown(tmp_path: Path) -> None:
    with page(tmp_path) as here:
        procs = [here.start(c) for c in (CODEC, SEEKCOLOR, SIM_CALIBRATE, TRACK_CALIBRATE)]
        # where a simulated second goes, on one short run (its default: 3 runs of 25 s)
        procs.append(here.start(SIMSECOND, add=("--runs", "1", "--duration", "1")))
        codec, seekcolor, sim, track, simsecond = (ended(proc) for proc in procs)
    # decode + validate and encode of each message type, beside plain msgpack
    assert re.search(r"^drive +\d+ +[\d.]+ µs .* [\d.]+×$", codec, re.M), codec
    # seekcolor per frame vs a per-pixel Python loop
    assert re.search(r"^speed-up of seekcolor over the loop \(median / median\): \d+×$",
                     seekcolor, re.M), seekcolor
    # the simulated camera's pink count vs distance
    assert sim.splitlines()[1].split() == ["distance_m", "max_bin_mean", "min", "max",
                                           "total_mean"], sim
    assert re.search(r"^ +0\.45 +[\d.]+ +\d+ +\d+ +[\d.]+$", sim, re.M), sim
    # the effective track the simulated Mini-WHEGS has: 0.420 m (hardware.md, scenarios.md)
    [fitted] = re.findall(r"^effective track: ([\d.]+) m", track, re.M)
    assert round(float(fitted), 3) == 0.420, track
    parts = dict(re.findall(r"^(\S[^\n]*?) +([\d.]+)% +[\d.]+", simsecond, re.M))
    assert {"physics (pymunk + wheel forces)", "camera: render", "the event loop and the rest",
            "all (CPU time, every thread)"} <= set(parts), simsecond
    assert float(parts["all (CPU time, every thread)"]) == 100, simsecond


# -- ROS 2 (README.md, ros2.md) --------------------------------------------------------------

ROS2_ROUTER = "python -m ubf_async.router --listen tcp/0.0.0.0:7447"
ROS2_ROBOT = "python -m ubf_async.launch my_robot.yaml --mode client --connect tcp/127.0.0.1:7447"


def ros2_section() -> str:
    """ros2.md's robot-file section (its first yaml block)."""
    text = (ROOT / "docs" / "ros2.md").read_text("utf-8")
    section = text.split("```yaml\n", 1)[1].split("```", 1)[0]
    assert section.startswith("ros2:\n"), section
    return section


@pytest.mark.slow
@runs(ROS2_ROUTER, ROS2_ROBOT)
def test_ros2_sees_the_robot_through_a_router(tmp_path: Path) -> None:
    """ros2.md's two hosts on one: the router (on loopback, not 0.0.0.0), the robot with the
    page's ``ros2:`` section as a client, and the ROS side (tests/ros2_side.py) doing what
    the page's ros2 commands do: list the node and topics, echo odom, drive with Twists."""
    from tests.ros2_side import RosSide

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    with page(tmp_path) as here:
        (here.cwd / "my_robot.yaml").write_text(ROBOT_FILE.read_text("utf-8") + ros2_section())
        router = here.start(ROS2_ROUTER, endpoint=endpoint)
        router.wait_for(rf"^router: listening on {endpoint}$")
        robot = here.start(ROS2_ROBOT, endpoint=endpoint)
        robot.wait_for(r"ROS 2 bridge: /mini/ubf_bridge, domain 0, jazzy")
        robot.wait_for(r"^\[mini\] [\d.]+s \| drive ")
        ros = RosSide(port)
        try:
            # The graph as ``ros2 node list`` / ``topic list`` see it, asked again until the
            # bridge is in it: each asking is a liveliness query answered within 1 s, and on a
            # busy machine the first may be answered before the router has the bridge's
            # tokens (it came back empty beside bench.cpu_hog).
            deadline = time.monotonic() + 30
            while True:
                ros.send(op="list")
                listed = ros.wait("list")
                seen = (any(node.endswith("/NN/%/%mini/ubf_bridge") for node in listed["nodes"])
                        and ["/mini/odom", ["nav_msgs/msg/Odometry"]] in listed["topics"])
                if seen or time.monotonic() > deadline:
                    break
            assert any(node.endswith("/NN/%/%mini/ubf_bridge") for node in listed["nodes"]), listed
            assert ["/mini/odom", ["nav_msgs/msg/Odometry"]] in listed["topics"], listed
            ros.send(op="sub", topic="/mini/odom", type="nav_msgs/msg/Odometry")
            ros.wait("subscribed")
            since = len(robot.lines)
            ros.send(op="pub", topic="/mini/cmd_vel_in", linear=0.034, angular=0.0,
                     rate_hz=20, count=40)  # speed +10 for 2 s
            robot.wait_for(r"\| drive \+10/\+0 \(teleop\) \|", after=since)
            ros.wait("pub_done")
            assert ros.received("/mini/odom"), "no odom message"
        finally:
            ros.close()
        stopped(robot)
        stopped(router)
