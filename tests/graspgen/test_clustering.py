"""FasterPAM k-medoids and the two-stage clustering.

The GPL-3 `kmedoids` package is imported here only as a yardstick (never by graspgen itself).
"""

from __future__ import annotations

import math

import kmedoids as reference
import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from graspgen import clustering
from graspgen.clustering import KMedoidsResult, dissimilarities, fasterpam, kmedoids, two_stage
from graspgen.errors import InvalidCandidatesError, InvalidParameterError


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _check_invariants(r: KMedoidsResult, D: np.ndarray) -> None:
    """Medoids are distinct members, labels point to a nearest medoid, loss is the sum, numbering is canonical."""
    n = D.shape[0]
    k = r.medoids.size
    assert r.medoids.dtype == np.int64 and r.labels.dtype == np.int32
    assert r.labels.shape == (n,)
    assert np.unique(r.medoids).size == k
    assert ((r.medoids >= 0) & (r.medoids < n)).all()
    assert ((r.labels >= 0) & (r.labels < k)).all()
    np.testing.assert_array_equal(r.labels[r.medoids], np.arange(k))  # each medoid is in its own cluster
    to_medoids = D[:, r.medoids]
    np.testing.assert_array_equal(to_medoids[np.arange(n), r.labels], to_medoids.min(axis=1))
    assert r.loss == pytest.approx(to_medoids[np.arange(n), r.labels].sum(), rel=1e-12, abs=1e-12)
    sizes = np.bincount(r.labels, minlength=k)
    key = list(zip(-sizes, r.medoids, strict=True))
    assert key == sorted(key)  # descending size, then smaller medoid index


# -- hand-checkable inputs --------------------------------------------------------------------------------------------


def test_six_points_two_obvious_clusters():
    X = np.array([[0.0], [1.0], [2.0], [10.0], [11.0], [12.0]])
    D = dissimilarities(X)
    for r in (fasterpam(D, 2), kmedoids(X, 2)):
        np.testing.assert_array_equal(r.medoids, [1, 4])  # equal sizes: smaller medoid index first
        np.testing.assert_array_equal(r.labels, [0, 0, 0, 1, 1, 1])
        assert r.loss == pytest.approx(4.0)


def test_larger_cluster_is_numbered_first():
    X = np.array([[0.0, 0.0], [0.0, 1.0], [0.0, 2.0], [9.0, 10.0], [9.0, 10.5], [9.0, 11.0], [9.0, 11.5], [9.0, 12.0]])
    r = kmedoids(X, 2)
    np.testing.assert_array_equal(r.medoids, [5, 1])
    np.testing.assert_array_equal(r.labels, [1, 1, 1, 0, 0, 0, 0, 0])
    assert r.loss == pytest.approx(2.0 + 3.0)
    assert r.n_iter >= 1


def test_axis_distance_is_the_sign_invariant_angle():
    x, y = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]
    a = _unit([0.3, -0.5, 0.8])
    D = dissimilarities(np.array([a, -a, x, _unit([1.0, 1.0, 0.0]), y, [-1.0, 1e-9, 0.0]]), metric="axis")
    assert D[0, 1] == 0.0 and D[1, 0] == 0.0  # a and -a: the same closing axis
    assert D[2, 3] == pytest.approx(math.pi / 4, abs=1e-15)
    assert D[2, 4] == pytest.approx(math.pi / 2, abs=1e-15)
    assert D[2, 5] == pytest.approx(1e-9, rel=1e-6)  # exact near 0, where arccos would give ~1.5e-8
    np.testing.assert_array_equal(D, D.T)
    np.testing.assert_array_equal(np.diag(D), 0.0)


def test_six_axes_two_obvious_directions():
    # 0 and 3 sit between their neighbours (atan 0.1 from each), the neighbours are ~0.141 rad apart
    A = _unit([[1, 0, 0], [-1, 0.1, 0], [1, 0, 0.1], [0, 0, 1], [0.1, 0, -1], [0, 0.1, 1]])
    r = kmedoids(A, 2, metric="axis")
    np.testing.assert_array_equal(r.medoids, [0, 3])
    np.testing.assert_array_equal(r.labels, [0, 0, 0, 1, 1, 1])


def test_flipping_axes_changes_nothing():
    rng = np.random.default_rng(3)
    A = _unit(rng.normal(size=(400, 3)))
    flipped = A * rng.choice([-1.0, 1.0], size=(400, 1))
    r, rf = kmedoids(A, 6, metric="axis"), kmedoids(flipped, 6, metric="axis")
    np.testing.assert_array_equal(r.medoids, rf.medoids)
    np.testing.assert_array_equal(r.labels, rf.labels)
    assert r.loss == rf.loss


