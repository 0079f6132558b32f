"""Issue 50, item 4: a robot started at boot — ``python -m ubf_async.deploy`` writes a systemd
unit for a robot file, which ``systemd-analyze verify`` accepts without a word."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ubf_async.tools import deploy

ROOT = Path(__file__).resolve().parent.parent
PI = ROOT / "examples" / "robots" / "pi-whegs.yaml"


def deploy_main(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """``python -m ubf_async.deploy ARGV``, in this process: its status, stdout and stderr."""
    code = deploy.main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def secure_set_up(folder: Path) -> Path:
    folder.mkdir(mode=0o700)
    (folder / "secure.json").write_text("{}")  # (the unit only names the folder)
    return folder


def test_the_unit_starts_the_robot_file_as_a_user_in_its_devices_groups(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    unit = tmp_path / "robot.service"
    secure = secure_set_up(tmp_path / "mini secure")
    code, out, err = deploy_main([str(PI), "--user", "pi", "--secure", str(secure),
                                           "--group", "dialout", "--out", str(unit)], capsys)
    assert (code, err) == (0, ""), err
    assert f"unit written to {unit}" in out
    lines = unit.read_text().splitlines()
    assert "User=pi" in lines
    assert "SupplementaryGroups=dialout gpio i2c video" in lines  # gpio, i2c, ads1115, video
    assert "Restart=on-failure" in lines and "KillSignal=SIGTERM" in lines
    assert "Wants=network-online.target" in lines and "WantedBy=multi-user.target" in lines
    exec_start = next(line for line in lines if line.startswith("ExecStart="))
    assert exec_start == (f"ExecStart={sys.executable} -m ubf_async.launch {PI} --listen "
                          f"tls/0.0.0.0:7447 --status-period-s 60 --secure \"{secure}\" "
                          f"--identity robot")
    assert not any(line.startswith("# Open mode") for line in lines)


def test_a_path_is_quoted_and_its_percent_signs_doubled() -> None:
    assert deploy.systemd_quote("/home/pi/robot.yaml") == "/home/pi/robot.yaml"
    assert deploy.systemd_quote("/home/pi/my robot/100%.yaml") == \
        '"/home/pi/my robot/100%%.yaml"'
    assert deploy.systemd_quote('a"b\\c') == '"a\\"b\\\\c"'
    assert deploy.systemd_text("/home/pi/my robot/100%") == "/home/pi/my robot/100%%"


@pytest.mark.skipif(shutil.which("systemd-analyze") is None,
                    reason="systemd-analyze is not installed here")
@pytest.mark.parametrize("secure", [False, True], ids=["open", "secure"])
def test_systemd_analyze_verify_accepts_the_unit_without_a_word(
        tmp_path: Path, secure: bool, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "100% my robot"  # a path systemd must be told with care
    folder.mkdir()
    robot_file = folder / "pi-whegs.yaml"
    robot_file.write_text(PI.read_text())
    unit = tmp_path / "ubf-robot-pi-whegs.service"
    flags = ["--secure", str(secure_set_up(tmp_path / "set-up"))] if secure else []
    code, _, err = deploy_main([str(robot_file), "--user", "pi", *flags,
                                         "--out", str(unit)], capsys)
    assert code == 0, err
    verified = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True,
                              text=True, timeout=60)
    assert verified.returncode == 0 and verified.stdout + verified.stderr == "", \
        verified.stdout + verified.stderr
    broken = tmp_path / "broken.service"  # and it does say a word when there is one
    broken.write_text(unit.read_text().replace("Type=exec", "Type=bogus"))
    said = subprocess.run(["systemd-analyze", "verify", str(broken)], capture_output=True,
                          text=True, timeout=60)
    assert "Failed to parse service type" in said.stderr


@pytest.mark.parametrize(("argv", "said"), [
    (["no-such.yaml", "--user", "pi"], "no-such.yaml: no such robot file"),
    ([str(PI), "--user", "root"], "the robot does not run as root"),
    ([str(PI), "--user", "pi", "--secure", "."], "no secure set-up there"),
])
def test_a_mistake_writes_nothing_and_says_why(tmp_path: Path, argv: list[str], said: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    unit = tmp_path / "u.service"
    code, _, err = deploy_main([*argv, "--out", str(unit)], capsys)
    assert code == 2 and said in err, err
    assert not unit.exists()


def test_a_robot_file_that_does_not_load_gets_no_unit(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: 1\nname: bad\ntree:\n  name: r\n  arbiter: PriorityMerge\n"
                   "  children:\n    - behavior: chasee\n")
    code, _, err = deploy_main([str(bad), "--user", "pi", "--out",
                                         str(tmp_path / "u.service")], capsys)
    assert code == 2 and "bad.yaml:7" in err and "chasee" in err, err
    assert not (tmp_path / "u.service").exists()
