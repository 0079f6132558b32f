"""Sweeps (ubf_async.runs.sweep, python -m ubf_async.sweep): the table is the same bytes for one
worker, two workers and Ray; a killed sweep resumes to the table of an uninterrupted one; a run
that fails is recorded and the others complete; a bad spec is refused at its line before
anything runs.

The sweep here is small: the shipped robot and a variant whose camera reads a video file that
is not there (a real failure: the device cannot be built, so the run raises), two arbiters,
two seeds, 2 simulated seconds of ball-in-sight — 8 runs, 4 of them failing at once.
"""

from __future__ import annotations

import csv
import io
import logging
import os
import selectors
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import pytest

from components.sim.scenarios.scenario import load_scenario
from tests.conftest import REPOSITORY, repository_env
from ubf_async.errors import ConfigurationError
from ubf_async.runs import sweep
from ubf_async.runs.sweep import execution, table
from ubf_async.runs.sweep.execution import RunRecord
from ubf_async.runs.sweep.journal import HEADER, JOURNAL, Journal, read_journal
from ubf_async.runs.sweep.spec import RunTask
from ubf_async.tools.sweep import main, report

ROBOT = REPOSITORY / "ubf_async" / "robots" / "mini-whegs.yaml"
SPEC = """\
robots: [mini-whegs, video-camera.yaml]
overrides:
  tree.arbiter: [PriorityMerge, UtilityFusion]
scenarios: [ball-in-sight]
seeds: [1, 2]
duration_s: 2
figures: [ball_distance_m, contacts.time_s]
"""
RUNS = 8
MISSING_VIDEO = "ConfigurationError: camera.video: cannot open video file 'no-such-video.mp4'"
WAIT_S = 120.0  # for a sweep's first run, on a loaded machine


def video_camera_robot() -> str:
    """The shipped robot with its camera reading a video file that is not there."""
    text = ROBOT.read_text()
    camera = "    name: front\n    backend: sim\n    params: {latency_s: 0.11}"
    assert camera in text
    return text.replace(camera, "    name: front\n    backend: video\n"
                                 "    backend_params: {source: no-such-video.mp4}\n"
                                 "    params: {latency_s: 0.11}")


@pytest.fixture(scope="module")
def spec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("spec")
    (folder / "video-camera.yaml").write_text(video_camera_robot())
    path = folder / "sweep.yaml"
    path.write_text(SPEC)
    return path


class InThisProcess:
    """A pool of no process: each run in this process, one after another (``map``)."""

    def imap_unordered(self, func: Callable[[RunTask], RunRecord], iterable: Iterable[RunTask],
                       chunksize: int = 1) -> Iterator[RunRecord]:
        return map(func, iterable)


