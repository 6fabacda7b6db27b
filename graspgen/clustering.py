"""k-medoids (FasterPAM) and the two-stage grasp clustering of Kleeberger et al.

`fasterpam` is Schubert & Rousseeuw's FasterPAM (Information Systems 101, 2021): eager swaps, the O(k)
removal-loss bookkeeping with nearest / second-nearest medoid per point, O(n^2) per pass over the data, seeded by
greedy k-medoids++ (points drawn with probability proportional to their distance, 2 + ln k trials per medoid, the
trial that lowers the loss most kept). It is written here with numba because the reference implementation (the
`kmedoids` package) is GPL-3 and graspgen is Apache-2.0; that package is used only by the tests and benchmarks, as a
yardstick.

`kmedoids` works on points: up to `exact_limit` points it runs FasterPAM on the full dissimilarity matrix; above it
runs CLARA-style draws (FasterPAM on a sample, every point assigned to its nearest medoid, the loss taken over all
points, the best draw kept), so memory stays O(n + sample_size^2) and never O(n^2).

`two_stage` clusters grasp candidates by their midpoints (Euclidean, metres, k1 clusters), then each translation
cluster by its closing axes (k2 clusters) with the sign-invariant angle

    d(a, b) = arccos |a . b|   in radians, 0 .. pi/2,

so a closing axis and its reverse (the same jaw pair, contacts swapped) are the same direction. A suction cup's
approach and its reverse are different grasps: `two_stage(..., signed=True)` (metric "direction") uses the signed
angle arccos(a . b), 0 .. pi, evaluated near 0 and pi from the chord as well. Near 0 it is
evaluated as 2 arcsin(|a - s b| / 2) with s = sign(a . b), exact where arccos loses half its digits. The angle is a
metric (the triangle inequality holds), unlike 1 - |a . b|, and it grows linearly with the deviation like the
Euclidean midpoint distance, so both stages minimise the same kind of loss (1 - |a . b| ~ angle^2 / 2 would weight
outlying axes like a squared error).

Label numbering, everywhere in this module: clusters are ordered by descending size, ties broken by the smaller
medoid index (in two_stage: translation clusters that way, and direction clusters that way within each translation
cluster). The same inputs and seed give identical labels and medoids.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

from .errors import InvalidCandidatesError, InvalidParameterError

__all__ = [
    "KMedoidsResult",
    "TwoStageResult",
    "METRICS",
    "fasterpam",
    "kmedoids",
    "two_stage",
    "dissimilarities",
    "EXACT_LIMIT",
    "DRAWS",
    "STAGE_TWO_EXACT_LIMIT",
    "compile_parallel_kernels",
]

#: kmedoids() defaults, also used by two_stage(): full-matrix FasterPAM up to this many points (128 MB), ...
EXACT_LIMIT = 4000
#: ... and this many seedings (exact) or samples (above EXACT_LIMIT), the lowest loss kept
DRAWS = 5
MAX_ITER = 100
#: two_stage()'s second stage (the axis clusters within each translation cluster) goes to sampling above this many
#: members: on tless_04's 79,196 candidates that costs 0.4 of the exact stage's CPU time for a direction loss
#: 0.03 % higher (bench/bench_clustering.py)
STAGE_TWO_EXACT_LIMIT = 2000
#: ... and samples this many members per draw (kmedoids() defaults to 1000 + 50 k): directions on a sphere need few
#: samples. On the 10,000-point cylinder's 717,357 candidates (16 clusters of 20-73 k members, k2 = 4) stage two
#: takes 0.61 s of CPU, a quarter of what twice the sample costs, for a direction loss 0.12 % higher
STAGE_TWO_SAMPLE = 600

#: the default CLARA sample, 1000 + 50 k, stops growing here (unless 2 k is larger) ...
_SAMPLE_CAP = 10_000
#: ... and the largest matrix side kmedoids() builds: 20,000^2 float64 is 3.2 GB (so k1 <= 10,000, as Params allow)
_MAX_MATRIX = 20_000

#: metric name -> kernel code
METRICS: dict[str, int] = {"euclidean": 0, "axis": 1, "direction": 2}
_EUCLIDEAN = 0
_AXIS = 1
#: the signed angle arccos(a . b), 0 .. pi: a suction cup's approach and its reverse are different grasps
_DIRECTION = 2

#: axes shorter than this cannot be normalised
_MIN_AXIS_NORM = 1e-9
#: below this |a . b| the axis angle is arccos |a . b|, above it 2 arcsin(chord / 2) (both exact there)
_ACOS_SAFE = 0.9
#: distance evaluations below which a kernel runs on one thread (waking a thread pool costs more than it saves,
#: and a lot more on a busy machine)
_PARALLEL_MIN_WORK = 1 << 18
_BLOCK = 64
#: a swap is taken only if it lowers the loss by more than this fraction of it (guards against rounding cycles)
_REL_GAIN = 1e-12


@dataclass(frozen=True)
class KMedoidsResult:
    """One k-medoids clustering of n points.

    loss: sum of the distances of the points to their medoid.
    medoids: (k,) int64 indices into the input (k = min(k, n)); medoid j is the medoid of cluster j.
    labels: (n,) int32 in [0, k); clusters are numbered by descending size, ties by the smaller medoid index.
    n_iter: passes over the data of FasterPAM (of the kept draw, on the sampled path).
    """

    loss: float
    medoids: np.ndarray
    labels: np.ndarray
    n_iter: int


@dataclass(frozen=True)
class TwoStageResult:
    """The two-stage clustering of n grasp candidates into at most k1 * k2 medoids.

    labels: (n, 2) int32 translation cluster, direction cluster (direction numbering restarts per translation cluster).
    medoids: (m,) int64 candidate indices of the final medoids, grouped by translation cluster (cluster 0 first),
        then direction cluster.
    medoid_clusters: (m, 2) int32 the (translation, direction) cluster of each medoid.
    cluster_sizes: (m,) int64 members represented by each medoid (sums to n).
    loss_translation: sum of midpoint distances to the translation medoid's midpoint, metres.
    loss_direction: sum of axis angles to the direction medoid's axis, radians.
    note: set when the result is not the plain k1 x k2 clustering (too few candidates).
    translation_medoids: (min(k1, n),) int64 candidate indices of the stage-one medoids, by translation cluster.
    """

    labels: np.ndarray
    medoids: np.ndarray
    medoid_clusters: np.ndarray
    cluster_sizes: np.ndarray
    loss_translation: float
    loss_direction: float
    note: str | None
    translation_medoids: np.ndarray


# --------------------------------------------------------------------------------------------------------------------
# kernels


@njit(cache=True, nogil=True, inline="always")
def _dot(X: np.ndarray, i: int, Y: np.ndarray, j: int) -> float:
    s = 0.0
    for c in range(X.shape[1]):
        s += X[i, c] * Y[j, c]
    return s


@njit(cache=True, nogil=True, inline="always")
def _dist(X: np.ndarray, i: int, Y: np.ndarray, j: int, metric: int) -> float:
    d = X.shape[1]
    if metric == _EUCLIDEAN:
        s = 0.0
        for c in range(d):
            t = X[i, c] - Y[j, c]
            s += t * t
        euclidean: float = np.sqrt(s)
        return euclidean
    dot = _dot(X, i, Y, j)
    if metric == _DIRECTION:
        return _direction_angle(X, i, Y, j, dot)
    ac = abs(dot)
    if ac < _ACOS_SAFE:
        angle: float = np.arccos(ac)
        return angle
    # near 0 rad arccos loses half its digits; the chord |a - s b| (s = sign(a . b)) is exact there (0 for a = +-b)
    sg = 1.0 if dot >= 0.0 else -1.0
    dm = 0.0
    for c in range(d):
        t = X[i, c] - sg * Y[j, c]
        dm += t * t
    chord_angle: float = 2.0 * np.arcsin(min(0.5 * np.sqrt(dm), 1.0))
    return chord_angle


@njit(cache=True, nogil=True, inline="always")
def _direction_angle(X: np.ndarray, i: int, Y: np.ndarray, j: int, dot: float) -> float:
    """arccos(a . b) of unit rows a = X[i], b = Y[j]; near 0 and pi from the chord |a -+ b| (exact there)."""
    if abs(dot) < _ACOS_SAFE:
        angle: float = np.arccos(dot)
        return angle
    sg = 1.0 if dot >= 0.0 else -1.0
    dm = 0.0
    for c in range(X.shape[1]):
        t = X[i, c] - sg * Y[j, c]
        dm += t * t
    near: float = 2.0 * np.arcsin(min(0.5 * np.sqrt(dm), 1.0))
    return near if dot >= 0.0 else math.pi - near


@njit(cache=True, nogil=True, inline="always")
def _upper_row(X: np.ndarray, i: int, metric: int, D: np.ndarray) -> None:
    D[i, i] = 0.0
    for j in range(i + 1, X.shape[0]):
        D[i, j] = _dist(X, i, X, j, metric)


@njit(cache=True, nogil=True, inline="always")
def _mirror_block_row(D: np.ndarray, bi: int) -> None:
    # blocks of B x B rows/columns so that reading the upper triangle column-wise stays in cache
    n = D.shape[0]
    i0 = bi * _BLOCK
    i1 = min(i0 + _BLOCK, n)
    for bj in range(bi + 1):
        j0 = bj * _BLOCK
        j1 = min(j0 + _BLOCK, n)
        for i in range(i0, i1):
            for j in range(j0, min(j1, i)):
                D[i, j] = D[j, i]


@njit(cache=True, nogil=True)
def _pairwise_serial(X: np.ndarray, metric: int) -> np.ndarray:
    n = X.shape[0]
    D = np.empty((n, n))
    for i in range(n):
        _upper_row(X, i, metric, D)
    for bi in range((n + _BLOCK - 1) // _BLOCK):
        _mirror_block_row(D, bi)
    return D


@njit(cache=True, nogil=True, parallel=True)
def _pairwise_parallel(X: np.ndarray, metric: int) -> np.ndarray:
    n = X.shape[0]
    D = np.empty((n, n))
    for i in prange(n):
        _upper_row(X, i, metric, D)
    for bi in prange((n + _BLOCK - 1) // _BLOCK):
        _mirror_block_row(D, bi)
    return D


def _pairwise(X: np.ndarray, metric: int, threads: bool = True) -> np.ndarray:
    """(n, n) distances between the rows of X: the upper triangle (the axis angle costs a transcendental per pair;
    _dist is exactly symmetric), then a blocked mirror. Serial and parallel kernels give identical results."""
    n = X.shape[0]
    big = threads and n * n // 2 >= _PARALLEL_MIN_WORK
    return (_pairwise_parallel if big else _pairwise_serial)(X, metric)


@njit(cache=True, nogil=True, inline="always")
def _nearest(X: np.ndarray, i: int, C: np.ndarray, metric: int) -> tuple[int, float]:
    """Nearest row of C to row i of X (first one on ties) and the distance to it."""
    k = C.shape[0]
    best = np.inf
    bj = 0
    if metric == _AXIS:
        # the angle falls as |a . b| grows: rank by |a . b| and take the transcendental only for the few medoids
        # close to the best (the two can disagree by rounding, never by 1e-9)
        top = -1.0
        for j in range(k):
            top = max(top, abs(_dot(X, i, C, j)))
        for j in range(k):
            if abs(_dot(X, i, C, j)) >= top - 1e-9:
                v = _dist(X, i, C, j, metric)
                if v < best:
                    best = v
                    bj = j
    else:
        for j in range(k):
            v = _dist(X, i, C, j, metric)
            if v < best:
                best = v
                bj = j
    return bj, best


@njit(cache=True, nogil=True)
def _assign_serial(X: np.ndarray, C: np.ndarray, metric: int) -> tuple[np.ndarray, np.ndarray]:
    n = X.shape[0]
    labels = np.empty(n, np.int32)
    dist = np.empty(n)
    for i in range(n):
        labels[i], dist[i] = _nearest(X, i, C, metric)
    return labels, dist


@njit(cache=True, nogil=True, parallel=True)
def _assign_parallel(X: np.ndarray, C: np.ndarray, metric: int) -> tuple[np.ndarray, np.ndarray]:
    n = X.shape[0]
    labels = np.empty(n, np.int32)
    dist = np.empty(n)
    for i in prange(n):
        labels[i], dist[i] = _nearest(X, i, C, metric)
    return labels, dist


def _assign(X: np.ndarray, C: np.ndarray, metric: int, threads: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(n,) int32 nearest row of C for every row of X (first one on ties), (n,) float64 distance to it."""
    big = threads and X.shape[0] * C.shape[0] >= _PARALLEL_MIN_WORK
    return (_assign_parallel if big else _assign_serial)(X, C, metric)


