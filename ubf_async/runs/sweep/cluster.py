"""Joining a Ray cluster for a sweep, or saying in one line why it cannot be joined.

Ray's own failures to join are slow and say little: a head that refuses this machine's token
(or one that wants a token this machine does not send) reads ``ConnectionError: Failed to
connect to Ray cluster`` after 20 s of retries, Ray Client's ``ray client connection
timeout`` after 30 s, and a head that is not there keeps ``ray.init`` retrying for minutes.
So :func:`join` first asks the head once, over a gRPC channel made as Ray makes its own
(``init_grpc_channel``: this process's token, if token authentication is on here), and tells
each cause apart — nothing answers, the token refused, this machine not a node of the cluster
— each as a :class:`~ubf_async.errors.ClusterError` naming the fix. Then ``ray.init``; what it
still raises becomes a ClusterError too. The probe leans on Ray's internals (its channel
helper and its generated gRPC stubs, as of Ray 2.60); where they moved in another Ray, the
probe is left out and ``ray.init`` alone decides.
"""

from __future__ import annotations

import importlib
import logging
import os
import socket
from typing import Any

from ubf_async.errors import ClusterError

__all__ = ["CLIENT_ATTEMPTS", "CLIENT_PREFIX", "CLIENT_SERVER_DIED", "DOCS", "PROBE_S", "join",
           "ray_said"]

PROBE_S = 3.0
"""How long the head has to answer the probe: a head on a LAN answers in milliseconds."""
CLIENT_PREFIX = "ray://"
DOCS = "docs/experiments.md, On a Ray cluster"
_INTERNALS = ("grpc", "ray._private.services",
              "ray._private.authentication.authentication_token_setup",
              "ray._private.authentication.authentication_utils", "ray._private.grpc_utils",
              "ray._raylet", "ray.core.generated.gcs_service_pb2",
              "ray.core.generated.gcs_service_pb2_grpc", "ray.core.generated.ray_client_pb2",
              "ray.core.generated.ray_client_pb2_grpc")
"""What the probe uses of Ray (2.60) and of its gRPC."""
CLIENT_SERVER_DIED = "Starting Ray client server failed"
"""Ray Client's head forks a server for each client, which dies at its start now and then
under load (ray-project/ray#63202, in Ray 2.60): a new connection gets a new one."""
CLIENT_ATTEMPTS = 3
TOKEN_FIX = ("copy the head's ~/.ray/auth_token to this machine's ~/.ray/auth_token (or set "
             "RAY_AUTH_TOKEN)")


def join(address: str | None, ray: Any, runtime_env: dict[str, Any]) -> None:
    """Join the Ray cluster at ``address`` (``auto``: the one this machine is a node of;
    ``ray://HOST:PORT``: through its head's Ray Client port; ``HOST:PORT``: its head's GCS,
    from one of its nodes; ``None``: ``RAY_ADDRESS``, else a new cluster of this machine) with
    ``ray`` (the module), or raise :class:`ClusterError` saying why not and what to do."""
    given = address or os.environ.get("RAY_ADDRESS") or None
    if given is not None and given != "local":
        _probe(given)
    for attempt in range(1, CLIENT_ATTEMPTS + 1):
        try:
            ray.init(address=address, logging_level=logging.WARNING, runtime_env=runtime_env)
            return
        except ray.exceptions.AuthenticationError as exc:
            raise ClusterError(f"cannot join Ray at {given}: {ray_said(exc)}: "
                               f"{TOKEN_FIX} ({DOCS})") from None
        except (ConnectionError, RuntimeError, ValueError) as exc:
            if CLIENT_SERVER_DIED in str(exc) and attempt < CLIENT_ATTEMPTS:
                ray.shutdown()
                continue
            where = f"Ray at {given}" if given else "a new Ray cluster of this machine"
            raise ClusterError(f"cannot join {where}: {ray_said(exc)} "
                               f"({DOCS})") from None


