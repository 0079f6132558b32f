"""Evolution and tuning (python -m ubf_async.evolve, python -m ubf_async.tune): a tiny
evolution writes every output well within a minute; one worker and two give the same bytes;
an evolution killed outright resumes to the uninterrupted one's result; a bad SPEC is refused
at its line before anything runs; a tuning study kept in a storage resumes.

The evolution here is tiny: a population of 4 for 3 generations, each individual scored on
2 scenarios (a built-in and a generated one) of half a simulated second, held out on one
generated scenario.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import REPOSITORY, repository_env
from ubf_async.assembly.robotfile import load_robot
from ubf_async.runs.evolve import scenarios
from ubf_async.tools.evolve import main
from ubf_async.tools.tune import main as tune_main

SPEC = """\
seed: 3
population: 4
generations: 3
elites: 1
tournament: 2
parsimony: 0.001
genome:
  max_depth: 3
  max_nodes: 8
  priorities: [0, 3]
  behaviors:
    search: {speed: [0, 40], period_s: [1.0, 8.0]}
    chase: {speed: [10, 80]}
    flee: {start_pixels: [60, 220]}
    stop: {}
  arbiters: {PriorityMerge: {}, HighestPriority: {}, MonteCarlo: {hold_ticks: [1, 25]},
             Conditional: {}}
  predicates: {sees_color: {min_pixels: [1, 250]}}
training:
  scenarios: [ball-in-sight, {generate: behind}]
  seeds: [1]
  duration_s: 0.5
held_out:
  seed: 9
  scenarios: [{generate: random}]
  seeds: [5]
  duration_s: 0.5
fitness:
  terms:
    - {figure: ball_distance_m, target: 0.45, weight: -1.0, missing: 2.0}
    - {figure: ball_view.facing_share, weight: 1.0}
  worst: 0.5
tune:
  trials: 2
  parameters:
    tree.children[0].params.period_s: [1.0, 8.0]
    tree.children[1].params.speed: [10.0, 80.0]
"""
SAME_BYTES = ("log.jsonl", "best.yaml", "checkpoint.json", "heldout.csv", "report.md")
WAIT_S = 120.0  # for a first checkpoint, on a loaded machine


@pytest.fixture(scope="module")
def spec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("spec") / "tiny.yaml"
    path.write_text(SPEC)
    return path


@pytest.fixture(scope="module")
def uninterrupted(spec: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny evolution on one worker, and how long it took."""
    out = tmp_path_factory.mktemp("one") / "out"
    start = time.monotonic()
    assert main([str(spec), "--out", str(out), "--workers", "1"]) == 0
    (out / "took_s").write_text(str(time.monotonic() - start))
    return out


def same_bytes(a: Path, b: Path) -> None:
    for name in SAME_BYTES:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert sorted(p.name for p in (a / "hall-of-fame").iterdir()) == \
        sorted(p.name for p in (b / "hall-of-fame").iterdir())


def test_a_tiny_evolution_writes_every_output_well_within_a_minute(uninterrupted: Path) -> None:
    out = uninterrupted
    assert float((out / "took_s").read_text()) < 60.0
    log = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [e["generation"] for e in log] == [0, 1, 2]
    # The seed robot is in the first population and the elites are kept: never worse.
    bests = [e["best"]["fitness"] for e in log]
    assert bests == sorted(bests)
    assert log[0]["children"] == {"first": 3, "seed": 1}
    assert all(sum(e["children"].values()) == 4 for e in log)
    best = load_robot(out / "best.yaml")  # a robot file launch runs
    assert best.name == "mini" and best.simulators() == ["mini-whegs"]
    assert log[-1]["hall_of_fame"]["hash"] in {p.stem.split("-")[1]
                                               for p in (out / "hall-of-fame").iterdir()}
    front = sorted((out / "pareto").iterdir())
    assert front and all(load_robot(p).root for p in front)
    rows = list(csv.DictReader((out / "heldout.csv").read_text().splitlines()))
    assert [r["robot"] for r in rows] == ["shipped", "evolved"]
    assert all(math.isfinite(float(r["fitness"])) for r in rows)
    assert (out / "fitness.png").stat().st_size > 1000
    assert (out / "scenarios" / "training" / "training-behind-0.json").is_file()
    assert (out / "scenarios" / "held-out" / "held-out-random-0.json").is_file()


