"""Schemathesis against the service's own OpenAPI document, in-process (ASGI) on a PostgreSQL-backed app.

Every operation gets generated requests twice: with an admin token (which has every scope) and without a token.
Each response must not be a 5xx, must have a status code and content type the document declares, and must match the
declared response schema. The run is bounded (examples per operation, no shrinking, no example database) so that it
takes well under a minute; its size is printed and recorded in docs/reliability_schemathesis.md.
"""

from __future__ import annotations

import collections

import pytest
from services_conftest import (
    PG_URL,
    Service,
    create_schema,
    drop_schema,
    pg_values,
    seed_grasp_sets,
    unique_name,
)

pytestmark = [pytest.mark.integration, pytest.mark.slow]

schemathesis = pytest.importorskip("schemathesis")

#: generated requests per operation and token variant
MAX_EXAMPLES = 12


@pytest.fixture(scope="module")
def st_app(tmp_path_factory):  # type: ignore[no-untyped-def]
    """An app of its own (schemathesis drives its lifespan) on a PostgreSQL schema and storage of its own (the shared
    session schema holds other apps' grasp sets, whose artifacts this app's storage does not have), with an object,
    a gripper and grasp sets, so that generated ids and names sometimes exist."""
    from fastapi.testclient import TestClient
    from schemathesis.python import asgi

    from services.api.app import create_app
    from services.common.migrate import upgrade
    from services.common.settings import Settings

    pg = unique_name("ggst")
    create_schema(pg)
    try:
        with pg_values(tmp_path_factory.mktemp("schemathesis"), pg, max_upload_bytes=256 * 1024) as (values, tokens):
            settings = Settings(**values)
            upgrade(settings)
            app = create_app(settings)
            seed_grasp_sets(
                Service(TestClient(app), settings, tokens), "pgn-80", ["part-a", "part-b"], version_of={"part-a": 2}
            )
            try:
                yield app, tokens
            finally:
                asgi.shutdown_lifespans()
    finally:
        drop_schema(pg)


def test_openapi_conformance(st_app, record_property):
    from hypothesis import HealthCheck, Phase, given, settings
    from schemathesis.checks import not_a_server_error
    from schemathesis.specs.openapi.checks import (
        content_type_conformance,
        response_schema_conformance,
        status_code_conformance,
    )

    app, tokens = st_app
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    checks = [not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance]
    secrets = (*tokens.values(), PG_URL, "postgresql", "Traceback", 'File "')
    calls: collections.Counter[str] = collections.Counter()
    statuses: collections.Counter[int] = collections.Counter()
    failures: list[str] = []
    operations = [result.ok() for result in schema.get_all_operations()]
    variants = {"admin": {"Authorization": f"Bearer {tokens['admin']}"}, "no-token": {}}

    def runner(op, variant: str, headers: dict[str, str]):  # type: ignore[no-untyped-def]
        @settings(
            max_examples=MAX_EXAMPLES,
            deadline=None,
            database=None,
            phases=[Phase.explicit, Phase.generate],
            suppress_health_check=list(HealthCheck),
        )
        @given(case=op.as_strategy())
        def run(case) -> None:  # type: ignore[no-untyped-def]
            response = case.call(headers=headers)
            calls[f"{op.label} [{variant}]"] += 1
            statuses[response.status_code] += 1
            leaked = [s for s in secrets if s.encode() in response.content]
            assert not leaked, (op.label, variant, leaked)
            case.validate_response(response, checks=checks, headers=headers)

        return run

    for op in operations:
        for variant, headers in variants.items():
            try:
                runner(op, variant, headers)()
            except Exception as exc:  # collect every operation's failure, then report them together
                failures.append(f"{op.label} [{variant}]: {type(exc).__name__}: {str(exc)[:1500]}")
    total = sum(calls.values())
    summary = (
        f"{len(operations)} operations x {len(variants)} token variants, {total} requests, "
        f"statuses {dict(sorted(statuses.items()))}, {len(failures)} failing"
    )
    print(summary)
    record_property("schemathesis", summary)
    assert len(operations) >= 15
    assert not failures, "\n\n".join(failures)
