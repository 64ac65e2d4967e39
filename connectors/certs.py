"""Self-signed OPC UA application certificates (OPC 10000-6 §6.2.2) for tests and first start.

A plant uses certificates from its own PKI; this helper makes ones good enough for the
embedded default and the tests: RSA 2048, SHA-256, the application URI as a URI
SubjectAlternativeName (a peer checks it against the ApplicationUri it announces), DNS
``localhost`` and IP ``127.0.0.1``, key usage as Part 6 asks and the extended key usage of a
client and/or server. Files are PEM; :class:`asyncua.crypto.truststore.TrustStore` and
node-opcua read PEM.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CertPair:
    """Paths of one application's certificate and private key (PEM) and its URI."""

    certificate: Path
    private_key: Path
    application_uri: str


def make_certificate(
    directory: Path | str,
    name: str,
    application_uri: str,
    *,
    client: bool = True,
    server: bool = False,
    hostnames: tuple[str, ...] | None = None,
    ips: tuple[str, ...] = ("127.0.0.1",),
    days: int = 365,
) -> CertPair:
    """Write ``<name>.pem`` and ``<name>.key.pem`` into ``directory``; return their paths.

    ``client``/``server`` choose the extended key usages (clientAuth/serverAuth); the DNS
    names are ``localhost`` and this host's name unless ``hostnames`` says otherwise.
    """
    from asyncua.crypto import cert_gen
    from cryptography import x509
    from cryptography.x509.oid import ExtendedKeyUsageOID

    if not (client or server):
        raise ValueError("a certificate must be for a client, a server or both")
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    key = cert_gen.generate_private_key()
    san: list[x509.GeneralName] = [x509.UniformResourceIdentifier(application_uri)]
    if hostnames is None:
        hostnames = tuple(dict.fromkeys(("localhost", socket.gethostname())))
    san += [x509.DNSName(h) for h in hostnames]
    san += [x509.IPAddress(ipaddress.ip_address(i)) for i in ips]
    usage = []
    if client:
        usage.append(ExtendedKeyUsageOID.CLIENT_AUTH)
    if server:
        usage.append(ExtendedKeyUsageOID.SERVER_AUTH)
    cert = cert_gen.generate_self_signed_app_certificate(
        key, name, {"organizationName": "diag-plugin"}, san, extended=usage, days=days
    )
    from cryptography.hazmat.primitives import serialization

    cert_path, key_path = d / f"{name}.pem", d / f"{name}.key.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(cert_gen.dump_private_key_as_pem(key))
    key_path.chmod(0o600)
    log.info("wrote certificate %s for %s", cert_path, application_uri)
    return CertPair(cert_path, key_path, application_uri)


def trust(pair: CertPair, trusted_dir: Path | str) -> Path:
    """Copy ``pair``'s certificate into a trust-list folder (what an administrator does)."""
    d = Path(trusted_dir)
    d.mkdir(parents=True, exist_ok=True)
    target = d / pair.certificate.name
    target.write_bytes(pair.certificate.read_bytes())
    return target


def certificate_der(path: Path | str) -> bytes:
    """The DER bytes of a PEM or DER certificate file; ValueError saying why it is unreadable."""
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding

    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        if b"-----BEGIN" in data:
            cert = x509.load_pem_x509_certificate(data)
        else:
            cert = x509.load_der_x509_certificate(data)
    except ValueError as exc:
        raise ValueError(f"{path}: not a PEM or DER X.509 certificate ({exc})") from None
    return cert.public_bytes(Encoding.DER)


def check_private_key(path: Path | str) -> None:
    """ValueError saying why ``path`` is not a readable, unencrypted PEM/DER private key."""
    from cryptography.hazmat.primitives import serialization

    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    load = (
        serialization.load_pem_private_key
        if b"-----BEGIN" in data
        else serialization.load_der_private_key
    )
    try:
        load(data, password=None)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: not an unencrypted PEM or DER private key ({exc})") from None


def fingerprint(der: bytes) -> str:
    """SHA-256 fingerprint of a DER certificate, as colon-separated hex (what tools print)."""
    import hashlib

    return ":".join(f"{b:02X}" for b in hashlib.sha256(der).digest())


def ensure_certificate(
    certificate: Path, private_key: Path, application_uri: str, *, server: bool = True
) -> bool:
    """Create a self-signed certificate and key at these paths when the certificate is absent
    (a first start); True when created. An existing pair is left alone."""
    certificate, private_key = Path(certificate), Path(private_key)
    if certificate.exists():
        return False
    import tempfile

    certificate.parent.mkdir(parents=True, exist_ok=True)
    private_key.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=certificate.parent) as tmp:
        pair = make_certificate(
            tmp, "cert", application_uri, client=not server, server=server, days=3650
        )
        pair.private_key.replace(private_key)
        pair.certificate.replace(certificate)
    return True


def trusted_ders(folder: Path | str | None) -> dict[bytes, Path]:
    """DER bytes of every certificate file in a trust-list folder (unreadable files raise
    ValueError naming them; other files such as README are skipped by extension)."""
    out: dict[bytes, Path] = {}
    if folder is None or not Path(folder).is_dir():
        return out
    for p in sorted(Path(folder).iterdir()):
        if p.suffix.lower() in (".pem", ".der", ".crt", ".cer"):
            out[certificate_der(p)] = p
    return out
