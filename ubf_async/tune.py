"""A robot file's parameters tuned with Optuna on simulated runs (docs/evolve.md).

``python -m ubf_async.tune SPEC.yaml --out DIR`` runs the command line
(:mod:`ubf_async.tools.tune`); the library is :mod:`ubf_async.runs.tune`, and this module is
its public face::

    from ubf_async import evolve, tune

    outputs = tune.run_study(evolve.load_evolve("examples/evolve/mini-whegs.yaml"),
                             "out/tune", storage="sqlite:///study.db")
"""

from ubf_async.runs.tune import TuneOutputs, run_study
from ubf_async.tools.tune import main

__all__ = ["TuneOutputs", "main", "run_study"]

if __name__ == "__main__":
    raise SystemExit(main())
