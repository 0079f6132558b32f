"""Evolution of behaviour trees by genetic programming, scored by lockstep runs
(``python -m ubf_async.evolve``, docs/evolve.md); the same runs and fitness tune a robot
file's parameters with Optuna (:mod:`ubf_async.runs.tune`).

A robot file is the genome: every behaviour and arbiter is in a registry with a typed
parameter schema, and a simulated run is a pure function of (robot file, scenario, seed), so
fitness is exact and cacheable.

* :mod:`.spec` — the SPEC, checked whole before anything runs (``SPEC:LINE: …``);
* :mod:`.scenarios` — scenario sets made by generators (the ball at random, behind, at the
  field of view's edge, moving);
* :mod:`.genome` — trees as robot-file data, their canonical text, the operators;
* :mod:`.fitness` — run summaries' figures combined, and the evaluation of candidates on the
  sweep's pools and journal (:mod:`ubf_async.runs.sweep`);
* :mod:`.loop` — the generational loop, one seeded generator in this process, a checkpoint
  each generation;
* :mod:`.report` and :mod:`.driver` — the outputs, and the whole from plan to outputs.

Library code: nothing here prints or reads a command line (the tool is
:mod:`ubf_async.tools.evolve`).
"""

from ubf_async.errors import EvolveSpecError
from ubf_async.runs.evolve.driver import (
    EvolveOutputs,
    check_folder,
    compared_robots,
    run_evolution,
)
from ubf_async.runs.evolve.fitness import FAILED_FITNESS, Evaluation, Evaluator, Fitness, Term
from ubf_async.runs.evolve.genome import OPERATORS, Space
from ubf_async.runs.evolve.loop import Evolution, Individual, State
from ubf_async.runs.evolve.spec import EvolvePlan, ScenarioSet, load_evolve

__all__ = ["FAILED_FITNESS", "OPERATORS", "Evaluation", "Evaluator", "Evolution", "EvolveOutputs",
           "EvolvePlan", "EvolveSpecError", "Fitness", "Individual", "ScenarioSet", "Space",
           "State", "Term", "check_folder", "compared_robots", "load_evolve", "run_evolution"]
