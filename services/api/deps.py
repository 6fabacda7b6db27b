"""Dependencies: the database session, the current principal (bearer token) and its scope checks."""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Query, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from services.common.settings import Settings
from services.common.storage import Storage
from services.common.tokens import Principal, TokenStore
from services.worker.dispatch import Dispatcher

from .problems import ApiError
from .ratelimit import check_rate

__all__ = [
    "SessionDep",
    "ReadSessionDep",
    "SettingsDep",
    "StorageDep",
    "DispatcherDep",
    "PrincipalDep",
    "ReadDep",
    "WriteDep",
    "Paging",
    "PagingDep",
    "require",
]

_bearer = HTTPBearer(auto_error=False, description="A token from the tokens file; scopes read < write < admin")


async def get_session(request: Request) -> AsyncIterator[Session]:
    """One session per request; the route commits explicitly, anything unfinished rolls back.

    Async so that opening it costs no thread-pool hop: a Session does no I/O until the route (in a worker thread)
    uses it; closing only returns its connection to the pool.
    """
    session = request.app.state.db.sessions()
    try:
        yield session
    finally:
        session.close()


async def get_read_session(request: Request) -> AsyncIterator[Session]:
    """A session for routes that only read: autocommit on PostgreSQL, so no transaction round trips."""
    session = request.app.state.db.read_sessions()
    try:
        yield session
    finally:
        session.close()


async def get_settings(request: Request) -> Settings:
    return request.app.state.settings


async def get_storage(request: Request) -> Storage:
    return request.app.state.storage


async def get_dispatcher(request: Request) -> Dispatcher:
    return request.app.state.dispatcher


async def get_principal(
    request: Request, credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
) -> Principal:
    challenge = {"WWW-Authenticate": 'Bearer realm="graspgen"'}
    if credentials is None or credentials.scheme.lower() != "bearer" or not credentials.credentials:
        raise ApiError(401, "unauthorized", "a bearer token is required", headers=challenge)
    tokens: TokenStore = request.app.state.tokens
    principal = tokens.authenticate(credentials.credentials)
    if principal is None:
        raise ApiError(401, "unauthorized", "the bearer token is not valid", headers=challenge)
    check_rate(request, principal.name)  # 429 when per-token rate limits are on and this token is over its rate
    return principal


def require(scope: str) -> Callable[[Principal], Awaitable[Principal]]:
    # async: no I/O here, and a sync dependency would cost a thread-pool hop on every request
    async def _check(principal: Annotated[Principal, Depends(get_principal)]) -> Principal:
        if not principal.has(scope):
            raise ApiError(403, "forbidden", f"the token lacks the {scope!r} scope", required_scope=scope)
        return principal

    return _check


SessionDep = Annotated[Session, Depends(get_session)]
ReadSessionDep = Annotated[Session, Depends(get_read_session)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
StorageDep = Annotated[Storage, Depends(get_storage)]
DispatcherDep = Annotated[Dispatcher, Depends(get_dispatcher)]
PrincipalDep = Annotated[Principal, Depends(get_principal)]
ReadDep = Annotated[Principal, Depends(require("read"))]
WriteDep = Annotated[Principal, Depends(require("write"))]
AdminDep = Annotated[Principal, Depends(require("admin"))]


@dataclass(frozen=True)
class Paging:
    """The page a list route is asked for: the previous page's cursor and how many items (the settings' default when
    not given, never more than their maximum)."""

    cursor: str | None
    limit: int


async def get_paging(
    settings: SettingsDep, cursor: str | None = None, limit: Annotated[int | None, Query(ge=1)] = None
) -> Paging:
    return Paging(cursor, min(limit or settings.page_size_default, settings.page_size_max))


PagingDep = Annotated[Paging, Depends(get_paging)]
