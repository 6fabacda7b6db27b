"""GET /v1/grasp-sets/{id}/candidates on PostgreSQL: the stored NPZ byte for byte, or with `arrays` / `max_rows` a view
of it (graspgen.export.candidate_view) as an NPZ numpy reads, with a strong ETag, 304 on a match, and problems for bad
parameters and sets without candidates."""

from __future__ import annotations

import io

import numpy as np
import pytest
from services_conftest import seed_grasp_sets, slug

from graspgen.export import npz_bytes

pytestmark = pytest.mark.integration

N = 1003


@pytest.fixture(scope="module")
def seeded(pg_service):
    """Two grasp sets of one pair; the newer has a candidate NPZ of N rows in storage, the older none."""
    from sqlalchemy import update

    from services.common.models import GraspSet

    grip, obj = slug("cand-g"), slug("cand-o")
    ids = seed_grasp_sets(pg_service, grip, [obj], version_of={obj: 2})[obj]
    rng = np.random.default_rng(5)
    arrays = {
        "contacts": rng.normal(size=(N, 2, 3)),
        "midpoints": rng.normal(size=(N, 3)),
        "free_rolls": rng.random((N, 16)) < 0.5,
        "roll_angles_rad": np.arange(16) * np.pi / 8,
        "friction_margin_deg": rng.uniform(0, 20, N),
        "medoids": np.array([5, 900, 17], dtype=np.int64),
    }
    data = npz_bytes(arrays)
    blob = pg_service.app.state.storage.put_bytes(data)
    with pg_service.app.state.db.session() as s:
        s.execute(update(GraspSet).where(GraspSet.id == ids[-1]).values(candidates_key=blob.key))
    return {"id": ids[-1], "without": ids[0], "arrays": arrays, "bytes": data}


def load(content: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(content), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def test_without_parameters_the_stored_npz_comes_byte_for_byte(pg_service, seeded):
    r = pg_service.get(f"/v1/grasp-sets/{seeded['id']}/candidates")
    assert r.status_code == 200 and r.content == seeded["bytes"]
    assert "immutable" in r.headers["cache-control"]


def test_a_view_holds_the_named_arrays_over_an_even_stride_of_the_rows(pg_service, seeded):
    url = f"/v1/grasp-sets/{seeded['id']}/candidates?arrays=midpoints,friction_margin_deg,hold_margin,medoids"
    r = pg_service.get(url + "&max_rows=100")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/octet-stream"
    view = load(r.content)
    # ceil(1003 / 100) = 11: rows 0, 11, ..., 1001, i.e. 92 rows; hold_margin is not in this set
    assert sorted(view) == ["friction_margin_deg", "medoids", "midpoints", "row_count", "rows"]
    rows = np.arange(0, N, 11)
    assert view["rows"].tolist() == rows.tolist() and int(view["row_count"]) == N and len(rows) == 92
    full = seeded["arrays"]
    assert np.array_equal(view["midpoints"], full["midpoints"][rows])
    assert np.array_equal(view["friction_margin_deg"], full["friction_margin_deg"][rows])
    assert view["medoids"].tolist() == [5, 900, 17]  # rows of the full NPZ
    # the members are stored, not deflated: nothing to inflate for a browser
    assert view["midpoints"].tobytes() in r.content

    # arrays alone: every row; max_rows alone: every array
    whole = load(pg_service.get(f"/v1/grasp-sets/{seeded['id']}/candidates?arrays=friction_margin_deg").content)
    assert list(whole) == ["friction_margin_deg"]
    assert np.array_equal(whole["friction_margin_deg"], full["friction_margin_deg"])
    every = load(pg_service.get(f"/v1/grasp-sets/{seeded['id']}/candidates?max_rows=5000").content)
    assert set(every) == set(full) | {"rows", "row_count"} and every["rows"].tolist() == list(range(N))


def test_a_view_has_a_strong_etag_and_answers_a_match_with_304(pg_service, seeded):
    url = f"/v1/grasp-sets/{seeded['id']}/candidates?arrays=midpoints&max_rows=10"
    first = pg_service.get(url)
    again = pg_service.get(url)
    etag = first.headers["etag"]
    assert first.status_code == again.status_code == 200 and again.content == first.content
    assert etag == again.headers["etag"] and not etag.startswith("W/")
    assert first.headers["cache-control"] == "private, no-cache"
    assert pg_service.get(url, headers={"If-None-Match": etag}).status_code == 304
    other = pg_service.get(url.replace("max_rows=10", "max_rows=11"))
    assert other.headers["etag"] != etag


@pytest.mark.parametrize(
    "query",
    ["max_rows=0", "max_rows=-3", "max_rows=many", "arrays=", "arrays=Midpoints", "arrays=a,,b", "arrays=a;b"],
)
def test_bad_parameters_are_a_422_problem(pg_service, seeded, query):
    r = pg_service.get(f"/v1/grasp-sets/{seeded['id']}/candidates?{query}")
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json", (query, r.text)


def test_a_set_without_candidates_is_a_404_problem_and_a_read_token_is_needed(pg_service, seeded):
    r = pg_service.get(f"/v1/grasp-sets/{seeded['without']}/candidates?max_rows=10")
    assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json"
    anonymous = pg_service.client.get(f"/v1/grasp-sets/{seeded['id']}/candidates?max_rows=10")
    assert anonymous.status_code == 401
