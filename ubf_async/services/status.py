"""The live status line of ``python -m ubf_async.launch``.

Fields come in order of importance — the run's time, the drive command and who won, the tick
rates labelled by what ran them, the simulation's real-time factor, anything wrong, then each
source with the age of its newest sample — and :func:`fit` packs them into at most two lines
of the terminal's width: a field never runs off the edge, and what does not fit is counted
(``+3 more``) rather than wrapped by the terminal, so redrawing in place never scrolls.

The tick rate says what ticked: ``tick 50.0Hz`` is the clock's periodic ticks, ``+reflex
24.9Hz`` the ticks run at once by a reflex sample, ``sync 9.1Hz`` the thesis's loop (one tick
per frame of its sync source), ``event`` a triggered controller's. The same labels name the
plan before a run (:func:`planned_ticks`: the launch banner, ``launch --check``) and a running
controller seen from another process (``inspector state``, :func:`tick_rates`).
"""

from __future__ import annotations

import time
from collections.abc import Collection, Sequence
from typing import TextIO

from ubf_async.clocks.clock import Clock
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.component import HealthMonitor
from ubf_async.runtime.controller import Controller, TickMode
from ubf_async.wire.topics import LED_STATE, sensor_topic

__all__ = ["CLOCK_SILENT_S", "MAX_LINES", "SEPARATOR", "StatusWriter", "fit", "followed_clock",
           "planned_ticks", "status_fields",
           "tick_label", "tick_rates"]

SEPARATOR = " | "
MAX_LINES = 2


def tick_rates(mode: str, total_hz: float | None, periodic_hz: float | None, *,
               reflex: bool = True, source: str | None = None) -> str:
    """The tick rates, each named by what ran the ticks: ``tick 50.0Hz +reflex 24.9Hz``
    (periodic: the clock's ticks, then those run at once by a reflex sample), ``sync 9.1Hz
    (camera/front)``, ``event 25.0Hz (range/front)``. ``reflex``: whether reflex ticks can
    happen (the gap between all ticks and the clock's is shown only then)."""
    if mode == TickMode.PERIODIC.value:
        label = f"tick {periodic_hz:.1f}Hz" if periodic_hz else "tick --"
        extra = (total_hz or 0.0) - (periodic_hz or 0.0)
        if reflex and extra >= 0.05:
            label += f" +reflex {extra:.1f}Hz"
        return label
    rate = f"{total_hz:.1f}Hz" if total_hz else "--"
    return f"{mode} {rate}" + (f" ({source})" if source else "")


def tick_label(controller: Controller) -> str:
    """The controller's tick rates now (:func:`tick_rates`)."""
    stats = controller.stats
    source = controller.sync_source if controller.mode is TickMode.SYNC else controller.trigger
    return tick_rates(controller.mode.value, stats.rate_hz(), stats.periodic_rate_hz(),
                      reflex=bool(controller.reflex_sources), source=source)


def planned_ticks(mode: TickMode, *, rate_hz: float, reflex: Sequence[str] = (),
                  sync_source: str = "", trigger: str | None = None,
                  sources: Collection[str] | None = None) -> str:
    """What will tick a controller, in the status line's terms, before it runs (the launch
    banner, ``launch --check``). Only a periodic controller ticks at ``rate_hz``: a sync or
    event controller ticks per sample and re-sends its last decision at ``rate_hz`` between
    ticks (a hold), and it takes no reflex ticks. ``sources``: the robot's own sources
    (``kind/name``); a reflex prefix that none of them starts with is not said, as none of
    them will tick the controller (a robot without a range finder has no ``range/`` reflex)."""
    if mode is TickMode.PERIODIC:
        ticking = [p for p in reflex
                   if sources is None or any(s.startswith(p) for s in sources)]
        return (f"periodic tick {rate_hz:g}Hz"
                + (f" +reflex on each {', '.join(ticking)} sample" if ticking
                   else " (no reflex source)" if reflex else " (no reflex)"))
    source = sync_source if mode is TickMode.SYNC else trigger
    loop = "the thesis's loop; " if mode is TickMode.SYNC else ""
    return (f"{mode.value} on each {source} sample ({loop}between ticks the decision is "
            f"re-sent at {rate_hz:g} Hz)")