def compile_parallel_kernels() -> None:
    """Run the parallel nearest-medoid assignment once on an input just large enough to take it, so that numba
    compiles it (graspgen warmup): small runs take the serial kernel only."""
    X = np.ascontiguousarray(np.random.default_rng(0).random((_PARALLEL_MIN_WORK // 16 + 1, 3)))
    _assign(X, np.ascontiguousarray(X[:16]), 0)


@njit(cache=True, nogil=True)
def _init_greedy_pp(D: np.ndarray, k: int, u: np.ndarray) -> np.ndarray:
    """Greedy k-medoids++ on a dissimilarity matrix: seeding by distance (D^1) with 2 + ln k trials per medoid,
    keeping the trial that lowers the loss most. `u` (k, trials) uniforms in [0, 1) make it deterministic."""
    n = D.shape[0]
    trials = u.shape[1]
    med = np.empty(k, np.int64)
    is_med = np.zeros(n, np.bool_)
    med[0] = min(int(u[0, 0] * n), n - 1)
    is_med[med[0]] = True
    dmin = D[med[0]].copy()
    cum = np.empty(n)
    for m in range(1, k):
        total = 0.0
        for i in range(n):
            total += dmin[i]
            cum[i] = total
        if total <= 0.0:
            # every point coincides with a medoid: take the first free index
            for i in range(n):
                if not is_med[i]:
                    med[m] = i
                    break
        else:
            best_cost = np.inf
            best_c = -1
            for t in range(trials):
                target = u[m, t] * total
                lo = 0
                hi = n - 1
                while lo < hi:  # first i with cum[i] > target
                    mid = (lo + hi) // 2
                    if cum[mid] > target:
                        hi = mid
                    else:
                        lo = mid + 1
                c = lo
                while c < n and (is_med[c] or dmin[c] <= 0.0):  # rounding at the ends of cum
                    c += 1
                if c == n:
                    c = lo
                    while c >= 0 and (is_med[c] or dmin[c] <= 0.0):
                        c -= 1
                cost = 0.0
                for i in range(n):
                    cost += min(dmin[i], D[c, i])
                if cost < best_cost:
                    best_cost = cost
                    best_c = c
            med[m] = best_c
        is_med[med[m]] = True
        row = D[med[m]]
        for i in range(n):
            if row[i] < dmin[i]:
                dmin[i] = row[i]
    return med


@njit(cache=True, nogil=True)
def _second(D: np.ndarray, med: np.ndarray, o: int, skip: int) -> tuple[int, float]:
    """Nearest medoid of point o other than slot `skip`: (slot, distance)."""
    best = np.inf
    bi = -1
    for i in range(med.shape[0]):
        if i != skip:
            v = D[o, med[i]]
            if v < best:
                best = v
                bi = i
    return bi, best


@njit(cache=True, nogil=True)
def _fasterpam_kernel(D: np.ndarray, med: np.ndarray, max_iter: int) -> tuple[np.ndarray, float, int]:
    """FasterPAM from the medoids `med` (k >= 2, modified in place). Returns (labels, loss, n_iter)."""
    n = D.shape[0]
    k = med.shape[0]
    near = np.empty(n, np.int64)
    dn = np.empty(n)
    sec = np.empty(n, np.int64)
    ds = np.empty(n)
    for o in range(n):
        a, da = _second(D, med, o, -1)
        near[o] = a
        dn[o] = da
        b, db = _second(D, med, o, a)
        sec[o] = b
        ds[o] = db
    removal = np.zeros(k)
    loss = 0.0
    for o in range(n):
        loss += dn[o]
        removal[near[o]] += ds[o] - dn[o]
    delta_td = np.empty(k)

    xlast = -1
    n_iter = 0
    done = False
    while n_iter < max_iter and not done:
        n_iter += 1
        swaps = 0
        for j in range(n):
            if j == xlast:
                done = True  # a full round without an improving swap
                break
            if dn[j] == 0.0:
                continue  # a medoid or a duplicate of one: swapping it in cannot help
            # best swap of j with any medoid (Schubert & Rousseeuw, Alg. 2)
            for i in range(k):
                delta_td[i] = removal[i]
            acc = 0.0
            Dj = D[j]  # row access: D is symmetric, and columns would stride through memory
            for o in range(n):
                # branch-free form of: if doj < dn: acc += doj - dn; delta[near] += dn - ds
                #                      elif doj < ds: delta[near] += doj - ds
                # (adds +0.0 otherwise, so bit-identical; about twice as fast as the mispredicted branches)
                doj = Dj[o]
                a = dn[o]
                b = ds[o]
                acc += min(doj - a, 0.0)
                delta_td[near[o]] += min(max(doj, a), b) - b
            b = 0
            for i in range(1, k):
                if delta_td[i] < delta_td[b]:
                    b = i
            change = delta_td[b] + acc
            if not change < -_REL_GAIN * loss:
                continue
            # swap medoid slot b for point j, then repair nearest / second nearest
            swaps += 1
            xlast = j
            med[b] = j
            loss = 0.0
            for o in range(n):
                doj = Dj[o]
                if o == j:
                    near[o] = b
                    dn[o] = 0.0
                    s2, d2 = _second(D, med, o, b)
                    sec[o] = s2
                    ds[o] = d2
                elif near[o] == b:
                    if doj < ds[o]:
                        dn[o] = doj  # the new medoid takes the old one's slot and stays nearest
                    else:
                        near[o] = sec[o]
                        dn[o] = ds[o]
                        s2, d2 = _second(D, med, o, near[o])
                        sec[o] = s2
                        ds[o] = d2
                elif doj < dn[o]:
                    sec[o] = near[o]
                    ds[o] = dn[o]
                    near[o] = b
                    dn[o] = doj
                elif sec[o] == b:
                    s2, d2 = _second(D, med, o, near[o])
                    sec[o] = s2
                    ds[o] = d2
                elif doj < ds[o]:
                    sec[o] = b
                    ds[o] = doj
                loss += dn[o]
            for i in range(k):
                removal[i] = 0.0
            for o in range(n):
                removal[near[o]] += ds[o] - dn[o]
        if swaps == 0:
            done = True
    labels = near.astype(np.int32)
    for i in range(k):
        labels[med[i]] = i
    loss = 0.0
    for o in range(n):
        loss += D[o, med[labels[o]]]
    return labels, loss, n_iter


@njit(cache=True, nogil=True)
def _is_symmetric(D: np.ndarray, rtol: float, atol: float) -> bool:
    n = D.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            a = D[i, j]
            b = D[j, i]
            if abs(a - b) > atol + rtol * max(a, b):
                return False
    return True


@njit(cache=True, nogil=True)
def _one_medoid(D: np.ndarray) -> tuple[int, float]:
    """The exact 1-medoid: smallest row sum, smallest index on ties."""
    n = D.shape[0]
    best = np.inf
    bi = 0
    for i in range(n):
        s = 0.0
        for o in range(n):
            s += D[i, o]
        if s < best:
            best = s
            bi = i
    return bi, best


# --------------------------------------------------------------------------------------------------------------------
# helpers


def _canonical(medoids: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Renumber clusters by descending size, ties by the smaller medoid index."""
    k = medoids.shape[0]
    sizes = np.bincount(labels, minlength=k)
    order = np.lexsort((medoids, -sizes))
    rank = np.empty(k, np.int32)
    rank[order] = np.arange(k, dtype=np.int32)
    return medoids[order].astype(np.int64), rank[labels].astype(np.int32)


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _result(loss: float, medoids: np.ndarray, labels: np.ndarray, n_iter: int) -> KMedoidsResult:
    medoids, labels = _canonical(np.asarray(medoids, np.int64), np.asarray(labels, np.int32))
    return KMedoidsResult(float(loss), _frozen(medoids), _frozen(labels), int(n_iter))


def _all_own(n: int) -> KMedoidsResult:
    return KMedoidsResult(0.0, _frozen(np.arange(n, dtype=np.int64)), _frozen(np.arange(n, dtype=np.int32)), 0)


def _check_int(name: str, v: object, lo: int, hi: int | None = None) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        raise InvalidParameterError(f"{name} must be an integer, got {v!r}", field=name)
    v = int(v)
    if v < lo or (hi is not None and v > hi):
        rng = f">= {lo}" if hi is None else f"between {lo} and {hi}"
        raise InvalidParameterError(f"{name} must be {rng}, got {v}", field=name)
    return v


def _check_points(name: str, X: object, dim: int | None = None) -> np.ndarray:
    try:
        A = np.asarray(X, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InvalidCandidatesError(f"{name} must be a numeric array: {e}", field=name) from None
    if A.size == 0 and A.ndim == 1:  # [] is an empty set of points
        A = A.reshape(0, dim or 0)
    if A.ndim != 2 or (dim is not None and A.shape[1] != dim) or (A.shape[0] > 0 and A.shape[1] < 1):
        want = f"(n, {dim})" if dim is not None else "(n, d)"
        raise InvalidCandidatesError(f"{name} must have shape {want}, got {A.shape}", field=name)
    if not np.isfinite(A).all():
        bad = int(np.flatnonzero(~np.isfinite(A).all(axis=1))[0])
        raise InvalidCandidatesError(f"{name}[{bad}] is not finite: {A[bad].tolist()}", field=name)
    return np.ascontiguousarray(A)


def _unit_rows(name: str, A: np.ndarray) -> np.ndarray:
    norms = np.sqrt(np.einsum("ij,ij->i", A, A))
    if A.shape[0] and norms.min() < _MIN_AXIS_NORM:
        bad = int(np.argmin(norms))
        raise InvalidCandidatesError(f"{name}[{bad}] has (near) zero length and no direction", field=name)
    return np.ascontiguousarray(A / norms[:, None])


def _metric_code(metric: object) -> int:
    if metric not in METRICS:
        raise InvalidParameterError(f"metric must be one of {', '.join(METRICS)}, got {metric!r}", field="metric")
    return METRICS[metric]


def _uniforms(rng: np.random.Generator, k: int) -> np.ndarray:
    return rng.random((k, 2 + int(math.log(k))))


def _run(D: np.ndarray, k: int, rng: np.random.Generator, max_iter: int) -> tuple[np.ndarray, np.ndarray, float, int]:
    """FasterPAM on a checked matrix, 1 <= k < n, seeded by greedy k-medoids++: (medoids, labels, loss, n_iter)."""
    if k == 1:
        m, loss = _one_medoid(D)
        return np.array([m], np.int64), np.zeros(D.shape[0], np.int32), float(loss), 1
    med = _init_greedy_pp(D, k, _uniforms(rng, k))
    labels, loss, n_iter = _fasterpam_kernel(D, med, max_iter)
    return med, labels, float(loss), int(n_iter)


# --------------------------------------------------------------------------------------------------------------------
# public


def dissimilarities(X: np.ndarray, *, metric: str = "euclidean") -> np.ndarray:
    """(n, n) float64 matrix of the module's distances between the rows of X (n, d); "axis" normalises the rows."""
    code = _metric_code(metric)
    A = _check_points("X", X)
    if code != _EUCLIDEAN:
        A = _unit_rows("X", A)
    return _pairwise(A, code)


def fasterpam(
    diss: np.ndarray, k: int, *, seed: int = 0, max_iter: int = MAX_ITER, init: np.ndarray | None = None
) -> KMedoidsResult:
    """FasterPAM on an (n, n) float64 dissimilarity matrix (finite, >= 0, symmetric; a zero diagonal is assumed).

    Starts from `init` ((k,) distinct indices) if given, else from a greedy k-medoids++ seeding drawn with `seed`.
    With n <= k every point is its own medoid; k = 1 is solved exactly.
    """
    k = _check_int("k", k, 1)
    seed = _check_int("seed", seed, 0)
    max_iter = _check_int("max_iter", max_iter, 1)
    try:
        D = np.ascontiguousarray(diss, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InvalidCandidatesError(f"diss must be a numeric matrix: {e}", field="diss") from None
    if D.ndim != 2 or D.shape[0] != D.shape[1]:
        raise InvalidCandidatesError(f"diss must be a square (n, n) matrix, got shape {D.shape}", field="diss")
    if not np.isfinite(D).all() or (D < 0).any():
        raise InvalidCandidatesError("diss must be finite and non-negative", field="diss")
    if not _is_symmetric(D, 1e-9, 1e-12):
        raise InvalidCandidatesError("diss must be symmetric", field="diss")
    n = D.shape[0]
    if init is not None:
        med0 = np.asarray(init)
        if (
            med0.shape != (min(k, n),)
            or not np.issubdtype(med0.dtype, np.integer)
            or np.unique(med0).size != med0.size
            or (med0.size and (med0.min() < 0 or med0.max() >= n))
        ):
            raise InvalidParameterError(f"init must hold {min(k, n)} distinct indices in [0, {n})", field="init")
    if n <= k:
        return _all_own(n)
    if init is None or k == 1:
        med, labels, loss, n_iter = _run(D, k, np.random.default_rng(seed), max_iter)
    else:
        med = med0.astype(np.int64).copy()
        labels, loss, n_iter = _fasterpam_kernel(D, med, max_iter)
    return _result(loss, med, labels, n_iter)


def _default_sample_size(k: int) -> int:
    # CLARA's 40 + 2k is tuned for PAM's cost; FasterPAM affords far more, but keep the sample matrix <= 800 MB
    return min(1000 + 50 * k, max(_SAMPLE_CAP, 2 * k))


def kmedoids(
    X: np.ndarray,
    k: int,
    *,
    metric: str = "euclidean",
    seed: int = 0,
    exact_limit: int = EXACT_LIMIT,
    draws: int = DRAWS,
    sample_size: int | None = None,
    max_iter: int = MAX_ITER,
) -> KMedoidsResult:
    """k-medoids of the rows of X (n, d) under `metric` ("euclidean", or "axis": arccos |a . b| of the normalised rows).

    n <= exact_limit: FasterPAM on the full matrix, `draws` seedings, the lowest loss kept.
    n > exact_limit: `draws` CLARA draws of `sample_size` points (default 1000 + 50 k, at most 10,000 or 2 k; the
    best medoids so far are part of every later sample), FasterPAM on each sample, all n points assigned to the
    nearest medoid and the loss summed over all of them; the lowest loss is kept. Memory O(n + sample_size^2).
    n <= k: every point is its own medoid (loss 0).
    """
    code = _metric_code(metric)
    k = _check_int("k", k, 1)
    seed = _check_int("seed", seed, 0)
    exact_limit = _check_int("exact_limit", exact_limit, 1, _MAX_MATRIX)
    draws = _check_int("draws", draws, 1)
    max_iter = _check_int("max_iter", max_iter, 1)
    sample_size = _default_sample_size(k) if sample_size is None else sample_size
    sample_size = _check_int("sample_size", sample_size, k + 1, _MAX_MATRIX)
    A = _check_points("X", X)
    if code != _EUCLIDEAN:
        A = _unit_rows("X", A)
    return _kmedoids(A, k, code, seed, exact_limit, draws, sample_size, max_iter, threads=True)


def _kmedoids(
    A: np.ndarray,
    k: int,
    code: int,
    seed: int,
    exact_limit: int,
    draws: int,
    sample_size: int,
    max_iter: int,
    *,
    threads: bool,
) -> KMedoidsResult:
    """kmedoids() on checked (and for "axis" normalised) points; `threads=False` keeps every kernel on the calling
    thread, for callers that run several of these at once."""
    n = A.shape[0]
    if n <= k:
        return _all_own(n)
    rng = np.random.default_rng(seed)

    if n <= exact_limit:
        D = _pairwise(A, code, threads)
        best = None
        for _ in range(draws):
            med, labels, loss, n_iter = _run(D, k, rng, max_iter)
            if best is None or loss < best[2]:
                best = (med, labels, loss, n_iter)
        assert best is not None  # draws >= 1
        return _result(best[2], best[0], best[1], best[3])

    s = min(sample_size, n)
    best = None
    for _ in range(draws):
        if best is None:
            sample = rng.choice(n, size=s, replace=False)
        else:
            extra = rng.choice(n, size=s, replace=False)
            extra = extra[~np.isin(extra, best[0])][: s - k]
            sample = np.concatenate([best[0], extra])
        sample = np.sort(sample)
        med_s, _, _, n_iter = _run(_pairwise(A[sample], code, threads), k, rng, max_iter)
        med = sample[med_s]
        labels, dist = _assign(A, np.ascontiguousarray(A[med]), code, threads)
        labels[med] = np.arange(k, dtype=np.int32)  # duplicates of a medoid belong to their own medoid
        dist[med] = 0.0
        loss = float(np.sum(dist))
        if best is None or loss < best[2]:
            best = (med, labels, loss, n_iter)
    assert best is not None  # draws >= 1
    return _result(best[2], best[0], best[1], best[3])


def _sub_seed(seed: int, *path: int) -> int:
    return int(np.random.SeedSequence([seed, *path]).generate_state(1)[0])


def two_stage(
    midpoints: np.ndarray, axes: np.ndarray, k1: int, k2: int, *, seed: int = 0, signed: bool = False
) -> TwoStageResult:
    """Two-stage k-medoids of grasp candidates: k1 clusters of the midpoints (n, 3) float64 metres (Euclidean), then
    k2 clusters of the closing axes (n, 3) (normalised here; sign-invariant angle) within each translation cluster.
    `signed`: the axes are directions (a suction cup's approaches), compared by the signed angle arccos(a . b).

    A translation cluster with at most k2 members keeps each member as its own medoid. With fewer than k1 * k2
    candidates every candidate is returned as its own medoid: translation clusters as usual (min(k1, n) of them),
    each member its own direction cluster (numbered by candidate index, so direction labels may reach k2 or more),
    and `note` says so.
    """
    k1 = _check_int("k1", k1, 1)
    k2 = _check_int("k2", k2, 1)
    seed = _check_int("seed", seed, 0)
    P = _check_points("midpoints", midpoints, 3)
    U = _check_points("axes", axes, 3)
    if P.shape[0] != U.shape[0]:
        raise InvalidCandidatesError(
            f"midpoints and axes must have the same length, got {P.shape[0]} and {U.shape[0]}", field="axes"
        )
    U = _unit_rows("axes", U)
    n = P.shape[0]
    if n == 0:
        e32 = np.zeros((0, 2), np.int32)
        return TwoStageResult(
            _frozen(e32),
            _frozen(np.zeros(0, np.int64)),
            _frozen(e32.copy()),
            _frozen(np.zeros(0, np.int64)),
            0.0,
            0.0,
            "0 candidates: nothing to cluster",
            _frozen(np.zeros(0, np.int64)),
        )

    all_returned = n < k1 * k2
    r1 = kmedoids(P, k1, metric="euclidean", seed=_sub_seed(seed, 1))
    labels = np.empty((n, 2), np.int32)
    labels[:, 0] = r1.labels
    order = np.argsort(r1.labels, kind="stable")  # members of each cluster in index order
    bounds = np.concatenate([[0], np.cumsum(np.bincount(r1.labels, minlength=r1.medoids.size))])
    groups = [order[bounds[t] : bounds[t + 1]] for t in range(r1.medoids.size)]

    def stage_two(t: int, threads: bool) -> KMedoidsResult:
        if all_returned:
            return _all_own(groups[t].size)
        return _kmedoids(
            U[groups[t]],
            k2,
            _DIRECTION if signed else _AXIS,
            _sub_seed(seed, 2, t),
            STAGE_TWO_EXACT_LIMIT,
            DRAWS,
            max(STAGE_TWO_SAMPLE, 2 * k2),
            MAX_ITER,
            threads=threads,
        )

    # the translation clusters are independent: one per core, each on a single thread (the kernels release the GIL);
    # the result does not depend on the schedule
    workers = min(numba.get_num_threads(), len(groups))
    if workers > 1 and not all_returned:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            second = list(pool.map(lambda t: stage_two(t, False), range(len(groups))))
    else:
        second = [stage_two(t, True) for t in range(len(groups))]

    medoids, clusters, sizes = [], [], []
    loss_direction = 0.0
    for t, (members, r2) in enumerate(zip(groups, second, strict=True)):
        labels[members, 1] = r2.labels
        loss_direction += r2.loss
        m = r2.medoids.size
        medoids.append(members[r2.medoids])
        clusters.append(np.column_stack([np.full(m, t, np.int32), np.arange(m, dtype=np.int32)]))
        sizes.append(np.bincount(r2.labels, minlength=m).astype(np.int64))
    medoids_a = np.concatenate(medoids).astype(np.int64)
    note = None
    if all_returned:
        note = f"{n} candidates, fewer than k1*k2={k1 * k2}: all returned"
    elif medoids_a.size < k1 * k2:
        note = (
            f"{medoids_a.size} medoids, fewer than k1*k2={k1 * k2}: "
            f"some translation clusters have fewer than k2={k2} members"
        )
    return TwoStageResult(
        _frozen(labels),
        _frozen(medoids_a),
        _frozen(np.concatenate(clusters).astype(np.int32)),
        _frozen(np.concatenate(sizes)),
        float(r1.loss),
        float(loss_direction),
        note,
        r1.medoids,
    )
