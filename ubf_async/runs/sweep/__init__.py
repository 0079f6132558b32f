"""Sweeps: the product of robot files (or overrides of their values), scenarios and seeds, each
run in-process (:func:`ubf_async.runs.inprocess.run`) on a pool of worker processes — this
machine's cores or a Ray cluster's — into one table (``python -m ubf_async.sweep``,
docs/experiments.md).

* :mod:`.spec` — the SPEC file, checked whole before anything runs (``SPEC:LINE: …``), and
  its runs as picklable tasks;
* :mod:`.execution` — what a worker does with a run (a run that raises is recorded as failed),
  and the pools: multiprocessing's or Ray's, one interface;
* :mod:`.cluster` — joining a Ray cluster, or one line saying why it cannot be joined;
* :mod:`.journal` — each finished run appended to ``DIR/journal.jsonl`` (resuming reads it);
* :mod:`.table` — ``runs.csv`` (byte-identical whatever ran it), ``runs.parquet``,
  ``cells.csv``; :mod:`.plot` — a figure against each swept parameter;
* :mod:`.driver` — the three steps: open the folder, execute, finish.

Library code: nothing here prints or reads a command line (the tool is
:mod:`ubf_async.tools.sweep`).
"""

from ubf_async.errors import SweepSpecError
from ubf_async.runs.sweep.driver import (
    Sweep,
    SweepOutputs,
    execute,
    finish,
    open_sweep,
    run_sweep,
)
from ubf_async.runs.sweep.execution import RunRecord, default_workers, open_pool
from ubf_async.runs.sweep.spec import RunTask, SweepPlan, load_sweep

__all__ = ["RunRecord", "RunTask", "Sweep", "SweepOutputs", "SweepPlan", "SweepSpecError",
           "default_workers", "execute", "finish", "load_sweep", "open_pool", "open_sweep",
           "run_sweep"]