def test_k_equal_one_is_the_exact_medoid():
    X = np.random.default_rng(0).normal(size=(50, 3))
    D = dissimilarities(X)
    r = fasterpam(D, 1)
    assert r.medoids[0] == np.argmin(D.sum(axis=1))
    assert r.loss == pytest.approx(D.sum(axis=1).min())


# -- properties -------------------------------------------------------------------------------------------------------


@st.composite
def _instances(draw):
    n = draw(st.integers(2, 40))
    d = draw(st.integers(1, 3))
    # a small grid of values, so that duplicates and ties happen
    X = draw(hnp.arrays(np.float64, (n, d), elements=st.integers(-4, 4).map(float)))
    k = draw(st.integers(1, n - 1))
    perm = draw(st.permutations(range(n)))
    return X, k, np.array(perm[:k], dtype=np.int64)


@settings(max_examples=150, deadline=None)
@given(_instances(), st.sampled_from(["euclidean", "axis"]))
def test_fasterpam_properties(inst, metric):
    X, k, init = inst
    if metric == "axis":
        X = X + np.where(np.abs(X).sum(axis=1, keepdims=True) == 0, 1.0, 0.0)  # no zero-length axes
    D = dissimilarities(X, metric=metric)
    initial_loss = D[:, init].min(axis=1).sum()
    r = fasterpam(D, k, init=init)
    _check_invariants(r, D)
    assert r.loss <= initial_loss + 1e-12
    _check_invariants(fasterpam(D, k, seed=7), D)


@settings(max_examples=40, deadline=None)
@given(
    hnp.arrays(np.float64, st.tuples(st.integers(30, 120), st.just(3)), elements=st.floats(-1, 1, width=32)),
    st.integers(1, 6),
    st.sampled_from(["euclidean", "axis"]),
)
def test_sampled_path_properties(X, k, metric):
    if metric == "axis":
        X = X + np.where(np.abs(X).sum(axis=1, keepdims=True) < 1e-6, 1.0, 0.0)
    r = kmedoids(X, k, metric=metric, exact_limit=10, sample_size=max(k + 1, 20), draws=3)
    _check_invariants(r, dissimilarities(X, metric=metric))


def test_a_swap_local_optimum_of_the_reference_is_one_of_ours_and_back():
    # both implementations stop where no single swap improves: from each other's result neither moves the loss
    X = np.random.default_rng(5).normal(size=(700, 3))
    D = dissimilarities(X)
    ref = reference.fasterpam(D, 12, random_state=0, n_cpu=1)
    ours = fasterpam(D, 12, init=np.asarray(ref.medoids, dtype=np.int64))
    assert ours.loss == pytest.approx(ref.loss, rel=1e-9)
    ours = fasterpam(D, 12, seed=1)
    back = reference.fasterpam(D, ours.medoids.copy(), n_cpu=1)
    assert back.loss == pytest.approx(ours.loss, rel=1e-9)


# -- against the reference implementation -----------------------------------------------------------------------------


def _blobs(rng, n, centres, spread):
    return centres[rng.integers(0, len(centres), n)] + rng.normal(scale=spread, size=(n, centres.shape[1]))


def _instance(kind: str, n: int):
    rng = np.random.default_rng(n)
    if kind == "uniform":
        return rng.random((n, 3)) * [0.12, 0.08, 0.05]
    if kind == "blobs":
        return _blobs(rng, n, rng.random((25, 3)) * 0.1, 0.006)
    if kind == "axes":
        return _unit(rng.normal(size=(n, 3)))
    if kind == "axis_bundles":
        return _unit(_blobs(rng, n, _unit(rng.normal(size=(10, 3))), 0.15) * rng.choice([-1.0, 1.0], (n, 1)))
    raise AssertionError(kind)


@pytest.mark.parametrize(
    ("kind", "metric", "n", "k"),
    [
        ("uniform", "euclidean", 3000, 16),
        ("blobs", "euclidean", 2000, 16),
        ("uniform", "euclidean", 600, 40),
        ("axes", "axis", 3000, 4),
        ("axis_bundles", "axis", 2000, 8),
        ("axes", "axis", 500, 16),
    ],
)
def test_loss_within_one_percent_of_the_reference(kind, metric, n, k):
    X = _instance(kind, n)
    D = dissimilarities(X, metric=metric)
    best_ref = min(reference.fasterpam(D, k, random_state=s, n_cpu=1).loss for s in range(4))
    r = kmedoids(X, k, metric=metric)
    assert r.loss <= 1.01 * best_ref
    _check_invariants(r, D)


