"""launch --trajectory FILE.csv: the trajectory alone, without recording the bus (what the
suite's shared launches write, tests/shared_runs.py; its bytes are the in-process run's,
tests/test_experiment.py). Here: what it refuses, before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from ubf_async.errors import ConfigurationError
from ubf_async.tools import launch


@pytest.mark.parametrize(("argv", "message"), [
    (["--scenario", "ball-in-sight", "--trajectory", "{tmp}/t.csv", "--record", "{tmp}/rec"],
     "--trajectory: --record {tmp}/rec writes the trajectory already"),
    (["--scenario", "ball-in-sight", "--trajectory", "{tmp}"],
     "--trajectory {tmp}: is a directory; give a file name"),
    (["--no-sim", "--trajectory", "{tmp}/t.csv"],
     r"--trajectory: there is no simulator \(--no-sim is given\)"),
])
def test_what_launch_trajectory_refuses(tmp_path: Path, argv: list[str], message: str) -> None:
    with pytest.raises(ConfigurationError, match=message.format(tmp=tmp_path)):
        launch.plan_launch(launch.parse_args([word.format(tmp=tmp_path) for word in argv]))
    assert not (tmp_path / "t.csv").exists()
