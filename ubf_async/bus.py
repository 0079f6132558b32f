"""Deprecated: ``ubf_async.bus``, the bus's home before the rooms (issue 26). Import ``Bus``
from :mod:`ubf_async` (``from ubf_async import Bus``); this module goes in the next release."""

import warnings

from ubf_async.runtime.bus import Bus

__all__ = ["Bus"]

warnings.warn("ubf_async.bus is deprecated and goes in the next release: "
              "use `from ubf_async import Bus`", DeprecationWarning, stacklevel=2)
