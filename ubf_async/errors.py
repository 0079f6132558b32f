"""One exception tree with one root, :class:`UbfError`.

Library code raises these; only a command line's ``main()`` turns them into an exit status
(:func:`ubf_async.cli.run.run_main`). Each subclass also derives from the built-in exception a
caller would naturally catch (``ValueError``, ``LookupError``), so existing ``except
ValueError`` code keeps working.

::

    UbfError
    ├── ProtocolError        a payload or key that does not follow docs/protocol.md
    └── ConfigurationError   something a user wrote or asked for is wrong
        ├── RobotFileError   a robot file (docs/robot-file.md), with its file and line
        ├── ScenarioError    a scenario file (docs/scenarios.md)
        ├── PluginError      an unknown or broken behaviour/arbiter/device/backend name
        └── TreeChangeError  a live change of the running tree that was refused
"""

from __future__ import annotations


class UbfError(Exception):
    """Root of every error ubf_async raises on purpose."""


class ProtocolError(UbfError, ValueError):
    """A payload or key that does not follow the protocol. The message says what and where."""


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
        super().__init__(self._format())

    def _format(self) -> str:
        where = self.path or "<robot file>"
        if self.line is not None:
            where += f":{self.line}"
        return f"{where}: {self.message}"


class ScenarioError(ConfigurationError):
    """A scenario file that does not follow docs/scenarios.md (the message says where)."""


class PluginError(ConfigurationError, LookupError):
    """A name that no registered plug-in provides, or a plug-in that fails to load."""


class TreeChangeError(ConfigurationError):
    """A live change of the running behaviour tree that was refused; the tree is untouched."""