def test_one_worker_and_two_give_the_same_bytes(spec: Path, uninterrupted: Path,
                                                tmp_path: Path) -> None:
    assert main([str(spec), "--out", str(tmp_path / "two"), "--workers", "2"]) == 0
    same_bytes(uninterrupted, tmp_path / "two")


@pytest.mark.slow
def test_a_killed_evolution_resumes_to_the_uninterrupted_result(spec: Path, uninterrupted: Path,
                                                                tmp_path: Path) -> None:
    out = tmp_path / "killed"
    said = tmp_path / "stderr.txt"
    with said.open("wb") as stderr:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ubf_async.evolve", str(spec), "--out", str(out),
             "--workers", "2"], cwd=REPOSITORY, env=repository_env(),
            stdout=subprocess.DEVNULL, stderr=stderr, start_new_session=True)
    checkpoint = out / "checkpoint.json"
    deadline = time.monotonic() + WAIT_S
    try:
        while not checkpoint.exists():
            assert proc.poll() is None, said.read_text()
            assert time.monotonic() < deadline, "no checkpoint"
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGKILL)  # its workers too: nothing ends cleanly
    finally:
        proc.wait(30)
    killed_at = json.loads(checkpoint.read_text())["generation"]
    assert killed_at < 2, "the evolution ended before it was killed"
    assert not (out / "best.yaml").exists()
    assert main([str(spec), "--out", str(out), "--workers", "1", "--resume"]) == 0
    same_bytes(uninterrupted, out)


