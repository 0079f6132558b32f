"""The optional parts of the install (*extras*), and the one way a feature asks for its own.

``pip install ubf-async`` brings what a robot's process imports — zenoh, msgspec/msgpack,
numpy, PyYAML, OpenCV (a real camera reads frames with ``cv2.VideoCapture``) and cryptography
(secure mode). Everything else is an extra, named in ``[project.optional-dependencies]`` of
``pyproject.toml``:

==========  =================================  ==========================================
extra       distributions                      what needs it
==========  =================================  ==========================================
sim         pymunk, matplotlib, rich           the simulator (every ``sim`` backend, a
                                               simulated launch, experiment.run, fleets),
                                               a run's pictures, sweeps, evolution
view        foxglove-sdk                       the live view (``launch --foxglove``,
                                               ``python -m ubf_async.liveview``)
monitor     aiohttp                            the tree monitor in a browser
                                               (``launch --monitor``,
                                               ``python -m ubf_async.monitor``)
record      mcap, foxglove-sdk                 recording and replay (``--record``,
                                               ``python -m ubf_async.record``/``replay``)
ros2        rosbags                            the ROS 2 bridge (``python -m ubf_async.ros2``,
                                               a robot file's ``ros2:``)
tune        optuna, cmaes (and ``sim``)        ``python -m ubf_async.tune``
hardware    gpiozero, smbus2                   the ``gpio``, ``i2c``, ``ads1115`` backends
fast        uvloop                             ``UBF_LOOP=uvloop``
cluster     ray[default] (and ``sim``)         ``sweep --executor ray``
parquet     pyarrow                            a sweep's table as Parquet
all         sim, view, monitor, record, ros2,  everything a workstation runs
            tune, hardware
==========  =================================  ==========================================

A feature calls :func:`require` where it starts, before it imports what its extra brings:
a missing extra is then one line — :class:`~ubf_async.errors.MissingExtraError`, which
``run_main`` prints with exit status 2 — naming the feature, the extra and the command
(``launch --record needs the 'record' extra (mcap is not installed): pip install
'ubf-async[record]'``), never an ``ImportError`` traceback. A plug-in whose module imports a
missing extra's module is reported the same way by the registry (:func:`missing_extra`).
"""

from __future__ import annotations

import importlib
import importlib.util
from types import ModuleType

from ubf_async.errors import MissingExtraError

__all__ = ["EXTRA_OF", "check", "missing_extra", "require"]

EXTRA_OF: dict[str, str] = {
    "pymunk": "sim",
    "matplotlib": "sim",
    "rich": "sim",
    "foxglove": "view",
    "aiohttp": "monitor",
    "mcap": "record",
    "rosbags": "ros2",
    "optuna": "tune",
    "cmaes": "tune",
    "gpiozero": "hardware",
    "smbus2": "hardware",
    "uvloop": "fast",
    "ray": "cluster",
    "pyarrow": "parquet",
}
"""Each optional top-level module, and the extra that installs it (a test keeps this table
and ``pyproject.toml`` in step)."""


def require(extra: str, module: str, *, who: str) -> ModuleType:
    """Import ``module`` — a part of ``extra`` — for ``who`` (the feature, as a user names
    it: ``launch --record``), or raise :class:`MissingExtraError` saying how to install it.

    A module that is there but fails to import for another reason raises as it would."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.partition(".")[0] != module.partition(".")[0]:
            raise  # something inside the installed module is broken: not a missing extra
        raise MissingExtraError(who, extra, exc.name) from None


def check(extra: str, module: str, *, who: str) -> None:
    """As :func:`require`, without importing ``module``: for a feature that only imports it
    later, if at all (the simulator's plots: matplotlib costs ≈ 0.1 s to import)."""
    try:
        found = importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:  # a finder that refuses the name outright
        found = False
    if not found:
        raise MissingExtraError(who, extra, module)


def missing_extra(exc: BaseException, *, who: str) -> MissingExtraError | None:
    """The :class:`MissingExtraError` that ``exc`` means when it is a ``ModuleNotFoundError``
    for a module of an extra (:data:`EXTRA_OF`), else ``None``."""
    if not isinstance(exc, ModuleNotFoundError) or exc.name is None:
        return None
    extra = EXTRA_OF.get(exc.name.partition(".")[0])
    return None if extra is None else MissingExtraError(who, extra, exc.name)
