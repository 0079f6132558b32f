"""ubf_async — the Unified Behavior Framework as an asyncio controller over zenoh.

The core (this module's exports) is pure Python: no I/O, no middleware.
"""

from ubf_async.action import COMMAND_LIMIT, STOP, Action, SeekColor, clamp_command
from ubf_async.arbiters import (
    Arbiter,
    CommandFusion,
    Conditional,
    HighestActivation,
    HighestPriority,
    MonteCarlo,
    PriorityFusion,
    PriorityMerge,
    UtilityFusion,
)
from ubf_async.behavior import (
    Behavior,
    Candidate,
    Child,
    Composite,
    Decision,
    FunctionBehavior,
    Trace,
    behavior,
)
from ubf_async.state import Reading, State

__all__ = [
    "COMMAND_LIMIT",
    "STOP",
    "Action",
    "Arbiter",
    "Behavior",
    "Candidate",
    "Child",
    "CommandFusion",
    "Composite",
    "Conditional",
    "Decision",
    "FunctionBehavior",
    "HighestActivation",
    "HighestPriority",
    "MonteCarlo",
    "PriorityFusion",
    "PriorityMerge",
    "Reading",
    "SeekColor",
    "State",
    "Trace",
    "UtilityFusion",
    "behavior",
    "clamp_command",
]
