"""Which clock samples may move simulated time: the policy of a clock follower.

A process that follows simulation time (a device started on its own, ``launch --no-sim
--sim-time``, a remote behaviour with ``--clock sim``) hears ``ubf/<robot>/clock`` — and so
does anyone else on the bus. :class:`ClockFollower` decides, sample by sample, what such a
sample may do. It is pure (no bus, no clock of its own: the caller passes the host monotonic
time of arrival), so the policy is unit-tested on its own;
:func:`ubf_async.clocks.simclock.follow_sim_clock` wires it to a subscription and a
:class:`~ubf_async.clocks.clock.SimClock`.

The rules:

* Every simulator run publishes a random ``epoch`` with its samples. The follower locks onto
  the epoch it hears first, or onto the one it is configured with (then it never changes).
* Several runs of one robot name may reach a process: another simulator of robot ``mini`` on
  the machine, reached through zenoh's gossip. A follower told the sessions of the robot it
  connected to (``robot_sessions``: :meth:`~ubf_async.runtime.bus.Bus.connected_sessions`)
  locks first onto a run published by one of them (a simulator names its session in its
  samples, ``zid``). Another run heard first is refused (``not the robot's``) for
  ``prefer_s`` of wall time from its first sample; only if the robot's session has published
  no time by then — its simulator runs in another process than the one connected to —
  is the run heard first followed, with a warning.
* Within the locked epoch time never runs backwards (an older time is refused) and never
  jumps forward more than plausible: at most ``max_speed`` × the wall time since the last
  accepted sample, plus ``slack_s`` of simulated time.
* A different epoch (a sample without one counts as the epoch ``None``) is refused while the
  locked one is alive. Once the locked epoch has been silent — no accepted sample — for
  ``takeover_s`` of wall time, the next sample of another epoch starts a new run: the clock
  resets to its time (which may be earlier), and sleepers and periodic loops re-anchor.
* Refused samples are counted per reason in :attr:`ClockFollower.refused` and logged (the
  first and every 100th).

What this does **not** protect against, on an open bus: whoever speaks first locks the
follower when it knows no session of the robot, or the robot's is silent for ``prefer_s``
(configure the epoch to avoid that); a process that names itself with the robot's session id
is taken for it; a process that knows the running epoch can
move time forward at a plausible pace; and once the simulator has been silent for
``takeover_s``, anyone may start a "new run". Making ``ubf/<robot>/clock`` writable only by
the simulator takes zenoh access control (the secure mode).
"""

from __future__ import annotations

import enum
import logging
from collections import Counter
from dataclasses import dataclass

from ubf_async import throttle

__all__ = ["DEFAULT_MAX_SPEED", "DEFAULT_PREFER_S", "DEFAULT_SLACK_S", "DEFAULT_TAKEOVER_S",
           "ClockAction", "ClockFollower", "ClockVerdict"]

log = logging.getLogger(__name__)

DEFAULT_TAKEOVER_S = 1.0
DEFAULT_MAX_SPEED = 1000.0
DEFAULT_SLACK_S = 1.0
DEFAULT_PREFER_S = 2.0
"""How long another run heard first is refused while the robot's own may still speak: a
running simulator sends its time to a new follower within 20 steps of noticing it (0.1 s of
simulated time), and a busy one may take a second."""


class ClockAction(enum.Enum):
    ADVANCE = "advance"
    """Move the clock forward to the sample's time (or keep it: same time)."""
    RESET = "reset"
    """A new run (epoch): reset the clock to the sample's time, which may be earlier."""
    REFUSE = "refuse"
    """Ignore the sample (counted)."""


@dataclass(frozen=True, slots=True)
class ClockVerdict:
    action: ClockAction
    reason: str = ""
    """Why a sample was refused: ``other epoch``, ``backwards``, ``implausible jump``,
    ``not the robot's`` (another run, before the robot's has spoken)."""


_ADVANCE = ClockVerdict(ClockAction.ADVANCE)
_RESET = ClockVerdict(ClockAction.RESET)


