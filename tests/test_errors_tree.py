"""Every error the project raises on purpose is in one tree under ``UbfError`` (issue 53, item
5): a public exception class defined in ``ubf_async`` or ``components`` derives from the
project's errors, not from a built-in exception alone — besides ``UbfError`` itself, the
private ones (a module's own control flow) and ``BaseException`` signals like
``KeyboardInterrupt`` (``components.motors.check.Interrupted``)."""

from __future__ import annotations

import ast
import builtins
from pathlib import Path

from components.camera.videocapture import CameraError
from components.range.backend import RangeReadError
from components.sim.render.process import RenderProcessError
from ubf_async.errors import DeviceError, UbfError

ROOT = Path(__file__).resolve().parent.parent
BUILTIN_EXCEPTIONS = {name for name, value in vars(builtins).items()
                      if isinstance(value, type) and issubclass(value, BaseException)}


def test_every_public_exception_class_is_under_ubf_error() -> None:
    outside = []
    for package in ("ubf_async", "components"):
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text("utf-8"))):
                if not isinstance(node, ast.ClassDef) or node.name.startswith("_"):
                    continue
                bases = {base.id for base in node.bases if isinstance(base, ast.Name)}
                if not bases or not bases <= BUILTIN_EXCEPTIONS or bases == {"BaseException"}:
                    continue  # not an exception, or one of ours, or a signal
                if f"{path.relative_to(ROOT)}:{node.name}" != "ubf_async/errors.py:UbfError":
                    outside.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.name}"
                                   f"({', '.join(sorted(bases))})")
    assert not outside, "exceptions outside the UbfError tree:\n" + "\n".join(outside)


def test_the_devices_errors_are_device_errors_and_still_what_callers_caught() -> None:
    for error in (CameraError, RangeReadError, RenderProcessError):
        assert issubclass(error, DeviceError) and issubclass(error, UbfError)
        assert issubclass(error, OSError)  # RangeReadError was one; a hardware failure is
