"""Bearer tokens with a role (rider, operator, vehicle, infrastructure): who may call what.

Tokens are random strings; the database keeps only their SHA-256, so a copied database grants nothing.
No token or an unknown one is 401; a known token whose role is not allowed is 403.
"""

from __future__ import annotations

import hashlib
import secrets
from dataclasses import dataclass, field

from fastapi import HTTPException, status

ROLES = ("rider", "operator", "vehicle", "infrastructure")


@dataclass(frozen=True, slots=True)
class Principal:
    """Who is calling: ``subject`` is a rider's name, an operator's name, or a vehicle id ("*" = any).

    ``token_sha`` is the SHA-256 of the token used (the key of its rate limit); not part of equality.
    """

    role: str
    subject: str
    token_sha: str = field(default="", compare=False, repr=False)


def new_token(role: str) -> str:
    return f"{role[:3]}_{secrets.token_urlsafe(24)}"


def token_hash(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


class TokenBook:
    """The known tokens, mirrored from the ``tokens`` table."""

    def __init__(self) -> None:
        self._by_hash: dict[str, Principal] = {}

    def add(self, sha256: str, role: str, subject: str) -> None:
        self._by_hash[sha256] = Principal(role, subject, sha256)

    def revoke(self, sha256: str) -> None:
        self._by_hash.pop(sha256, None)

    def __len__(self) -> int:
        return len(self._by_hash)

    def authenticate(self, authorization: str | None) -> Principal:
        """The principal of an ``Authorization: Bearer <token>`` header value.

        Raises:
            HTTPException: 401 naming what was missing or wrong.
        """
        if not authorization:
            raise HTTPException(
                status.HTTP_401_UNAUTHORIZED,
                "missing bearer token: expected header 'Authorization: Bearer <token>'",
                headers={"WWW-Authenticate": "Bearer"},
            )
        scheme, _, token = authorization.partition(" ")
        if scheme.lower() != "bearer" or not token.strip():
            raise HTTPException(
                status.HTTP_401_UNAUTHORIZED,
                f"malformed authorization: expected 'Bearer <token>', got scheme {scheme!r}",
                headers={"WWW-Authenticate": "Bearer"},
            )
        return self.authenticate_token(token.strip())

    def lookup(self, token: str) -> Principal | None:
        """The principal of a bare token, or None if it is unknown."""
        return self._by_hash.get(token_hash(token))

    def authenticate_token(self, token: str) -> Principal:
        principal = self._by_hash.get(token_hash(token))
        if principal is None:
            raise HTTPException(
                status.HTTP_401_UNAUTHORIZED,
                "invalid bearer token: not issued by this server or revoked",
                headers={"WWW-Authenticate": "Bearer"},
            )
        return principal


def check_role(principal: Principal, allowed: tuple[str, ...]) -> None:
    """Raises HTTPException 403 unless the principal's role is one of ``allowed``."""
    if principal.role not in allowed:
        raise HTTPException(
            status.HTTP_403_FORBIDDEN,
            f"role {principal.role!r} may not do this: expected one of {list(allowed)}",
        )