@pytest.fixture(scope="module")
def reference(spec: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sweep uninterrupted, each run in this process (no pool to start): its folder, the
    tables every other way of running it must give byte for byte."""
    out = tmp_path_factory.mktemp("reference")
    state = sweep.open_sweep(sweep.load_sweep(spec), out)
    sweep.execute(state, InThisProcess())  # execute uses only imap_unordered
    outputs = sweep.finish(state)
    assert (outputs.runs, outputs.failed) == (RUNS, 4)
    return out


def rows(folder: Path, name: str = "runs.csv") -> list[dict[str, str]]:
    return list(csv.DictReader(io.StringIO((folder / name).read_text())))


@pytest.mark.slow
def test_a_failing_run_is_recorded_with_its_error_and_the_others_complete(
        reference: Path) -> None:
    table = rows(reference)
    assert [(r["robot"], r["tree.arbiter"], r["seed"]) for r in table] == [
        (robot, arbiter, seed) for robot in ("mini-whegs", "video-camera.yaml")
        for arbiter in ("PriorityMerge", "UtilityFusion") for seed in ("1", "2")]
    for row in table[:4]:
        assert row["status"] == "ok" and row["error"] == ""
        assert 0.2 < float(row["ball_distance_m"]) < 0.7
        assert row["pass"] in ("true", "false") and row["pass:ball_distance_m"] == "true"
    for row in table[4:]:
        assert row["status"] == "failed" and row["error"] == MISSING_VIDEO
        assert row["ball_distance_m"] == row["pass"] == ""
    cells = rows(reference, "cells.csv")
    assert [(c["robot"], c["tree.arbiter"], c["runs"], c["failed"], c["pass_rate"],
             c["worst_seed"]) for c in cells[2:]] == [
        ("video-camera.yaml", "PriorityMerge", "2", "2", "0.0", "1"),
        ("video-camera.yaml", "UtilityFusion", "2", "2", "0.0", "1")]
    mean = float(cells[0]["ball_distance_m.mean"])
    assert float(cells[0]["ball_distance_m.min"]) <= mean <= float(
        cells[0]["ball_distance_m.max"])
    log = (reference / "runs.log").read_text()
    assert "robot=video-camera.yaml tree.arbiter=PriorityMerge scenario=ball-in-sight seed=1: " \
           "failed\n  Traceback" in log
    assert (reference / "ball_distance_m.png").read_bytes().startswith(b"\x89PNG")


def test_the_console_shows_each_cell_and_the_plot_the_scenarios_expected_band(
        reference: Path, spec: Path, tmp_path: Path) -> None:
    out = tmp_path / "copy"
    shutil.copytree(reference, out)
    plan = sweep.load_sweep(spec)
    state = sweep.open_sweep(plan, out, resume=True)  # the journal's runs ...
    sweep.execute(state, InThisProcess())  # ... but the failed ones, which fail again
    # The band: the range ball-in-sight's expected outcome gives ball_distance_m, read from
    # the runs' summaries, as its scenario file states it.
    [criterion] = [c for c in load_scenario("ball-in-sight").expect.criteria  # type: ignore[union-attr]
                   if c.path == "ball_distance_m"]
    assert table.expected_ranges(plan, state.records, "ball_distance_m") == {
        "ball-in-sight": (criterion.low, criterion.high, False)}
    assert table.expected_ranges(plan, state.records, "contacts.time_s") == {}
    outputs = sweep.finish(state)
    assert (out / "runs.csv").read_bytes() == (reference / "runs.csv").read_bytes()
    # The console: a line per cell — its runs, the share that met the expected outcome and
    # the plotted figure over the seeds — aligned, as cells.csv has them.
    said = io.StringIO()
    report(outputs, out, said, plan)
    lines = said.getvalue().splitlines()
    head = lines[1].split()
    assert head == ["robot", "tree.arbiter", "scenario", "runs", "passed", "ball_distance_m",
                    "mean", "min", "max"], lines
    cells = rows(out, "cells.csv")
    for line, cell in zip(lines[2:6], cells, strict=True):
        words = line.split()
        assert words[:4] == [cell["robot"], cell["tree.arbiter"], cell["scenario"],
                             cell["runs"]], line
        if cell["failed"] == "2":
            assert words[4:] == ["0%"], line  # every run failed: no figure
        else:
            assert words[4] == f"{float(cell['pass_rate']):.0%}", line
            assert words[5:] == [cell[f"ball_distance_m.{w}"] for w in ("mean", "min", "max")]
    assert lines[6].startswith("written in "), lines


@pytest.mark.slow
def test_the_table_is_the_same_bytes_for_one_worker_two_workers_and_ray(
        spec: Path, reference: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import ray

    # One worker, through the library.
    assert sweep.run_sweep(spec, tmp_path / "one", workers=1).runs == RUNS
    # Two workers, through the command line (not a terminal: plain progress lines).
    assert main([str(spec), "--out", str(tmp_path / "two"), "--workers", "2"]) == 1
    out = capsys.readouterr().out
    assert f"running {RUNS} runs on 2 local worker processes" in out
    assert f"  {RUNS}/{RUNS} runs (100 %), 4 failed, " in out
    assert "8 runs: 4 ok, 4 failed;" in out
    # Ray on this machine, two CPUs. Its workers start in this process's folder, where this
    # checkout's code is: shipping it (the command line's default, code_runtime_env) is for
    # other machines, and would cost the workers Ray starts in advance (below).
    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.WARNING)
    try:
        outputs = sweep.run_sweep(spec, tmp_path / "ray", executor="ray", workers=2)
    finally:
        ray.shutdown()
    assert outputs.runs == RUNS
    for name in ("runs.csv", "cells.csv"):
        expected = (reference / name).read_bytes()
        for way in ("one", "two", "ray"):
            assert (tmp_path / way / name).read_bytes() == expected, (way, name)
    import pyarrow.parquet as pq

    table = pq.read_table(tmp_path / "ray" / "runs.parquet")
    assert table.column_names == next(csv.reader(io.StringIO((reference / "runs.csv")
                                                            .read_text())))
    assert table.column("seed").to_pylist() == [1, 2] * 4


def test_rays_workers_get_this_checkouts_packages() -> None:
    env = execution.code_runtime_env()
    assert env["py_modules"] == [str(REPOSITORY / "ubf_async"), str(REPOSITORY / "components")]


def first_line(proc: subprocess.Popen[bytes], pattern: bytes, deadline: float) -> bytes:
    """The first line of ``proc``'s output containing ``pattern``, waiting for it until
    ``deadline`` (a monotonic time)."""
    assert proc.stdout is not None
    seen = b""
    with selectors.DefaultSelector() as selector:
        selector.register(proc.stdout, selectors.EVENT_READ)
        while time.monotonic() < deadline:
            if not selector.select(deadline - time.monotonic()):
                continue
            line = proc.stdout.readline()
            seen += line
            if pattern in line:
                return line
            if not line:
                break
    raise AssertionError(f"no line with {pattern!r} in time; output so far:\n{seen.decode()}")


@pytest.mark.slow
def test_a_killed_sweep_resumes_to_the_table_of_an_uninterrupted_one(
        spec: Path, reference: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ubf_async.sweep", str(spec), "--out", str(out), "--workers",
         "1"], cwd=REPOSITORY, env=repository_env(), stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, start_new_session=True)
    try:
        # The progress line of the first run comes once the run is journaled.
        first_line(proc, f" 1/{RUNS} runs ".encode(), time.monotonic() + WAIT_S)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the sweep and its worker, outright
        proc.wait()
        assert proc.stdout is not None
        proc.stdout.close()
    done = read_journal(out / JOURNAL)
    assert 1 <= len(done) < RUNS
    assert not (out / "runs.csv").exists()
    # A kill in the middle of a line leaves it without its newline: it is not a run.
    with (out / JOURNAL).open("ab") as journal:
        journal.write(b'{"id":"0123456789abcdef","status":"ok","key":{"ro')
    assert main([str(spec), "--out", str(out)]) == 2  # a folder holding a sweep
    assert "holds a sweep already" in capsys.readouterr().err
    assert main([str(spec), "--out", str(out), "--resume", "--workers", "2"]) == 1
    said = capsys.readouterr().out
    kept = sum(1 for record in done.values() if record.status == "ok")
    assert f"resuming {out}: {kept} runs done already" in said, said
    assert f"running {RUNS - kept} runs" in said
    assert (out / "runs.csv").read_bytes() == (reference / "runs.csv").read_bytes()
    assert (out / "cells.csv").read_bytes() == (reference / "cells.csv").read_bytes()
    assert len(read_journal(out / JOURNAL)) == RUNS


def test_a_journal_is_read_up_to_its_last_complete_line(tmp_path: Path) -> None:
    path = tmp_path / JOURNAL
    with Journal(path) as journal:
        journal.append(execution.RunRecord(id="a", status="failed", key={"seed": 1},
                                           error="RuntimeError: x"))
    path.write_bytes(path.read_bytes() + b'{"id":"b","sta')
    assert list(read_journal(path)) == ["a"]
    with Journal(path) as journal:  # appending cuts the broken line off first
        journal.append(execution.RunRecord(id="a", status="ok", key={"seed": 1}, summary={}))
    assert read_journal(path)["a"].status == "ok"  # a run's last line counts
    assert path.read_text().splitlines()[0] == '{"journal": "ubf_async.sweep", "format": 1}'
    assert HEADER == {"journal": "ubf_async.sweep", "format": 1}
    path.write_text('{"journal": "ubf_async.sweep", "format": 1}\nnot json\n')
    with pytest.raises(ConfigurationError, match=r"journal.jsonl:2: not a run's record"):
        read_journal(path)


def test_a_folder_of_another_specs_sweep_is_refused_even_to_resume(spec: Path,
                                                                   tmp_path: Path) -> None:
    plan = sweep.load_sweep(spec)
    with Journal(tmp_path / JOURNAL) as journal:
        journal.append(execution.RunRecord(id="0123456789abcdef", status="ok", key={}))
    with pytest.raises(ConfigurationError, match="holds a sweep already"):
        sweep.open_sweep(plan, tmp_path)
    with pytest.raises(ConfigurationError, match=r"none of the 1 runs in .* is a run of"):
        sweep.open_sweep(plan, tmp_path, resume=True)


BAD_SPECS = {
    "a typo'd key": (
        "robots: [mini-whegs]\nscenarios: [ball-in-sight]\nseedz: [1, 2]\n", 3,
        "Object contains unknown field `seedz`; did you mean `seeds`? a sweep spec takes: "
        "robots, scenarios, seeds, "),
    "one value where a list of them belongs": (
        "robots: [mini-whegs]\noverrides:\n  tree.arbiter: PriorityMerge\n"
        "scenarios: [ball-in-sight]\nseeds: [1]\n", 3,
        'overrides["tree.arbiter"] must be a list of values to try: write [PriorityMerge]'),
    "a figure no summary has": (
        "robots: [mini-whegs]\nscenarios: [ball-in-sight]\nseeds: [1]\n"
        "figures: [ball_distance_m, ball_distnce_m]\nplot: ball_distnce_m\n", 4,
        "figures: 'ball_distnce_m': a run's summary has no such field (the nearest: "
        "ball_distance_m;"),
    "an unknown scenario": (
        "robots: [mini-whegs]\nscenarios:\n  - ball-in-sight\n  - no-such-scenario\n"
        "seeds: [1]\n", 4, "scenario 'no-such-scenario': unknown scenario 'no-such-scenario'"),
    "a path that does not exist": (
        "robots: [mini-whegs]\noverrides:\n  tree.arbiter: [PriorityMerge]\n"
        "  tree.children[9].params.period_s:\n    - 2\n    - 4\n"
        "scenarios: [ball-in-sight]\nseeds: [1]\n", 4,
        "robot 'mini-whegs': mini-whegs.yaml:48: override tree.children[9].params.period_s: "
        "tree.children has 5 item(s)"),
    "a value outside the parameter's schema": (
        "robots: [mini-whegs]\noverrides:\n  tree.children[0].params.period_s:\n    - 2\n"
        "    - -1\nscenarios: [ball-in-sight]\nseeds: [1]\n", 5,
        "robot 'mini-whegs': mini-whegs.yaml:50: with tree.children[0].params.period_s = -1: "
        "behaviour 'search': Expected `float` > 0.0"),
    "an unknown arbiter": (
        "robots: [mini-whegs]\noverrides:\n  tree.arbiter: [PriorityMerge, Priority]\n"
        "scenarios: [ball-in-sight]\nseeds: [1]\n", 3, "unknown arbiter 'Priority'"),
    "a robot file that does not load": (
        "robots:\n  - mini-whegs\n  - broken.yaml\nscenarios: [ball-in-sight]\nseeds: [1]\n", 3,
        "robot 'broken.yaml': "),
    "a robot file that is not there": (
        "robots: [nowhere.yaml]\nscenarios: [ball-in-sight]\nseeds: [1]\n", 1,
        "robot 'nowhere.yaml': nowhere.yaml: no such file"),
    "a seed twice": (
        "robots: [mini-whegs]\nscenarios: [ball-in-sight]\nseeds: [1, 2, 1]\n", 3,
        "seed 1 twice (also seeds[0])"),
    "an empty seed range": (
        "robots: [mini-whegs]\nscenarios: [ball-in-sight]\nseeds: {first: 5, last: 2}\n", 3,
        "seeds: first (5) is past last (2)"),
    "a negative seed": (
        "robots: [mini-whegs]\nscenarios: [ball-in-sight]\nseeds: [-1]\n", 3,
        "Expected `int` >= 0"),
    "a plot of no figure": (
        "robots: [mini-whegs]\nscenarios: [ball-in-sight]\nseeds: [1]\n"
        "figures: [ball_distance_m]\nplot: contacts.time_s\n", 5,
        "plot: 'contacts.time_s' is not one of the figures (ball_distance_m)"),
    "an override of the seed": (
        "robots: [mini-whegs]\noverrides: {seed: [1, 2]}\nscenarios: [ball-in-sight]\n"
        "seeds: [1]\n", 2, "overrides: the robot file's `seed` is replaced by each run's seed"),
    "not YAML": (
        "robots: [mini-whegs\nscenarios: [ball-in-sight]\nseeds: [1]\n", 1, "not valid YAML"),
}


def test_every_mistake_of_a_spec_is_told_at_once(tmp_path: Path) -> None:
    # Four mistakes of form, each where msgspec alone would have stopped at the first...
    path = tmp_path / "sweep.yaml"
    path.write_text("robots: [mini-whegs]\noverrides:\n  tree.arbiter: PriorityMerge\n"
                    "scenarios: ball-in-sight\nseeds: [1, -2]\nduration_s: -1\n")
    with pytest.raises(sweep.SweepSpecError) as refused:
        sweep.load_sweep(path)
    told = refused.value
    assert [(p.line, p.message) for p in told.problems] == [
        (3, 'overrides["tree.arbiter"] must be a list of values to try: write [PriorityMerge]'),
        (4, "scenarios must be a list of scenarios: write [ball-in-sight]"),
        (5, "Expected `int` >= 0 (at seeds[1])"),
        (6, "Expected `float` > 0.0 (at duration_s)")]
    assert str(told).splitlines() == [f"{path}: 4 mistakes:",
                                      *(f"  {path}:{p.line}: {p.message}" for p in told.problems)]
    # ... and the spec's checks with its figures: a clash with the table, a seed twice, two
    # figures no run's summary has (each with the nearest real names).
    path.write_text("robots: [mini-whegs]\nscenarios: [ball-in-sight]\nseeds: [1, 1]\n"
                    "figures: [seed, ball_distnce_m, motion_last_2s.max_ofset_m]\n")
    with pytest.raises(sweep.SweepSpecError) as refused:
        sweep.load_sweep(path)
    messages = [p.message for p in refused.value.problems]
    assert messages[0] == "seed 1 twice (also seeds[0])"
    assert messages[1] == "figures: 'seed' is a column of the table already"
    assert messages[2].startswith("figures: 'ball_distnce_m': a run's summary has no such "
                                  "field (the nearest: ball_distance_m;")
    assert messages[3].startswith("figures: 'motion_last_2s.max_ofset_m': a run's summary has "
                                  "no such field (the nearest: motion_last_2s.max_offset_m")
    assert len(messages) == 4


@pytest.mark.parametrize("case", sorted(BAD_SPECS))
def test_a_bad_spec_is_refused_at_its_line_before_anything_runs(case: str,
                                                                tmp_path: Path) -> None:
    text, line, message = BAD_SPECS[case]
    (tmp_path / "broken.yaml").write_text("format: 1\nname: x\ntre: {}\n")
    path = tmp_path / "sweep.yaml"
    path.write_text(text)
    with pytest.raises(sweep.SweepSpecError) as refused:
        sweep.load_sweep(path)
    assert (refused.value.path, refused.value.line) == (str(path), line), str(refused.value)
    assert message in refused.value.message, str(refused.value)


def test_the_command_line_says_a_bad_spec_in_one_line_and_runs_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "sweep.yaml"
    path.write_text("robots: [mini-whegs]\nscenarios: [ball-in-sight]\nseedz: [1]\n")
    assert main([str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"python -m ubf_async.sweep: error: {path}:3: Object contains "
                          f"unknown field `seedz`"), err
    assert err.count("\n") == 1
    assert not (tmp_path / "out").exists()
    assert main([str(path)]) == 2
    assert "--out DIR is required" in capsys.readouterr().err
    assert main([str(tmp_path / "nowhere.yaml"), "--check"]) == 2
    assert "nowhere.yaml: no such sweep spec" in capsys.readouterr().err


def test_check_says_what_would_run(spec: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(spec), "--check"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == (f"{spec}: {RUNS} runs: 2 robot files × 2 values of tree.arbiter × "
                      f"1 scenario × 2 seeds — OK")
    assert "  tree.arbiter: PriorityMerge, UtilityFusion" in out
