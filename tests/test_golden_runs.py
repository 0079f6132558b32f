"""The shipped Mini-WHEGS's runs, pinned by digest (issue 49: bodies became data without moving
them).

Every built-in scenario is run for its first :data:`SECONDS` simulated seconds in this process
(:func:`ubf_async.experiment.run`, the scenario's seed) and the sha256 of its
``trajectory.csv`` and of its summary — without the fields that measure the machine — must be
the ones recorded before the body, the mounts and the lenses were read from the robot file.
A change that means to move the thesis robot's runs updates :data:`GOLDEN` and says why;
anything else that moves them is a regression.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pytest

from components.sim.scenarios.scenario import builtin_names
from ubf_async import experiment

SECONDS = 4.0
"""Long enough for every scenario's robot to turn, drive and see the ball; short for the suite."""

MACHINE = ("wall_time_s", "real_time_factor", "real_time_factor_windows", "command_line")
"""The summary's fields that measure the machine, not the run (as tests/test_experiment.py)."""
MACHINE_TICKS = ("periodic_jitter_ms_p99", "tick_us_p50", "tick_us_max")

GOLDEN: dict[str, tuple[str, str]] = {
    "ball-behind": ("b9d1175843d7ce63a22d34cac8ad2a854f58b3fadd237380f15cdf7d7d75d4af",
                    "b3a7b2c6ae70f75acce519ce087137060a8a96d2efd2673fad9d3eb748fc2fe7"),
    "ball-held-close": ("b5634732804781aab4f0c9504bbebe7fea9870f132fd3e8e2f231ba570d724da",
                        "95d531ff72a3270285bf42f9edad4ffddfa4920f2d0f9efbfcb4589dfe086822"),
    "ball-in-sight": ("d8bc9c6879f429d56b317bd231cbbaa4361edbb3c64ed4e2894f231bff90eb67",
                      "75d7bc63c964944c139b690c55c9bf0ed31be41706c65d3b10e6805033e64d93"),
    "ball-in-sight-orange": ("d8bc9c6879f429d56b317bd231cbbaa4361edbb3c64ed4e2894f231bff90eb67",
                             "74652660bf2fc219cbdf4c9dcbec85a070a07624589673f6f6cea96dc90c6a50"),
    "busy-room": ("3d06dcfaf4163c68f63d7203e3bed84fb5878ae21c196553c6f29ac611c004bc",
                  "c06785bded52180778f962bd45a28fa38be6319ee7bd2c857d2460054776f529"),
    "dance": ("86ea828610dd7dce53953aff7708460e8fcccf4009b6e9f1e59cc04b8f495577",
              "09afe469b7662f86717e4941a5afc3ed98b91d9058dae5cce5bd11aa1a904ba7"),
    "fleet-search": ("fdd631ae4ff88094058c989935ee2db9f2b8942b54f36b83b8bac70b97c34e76",
                     "969c179d86b99318272940ae1c5445182203bd65b88d03a318c16373d380938e"),
    "keep-away": ("c03eeb1b544f8e80101071464be9025c162ce2fa03f7f4cd4a553cd394c18273",
                  "7e21390e21582d4f49dead1fafebf8e9bbdb5d27c84899337b2b6bd1293e8092"),
    "obstacle-course": ("9f169ba81d1cfaebde986f307440d95ef43264523e07c4048645d1450fcfbbd4",
                        "a3a66b2dcfca4cfbd4b47417ac77a665e9a47cc4fd01d3ece49f0295fea308d2"),
}


def digests(folder: Path) -> tuple[str, str]:
    """sha256 of a run's ``trajectory.csv`` and of its summary without the machine's fields."""
    summary: dict[str, Any] = json.loads((folder / "summary.json").read_text())
    for key in MACHINE:
        summary.pop(key, None)
    for key in MACHINE_TICKS:
        summary.get("ticks", {}).pop(key, None)
    csv = (folder / "trajectory.csv").read_bytes()
    return (hashlib.sha256(csv).hexdigest(),
            hashlib.sha256(json.dumps(summary, sort_keys=True).encode()).hexdigest())


def test_every_built_in_scenario_is_pinned() -> None:
    assert sorted(GOLDEN) == builtin_names()


@pytest.mark.parametrize("scenario", sorted(GOLDEN))
def test_the_mini_whegs_run_has_not_moved(scenario: str, tmp_path: Path) -> None:
    experiment.run("mini-whegs", scenario, duration_s=SECONDS, out_dir=tmp_path)
    trajectory, summary = digests(tmp_path)
    assert (trajectory, summary) == GOLDEN[scenario]
