"""Why a TLS endpoint did not let this process in, found with a handshake of its own.

zenoh reports every refused TLS link as "Unable to connect to any of [...]" — the same words as
for nothing listening — and says nothing of the reason. So a process that could not connect
shakes hands with the endpoint itself, with Python's :mod:`ssl` and this process's own
certificate, and reads which side refused what: this process refusing the robot's certificate
(another CA, not the name dialled, expired), the robot refusing this process's (none, unknown
CA, expired, bad), or no TLS there at all. Blocking: run it in a worker thread.
"""

from __future__ import annotations

import socket
import ssl
from dataclasses import dataclass
from pathlib import Path

__all__ = ["PROBE_TIMEOUT_S", "Finding", "peer_names", "probe", "split_endpoint"]

PROBE_TIMEOUT_S = 1.0
"""How long the probe waits to connect, and after its handshake for the robot's verdict on
this process's certificate (in TLS 1.3 the server checks it after the client has finished)."""

# OpenSSL's verify codes for this side's check of the robot's certificate (x509_vfy.h)
_EXPIRED, _NOT_YET = 10, 9
_UNKNOWN_ISSUER = (2, 18, 19, 20, 21)
_NAME_MISMATCH = (62, 64)


@dataclass(frozen=True, slots=True)
class Finding:
    """What the probe found: ``kind`` is one of ``no-tls`` (the endpoint does not speak TLS),
    ``server-unknown-ca``, ``server-name``, ``server-expired``, ``server-other`` (this side
    refuses the robot's certificate), ``client-required``, ``client-unknown-ca``,
    ``client-expired``, ``client-bad`` (the robot refuses this process's certificate),
    ``accepted`` (TLS went through: a refusal, if any, comes later), ``tls-speaks`` (a
    handshake without verification went through: the endpoint speaks TLS); ``detail`` is
    what ssl said."""

    kind: str
    detail: str = ""


def split_endpoint(endpoint: str) -> tuple[str, str, int] | None:
    """``(protocol, host, port)`` of ``tcp/HOST:PORT`` or ``tls/HOST:PORT`` (options cut)."""
    plain = endpoint.split("?", 1)[0].split("#", 1)[0]
    proto, _, rest = plain.partition("/")
    host, _, port = rest.rpartition(":")
    if proto not in ("tcp", "tls") or not host or not port.isdigit():
        return None
    return proto, host.strip("[]"), int(port)


def probe(host: str, port: int, *, ca: Path | None, cert: Path | None = None,
          key: Path | None = None, timeout_s: float = PROBE_TIMEOUT_S) -> Finding | None:
    """Shake hands with ``host:port`` as a TLS client verifying the server against ``ca``
    (its name against ``host``) and presenting ``cert``/``key``; without ``ca`` nothing is
    verified (is it TLS at all?). ``None`` when nothing accepts a TCP connection there."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    if ca is None:
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
    else:
        context.load_verify_locations(cafile=str(ca))
    if cert is not None and key is not None:
        context.load_cert_chain(str(cert), str(key))
    finding = _shake_hands(host, port, context, verify=ca is not None, timeout_s=timeout_s)
    if finding is _SLOW:  # a busy host's robot, most likely: give it longer, once
        finding = _shake_hands(host, port, context, verify=ca is not None,
                               timeout_s=SLOW_TIMEOUT_S)
    return None if finding is None else (
        Finding("no-tls", "no answer to the handshake") if finding is _SLOW else finding)


SLOW_TIMEOUT_S = 5.0
"""The second try's wait for a handshake that got no answer within :data:`PROBE_TIMEOUT_S`."""
_SLOW = Finding("slow")


def _shake_hands(host: str, port: int, context: ssl.SSLContext, *, verify: bool,
                 timeout_s: float) -> Finding | None:
    try:
        raw = socket.create_connection((host, port), timeout=timeout_s)
    except OSError:
        return None
    with raw:
        try:
            tls = context.wrap_socket(raw, server_hostname=host)
        except ssl.SSLCertVerificationError as exc:
            return Finding(_server_refused(exc.verify_code), exc.verify_message)
        except ssl.SSLError as exc:
            return Finding(_client_refused(exc) or "no-tls", exc.reason or str(exc))
        except TimeoutError:  # no answer yet: not proof that it does not speak TLS
            return _SLOW
        except OSError as exc:  # closed before any TLS: not a TLS listener
            return Finding("no-tls", str(exc) or type(exc).__name__)
        with tls:
            if not verify:
                return Finding("tls-speaks")
            try:
                tls.recv(1)  # the robot's verdict on this certificate comes as an alert
            except ssl.SSLError as exc:
                return Finding(_client_refused(exc) or "client-bad", exc.reason or str(exc))
            except (TimeoutError, OSError):
                pass  # nothing to read: it waits for zenoh's handshake, TLS went through
            return Finding("accepted")


def _server_refused(code: int) -> str:
    if code in _NAME_MISMATCH:
        return "server-name"
    if code in (_EXPIRED, _NOT_YET):
        return "server-expired"
    if code in _UNKNOWN_ISSUER:
        return "server-unknown-ca"
    return "server-other"


def _client_refused(exc: ssl.SSLError) -> str | None:
    reason = (exc.reason or "").upper()
    if "CERTIFICATE_REQUIRED" in reason or "HANDSHAKE_FAILURE" in reason:
        return "client-required"
    if "UNKNOWN_CA" in reason:
        return "client-unknown-ca"
    if "CERTIFICATE_EXPIRED" in reason:
        return "client-expired"
    if "BAD_CERTIFICATE" in reason or "CERTIFICATE_UNKNOWN" in reason \
            or "DECRYPT_ERROR" in reason:
        return "client-bad"
    return None


def peer_names(host: str, port: int, *, timeout_s: float = PROBE_TIMEOUT_S) -> list[str]:
    """The names and addresses the certificate served at ``host:port`` carries (read without
    verifying it); empty if none could be read."""
    from ubf_async.net import pki  # (cryptography: only when a name is wrong)

    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname = False
    context.verify_mode = ssl.CERT_NONE
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as raw, \
                context.wrap_socket(raw, server_hostname=host) as tls:
            der = tls.getpeercert(binary_form=True)
    except OSError:
        return []
    return pki.hosts_of(pki.x509.load_der_x509_certificate(der)) if der else []
