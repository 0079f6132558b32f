"""What a device backend factory is handed: :class:`DeviceContext`.

Its own small module, below everything that builds devices (:mod:`ubf_async.assembly.devices`,
:mod:`ubf_async.assembly.robotfile`) and below :mod:`ubf_async.assembly.simulation` (which
re-exports it), so building a device never imports the simulator seam.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ubf_async.assembly.body import DEFAULT_BODY, BodySpec

if TYPE_CHECKING:
    from ubf_async.clocks.clock import Clock
    from ubf_async.runtime.bus import Bus

__all__ = ["DeviceContext"]


@dataclass(kw_only=True)
class DeviceContext:
    """What a backend factory receives besides its own parameters."""

    bus: Bus
    clock: Clock
    seed: int = 0
    """The run's seed: backends with noise derive their random streams from it."""
    simulation: Any = None
    """The world of the simulator the backend requires (``None`` without one)."""
    helper_processes: bool = True
    """Whether a backend may start helper processes of its own (a simulated camera's render
    process); ``False`` for a run that must stay in the calling process (a library run:
    :func:`ubf_async.runs.inprocess.run`), which then does that work in threads."""
    body: BodySpec = DEFAULT_BODY
    """The robot's body (its robot file's ``body``): what a device whose factory takes
    ``body`` is given (the motors' PWM mapping, the encoders' odometry)."""
    extras: Mapping[str, Any] = field(default_factory=dict)
