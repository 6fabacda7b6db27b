"""Issue 16 (3): heavy reads never starve light ones. A real `graspgen serve` process, four client threads asking for
large preview.png renders (every one a different size, so none is cached) while another thread makes catalogue
lookups; on the embedded SQLite mode and on PostgreSQL. Every lookup must answer 200 (no 5xx, no 30 s wait); previews
answer 200 or, when the render pool is full, 503 `previews-busy` with Retry-After. The latency is measured, not
asserted, by bench/bench_isolation.py (docs/benchmarks_service.md).
"""

from __future__ import annotations

import threading
import time

import httpx
import pytest
from services_conftest import (
    PG_URL,
    Service,
    broker_settings,
    redis_cleanup,
    seed_grasp_sets,
    settings_env,
    slug,
    start_serve,
    stop_process,
    write_tokens_file,
)

pytestmark = [pytest.mark.integration, pytest.mark.slow]

LOOKUPS = 150
PREVIEW_CLIENTS = 4


def _seed(values: dict, tokens: dict[str, str]) -> tuple[str, str, int]:
    """One object with a grasp set in the catalogue, written through an in-process app on the same database."""
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.settings import Settings

    with TestClient(create_app(Settings(**values), recover_jobs=False)) as client:
        svc = Service(client, client.app.state.settings, tokens)
        obj, grip = slug("iso"), slug("grip")
        ids = seed_grasp_sets(svc, grip, [obj])
    return obj, grip, ids[obj][0]


@pytest.fixture(params=["embedded", "postgres"])
def server(request, tmp_path):
    tokens = write_tokens_file(tmp_path / "tokens.json")
    values: dict = {"storage_dir": tmp_path / "var", "tokens_file": tmp_path / "tokens.json"}
    broker = None
    if request.param == "postgres":
        broker = broker_settings()
        values.update(database_url=PG_URL, database_schema=request.getfixturevalue("pg_schema"), **broker)
    proc, url = start_serve(settings_env(**values), tmp_path / "serve.log")  # embedded: migrates the SQLite file
    try:
        obj, grip, gs = _seed(values, tokens)
        yield url, tokens, obj, grip, gs
    finally:
        stop_process(proc)
        if broker:
            redis_cleanup(broker["broker_key_prefix"])


def test_catalogue_lookups_answer_while_four_clients_render_large_previews(server):
    url, tokens, obj, grip, gs = server
    auth = {"Authorization": f"Bearer {tokens['reader']}"}
    stop = threading.Event()
    preview_status: list[tuple[int, str | None, str | None]] = []
    errors: list[BaseException] = []

    def previews(k: int) -> None:
        try:
            with httpx.Client(base_url=url, headers=auth, timeout=120) as c:
                n = 0
                while not stop.is_set():
                    n += 1
                    # a new size every time: never served from the PNG cache, always a full render
                    r = c.get(f"/v1/grasp-sets/{gs}/preview.png", params={"size": f"2048x{2048 - 4 * n - k}"})
                    code = r.json().get("code") if r.status_code != 200 else None
                    preview_status.append((r.status_code, code, r.headers.get("retry-after")))
                    if r.status_code == 503:
                        time.sleep(0.2)
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            errors.append(exc)

    threads = [threading.Thread(target=previews, args=(k,)) for k in range(PREVIEW_CLIENTS)]
    for t in threads:
        t.start()
    lookups: list[int] = []
    try:
        with httpx.Client(base_url=url, headers=auth, timeout=60) as c:
            time.sleep(1.0)  # the renders are under way
            for i in range(LOOKUPS):
                r = c.get(f"/v1/catalogue/{obj}/{grip}")
                lookups.append(r.status_code)
                assert r.status_code == 200, (i, r.status_code, r.text)
                assert r.headers["x-request-id"]
                time.sleep(0.02)
    finally:
        stop.set()
        for t in threads:
            t.join(timeout=180)
    assert not errors, errors
    assert lookups == [200] * LOOKUPS
    rendered = [s for s in preview_status if s[0] == 200]
    assert rendered, preview_status  # the lookups really ran against renders
    for status, code, retry_after in preview_status:
        assert status in (200, 503), preview_status
        if status == 503:
            assert code == "previews-busy" and retry_after is not None


def test_preview_size_is_capped_and_the_render_queue_is_bounded(tmp_path):
    """One render process and no waiting line: a second concurrent render is refused at once (503, Retry-After), an
    oversized picture is a 422 problem, and the same picture asked twice at once is rendered once."""
    tokens = write_tokens_file(tmp_path / "tokens.json")
    values: dict = {
        "storage_dir": tmp_path / "var",
        "tokens_file": tmp_path / "tokens.json",
        "preview_workers": 1,
        "preview_queue": 0,
        "preview_max_pixels": 1024 * 1024,
    }
    proc, url = start_serve(settings_env(**values), tmp_path / "serve.log")
    try:
        obj, grip, gs = _seed(values, tokens)
        auth = {"Authorization": f"Bearer {tokens['reader']}"}
        big = httpx.get(f"{url}/v1/grasp-sets/{gs}/preview.png?size=2048x2048", headers=auth)
        assert big.status_code == 422 and big.json()["field"] == "size"
        results: dict[str, httpx.Response] = {}

        def get(name: str, size: str) -> None:
            results[name] = httpx.get(
                f"{url}/v1/grasp-sets/{gs}/preview.png", params={"size": size}, headers=auth, timeout=120
            )

        first = threading.Thread(target=get, args=("a", "1024x1024"))
        first.start()
        time.sleep(0.5)  # "a" holds the only render slot
        same = threading.Thread(target=get, args=("a2", "1024x1024"))
        same.start()
        get("b", "1000x1000")
        first.join()
        same.join()
        assert results["b"].status_code == 503 and results["b"].json()["code"] == "previews-busy"
        assert results["b"].headers["retry-after"]
        assert results["a"].status_code == 200 and results["a2"].status_code == 200
        assert results["a"].content == results["a2"].content
        assert httpx.get(f"{url}/v1/catalogue/{obj}/{grip}", headers=auth).status_code == 200
        admin = {"Authorization": f"Bearer {tokens['admin']}"}
        metrics = httpx.get(f"{url}/metrics", headers=admin).text
        assert 'graspgen_previews_total{outcome="rejected"} 1.0' in metrics
        assert 'graspgen_previews_total{outcome="rendered"} 2.0' in metrics  # a2 shared a's render (no slot left)
    finally:
        stop_process(proc)
