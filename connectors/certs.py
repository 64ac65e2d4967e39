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
