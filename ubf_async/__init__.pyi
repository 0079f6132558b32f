"""Types of :mod:`ubf_async`'s public names, which ``__init__.py`` loads on first use."""

from ubf_async.assembly.backend import (
    Backend,
)
from ubf_async.assembly.context import (
    DeviceContext,
)
from ubf_async.cli.args import (
    add_connection_arguments,
    connection_options,
)
from ubf_async.cli.run import (
    run_main,
)
from ubf_async.clocks.clock import (
    Clock,
    SimClock,
    every,
)
from ubf_async.core.action import (
    COMMAND_LIMIT,
    STOP,
    Action,
    ColorBox,
    clamp_command,
)
from ubf_async.core.arbiters import (
    CommandFusion,
    Conditional,
    HighestActivation,
    HighestPriority,
    MonteCarlo,
    Predicate,
    PriorityFusion,
    PriorityMerge,
    UtilityFusion,
)
from ubf_async.core.behavior import (
    Arbiter,
    Behavior,
    Candidate,
    Child,
    Composite,
    Decision,
    FunctionBehavior,
    Trace,
    behavior,
)
from ubf_async.core.state import (
    Reading,
    State,
)
from ubf_async.errors import (
    ConfigurationError,
    MissingExtraError,
    ParameterError,
    PluginError,
    ProtocolError,
    RobotFileError,
    ScenarioError,
    TreeChangeError,
    UbfError,
)
from ubf_async.net.options import (
    ConnectionOptions,
)
from ubf_async.runtime.aggregator import (
    StateAggregator,
)
from ubf_async.runtime.bus import (
    Bus,
)
from ubf_async.runtime.component import (
    Component,
)
from ubf_async.runtime.controller import (
    Controller,
    TickMode,
)

__version__: str

__all__ = [
    "COMMAND_LIMIT",
    "STOP",
    "Action",
    "Arbiter",
    "Backend",
    "Behavior",
    "Bus",
    "Candidate",
    "Child",
    "Clock",
    "ColorBox",
    "CommandFusion",
    "Component",
    "Composite",
    "Conditional",
    "ConfigurationError",
    "ConnectionOptions",
    "Controller",
    "Decision",
    "DeviceContext",
    "FunctionBehavior",
    "HighestActivation",
    "HighestPriority",
    "MissingExtraError",
    "MonteCarlo",
    "ParameterError",
    "PluginError",
    "Predicate",
    "PriorityFusion",
    "PriorityMerge",
    "ProtocolError",
    "Reading",
    "RobotFileError",
    "ScenarioError",
    "SimClock",
    "State",
    "StateAggregator",
    "TickMode",
    "Trace",
    "TreeChangeError",
    "UbfError",
    "UtilityFusion",
    "__version__",
    "add_connection_arguments",
    "behavior",
    "clamp_command",
    "connection_options",
    "every",
    "run_main",
]
