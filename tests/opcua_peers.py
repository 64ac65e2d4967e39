"""Peers for the OPC UA tests (not tests themselves): a PKI on disk, users, clients by role.

``pki(folder)`` makes the server's and clients' self-signed certificates (our own
:func:`connectors.certs.make_certificate`), trusts the good clients and leaves a stranger out;
``secured_server`` runs our server with SignAndEncrypt, a trust list, an operator (alice),
a viewer (bob), a user known by its certificate (carol, operator) and anonymous read-only
sessions; ``client(...)`` opens an asyncua client as one of them.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from helpers import free_port  # noqa: F401 - the peers' callers import it from here

from connectors.certs import CertPair, certificate_der, make_certificate, trust
from connectors.opcua_access import OpcUaUser
from connectors.opcua_client import ClientSecurity
from connectors.passwords import hash_password
from diag_plugin.status import NE107, Quality, UnitStatus

PASSWORDS = {"alice": "alice-pw-1", "bob": "bob-pw-22"}


class Events:
    """An OPC UA event subscription's handler that keeps every event."""

    def __init__(self) -> None:
        self.items: list = []

    def event_notification(self, event) -> None:
        self.items.append(event)


def pki(folder: Path) -> dict[str, CertPair | Path]:
    """Client certificates: ``hmi`` and ``carol`` trusted, ``stranger`` not."""
    d = Path(folder)
    hmi = make_certificate(d / "clients", "hmi", "urn:diag-plugin:test:hmi")
    carol = make_certificate(d / "clients", "carol", "urn:diag-plugin:test:carol")
    stranger = make_certificate(d / "strangers", "stranger", "urn:diag-plugin:test:stranger")
    trust(hmi, d / "trusted")
    trust(carol, d / "trusted")
    return {"hmi": hmi, "carol": carol, "stranger": stranger, "dir": d}


def users(keys: dict) -> tuple[OpcUaUser, ...]:
    return (
        OpcUaUser("alice", "operator", hash_password(PASSWORDS["alice"])),
        OpcUaUser("bob", "viewer", hash_password(PASSWORDS["bob"])),
        OpcUaUser("carol", "operator", certificate=certificate_der(keys["carol"].certificate)),
    )


async def client(
    endpoint: str, cert: CertPair, user: str | None = None, mode: str = "SignAndEncrypt"
):
    """A connected asyncua client with ``cert`` over Basic256Sha256 ``mode`` as ``user``
    (None: anonymous); the caller disconnects."""
    from asyncua import Client

    c = Client(endpoint, timeout=10)
    c.application_uri = cert.application_uri
    if user is not None:
        c.set_user(user)
        c.set_password(PASSWORDS[user])
    await c.set_security_string(f"Basic256Sha256,{mode},{cert.certificate},{cert.private_key}")
    await c.connect()
    return c


def security_of(pair: CertPair, username: str, password: str, **kw) -> ClientSecurity:
    """Our client's security settings: ``pair``'s certificate, key and URI, a user and its
    password, and ``kw`` (``trusted_dir``, ``server_certificate``, …)."""
    return ClientSecurity(
        pair.certificate, pair.private_key, pair.application_uri, username, password, **kw
    )


def unit_status(unit: str, status: NE107, c: float = 0.9) -> UnitStatus:
    """A unit's status now: residual r1 = 3, symptom r1 = 1, fault f1 of certainty ``c``
    (found unless ``status`` is NORMAL)."""
    return UnitStatus(
        unit,
        pd.Timestamp.now(tz="UTC"),
        status,
        Quality.GOOD,
        residuals={"r1": 3.0},
        symptoms={"r1": 1.0},
        certainties={"f1": c},
        detected=status != NE107.NORMAL,
        faults=["f1"] if status != NE107.NORMAL else [],
    )