@pytest.mark.parametrize("metric", ["euclidean", "axis"])
def test_loss_within_one_percent_of_exact_pam(metric):
    X = _instance("blobs" if metric == "euclidean" else "axis_bundles", 300)
    D = dissimilarities(X, metric=metric)
    assert kmedoids(X, 6, metric=metric).loss <= 1.01 * reference.pam(D, 6, init="build").loss


# -- large n: sampled --------------------------------------------------------------------------------------------------


def test_large_n_never_builds_the_full_matrix_and_finds_the_blobs(monkeypatch):
    rng = np.random.default_rng(11)
    centres = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1], [0.1, 0.1, 0.1]], dtype=float)
    truth = np.repeat(np.arange(5), [3000, 2000, 1500, 1000, 500])
    X = centres[truth] + rng.normal(scale=0.004, size=(truth.size, 3))
    sizes = []
    original = clustering._pairwise

    def spy(A, metric, threads=True):
        sizes.append(A.shape[0])
        return original(A, metric, threads)

    monkeypatch.setattr(clustering, "_pairwise", spy)
    r = kmedoids(X, 5, exact_limit=4000, sample_size=500, draws=3)
    assert sizes and max(sizes) == 500
    np.testing.assert_array_equal(r.labels, truth)  # blob sizes differ, so the numbering is the blob order
    np.testing.assert_array_equal(np.bincount(r.labels), [3000, 2000, 1500, 1000, 500])
    assert r.loss == pytest.approx(np.linalg.norm(X - X[r.medoids][r.labels], axis=1).sum())


def test_default_sample_grows_with_k_and_stays_bounded():
    assert clustering._default_sample_size(16) == 1800
    assert clustering._default_sample_size(4) == 1200
    assert clustering._default_sample_size(1000) == 10_000
    assert clustering._default_sample_size(10_000) == 20_000  # still more than k, as FasterPAM needs


def test_deterministic():
    rng = np.random.default_rng(2)
    X = rng.random((6000, 3))
    A = _unit(rng.normal(size=(6000, 3)))
    for kwargs in ({"exact_limit": 4000}, {"exact_limit": 100, "sample_size": 300}):
        a, b = kmedoids(X[:1500], 7, seed=3, **kwargs), kmedoids(X[:1500], 7, seed=3, **kwargs)
        np.testing.assert_array_equal(a.medoids, b.medoids)
        np.testing.assert_array_equal(a.labels, b.labels)
        assert a.loss == b.loss and a.n_iter == b.n_iter
    a, b = two_stage(X, A, 8, 3, seed=5), two_stage(X.copy(), A.copy(), 8, 3, seed=5)
    before = numba.get_num_threads()
    numba.set_num_threads(1)  # stage two then runs cluster after cluster instead of on a thread pool
    try:
        c = two_stage(X, A, 8, 3, seed=5)
    finally:
        numba.set_num_threads(before)
    for other in (b, c):
        for f in ("labels", "medoids", "medoid_clusters", "cluster_sizes", "translation_medoids"):
            np.testing.assert_array_equal(getattr(a, f), getattr(other, f))
        assert (a.loss_translation, a.loss_direction) == (other.loss_translation, other.loss_direction)


# -- few or no candidates ----------------------------------------------------------------------------------------------


def test_fewer_points_than_k_are_all_medoids():
    X = np.random.default_rng(0).random((3, 3))
    for r in (kmedoids(X, 5), kmedoids(X, 3), fasterpam(dissimilarities(X), 4)):
        np.testing.assert_array_equal(r.medoids, [0, 1, 2])
        np.testing.assert_array_equal(r.labels, [0, 1, 2])
        assert r.loss == 0.0


def test_empty_input():
    assert two_stage([], [], 16, 4).medoids.size == 0
    r = kmedoids(np.zeros((0, 3)), 4)
    assert r.medoids.shape == (0,) and r.labels.shape == (0,) and r.loss == 0.0
    assert fasterpam(np.zeros((0, 0)), 2).medoids.size == 0
    t = two_stage(np.zeros((0, 3)), np.zeros((0, 3)), 16, 4)
    assert t.labels.shape == (0, 2) and t.medoids.shape == (0,) and t.medoid_clusters.shape == (0, 2)
    assert t.cluster_sizes.shape == (0,) and t.note


