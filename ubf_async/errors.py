"""One exception tree with one root, :class:`UbfError`.

Library code raises these; only a command line's ``main()`` turns them into an exit status
(:func:`ubf_async.cli.run.run_main`, :func:`~ubf_async.cli.run.run_sync`). Each subclass also
derives from the built-in exception a caller would naturally catch (``ValueError``,
``LookupError``), so existing ``except ValueError`` code keeps working.

::

    UbfError
    ├── ProtocolError          a payload or key that does not follow docs/protocol.md
    ├── KeyExprError           a key expression zenoh refuses too (the in-process transport)
    ├── ConfigurationError     something a user wrote or asked for is wrong
    │   ├── RobotFileError     a robot file (docs/robot-file.md), with its file and line
    │   │   ├── SweepSpecError     a sweep's SPEC (docs/sweep.md), SPEC:LINE
    │   │   ├── EvolveSpecError    an evolution's SPEC (docs/evolve.md), SPEC:LINE
    │   │   └── OverridePathError  an override's path that leads nowhere in the robot file
    │   ├── JournalError       a run journal that cannot be read as one (FILE:LINE)
    │   ├── ParameterError     parameters a plug-in's factory refuses (its signature says why)
    │   ├── ScenarioError      a scenario file (docs/scenarios.md)
    │   ├── PluginError        an unknown or broken behaviour/arbiter/device/backend name
    │   │   └── MissingExtraError  a feature whose extra is not installed (ubf_async.extras)
    │   ├── TreeChangeError    a live change of the running tree that was refused
    │   ├── NameTakenError     a component name already alive on the robot
    │   ├── UnknownFieldError  a field a sample's topic does not declare (a behaviour's typo)
    │   └── NotAllowedError    what the robot's ACL would drop (secure mode)
    ├── SessionError           a zenoh session that cannot be opened or reach the robot
    │   ├── PortInUseError     a listen port another process holds
    │   ├── NoRobotError       no robot answers at the endpoints
    │   └── RefusedError       something there refuses this session (secure mode)
    ├── ClusterError           a Ray cluster a sweep cannot join (the cause and the fix)
    │   └── RunsLostError      runs lost with a worker of the cluster (a node that died)
    ├── DeviceError            a device's hardware or driver failed (a camera that cannot open
    │                          or read, a range finder's bus read), OSError too
    ├── QueryError             a queryable answered with an error
    ├── SettleError            the in-process network still busy after its limit
    ├── ResultsNotSavedError   a run's summary or recording could not be written
    └── ShutdownError          a step of a program's end failed
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["ClusterError", "ConfigurationError", "DeviceError", "EvolveSpecError", "JournalError",
           "KeyExprError", "MissingExtraError", "NameTakenError", "NoRobotError",
           "NotAllowedError", "OverridePathError", "ParameterError", "PluginError",
           "PortInUseError", "ProtocolError", "QueryError", "RefusedError",
           "ResultsNotSavedError", "RobotFileError", "RunsLostError", "ScenarioError",
           "SessionError", "SettleError", "ShutdownError", "SweepSpecError", "TreeChangeError",
           "UbfError", "UnknownFieldError"]


class UbfError(Exception):
    """Root of every error ubf_async raises on purpose."""


class ProtocolError(UbfError, ValueError):
    """A payload or key that does not follow the protocol. The message says what and where."""


class DeviceError(UbfError, OSError):
    """A device's hardware or its driver failed: a camera that cannot be opened or yields no
    frame, a range finder's bus read. The devices' own errors derive from it."""


class KeyExprError(UbfError, ValueError):
    """A key expression the in-process transport cannot route (zenoh refuses it too)."""


class ConfigurationError(UbfError, ValueError):
    """A configuration a user wrote or asked for is wrong; the message says what and where."""


class RobotFileError(ConfigurationError):
    """A robot file that does not follow the format.

    ``str()`` reads ``FILE:LINE: message`` (``FILE: message`` when the line is unknown), as
    compilers and linters print it, so editors can jump to the place.
    """

    def __init__(self, message: str, *, path: str | None = None, line: int | None = None,
                 column: int | None = None) -> None:
        self.message = message
        self.path = path
        self.line = line
        self.column = column
        self.problems: tuple[RobotFileError, ...] = (self,)
        """Every mistake this error tells (:meth:`all_of`): itself alone, or several."""
        super().__init__(self._format())

    @classmethod
    def all_of(cls, problems: Sequence[RobotFileError]) -> RobotFileError:
        """One error of this type telling every one of ``problems`` (one or more), so that a
        file with three mistakes is told all three at once: ``FILE: 3 mistakes:`` then each
        ``FILE:LINE: message`` on a line of its own, in the file's order (one alone reads as
        itself)."""
        if len(problems) == 1:
            [only] = problems
            return cls(only.message, path=only.path, line=only.line, column=only.column)
        ordered = sorted(problems, key=lambda problem: problem.line or 0)  # the file's order
        told = cls(f"{len(problems)} mistakes:" + "".join(f"\n  {p}" for p in ordered),
                   path=ordered[0].path)
        told.problems = tuple(ordered)
        return told

    @property
    def where(self) -> str:
        """``FILE:LINE`` (``FILE`` when the line is unknown)."""
        where = self.path or "<robot file>"
        return where if self.line is None else f"{where}:{self.line}"

    def _format(self) -> str:
        return f"{self.where}: {self.message}"


class SweepSpecError(RobotFileError):
    """A sweep spec that does not hold together; reads ``SPEC:LINE: message`` as a robot file's
    errors do."""


class EvolveSpecError(RobotFileError):
    """An evolution SPEC that does not hold together (``SPEC:LINE: message``)."""


class OverridePathError(RobotFileError):
    """An override's path that does not lead to a place of the robot file (whatever its
    value)."""


class JournalError(ConfigurationError):
    """A journal that cannot be read as one (``FILE:LINE: …``)."""


class ParameterError(ConfigurationError):
    """Parameters that the signature of a plug-in's factory refuses
    (:func:`ubf_async.assembly.registry.checked_params`).

    ``what`` names the factory (``backend encoders.sim``), ``problem`` is msgspec's (``Object
    contains unknown field `glitch```), ``at`` the field's place in msgspec's notation
    (``$.glitch``; empty for the parameters as a whole) and ``takes`` the parameters the factory
    takes. ``str()`` reads ``WHAT: PROBLEM (at $.FIELD); it takes: A, B``; a robot file tells
    the same refusal at its own place (:meth:`told_at`), after ``FILE:LINE:``.
    """

    def __init__(self, what: str, problem: str, *, at: str = "",
                 takes: tuple[str, ...] = ()) -> None:
        self.what = what
        self.problem = problem
        self.at = at
        self.takes = takes
        super().__init__(self.told_at(at))

    def told_at(self, place: str) -> str:
        """The refusal with the field's place named ``place`` (none when empty)."""
        where = f" (at {place})" if place else ""
        return f"{self.what}: {self.problem}{where}; it takes: {', '.join(self.takes) or 'none'}"


