"""Behaviour trees evolved by genetic programming, scored by simulated runs (docs/evolve.md).

``python -m ubf_async.evolve SPEC.yaml --out DIR`` runs the command line
(:mod:`ubf_async.tools.evolve`); as a library::

    from ubf_async import evolve

    plan = evolve.load_evolve("examples/evolve/mini-whegs.yaml", generations=3)
    outputs = evolve.run_evolution(plan, "out/evolve", workers=2)

The implementation is :mod:`ubf_async.runs.evolve`; this module is its public face.
"""

from ubf_async.runs.evolve import (
    EvolveOutputs,
    EvolvePlan,
    EvolveSpecError,
    check_folder,
    compared_robots,
    load_evolve,
    run_evolution,
)
from ubf_async.tools.evolve import main

__all__ = ["EvolveOutputs", "EvolvePlan", "EvolveSpecError", "check_folder", "compared_robots",
           "load_evolve", "main", "run_evolution"]

if __name__ == "__main__":
    raise SystemExit(main())