def test_two_stage_fewer_candidates_than_k1_times_k2_returns_all():
    rng = np.random.default_rng(1)
    P, A = rng.random((12, 3)), _unit(rng.normal(size=(12, 3)))
    t = two_stage(P, A, 16, 4)
    assert sorted(t.medoids.tolist()) == list(range(12))
    assert t.note == "12 candidates, fewer than k1*k2=64: all returned"
    np.testing.assert_array_equal(t.cluster_sizes, 1)
    assert t.loss_direction == 0.0 and t.loss_translation == 0.0

    P, A = rng.random((20, 3)), _unit(rng.normal(size=(20, 3)))
    t = two_stage(P, A, 4, 8)
    assert sorted(t.medoids.tolist()) == list(range(20)) and "fewer than k1*k2=32" in t.note
    assert set(t.labels[:, 0].tolist()) == {0, 1, 2, 3}
    assert len({tuple(row) for row in t.labels.tolist()}) == 20  # every candidate its own (t, d) cluster
    np.testing.assert_array_equal(t.labels[t.medoids], t.medoid_clusters)


# -- two stages --------------------------------------------------------------------------------------------------------


def test_two_stage_recovers_four_blobs_times_two_directions():
    rng = np.random.default_rng(4)
    centres = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0.05]])
    directions = _unit([[1, 0, 0], [0, 0.3, 1]])
    blob_sizes, first_dir = [80, 60, 40, 30], [50, 20, 25, 18]  # in blob 1 the second direction is the larger
    blob, direction = [], []
    for b, (m, f) in enumerate(zip(blob_sizes, first_dir, strict=True)):
        blob += [b] * m
        direction += [0] * f + [1] * (m - f)
    blob, direction = np.array(blob), np.array(direction)
    perm = rng.permutation(blob.size)
    blob, direction = blob[perm], direction[perm]
    P = centres[blob] + rng.normal(scale=0.003, size=(blob.size, 3))
    A = _unit(directions[direction] + rng.normal(scale=0.05, size=(blob.size, 3)))
    A *= rng.choice([-1.0, 1.0], size=(blob.size, 1))  # contacts in either order

    t = two_stage(P, A, 4, 2, seed=0)
    assert t.note is None
    np.testing.assert_array_equal(t.labels[:, 0], blob)  # blobs are numbered by size already
    expected_dir = np.where(blob == 1, 1 - direction, direction)  # the larger direction group is cluster 0
    np.testing.assert_array_equal(t.labels[:, 1], expected_dir)
    np.testing.assert_array_equal(t.medoid_clusters, [[0, 0], [0, 1], [1, 0], [1, 1], [2, 0], [2, 1], [3, 0], [3, 1]])
    np.testing.assert_array_equal(t.labels[t.medoids], t.medoid_clusters)
    np.testing.assert_array_equal(t.cluster_sizes, [50, 30, 40, 20, 25, 15, 18, 12])
    assert t.medoids.dtype == np.int64 and t.labels.dtype == np.int32 and t.medoid_clusters.dtype == np.int32
    assert (blob[t.translation_medoids] == np.arange(4)).all()

    # the losses are those of the stated metrics
    own_tm = t.translation_medoids[t.labels[:, 0]]
    assert t.loss_translation == pytest.approx(np.linalg.norm(P - P[own_tm], axis=1).sum())
    medoid_of = {tuple(c): m for c, m in zip(t.medoid_clusters.tolist(), t.medoids.tolist(), strict=True)}
    owner = np.array([medoid_of[tuple(row)] for row in t.labels.tolist()])
    angle = np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", A, A[owner])), 0, 1))
    assert t.loss_direction == pytest.approx(angle.sum(), abs=1e-6)