class ScenarioError(ConfigurationError):
    """A scenario file that does not follow docs/scenarios.md (the message says where)."""


class PluginError(ConfigurationError, LookupError):
    """A name that no registered plug-in provides, or a plug-in that fails to load."""


class MissingExtraError(PluginError, ImportError):
    """A feature needs an optional part of the install (an *extra*) that is not installed:
    ``str()`` names the feature, the extra and the command that installs it
    (:func:`ubf_async.extras.require`)."""

    def __init__(self, who: str, extra: str, missing: str, *, where: str | None = None) -> None:
        """``where``: the place that asked for the feature (a robot file's ``FILE:LINE``),
        which ``str()`` then starts with, as a :class:`RobotFileError`'s does."""
        self.who = who
        self.extra = extra
        self.missing = missing
        self.where = where
        said = (f"{who} needs the '{extra}' extra ({missing} is not installed): "
                f"pip install 'ubf-async[{extra}]'")
        super().__init__(said if where is None else f"{where}: {said}")

    def asked_at(self, where: str) -> MissingExtraError:
        """The same error, told where it was asked for (``FILE:LINE``)."""
        return MissingExtraError(self.who, self.extra, self.missing, where=where)


class TreeChangeError(ConfigurationError):
    """A live change of the running behaviour tree that was refused; the tree is untouched."""


class NameTakenError(ConfigurationError):
    """A component name already alive on the robot (see :func:`ensure_name_free`)."""


class UnknownFieldError(ConfigurationError, AttributeError):
    """A behaviour asked a sample for a field its topic does not declare (a typo)."""


class NotAllowedError(ConfigurationError):
    """An identity about to send what the robot's ACL would drop without a word."""


class SessionError(UbfError, ConnectionError):
    """A zenoh session that cannot be opened, or does not reach the robot (one line that
    says what to do)."""


class PortInUseError(SessionError):
    """A listen endpoint whose port another process already holds."""


class NoRobotError(SessionError):
    """Nothing to connect to: no robot answers at the endpoints given."""


class RefusedError(SessionError):
    """Something listens at the robot's endpoint but did not accept this process's zenoh
    session: a robot in secure mode refusing its credentials, as far as can be told."""


class ClusterError(UbfError, ConnectionError):
    """A Ray cluster that a sweep cannot join: one line naming the cause (nothing answers,
    a token missing or refused, this machine not a node) and the fix."""


class RunsLostError(ClusterError):
    """Runs lost with the worker that held them (a Ray node that died mid-sweep); the runs
    finished are in the journal, and resuming runs the lost ones again."""


class QueryError(UbfError, RuntimeError):
    """A queryable answered with an error instead of a reply (see
    :meth:`Bus.query <ubf_async.runtime.bus.Bus.query>`)."""


class SettleError(UbfError, RuntimeError):
    """:meth:`InProcessTransport.settle <ubf_async.net.inprocess.InProcessTransport.settle>`
    found work still pending after its limit."""


class ResultsNotSavedError(UbfError, OSError):
    """The run's summary or recording could not be written at the end of the run; the summary
    was printed instead (the message says where writing failed)."""


class ShutdownError(UbfError):
    """A step of the end failed (logged as it happened); everything else was still done."""