def ray_said(exc: BaseException) -> str:
    """What Ray says, on one line: its first sentence, and of a server's traceback it passes
    on, the last line (the error)."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    if not lines:
        return type(exc).__name__
    if len(lines) > 1 and lines[1].startswith("Traceback"):
        return f"{lines[0].rstrip(':')}: {ray_said(RuntimeError(lines[-1]))}"
    return " ".join(lines).split(". ")[0].rstrip(".")


def _probe(address: str) -> None:
    """Ask the head at ``address`` once (:data:`PROBE_S`); raise :class:`ClusterError` for a
    cause told apart, return when it answers (or when this Ray cannot be probed)."""
    try:
        grpc, services, token_setup, token_utils, channels, raylet, gcs, gcs_grpc, \
            client_pb, client_grpc = (importlib.import_module(name) for name in _INTERNALS)
    except ImportError:  # another Ray's internals: ray.init alone decides
        return
    client = address.startswith(CLIENT_PREFIX)
    target = address.removeprefix(CLIENT_PREFIX)
    if address == "auto":
        # As ray.init does for auto: token authentication on where a token is found.
        token_setup.maybe_enable_token_auth_if_token_available(warn_if_disabled=False)
        try:
            found = services.canonicalize_bootstrap_address("auto")
        except ConnectionError:
            found = None
        if found is None:
            raise ClusterError(
                "cannot join Ray at auto: no Ray cluster runs on this machine: start its head "
                "here (ray start --head) or join one (ray start --address=HEAD_IP:6379), or "
                f"give the head's address (--address ray://HEAD_IP:10001) ({DOCS})")
        target = found
    token_here = bool(token_utils.is_token_auth_enabled())
    if token_here and not raylet.AuthenticationTokenLoader.instance().has_token(
            ignore_auth_mode=True):
        raise ClusterError(f"cannot join Ray at {address}: RAY_AUTH_MODE is 'token' but this "
                           f"machine has no token: {TOKEN_FIX} ({DOCS})")
    channel = channels.init_grpc_channel(target)  # this process's token in each call, as Ray's
    try:
        try:
            grpc.channel_ready_future(channel).result(timeout=PROBE_S)
            if client:
                client_grpc.RayletDriverStub(channel).ClusterInfo(
                    client_pb.ClusterInfoRequest(type=client_pb.ClusterInfoType.PING),
                    timeout=PROBE_S)
                return
            reply = gcs_grpc.NodeInfoGcsServiceStub(channel).GetAllNodeInfo(
                gcs.GetAllNodeInfoRequest(), timeout=PROBE_S)
        except grpc.FutureTimeoutError:
            port = "Ray Client port" if client else "GCS port"
            raise ClusterError(
                f"cannot join Ray at {address}: nothing answers there within {PROBE_S:.0f} s: "
                f"is the head started (ray start --head), and its {port} reachable from this "
                f"machine? ({DOCS})") from None
        except grpc.RpcError as exc:
            if exc.code() == grpc.StatusCode.UNAUTHENTICATED:
                raise _refused(address, token_here=token_here) from None
            return  # not a cause told here: ray.init says it
    finally:
        channel.close()
    if not _a_node_of(target, reply):
        raise ClusterError(
            f"cannot join Ray at {address}: this machine is not a node of that cluster (a "
            f"HOST:PORT address is for its nodes): connect through the head's Ray Client port "
            f"(--address ray://HOST:10001), or make this machine a node first (ray start "
            f"--address={target}) ({DOCS})")


def _refused(address: str, *, token_here: bool) -> ClusterError:
    if token_here:
        return ClusterError(f"cannot join Ray at {address}: the head refused this machine's "
                            f"token (not the head's): {TOKEN_FIX} ({DOCS})")
    return ClusterError(f"cannot join Ray at {address}: the head requires a token and this "
                        f"machine sends none (RAY_AUTH_MODE is not 'token' here): export "
                        f"RAY_AUTH_MODE=token, and {TOKEN_FIX} ({DOCS})")


def _a_node_of(target: str, reply: Any) -> bool:
    """Whether this machine runs a live node of the cluster whose GCS is ``target``: the
    address it reaches the head from is a live node's (Ray's own test for a driver)."""
    host, _, port = target.rpartition(":")
    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET,
                           socket.SOCK_DGRAM) as probe:
            probe.connect((host.strip("[]"), int(port)))  # UDP: nothing is sent
            here = probe.getsockname()[0]
    except (OSError, ValueError):
        return True  # cannot tell: ray.init says
    alive = [node.node_manager_address for node in reply.node_info_list if node.state == 0]
    return here in alive or (host in ("127.0.0.1", "localhost", "::1") and bool(alive))
