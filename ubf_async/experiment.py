"""Simulated runs as library calls: ``ubf_async.experiment.run(robot, scenario, seed=…)``.

One run in this process, flat out, byte for byte the run ``python -m ubf_async.launch ROBOT
--scenario S --seed N --speed max`` makes (docs/experiments.md). The implementation is
:mod:`ubf_async.runs`; this module is its public face.
"""

from ubf_async.runs.inprocess import RunResult, run, run_async

__all__ = ["RunResult", "run", "run_async"]
