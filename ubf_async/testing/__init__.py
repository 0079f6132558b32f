"""Testing one's own behaviours: a script of sensor samples fed to a robot file's tree in
simulated time, assertions on what it drove, stand-ins for behaviours, and hypothesis
strategies of well-formed samples (docs/testing.md).

What it holds — importable as ``ubf_async.testing`` (the pytest plugin, registered through the
``pytest11`` entry point, gives the same as fixtures: :mod:`ubf_async.testing.plugin`):

* :class:`Script`, :func:`at`, :func:`every`, :func:`bins`, :func:`mm` — the samples;
* :func:`run_script` (and :func:`run_script_async` on a running loop) — the robot file's tree
  on the real aggregator and controller, over the in-process transport, in simulated time;
  it returns a :class:`ScriptRun`: ``drive_at(t)``, ``winners_at(t)``,
  ``became_active(name)``, ``held_for(name)``, each answer showing the ticks' traces around
  its moment;
* :func:`stand_in` — a behaviour of the file replaced for a test, by name;
* :mod:`ubf_async.testing.strategies` — hypothesis strategies (needs ``hypothesis``).

Its scope stops at the behaviours and the controller: the simulator's physics and camera are
the scenarios' (``ubf_async.experiment``).

May import ``runs`` and everything below it (it builds the controller as a launch does); beside
the tools, nothing of the framework imports it (only a user's tests, and pytest, through its
plugin).
"""

from ubf_async.testing._run import (
    Command,
    ScriptRun,
    StandIn,
    run_script,
    run_script_async,
    stand_in,
)
from ubf_async.testing._script import Sample, Script, at, bins, every, mm, source_of

__all__ = ["Command", "Sample", "Script", "ScriptRun", "StandIn", "at", "bins", "every", "mm",
           "run_script", "run_script_async", "source_of", "stand_in"]
