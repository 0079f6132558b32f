"""ubf_async — the Unified Behavior Framework as an asyncio controller over zenoh.

The core (this module's exports) is pure Python: no I/O, no middleware.
"""

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

from ubf_async.core.action import COMMAND_LIMIT, STOP, Action, ColorBox, clamp_command
from ubf_async.core.arbiters import (
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
from ubf_async.core.behavior import (
    Behavior,
    Candidate,
    Child,
    Composite,
    Decision,
    FunctionBehavior,
    Trace,
    behavior,
)
from ubf_async.core.state import Reading, State
from ubf_async.errors import (
    ConfigurationError,
    PluginError,
    ProtocolError,
    RobotFileError,
    ScenarioError,
    TreeChangeError,
    UbfError,
)

try:
    __version__ = _version("ubf-async")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = [
    "COMMAND_LIMIT",
    "STOP",
    "Action",
    "Arbiter",
    "Behavior",
    "Candidate",
    "Child",
    "ColorBox",
    "CommandFusion",
    "Composite",
    "Conditional",
    "ConfigurationError",
    "Decision",
    "FunctionBehavior",
    "HighestActivation",
    "HighestPriority",
    "MonteCarlo",
    "PluginError",
    "PriorityFusion",
    "PriorityMerge",
    "ProtocolError",
    "Reading",
    "RobotFileError",
    "ScenarioError",
    "State",
    "Trace",
    "TreeChangeError",
    "UbfError",
    "UtilityFusion",
    "__version__",
    "behavior",
    "clamp_command",
]
