"""Who may do what on our OPC UA server: users, roles, password hashes, the permission check.

Roles (docs/reference/connectors.md, "Security model"):

==========  =====================================================================
role        may
==========  =====================================================================
anonymous   browse, read, subscribe (data and events), ConditionRefresh
viewer      the same, as a named user
operator    also acknowledge, confirm, comment and shelve/unshelve alarms (the
            methods and the ``Alarm.AckRequest`` tag)
==========  =====================================================================

Nobody writes diagnosis values (they are not writable) or changes the address space.

A user logs in with a user name and password (stored as a scrypt hash,
:func:`connectors.passwords.hash_password`)
or is known by a client certificate: the application certificate of a secured channel (the
client proved it holds the key) or an X509 identity token. asyncua calls the
:class:`UserManager` at ActivateSession and the :class:`Permissions` check before every
request of a session; the check also puts the caller's :class:`Identity` in
:data:`current_identity`, so a method callback knows who called it (asyncua does not pass it).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any

from asyncua.crypto.permission_rules import PermissionRuleset, User, UserRole

from connectors.opcua_logins import login_verdict
from connectors.passwords import check_password, dummy_hash, hash_problem

log = logging.getLogger(__name__)

ROLES = ("anonymous", "viewer", "operator")


@dataclass(frozen=True)
class OpcUaUser:
    """One user of our server: a ``role`` of :data:`ROLES` and a password hash and/or the
    DER bytes of the client certificate that identifies the user."""

    name: str
    role: str = "viewer"
    password_hash: str | None = None
    certificate: bytes | None = None

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"user {self.name!r}: role must be one of {ROLES}, not {self.role!r}")
        if self.password_hash is None and self.certificate is None:
            raise ValueError(f"user {self.name!r}: needs a password_hash or a certificate")
        if self.password_hash is not None and (why := hash_problem(self.password_hash)):
            raise ValueError(f"user {self.name!r}: password_hash: {why}")


@dataclass
class Identity(User):
    """An asyncua user with our role; ``name`` None for anonymous."""

    access: str = "anonymous"

    @property
    def label(self) -> str:
        """``alice (operator)`` or ``anonymous``."""
        return f"{self.name} ({self.access})" if self.name else self.access


#: the identity of the session whose request is being processed (set by :class:`Permissions`)
current_identity: ContextVar[Identity | None] = ContextVar("diag_opcua_identity", default=None)

ANONYMOUS = Identity(role=UserRole.Anonymous, name=None, access="anonymous")


class UserManager:
    """asyncua user manager: user name + password, or a known certificate, or anonymous."""

    def __init__(self, users: Iterable[OpcUaUser], allow_anonymous: bool) -> None:
        self.users = {u.name: u for u in users}
        self.by_cert = {u.certificate: u for u in self.users.values() if u.certificate}
        self.allow_anonymous = allow_anonymous
        #: the hash whose cost an unknown user's check pays (the first user's)
        self._like = next((u.password_hash for u in self.users.values() if u.password_hash), None)
        dummy_hash(self._like)  # made now, not in the first unknown user's login

    def verify(self, username: str, password: Any) -> bool:
        """The password of ``username`` is ``password``: one scrypt whether or not the user
        exists (:func:`~connectors.passwords.check_password`), so the time taken does not
        tell which user names exist. Blocking (~50 ms): the server runs it in a pool."""
        u = self.users.get(username)
        stored = u.password_hash if u is not None else None
        return check_password(stored, None if password is None else str(password), self._like)

    def get_user(
        self,
        iserver: Any,
        username: str | None = None,
        password: str | None = None,
        certificate: Any = None,
    ) -> Identity | None:
        if username is not None:
            u = self.users.get(username)
            verdict = login_verdict.get()
            if verdict is not None and verdict[:2] == (str(username), password):
                ok = verdict[2]  # checked off the event loop by connectors.opcua_logins
            else:
                ok = self.verify(username, password)
                if not ok:
                    log.warning(
                        "OPC UA login refused for user %r (unknown or wrong password)", username
                    )
            if not ok or u is None:
                return None
            return Identity(role=UserRole.User, name=u.name, access=u.role)
        if certificate:
            u = self.by_cert.get(bytes(certificate))
            if u is not None:
                return Identity(role=UserRole.User, name=u.name, access=u.role)
        if self.allow_anonymous:
            return Identity(role=UserRole.Anonymous, name=None, access="anonymous")
        log.warning("OPC UA anonymous login refused (no anonymous access configured)")
        return None


def _ids(*names: str) -> frozenset:
    from asyncua import ua

    return frozenset(ua.NodeId(getattr(ua.ObjectIds, n)) for n in names)


class Permissions(PermissionRuleset):
    """Per-request check by role (module table). ``operator_methods``: method node ids only an
    operator may call (the server adds its own as it creates them); ``on_refused(identity,
    what)`` hears every refusal."""

    def __init__(self, on_refused: Callable[[Identity, str], None] | None = None) -> None:
        self.operator_methods: set[Any] = set(
            _ids(
                "AcknowledgeableConditionType_Acknowledge",
                "AcknowledgeableConditionType_Confirm",
                "ConditionType_AddComment",
                "ConditionType_Enable",
                "ConditionType_Disable",
                "AlarmConditionType_ShelvingState_TimedShelve",
                "AlarmConditionType_ShelvingState_OneShotShelve",
                "AlarmConditionType_ShelvingState_Unshelve",
                "ShelvedStateMachineType_TimedShelve",
                "ShelvedStateMachineType_OneShotShelve",
                "ShelvedStateMachineType_Unshelve",
            )
        )
        self.on_refused = on_refused
        self._read_only = _ids(
            "CreateSessionRequest_Encoding_DefaultBinary",
            "CloseSessionRequest_Encoding_DefaultBinary",
            "ActivateSessionRequest_Encoding_DefaultBinary",
            "ReadRequest_Encoding_DefaultBinary",
            "BrowseRequest_Encoding_DefaultBinary",
            "BrowseNextRequest_Encoding_DefaultBinary",
            "GetEndpointsRequest_Encoding_DefaultBinary",
            "FindServersRequest_Encoding_DefaultBinary",
            "TranslateBrowsePathsToNodeIdsRequest_Encoding_DefaultBinary",
            "CreateSubscriptionRequest_Encoding_DefaultBinary",
            "ModifySubscriptionRequest_Encoding_DefaultBinary",
            "DeleteSubscriptionsRequest_Encoding_DefaultBinary",
            "TransferSubscriptionsRequest_Encoding_DefaultBinary",
            "CreateMonitoredItemsRequest_Encoding_DefaultBinary",
            "ModifyMonitoredItemsRequest_Encoding_DefaultBinary",
            "DeleteMonitoredItemsRequest_Encoding_DefaultBinary",
            "HistoryReadRequest_Encoding_DefaultBinary",
            "PublishRequest_Encoding_DefaultBinary",
            "RepublishRequest_Encoding_DefaultBinary",
            "CloseSecureChannelRequest_Encoding_DefaultBinary",
            "SetMonitoringModeRequest_Encoding_DefaultBinary",
            "SetPublishingModeRequest_Encoding_DefaultBinary",
            "SetTriggeringRequest_Encoding_DefaultBinary",
            "RegisterNodesRequest_Encoding_DefaultBinary",
            "UnregisterNodesRequest_Encoding_DefaultBinary",
        )
        (self._call,) = _ids("CallRequest_Encoding_DefaultBinary")
        (self._write,) = _ids("WriteRequest_Encoding_DefaultBinary")

    def check_validity(self, user: Any, action_type_id: Any, body: Any) -> bool:
        ident = user if isinstance(user, Identity) else ANONYMOUS
        current_identity.set(ident)
        if action_type_id in self._read_only:
            return True
        operator = ident.access == "operator"
        if action_type_id == self._write:
            return operator or self._refuse(ident, "write")
        if action_type_id == self._call:
            if operator:
                return True
            from asyncua import ua
            from asyncua.ua.ua_binary import struct_from_binary

            try:
                params = struct_from_binary(ua.CallParameters, body.copy())
            except Exception:  # noqa: BLE001 - an undecodable call is refused
                return self._refuse(ident, "a call that could not be decoded")
            barred = [m for m in params.MethodsToCall if m.MethodId in self.operator_methods]
            if barred:
                what = ", ".join(
                    f"{m.MethodId.to_string()} on {m.ObjectId.to_string()}" for m in barred
                )
                return self._refuse(ident, f"call {what}")
            return True
        return self._refuse(ident, f"request {action_type_id.to_string()}")

    def _refuse(self, ident: Identity, what: str) -> bool:
        log.warning("OPC UA: %s refused for %s (operators only)", what, ident.label)
        if self.on_refused is not None:
            try:
                self.on_refused(ident, what)
            except Exception:  # noqa: BLE001 - a listener must not break the server
                log.exception("on_refused listener failed")
        return False