def status_fields(robot: str, elapsed_s: float, controller: Controller,
                  aggregator: StateAggregator, health: HealthMonitor, *,
                  simulation: str = "") -> list[str]:
    """The status line's fields, most important first."""
    fields = [f"[{robot}] {elapsed_s:.1f}s"]
    last = controller.last_action
    if last is not None:
        winners = ",".join(controller.last_trace.winning_leaves()) if controller.last_trace else ""
        fields.append(f"drive {last.speed:+.0f}/{last.turn:+.0f} ({winners or 'stop'})")
    fields.append(tick_label(controller))
    if simulation:
        fields.append(simulation)
    quarantined = controller.quarantined()
    if quarantined:
        fields.append("QUARANTINED " + ",".join(quarantined))
    if controller.tree_changes:  # the run is no longer the robot file's (inspector, monitor)
        fields.append(f"tree changed {len(controller.tree_changes)}")
    unhealthy = health.unhealthy()
    if unhealthy:
        fields.append("UNHEALTHY " + ",".join(unhealthy))
    bad = sum(aggregator.malformed.values())
    if bad:
        fields.append(f"rejected {bad}")
    refused = {reason: n for reason, n in aggregator.refusals().items()
               if n and reason != "malformed"}
    if refused:
        fields.append("refused " + ",".join(f"{reason} {n}" for reason, n in refused.items()))
    evicted = aggregator.dropped()["evicted"]
    if evicted:  # the table full: a flood of names (forgetting the silent is no news)
        fields.append(f"evicted {evicted}")
    if controller.stats.tick_faults:
        fields.append(f"TICK FAULTS {controller.stats.tick_faults}")
    if controller.stats.overruns:
        fields.append(f"overruns {controller.stats.overruns}")
    sources = aggregator.sources()
    if not sources:
        fields.append(f"no sensors yet (waiting on ubf/{robot}/sensor/*/*)")
    now_s = time.monotonic()
    for s in sources:
        if s.departed is not None:  # why it is quiet, instead of an age that keeps growing
            fields.append(f"{s.source} {s.departed.describe(now_s)}")
            continue
        fields.append(f"{s.source}{_reading(aggregator, s.source)} {s.age_s * 1e3:.0f}ms"
                      f"{' STALE' if s.stale else ''}")
    return fields


CLOCK_SILENT_S = 2.0
"""Wall seconds a followed simulated clock's source may be silent before the status line says
so: a replay or a simulator of another process that ended leaves the robot's time still."""


def followed_clock(clock: Clock, *, wall_now_ns: int | None = None) -> str:
    """The status line's field for a robot following a simulated clock published elsewhere
    (``launch --no-sim --sim-time`` fed by a replay or a simulator of another process): its
    time, and once its source has been silent :data:`CLOCK_SILENT_S`, that it has (the replay
    ended: the sources go stale and the robot's time stands still). Empty on wall time."""
    if not clock.is_simulated:
        return ""
    silent = clock.stalled_s(wall_now_ns)
    return (f"sim {clock.now_ns() / 1e9:.1f}s"
            + (f" CLOCK SILENT {silent:.0f}s (its replay or simulator ended?)"
               if silent >= CLOCK_SILENT_S else ""))


def _reading(aggregator: StateAggregator, source: str) -> str:
    """What a source shows besides its age: the LEDs, lit ● or dark ○ (LED 0 first)."""
    if sensor_topic(source) is not LED_STATE:
        return ""
    leds = aggregator.entries[source].message.data
    return " " + "".join("●" if leds.mask >> i & 1 else "○" for i in range(leds.count))


def fit(fields: Sequence[str], width: int, *, max_lines: int = MAX_LINES) -> list[str]:
    """Pack ``fields`` in order into at most ``max_lines`` lines of at most ``width``
    characters; a field longer than a line is cut (``…``), and the fields left over are
    counted at the end (``+N more``)."""
    width = max(width, 20)
    lines: list[list[str]] = [[]]
    for index, field in enumerate(fields):
        if len(field) > width:
            field = field[: width - 1] + "…"
        if len(SEPARATOR.join([*lines[-1], field])) <= width:
            lines[-1].append(field)
        elif len(lines) < max_lines:
            lines.append([field])
        else:
            left, last = len(fields) - index, lines[-1]
            while last and len(SEPARATOR.join([*last, f"+{left} more"])) > width:
                last.pop()
                left += 1
            last.append(f"+{left} more")
            break
    return [SEPARATOR.join(line) for line in lines]


class StatusWriter:
    """Writes status lines: redrawn in place on a terminal, one plain line per period
    otherwise (a log, a pipe, CI)."""

    def __init__(self, out: TextIO, *, width: int | None = None) -> None:
        self.out = out
        self.interactive = out.isatty()
        self._width = width
        self._drawn = 0

    def width(self) -> int:
        if self._width is not None:
            return self._width
        import shutil

        return shutil.get_terminal_size(fallback=(200, 24)).columns

    def write(self, fields: Sequence[str]) -> None:
        if not self.interactive:
            self.out.write(SEPARATOR.join(fields) + "\n")
        else:
            lines = fit(fields, self.width() - 1)  # the last column would wrap on some TTYs
            erase = "\x1b[1A\x1b[2K" * max(0, self._drawn - 1)
            self.out.write(erase + "\r\x1b[2K" + "\n\x1b[2K".join(lines))
            self._drawn = len(lines)
        self.out.flush()

    def end(self) -> None:
        """Leave the last status on screen and move below it."""
        if self.interactive and self._drawn:
            self.out.write("\n")
            self.out.flush()
            self._drawn = 0
