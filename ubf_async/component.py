"""Deprecated: ``ubf_async.component``, the components' home before the rooms (issue 26).
Import ``Component`` from :mod:`ubf_async` (``from ubf_async import Component``); this module
goes in the next release."""

import warnings

from ubf_async.runtime.component import Component

__all__ = ["Component"]

warnings.warn("ubf_async.component is deprecated and goes in the next release: "
              "use `from ubf_async import Component`", DeprecationWarning, stacklevel=2)
