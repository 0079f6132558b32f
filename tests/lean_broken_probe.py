"""A module that is installed but broken inside (tests/test_lean_install.py): importing it
fails on a module that is no extra's, which must not read as a missing extra."""

import no_such_inner  # type: ignore[import-not-found]  # noqa: F401
