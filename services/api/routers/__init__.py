"""Routers under /v1: parse, authorise, call crud, shape the response."""

from __future__ import annotations

from typing import Any

from ..problems import PROBLEM_JSON

_DESCRIPTIONS = {
    304: "Not modified (If-None-Match matched the current ETag)",
    401: "No or invalid bearer token",
    403: "The token lacks the required scope",
    404: "No such resource",
    409: "Conflict with the resource's state",
    413: "Request body larger than the configured limit",
    422: "Invalid input",
    429: "This token is over its request rate (only with GRASPGEN_RATE_LIMIT_PER_S set); retry after Retry-After",
    503: "A dependency (database, broker or artifact storage) is unavailable or lost an artifact; retry later",
}


def problems(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI entries for the problem+json responses a route can give: 401, 403 and 429 (per-token rate limits, when
    on) are on every protected route, and 503 too (every one reads the database; some read artifacts from storage)."""
    out: dict[int | str, dict[str, Any]] = {}
    for code in (401, 403, 429, *codes, 503):
        if code == 304:
            out[code] = {"description": _DESCRIPTIONS[304]}
            continue
        out[code] = {
            "description": _DESCRIPTIONS.get(code, "Error"),
            "content": {PROBLEM_JSON: {"schema": {"$ref": "#/components/schemas/Problem"}}},
        }
    return out
