"""graspgen.export.candidate_view: some arrays of a candidate NPZ over an even stride of its rows (the review page's
candidate cloud, GET /v1/grasp-sets/{id}/candidates?arrays=&max_rows=), checked against numpy slicing by hand."""

from __future__ import annotations

import io

import numpy as np
import pytest

from graspgen.errors import InvalidCandidatesError, InvalidParameterError
from graspgen.export import candidate_view, npz_bytes


def arrays(n: int = 10, rolls: int = 4) -> dict[str, np.ndarray]:
    """A candidate NPZ's arrays whose values say their row: contacts[i] = i, friction_margin_deg[i] = i, ..."""
    i = np.arange(n, dtype=np.float64)
    return {
        "contacts": np.repeat(i, 6).reshape(n, 2, 3),
        "normals": np.ones((n, 2, 3)),
        "midpoints": np.repeat(i, 3).reshape(n, 3),
        "free_rolls": np.arange(n * rolls).reshape(n, rolls) % 3 == 0,
        "roll_angles_rad": np.linspace(0, np.pi, rolls, endpoint=False),
        "friction_margin_deg": i,
        "labels": np.stack([np.arange(n), -np.arange(n)], axis=1).astype(np.int32),
        "medoids": np.array([7, 2], dtype=np.int64),
        "center_of_mass": np.array([0.1, 0.2, 0.3]),
    }


def test_without_max_rows_the_named_arrays_come_whole_in_the_order_asked():
    full = arrays()
    view = candidate_view(npz_bytes(full), arrays=["friction_margin_deg", "midpoints", "hold_margin", "midpoints"])
    assert list(view) == ["friction_margin_deg", "midpoints"]  # hold_margin is not in this NPZ; no duplicates
    assert np.array_equal(view["midpoints"], full["midpoints"])
    everything = candidate_view(npz_bytes(full))
    assert sorted(everything) == sorted(full) and all(np.array_equal(everything[k], full[k]) for k in full)


STRIDES = [
    (10, 4, [0, 3, 6, 9]),
    (10, 5, [0, 2, 4, 6, 8]),
    (10, 10, list(range(10))),
    (10, 50, list(range(10))),
    (10, 1, [0]),
    (0, 3, []),
]


@pytest.mark.parametrize(("n", "max_rows", "rows"), STRIDES)
def test_max_rows_keeps_an_even_stride_from_row_0(n, max_rows, rows):
    full = arrays(n)
    view = candidate_view(npz_bytes(full), max_rows=max_rows)
    assert view["rows"].dtype == np.int64 and view["rows"].tolist() == rows
    assert view["row_count"].shape == () and int(view["row_count"]) == n
    assert len(rows) <= max_rows
    for name in ("contacts", "normals", "midpoints", "free_rolls", "friction_margin_deg", "labels"):
        assert view[name].dtype == full[name].dtype
        assert np.array_equal(view[name], full[name][rows]), name
    # not over the candidates: whole, medoids still rows of the full NPZ
    for name in ("roll_angles_rad", "medoids", "center_of_mass"):
        assert np.array_equal(view[name], full[name]), name


def test_an_array_as_long_as_the_rolls_is_kept_whole_even_when_there_are_as_many_candidates():
    full = arrays(n=4, rolls=4)  # roll_angles_rad (4,) over the rolls, friction_margin_deg (4,) over the candidates
    view = candidate_view(npz_bytes(full), arrays=["roll_angles_rad", "friction_margin_deg"], max_rows=2)
    assert view["roll_angles_rad"].tolist() == full["roll_angles_rad"].tolist()
    assert view["friction_margin_deg"].tolist() == [0.0, 2.0]


def test_the_view_is_an_npz_that_numpy_reads_stored_or_deflated():
    view = candidate_view(npz_bytes(arrays(1000)), arrays=["midpoints", "friction_margin_deg"], max_rows=100)
    for deflate in (True, False):
        data = npz_bytes(view, deflate=deflate)
        assert npz_bytes(view, deflate=deflate) == data  # the same arrays, the same bytes
        with np.load(io.BytesIO(data)) as z:
            assert sorted(z.files) == ["friction_margin_deg", "midpoints", "row_count", "rows"]
            assert np.array_equal(z["midpoints"], view["midpoints"]) and z["rows"][-1] == 990
    # stored members: the raw bytes of midpoints appear in the file as they are
    assert view["midpoints"].tobytes() in npz_bytes(view, deflate=False)


def test_bad_input_is_refused_with_a_reason():
    with pytest.raises(InvalidParameterError, match="max_rows"):
        candidate_view(npz_bytes(arrays()), max_rows=0)
    with pytest.raises(InvalidCandidatesError, match="contacts"):
        candidate_view(npz_bytes({"midpoints": np.zeros((3, 3))}), max_rows=2)
    with pytest.raises(InvalidCandidatesError):
        candidate_view(b"not a zip file", max_rows=2)
