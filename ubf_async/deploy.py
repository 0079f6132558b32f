"""``python -m ubf_async.deploy``: the public entry point. The program is
:mod:`ubf_async.tools.deploy` (a systemd unit starting a robot at boot, docs/deploy.md)."""

from ubf_async.tools.deploy import main

__all__ = []

if __name__ == "__main__":
    raise SystemExit(main())