def test_two_stage_sampled_directions_lose_under_one_percent_against_a_sample_twice_as_large():
    """Stage two samples STAGE_TWO_SAMPLE members per draw (fewer than kmedoids' default): on 12,000 candidates in
    two translation clusters, each a spread of directions over a cone, the direction loss stays within 1 % of the
    one kmedoids reaches with its larger default sample, cluster by cluster."""
    from graspgen import clustering

    rng = np.random.default_rng(11)
    n = 12_000
    P = np.where((np.arange(n) < n // 2)[:, None], [0.0, 0.0, 0.0], [0.2, 0.0, 0.0]) + rng.normal(0, 0.01, (n, 3))
    A = _unit(rng.normal(0, 1, (n, 3)) * [1.0, 0.6, 0.3] + [0.0, 0.0, 0.4])
    t = two_stage(P, A, 2, 4, seed=3)
    assert clustering._default_sample_size(4) > clustering.STAGE_TWO_SAMPLE
    for c in range(2):
        members = np.flatnonzero(t.labels[:, 0] == c)
        assert members.size > clustering.STAGE_TWO_EXACT_LIMIT  # the sampled path
        ours = t.medoids[t.medoid_clusters[:, 0] == c]
        owner = ours[t.labels[members, 1]]
        loss = np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", A[members], A[owner])), 0, 1)).sum()
        larger = kmedoids(A[members], 4, metric="axis", seed=3).loss
        assert loss <= 1.01 * larger


def test_two_stage_notes_translation_clusters_smaller_than_k2():
    rng = np.random.default_rng(8)
    P = np.concatenate([rng.normal(scale=0.001, size=(40, 3)), [[1.0, 1.0, 1.0]]])
    A = _unit(rng.normal(size=(41, 3)))
    t = two_stage(P, A, 2, 4)
    assert t.medoids.size == 5 and t.medoids[-1] == 40
    np.testing.assert_array_equal(t.medoid_clusters[-1], [1, 0])
    assert "fewer than k1*k2=8" in t.note


# -- input checks ------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("call", "error", "field"),
    [
        (lambda: kmedoids(np.zeros((4, 3)), 0), InvalidParameterError, "k"),
        (lambda: kmedoids(np.zeros((4, 3)), True), InvalidParameterError, "k"),
        (lambda: kmedoids(np.zeros((4, 3)), 2, metric="cosine"), InvalidParameterError, "metric"),
        (lambda: kmedoids(np.zeros((4, 3)), 2, draws=0), InvalidParameterError, "draws"),
        (lambda: kmedoids(np.zeros((4, 3)), 2, sample_size=2), InvalidParameterError, "sample_size"),
        (lambda: kmedoids(np.zeros(4), 2), InvalidCandidatesError, "X"),
        (lambda: kmedoids([[0.0, np.nan]], 2), InvalidCandidatesError, "X"),
        (lambda: kmedoids([["a"]], 2), InvalidCandidatesError, "X"),
        (lambda: kmedoids(np.zeros((4, 3)), 2, metric="axis"), InvalidCandidatesError, "X"),
        (lambda: fasterpam(np.zeros((3, 4)), 2), InvalidCandidatesError, "diss"),
        (lambda: fasterpam(-np.ones((3, 3)), 2), InvalidCandidatesError, "diss"),
        (lambda: fasterpam(np.array([[0.0, 1.0], [2.0, 0.0]]), 1), InvalidCandidatesError, "diss"),
        (lambda: fasterpam(np.zeros((3, 3)), 2, init=np.array([0, 0])), InvalidParameterError, "init"),
        (lambda: fasterpam(np.zeros((3, 3)), 2, max_iter=0), InvalidParameterError, "max_iter"),
        (lambda: two_stage(np.zeros((4, 3)), np.eye(3)[[0, 1, 2, 0]], 0, 2), InvalidParameterError, "k1"),
        (lambda: two_stage(np.zeros((4, 3)), np.eye(3)[[0, 1, 2, 0]], 2, 1.5), InvalidParameterError, "k2"),
        (lambda: two_stage(np.zeros((4, 3)), np.eye(3)[[0, 1, 2, 0]], 2, 2, seed=-1), InvalidParameterError, "seed"),
        (lambda: two_stage(np.zeros((4, 2)), np.eye(3)[[0, 1, 2, 0]], 2, 2), InvalidCandidatesError, "midpoints"),
        (lambda: two_stage(np.zeros((4, 3)), np.eye(3)[[0, 1, 2]], 2, 2), InvalidCandidatesError, "axes"),
        (lambda: two_stage(np.zeros((3, 3)), np.zeros((3, 3)), 2, 2), InvalidCandidatesError, "axes"),
        (lambda: two_stage(np.full((3, 3), np.inf), np.eye(3), 2, 2), InvalidCandidatesError, "midpoints"),
    ],
)
def test_bad_input_is_refused_with_a_field(call, error, field):
    with pytest.raises(error) as info:
        call()
    assert info.value.field == field
    assert info.value.message


def test_two_stage_normalises_axes():
    rng = np.random.default_rng(6)
    P, A = rng.random((300, 3)), _unit(rng.normal(size=(300, 3)))
    a = two_stage(P, A, 3, 2)
    b = two_stage(P, A * rng.uniform(0.5, 2.0, size=(300, 1)), 3, 2)
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.medoids, b.medoids)
