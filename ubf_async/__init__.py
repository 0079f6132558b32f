"""ubf_async — the Unified Behavior Framework as an asyncio controller over zenoh.

The names a user needs to write a behaviour, an arbiter, a component, a device backend or a
tool are importable from here::

    from ubf_async import Action, Behavior, State            # a behaviour
    from ubf_async import Arbiter, Decision                  # an arbiter
    from ubf_async import Bus, Component, every              # a component
    from ubf_async import Backend, DeviceContext             # a device backend
    from ubf_async import add_connection_arguments, run_main # a tool

Each is loaded on first use (PEP 562): ``import ubf_async`` itself imports neither zenoh nor
msgspec, so a program pays only for what it uses. :data:`_HOMES` says where each name lives;
``__init__.pyi`` says the same to type checkers — a stub, not imports here, so that the
import-linter contracts see no import from this package into its rooms (tests/test_public.py
keeps the two, ``__all__`` and the documented imports in step).
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version
from typing import Any

_HOMES: dict[str, str] = {name: module for module, names in (
    ("ubf_async.core.action", ("COMMAND_LIMIT", "STOP", "Action", "ColorBox", "clamp_command")),
    ("ubf_async.core.arbiters", ("CommandFusion", "Conditional", "HighestActivation",
                                 "HighestPriority", "MonteCarlo", "Predicate", "PriorityFusion",
                                 "PriorityMerge", "UtilityFusion")),
    ("ubf_async.core.behavior", ("Arbiter", "Behavior", "Candidate", "Child", "Composite",
                                 "Decision", "FunctionBehavior", "Trace", "behavior")),
    ("ubf_async.core.state", ("Reading", "State")),
    ("ubf_async.errors", ("ConfigurationError", "MissingExtraError", "ParameterError",
                          "PluginError", "ProtocolError", "RobotFileError", "ScenarioError",
                          "TreeChangeError", "UbfError")),
    ("ubf_async.runtime.bus", ("Bus",)),
    ("ubf_async.runtime.component", ("Component",)),
    ("ubf_async.runtime.controller", ("Controller", "TickMode")),
    ("ubf_async.runtime.aggregator", ("StateAggregator",)),
    ("ubf_async.clocks.clock", ("Clock", "SimClock", "every")),
    ("ubf_async.assembly.backend", ("Backend",)),
    ("ubf_async.assembly.context", ("DeviceContext",)),
    ("ubf_async.net.options", ("ConnectionOptions",)),
    ("ubf_async.cli.args", ("add_connection_arguments", "connection_options")),
    ("ubf_async.cli.run", ("run_main",)),
) for name in names}
"""Each public name, and the module it is defined in."""

try:
    __version__ = _version("ubf-async")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = [*_HOMES, "__version__"]


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'ubf_async' has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value  # found once: later lookups do not come here
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
