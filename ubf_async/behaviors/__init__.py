"""Reusable behaviours, each registered by name in the ``ubf_async.behaviors`` entry-point
group: ``search``/``chase``/``flee`` (:mod:`.pink_ball`, the thesis's seek-the-pink-ball
demonstration), ``avoid`` (:mod:`.obstacles`), ``stop`` and ``drive`` (:mod:`.basic`),
``report_ball`` and ``go_to_report`` (:mod:`.ball_reports`, a fleet's cooperative search).

May import: :mod:`ubf_async.core`, :mod:`ubf_async.wire`, :mod:`ubf_async.errors`,
:mod:`ubf_async.throttle`. Not the runtime (a sibling), the network, the assembly or above: a
behaviour sees a ``State`` and returns an ``Action``.
"""

from ubf_async.behaviors.ball_reports import GoToReport, ReportBall
from ubf_async.behaviors.basic import ConstantDrive, Stop
from ubf_async.behaviors.obstacles import Avoid, nearest_obstacle
from ubf_async.behaviors.pink_ball import (
    CAMERA_SOURCE,
    Chase,
    Flee,
    Search,
    pink_bins,
    seek_pink_ball,
)

__all__ = [
    "CAMERA_SOURCE",
    "Avoid",
    "Chase",
    "ConstantDrive",
    "Flee",
    "GoToReport",
    "ReportBall",
    "Search",
    "Stop",
    "nearest_obstacle",
    "pink_bins",
    "seek_pink_ball",
]
