"""Certificates of a secure set-up: a certificate authority and one certificate per identity.

Made with the ``cryptography`` library (X.509, ECDSA P-256 keys, SHA-256 signatures): the
identity is the certificate's common name (zenoh's ACL matches ``cert_common_names`` on it);
an identity that listens (the robot, a router) also carries its host names and addresses as
subject alternative names, which every client checks against the name it dialled
(``verify_name_on_connect``). Keys are written ``0600``.

:func:`own_certificate_problem` checks, before anything connects, what a process can see of
its own certificate: expired, not yet valid, issued by another CA, another identity's, a key
that does not match.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from ubf_async.errors import ConfigurationError

__all__ = ["CA_DAYS", "IDENTITY_DAYS", "Issued", "check_host", "common_name", "hosts_of", "issue",
           "make_ca", "own_certificate_problem", "read", "signed_by", "write_private"]

CA_DAYS = 3650
IDENTITY_DAYS = 365
_EARLY = datetime.timedelta(minutes=5)
"""Certificates start this long before they are made: a host whose clock is a little behind
the set-up's still accepts them."""


@dataclass(frozen=True, slots=True)
class Issued:
    """A key and its certificate, as PEM bytes."""

    key_pem: bytes
    cert_pem: bytes


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.UTC)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def make_ca(common_name: str, *, days: int = CA_DAYS) -> Issued:
    """A self-signed certificate authority (it signs certificates, nothing else)."""
    key = ec.generate_private_key(ec.SECP256R1())
    now = _now()
    cert = (x509.CertificateBuilder()
            .subject_name(_name(common_name)).issuer_name(_name(common_name))
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - _EARLY).not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(
                digital_signature=False, content_commitment=False, key_encipherment=False,
                data_encipherment=False, key_agreement=False, key_cert_sign=True, crl_sign=True,
                encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()),
                           critical=False)
            .sign(key, hashes.SHA256()))
    return Issued(_key_pem(key), cert.public_bytes(serialization.Encoding.PEM))


def issue(ca: Issued, common_name: str, *, hosts: Sequence[str] = (), days: int = IDENTITY_DAYS,
          not_before: datetime.datetime | None = None) -> Issued:
    """A certificate for ``common_name`` signed by ``ca``, good for TLS clients and servers;
    ``hosts`` (names or IP addresses) become its subject alternative names. ``not_before``
    (default: now) with ``days`` sets its validity (tests make expired ones with it)."""
    ca_key = serialization.load_pem_private_key(ca.key_pem, password=None)
    ca_cert = x509.load_pem_x509_certificate(ca.cert_pem)
    if not isinstance(ca_key, ec.EllipticCurvePrivateKey):
        raise ConfigurationError("the CA's key is not an EC key")
    key = ec.generate_private_key(ec.SECP256R1())
    start = (not_before or _now()) - _EARLY
    builder = (x509.CertificateBuilder()
               .subject_name(_name(common_name)).issuer_name(ca_cert.subject)
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(start)
               .not_valid_after(start + _EARLY + datetime.timedelta(days=days))
               .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
               .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                     ExtendedKeyUsageOID.CLIENT_AUTH]),
                              critical=False)
               .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(
                   ca_key.public_key()), critical=False))
    if hosts:
        builder = builder.add_extension(
            x509.SubjectAlternativeName([_alt_name(h) for h in hosts]), critical=False)
    cert = builder.sign(ca_key, hashes.SHA256())
    return Issued(_key_pem(key), cert.public_bytes(serialization.Encoding.PEM))


def _alt_name(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def check_host(host: str) -> str:
    """``host`` if it can be a certificate's alternative name (an IP address or a DNS
    name); :class:`ConfigurationError` otherwise."""
    try:
        ipaddress.ip_address(host)
        return host
    except ValueError:
        pass
    labels = host.rstrip(".").split(".")
    if not host or not all(label and len(label) <= 63 and label.replace("-", "").isalnum()
                           and not label.startswith("-") for label in labels):
        raise ConfigurationError(f"--host {host!r}: not a host name or IP address")
    return host


def write_private(path: Path, data: bytes) -> None:
    """Write a private key (or any secret), readable by its owner only (0600)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as out:
        out.write(data)
    os.chmod(path, 0o600)  # O_CREAT's mode does not apply to a file that already existed


def read(path: Path, *, what: str) -> x509.Certificate:
    """The certificate in ``path``; :class:`ConfigurationError` naming ``what`` if none."""
    try:
        return x509.load_pem_x509_certificate(path.read_bytes())
    except FileNotFoundError:
        raise ConfigurationError(f"{path}: no such file: {what}") from None
    except (OSError, ValueError) as exc:
        raise ConfigurationError(f"{path}: not a PEM certificate ({what}): {exc}") from None


def common_name(cert: x509.Certificate) -> str:
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(names[0].value) if names else ""


def hosts_of(cert: x509.Certificate) -> list[str]:
    """The host names and addresses a certificate carries (its subject alternative names)."""
    try:
        sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return []
    return [*sans.get_values_for_type(x509.DNSName),
            *(str(a) for a in sans.get_values_for_type(x509.IPAddress))]


def signed_by(cert: x509.Certificate, ca: x509.Certificate) -> bool:
    try:
        cert.verify_directly_issued_by(ca)
        return True
    except (ValueError, TypeError, InvalidSignature):
        return False


def own_certificate_problem(*, cert_path: Path, key_path: Path, ca_path: Path,
                            identity: str, now: datetime.datetime | None = None) -> str | None:
    """What is wrong with a process's own certificate, in words, or ``None``: expired, not yet
    valid, not signed by the set-up's CA, issued to another identity, or not the certificate
    of its private key. Raises :class:`ConfigurationError` for a missing or unreadable file."""
    cert = read(cert_path, what=f"the certificate of identity {identity!r}")
    ca = read(ca_path, what="the set-up's certificate authority")
    try:
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except FileNotFoundError:
        raise ConfigurationError(f"{key_path}: no such file: the private key of identity "
                                 f"{identity!r}") from None
    except (OSError, ValueError, TypeError) as exc:
        raise ConfigurationError(f"{key_path}: not a private key: {exc}") from None
    now = now or _now()
    if cert.not_valid_after_utc < now:
        return (f"the certificate of identity {identity!r} ({cert_path}) expired on "
                f"{cert.not_valid_after_utc:%Y-%m-%d %H:%M} UTC")
    if cert.not_valid_before_utc > now:
        return (f"the certificate of identity {identity!r} ({cert_path}) is not valid before "
                f"{cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC (is this host's clock right?)")
    if not signed_by(cert, ca):
        return (f"the certificate of identity {identity!r} ({cert_path}) is not signed by the "
                f"set-up's certificate authority ({ca_path}): it comes from another set-up")
    if common_name(cert) != identity:
        return (f"{cert_path} is the certificate of {common_name(cert)!r}, not of identity "
                f"{identity!r}")
    if key.public_key() != cert.public_key():
        return f"{key_path} is not the private key of {cert_path}"
    return None