BAD = {
    "unknown behaviour": ("    stop: {}\n", "    stop: {}\n    wander: {}\n", 16,
                          "unknown behaviour 'wander'"),
    "range outside the schema": ("chase: {speed: [10, 80]}", "chase: {speed: [10, 180]}", 13,
                                 "behaviour 'chase': the range's high end 180"),
    "figure the summary lacks": ("figure: ball_view.facing_share",
                                 "figure: ball_view.facing_time", 31,
                                 "figure 'ball_view.facing_time': a run's summary has no such "
                                 "field (the nearest: ball_view.facing_share"),
    "an int range given as floats": ("flee: {start_pixels: [60, 220]}",
                                     "flee: {start_pixels: [60.5, 220]}", 14,
                                     "start_pixels is an int"),
    "Conditional without predicates": ("  predicates: {sees_color: {min_pixels: [1, 250]}}\n",
                                       "", 17, "Conditional needs a predicate"),
    "tune path that leads nowhere": ("tree.children[1].params.speed",
                                     "tree.children[7].params.speed", 37,
                                     "tree.children has 5 item(s)"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_spec_is_refused_at_its_line_before_anything_runs(
        case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    old, new, line, message = BAD[case]
    assert old in SPEC
    path = tmp_path / "bad.yaml"
    path.write_text(SPEC.replace(old, new))
    assert main([str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"python -m ubf_async.evolve: error: {path}:{line}: "), err
    assert message in err, err
    assert not (tmp_path / "out").exists()


def test_every_mistake_of_form_in_an_evolve_or_tune_spec_is_told_at_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(SPEC.replace("population: 4", "population: four")
                    .replace("  seeds: [1]\n", "  seeds: 1\n", 1)
                    .replace("weight: 1.0}", "weight: 1.0, wieght: 2}")
                    .replace("  trials: 2", "  trials: -2"))
    assert main([str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == f"python -m ubf_async.evolve: error: {path}: 4 mistakes:", err
    assert [line.split(": ", 1)[0] for line in err[1:]] == [
        f"  {path}:{n}" for n in (2, 21, 31, 34)], err
    assert err[1].endswith("Expected `int`, got `str` (at population)"), err
    assert err[2].endswith("training.seeds must be a list of seeds: write [1]"), err
    assert "unknown field `wieght`" in err[3], err
    assert err[4].endswith("(at tune.trials)"), err
    assert not (tmp_path / "out").exists()
    # The tuner reads the same spec, and tells the same.
    from ubf_async.tools.tune import main as tune_main
    assert tune_main([str(path), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.splitlines()[1:] == err[1:]


def test_an_evolution_whose_best_is_the_seed_says_so(tmp_path: Path) -> None:
    """Nothing evolved beat the seed robot: the report says the best tree is the seed's, and
    that the held-out lines are the same for that reason."""
    from ubf_async.runs.evolve.driver import EvolveOutputs
    from ubf_async.tools.evolve import report

    for is_seed in (True, False):
        said = io.StringIO()
        report(EvolveOutputs(out_dir=tmp_path, best=tmp_path / "best.yaml", generations=2,
                             best_fitness=0.5, seed_fitness=0.5, held_out=[], ran=0,
                             best_is_seed=is_seed), said)
        lines = said.getvalue().splitlines()
        assert ("  the best tree is the seed robot's own: no tree evolved beat it on the "
                "training set (more generations, a larger population or other operators may)"
                in lines) is is_seed
        assert ("held out (the evolved robot is the seed's tree: the same figures):" in lines
                ) is is_seed
    assert "trees.png" in main.__globals__["EXAMPLE"]  # the help lists every output


def test_generated_scenarios_are_the_same_for_a_seed_and_where_their_kind_says() -> None:
    import random

    first = scenarios.generate("fov_edge", 4, rng=random.Random(7), prefix="t", duration_s=5)
    again = scenarios.generate("fov_edge", 4, rng=random.Random(7), prefix="t", duration_s=5)
    assert first == again
    for kind, (low, high) in (("behind", (150, 210)), ("fov_edge", (14, 21))):
        for made in scenarios.generate(kind, 5, rng=random.Random(1), prefix="t", duration_s=5):
            data = json.loads(made.text)
            heading = math.radians(data["robot"]["heading_deg"])
            bearing = math.degrees(math.atan2(data["ball"]["y_m"], data["ball"]["x_m"])
                                   - heading) % 360
            bearing = min(bearing, 360 - bearing) if kind == "fov_edge" else bearing
            assert low - 0.1 <= bearing <= high + 0.1, (kind, bearing)
    moving = json.loads(scenarios.generate("moving", 1, rng=random.Random(2), prefix="t",
                                           duration_s=5)[0].text)
    assert list(moving["ball_script"][0]) == ["at_s", "speed_m_s", "move_to"]


def test_a_tune_study_kept_in_a_storage_resumes(spec: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    storage = f"sqlite:///{tmp_path / 'study.db'}"
    out = tmp_path / "tune"
    args = [str(spec), "--out", str(out), "--storage", storage, "--workers", "1"]
    # What it would do, checked first: the parameters by their names.
    assert tune_main([str(spec), "--check"]) == 0
    checked = capsys.readouterr().out.splitlines()
    assert checked[0] == f"{spec}: 2 parameters of mini-whegs.yaml, 2 trials (tpe, seed 3) — OK"
    assert checked[1:3] == [
        "  search.period_s: float in [1, 8], from 4  (tree.children[0].params.period_s)",
        "  chase.speed: float in [10, 80], from 40  (tree.children[1].params.speed)"]
    assert not out.exists()
    assert tune_main(args) == 0
    first = capsys.readouterr().out
    # A line per trial, with the count, the time spent and left; the best by name; and the
    # caution that an importance ranking of 2 trials is noise.
    assert re.search(r"^  trial 0 \(1/2\): \S+ \(best \S+\); \d+:\d\d elapsed, about "
                     r"\d+:\d\d left$", first, re.M), first
    assert re.search(r"^  trial 1 \(2/2\): \S+ \(best \S+\); \d+:\d\d elapsed$", first,
                     re.M), first
    assert re.search(r"best \S+: search.period_s = \S+, chase.speed = \S+$", first, re.M), first
    assert "caution: importance.png's ranking is from 2 trials, noise below 20" in first
    before = (out / "trials.csv").read_text().splitlines()
    assert len(before) == 3 and before[0] == "trial,state,value,search.period_s,chase.speed"
    # The first trial is the robot file's own values.
    assert before[1].endswith(",4.0,40.0"), before
    assert tune_main([*args, "--trials", "3"]) == 0
    second = capsys.readouterr().out
    assert "trial 0 " not in second and "  trial 2 (3/3): " in second, second
    after = (out / "trials.csv").read_text().splitlines()
    assert after[:3] == before and len(after) == 4
    assert load_robot(out / "best.yaml").name == "mini"
    assert (out / "history.png").is_file()
    rows = list(csv.DictReader((out / "heldout.csv").read_text().splitlines()))
    assert [r["robot"] for r in rows] == ["shipped", "tuned"]