class ClockFollower:
    """Decides what each clock sample may do (see the module docstring for the rules).

    ``epoch`` pins the follower to one run; ``takeover_s`` is the wall time the locked epoch
    must be silent before another is accepted; ``max_speed`` (simulated seconds per wall
    second) and ``slack_s`` (simulated seconds) bound a forward jump. ``robot_sessions``: the
    session ids of the robot connected to, whose run is locked onto first; another run heard
    first waits ``prefer_s`` of wall time.
    """

    def __init__(
        self,
        *,
        epoch: str | None = None,
        takeover_s: float = DEFAULT_TAKEOVER_S,
        max_speed: float = DEFAULT_MAX_SPEED,
        slack_s: float = DEFAULT_SLACK_S,
        robot_sessions: frozenset[str] = frozenset(),
        prefer_s: float = DEFAULT_PREFER_S,
        name: str = "clock",
    ) -> None:
        if not takeover_s > 0:
            raise ValueError(f"takeover_s must be > 0, got {takeover_s}")
        if not prefer_s >= 0:
            raise ValueError(f"prefer_s must be >= 0, got {prefer_s}")
        if not max_speed > 0:
            raise ValueError(f"max_speed must be > 0, got {max_speed}")
        if not slack_s >= 0:
            raise ValueError(f"slack_s must be >= 0, got {slack_s}")
        self.pinned = epoch is not None
        self.epoch: str | None = epoch
        """The epoch being followed (``None`` before the first sample unless pinned)."""
        self.takeover_s = takeover_s
        self.max_speed = max_speed
        self.slack_s = slack_s
        self.robot_sessions = robot_sessions
        self.prefer_s = prefer_s
        self.name = name
        self.locked = False
        """Whether a sample was accepted yet."""
        self.runs = 0
        """Runs (epochs) followed so far."""
        self.accepted = 0
        self.refused: Counter[str] = Counter()
        self.last_stamp_ns = 0
        self._last_wall_ns = 0
        self._other_since_ns: int | None = None
        """When another run than the robot's was first heard, before locking."""

    @property
    def refused_total(self) -> int:
        return sum(self.refused.values())

    def offer(self, *, stamp_ns: int, epoch: str | None, wall_ns: int,
              zid: str | None = None) -> ClockVerdict:
        """Judge one sample: simulated time ``stamp_ns`` of run ``epoch``, published by the
        session ``zid`` (if it says), arrived at host monotonic time ``wall_ns``."""
        if not self.locked:
            if self.pinned and epoch != self.epoch:
                return self._refuse("other epoch", stamp_ns, epoch)
            if not self.pinned and self.robot_sessions and zid not in self.robot_sessions:
                if self._other_since_ns is None:
                    self._other_since_ns = wall_ns
                if (wall_ns - self._other_since_ns) / 1e9 < self.prefer_s:
                    return self._refuse("not the robot's", stamp_ns, epoch)
                log.warning("%s: the robot's session (%s) has published no time within %.1f s: "
                            "following run %r of session %s", self.name,
                            ", ".join(sorted(self.robot_sessions)), self.prefer_s, epoch, zid)
            return self._start(stamp_ns, epoch, wall_ns, ClockVerdict(ClockAction.ADVANCE))
        if epoch != self.epoch:
            silent_s = (wall_ns - self._last_wall_ns) / 1e9
            if self.pinned or silent_s < self.takeover_s:
                return self._refuse("other epoch", stamp_ns, epoch)
            log.warning("%s: epoch %r silent for %.1f s: following the new run %r from %.3f s",
                        self.name, self.epoch, silent_s, epoch, stamp_ns / 1e9)
            return self._start(stamp_ns, epoch, wall_ns, _RESET)
        if stamp_ns < self.last_stamp_ns:
            return self._refuse("backwards", stamp_ns, epoch)
        elapsed_s = max(0.0, (wall_ns - self._last_wall_ns) / 1e9)
        if (stamp_ns - self.last_stamp_ns) / 1e9 > self.max_speed * elapsed_s + self.slack_s:
            return self._refuse("implausible jump", stamp_ns, epoch)
        self.last_stamp_ns = stamp_ns
        self._last_wall_ns = wall_ns
        self.accepted += 1
        return _ADVANCE

    def _start(self, stamp_ns: int, epoch: str | None, wall_ns: int,
               verdict: ClockVerdict) -> ClockVerdict:
        self.locked = True
        self.epoch = epoch
        self.runs += 1
        self.last_stamp_ns = stamp_ns
        self._last_wall_ns = wall_ns
        self.accepted += 1
        return verdict

    def _refuse(self, reason: str, stamp_ns: int, epoch: str | None) -> ClockVerdict:
        self.refused[reason] += 1
        n = self.refused_total
        if throttle.first_and_every(n):
            if self.locked:
                following = (f"following epoch {self.epoch!r} at "
                             f"{self.last_stamp_ns / 1e9:.3f} s")
            elif self.pinned:
                following = f"waiting for epoch {self.epoch!r}"
            else:
                following = (f"waiting up to {self.prefer_s:g} s for the time of the robot's "
                             f"session ({', '.join(sorted(self.robot_sessions))})")
            log.warning("%s: refused clock sample #%d (%s): epoch %r at %.3f s while %s",
                        self.name, n, reason, epoch, stamp_ns / 1e9, following)
        return ClockVerdict(ClockAction.REFUSE, reason)
