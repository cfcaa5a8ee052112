"""The 2D sector rule (eq. 5 in 2D): the grid path gives exactly the weights of the original
implementation, kept here verbatim as the reference."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from rbc_registration.core.interpolation import sector_grid
from rbc_registration.core.interpolation import sectors
from rbc_registration.core.interpolation.paper import PaperInterpolator


def reference_sectors(points, targets):
    """The reference sector rule: PaperInterpolator._sectors without the grid path."""
    tree = cKDTree(points)
    k = min(64, len(points))
    dist, cand = tree.query(targets, k=k)
    dist, cand = dist.reshape(len(targets), k), cand.reshape(len(targets), k)
    delta = points[cand] - targets[:, None, :]
    sector = np.floor((np.arctan2(delta[..., 1], delta[..., 0]) + np.pi / 8)
                      / (np.pi / 4)).astype(np.intp) % 8
    in_sector = sector[:, :, None] == np.arange(8)            # (K, k, 8)
    filled = in_sector.any(axis=1)                            # (K, 8)
    first = in_sector.argmax(axis=1)                          # candidates sorted by distance
    rows = np.arange(len(targets))[:, None]
    idx = cand[rows, first]
    w = np.where(filled, 1.0 / np.maximum(dist[rows, first], 1e-300), 0.0)
    on = dist[:, 0] <= 1e-12 * max(1.0, float(np.abs(points).max()))
    idx[on] = cand[on, :1]
    w[on] = np.eye(8)[0]
    return idx, w / w.sum(axis=1, keepdims=True)


def assert_same_weights(points, targets):
    """Weights identical (bit for bit), the same fiducial in every used slot, and the same
    interpolated corrections, through PaperInterpolator (grid path for K >= 32)."""
    eps = np.random.default_rng(99).normal(size=points.shape)
    ip = PaperInterpolator(points, eps)
    ref_idx, ref_w = reference_sectors(points, targets)
    used = ref_w > 0
    for _ in range(sector_grid.PREPARE_AFTER + 1):   # the cells are prepared, then used
        idx, w, _ = ip.weights(targets)
        np.testing.assert_array_equal(w, ref_w)
        np.testing.assert_array_equal(idx[used], ref_idx[used])
    np.testing.assert_array_equal(ip(targets).correction,
                                  np.einsum("km,kmd->kd", ref_w, eps[ref_idx]))
    return ip


def grid(nx, ny, pitch=25.0):
    return np.stack(np.meshgrid(np.arange(nx) * pitch, np.arange(ny) * pitch, indexing="ij"),
                    -1).reshape(-1, 2)


def spread_targets(points, k, rng, margin=0.1):
    lo, hi = points.min(axis=0), points.max(axis=0)
    ext = hi - lo
    return lo - margin * ext + (1 + 2 * margin) * ext * rng.uniform(size=(k, 2))


@pytest.mark.parametrize("case", ["uniform", "noisy-grid", "clusters", "thin", "far-offset",
                                  "few", "many"])
def test_grid_path_equals_reference_on_random_cells(case):
    rng = np.random.default_rng(hash(case) % 2**32)
    if case == "uniform":
        pts = rng.uniform(0, 3.0, (277, 2))
    elif case == "noisy-grid":
        pts = grid(17, 21) + rng.normal(scale=0.1, size=(357, 2))
    elif case == "clusters":
        pts = np.concatenate([c + rng.normal(scale=0.05, size=(60, 2))
                              for c in rng.uniform(0, 2, (5, 2))])
    elif case == "thin":                                   # 40 : 1 strip
        pts = rng.uniform(0, 1, (300, 2)) * [40.0, 1.0]
    elif case == "far-offset":                             # tracker coordinates far from 0
        pts = 1e5 + rng.uniform(0, 2.0, (200, 2))
    elif case == "few":                                    # J < 64: the cap never binds
        pts = rng.uniform(-1, 1, (12, 2))
    else:
        pts = rng.uniform(0, 10.0, (3000, 2))
    targets = spread_targets(pts, 3000, rng)
    ip = assert_same_weights(pts, targets)
    assert ip._sector_index._used > 0                      # the grid path was taken


def test_exact_grid_with_ties_midpoints_and_targets_on_fiducials():
    """A regular grid: targets on holes, on midpoints (equidistant fiducials), at cell centres
    and random; ties and on-fiducial targets take the reference path and still agree."""
    pts = grid(17, 21)
    rng = np.random.default_rng(3)
    special = np.concatenate([pts[::7], pts[:-1:5] + [12.5, 0.0], pts[:-1:3] + [12.5, 12.5],
                              pts[::11] + [0.0, 1e-13]])
    targets = np.concatenate([special, spread_targets(pts, 2000, rng)])
    assert_same_weights(pts, targets)


def test_fiducials_on_sector_boundaries():
    """Targets that see a fiducial exactly (to rounding) along a sector boundary, where the
    classification needs the formula itself."""
    rng = np.random.default_rng(7)
    pts = rng.uniform(0, 1, (200, 2))
    ang = np.pi / 8 + np.pi / 4 * rng.integers(0, 8, 1500)
    r = rng.uniform(0.01, 0.2, 1500)
    targets = pts[rng.integers(0, 200, 1500)] - r[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    assert_same_weights(pts, targets)


def test_small_batches_and_repeated_batches_agree():
    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 1, (150, 2))
    ip = assert_same_weights(pts, spread_targets(pts, 5, rng))           # general path only
    t = spread_targets(pts, 500, rng)
    for _ in range(3):                                      # cells prepared, then reused
        idx, w, _ = ip.weights(t)
        np.testing.assert_array_equal(w, reference_sectors(pts, t)[1])


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(j=st.integers(3, 200), seed=st.integers(0, 2**32 - 1),
       aspect=st.floats(0.05, 20.0), scale=st.sampled_from([1e-3, 1.0, 1e3]))
def test_property_grid_path_equals_reference(j, seed, aspect, scale):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0, 1, (j, 2)) * [scale * aspect, scale]
    if np.linalg.svd(pts - pts.mean(0), compute_uv=False)[-1] < 1e-6 * scale:
        return                                             # collinear: refused by the hull
    assert_same_weights(pts, spread_targets(pts, 400, rng, margin=0.3))


@pytest.mark.parametrize("case", ["uniform", "grid", "boundary", "few", "under-32"])
def test_staged_path_equals_reference(case, monkeypatch):
    """The staged path alone (smaller queries first, :class:`EmptySectors`): bit for bit the
    reference, with most targets settled before the rule's own query."""
    rng = np.random.default_rng(len(case))
    pts = {"uniform": lambda: rng.uniform(0, 3.0, (1000, 2)),
           "grid": lambda: grid(17, 21), "boundary": lambda: rng.uniform(0, 1, (200, 2)),
           "few": lambda: rng.uniform(-1, 1, (12, 2)),
           "under-32": lambda: rng.uniform(-1, 1, (25, 2))}[case]()
    if case == "boundary":           # fiducials seen exactly along sector boundaries
        ang = np.pi / 8 + np.pi / 4 * rng.integers(0, 8, 1500)
        r = rng.uniform(0.01, 0.2, 1500)
        targets = pts[rng.integers(0, 200, 1500)] - r[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    elif case == "grid":             # holes, midpoints, cell centres, near-holes and random
        targets = np.concatenate([pts[::7], pts[:-1:5] + [12.5, 0.0], pts[:-1:3] + [12.5, 12.5],
                                  pts[::11] + [0.0, 1e-13], spread_targets(pts, 2000, rng)])
    else:
        targets = spread_targets(pts, 3000, rng)
    fallback = []
    rule = sectors.sector_weights
    monkeypatch.setattr(sectors, "sector_weights",
                        lambda tree, p, t: (fallback.append(len(t)), rule(tree, p, t))[1])
    idx, w = sectors.staged_sector_weights(cKDTree(pts), pts, sectors.EmptySectors(pts), targets)
    ref_idx, ref_w = reference_sectors(pts, targets)
    np.testing.assert_array_equal(w, ref_w)
    np.testing.assert_array_equal(idx[ref_w > 0], ref_idx[ref_w > 0])
    if len(pts) > sectors.STAGES[0]:
        assert sum(fallback) < 0.5 * len(targets)           # the stages did most of the work


def test_empty_sectors_are_empty_and_found():
    rng = np.random.default_rng(11)
    pts = rng.uniform(0, 1, (300, 2))
    targets = spread_targets(pts, 2000, rng, margin=0.5)
    empty = sectors.EmptySectors(pts)(targets)
    delta = pts[None, :, :] - targets[:, None, :]
    holds = np.zeros_like(empty)
    for s in range(8):
        holds[:, s] = (sectors.sector_of(delta[..., 0], delta[..., 1]) == s).any(axis=1)
    assert not (empty & holds).any()                        # never a sector that holds one
    assert (empty == ~holds).mean() > 0.99                  # and (nearly) every empty one


def test_empty_sectors_far_from_the_cell():
    """A target millions of cells away sees a fiducial along a sector boundary: the margin grows
    with the target's coordinates, so that sector is not called empty (with a
    margin of the cell's scale alone the staged weights were [1, 0, ...], the rule's
    [0.5, 0.5, ...])."""
    u = np.array([np.cos(np.pi / 8), np.sin(np.pi / 8)])
    n = np.array([-u[1], u[0]])
    pts = np.vstack([-0.05 * np.arange(1, 21)[:, None] * u - 0.5 * n, [[0.0, 0.0]]])
    far = np.array([[-27716385.9753386, -11480502.97095269]])
    tree = cKDTree(pts)
    ref_idx, ref_w = sectors.sector_weights(tree, pts, far)
    idx, w = sectors.staged_sector_weights(tree, pts, sectors.EmptySectors(pts), far)
    np.testing.assert_array_equal(w, ref_w)
    np.testing.assert_array_equal(idx[ref_w > 0], ref_idx[ref_w > 0])
    rng = np.random.default_rng(12)                 # and along boundary rays, 1e4 to 1e12 away
    r = 10.0 ** rng.uniform(4, 12, 4000)
    ang = np.pi / 8 + np.pi / 4 * rng.integers(0, 8, 4000)
    t = pts[rng.integers(0, len(pts), 4000)] - r[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    ref_idx, ref_w = reference_sectors(pts, t)
    idx, w = sectors.staged_sector_weights(tree, pts, sectors.EmptySectors(pts), t)
    np.testing.assert_array_equal(w, ref_w)
    np.testing.assert_array_equal(idx[ref_w > 0], ref_idx[ref_w > 0])


def test_sector_of_is_the_formula():
    rng = np.random.default_rng(5)
    ang = np.concatenate([rng.uniform(-np.pi, np.pi, 20000),
                          np.arange(-8, 9) * np.pi / 8,                 # boundaries and axes
                          np.arange(-8, 9) * np.pi / 8 + 1e-12,
                          np.arange(-8, 9) * np.pi / 8 - 1e-12])
    r = rng.uniform(1e-3, 1e3, len(ang))
    dx, dy = r * np.cos(ang), r * np.sin(ang)
    dx = np.concatenate([dx, [0.0, -0.0, 1.0, -1.0, 0.0, 0.0, -1.0, -1.0]])
    dy = np.concatenate([dy, [0.0, 0.0, 0.0, 0.0, 1.0, -1.0, 0.0, -0.0]])
    want = np.floor((np.arctan2(dy, dx) + np.pi / 8) / (np.pi / 4)).astype(np.intp) % 8
    np.testing.assert_array_equal(sectors.sector_of(dx, dy), want)


def test_grid_cells_are_prepared_once_and_kept():
    rng = np.random.default_rng(6)
    pts = rng.uniform(0, 1, (100, 2))
    index = sector_grid.SectorIndex(pts, cKDTree(pts))
    t = spread_targets(pts, 200, rng, margin=0.0)
    index.weights(np.repeat(t[:3], sector_grid.PREPARE_AFTER, axis=0))
    once = index._used                    # the cells of 3 targets, each hit 8 times at once
    for _ in range(sector_grid.PREPARE_AFTER - 1):
        index.weights(t)
    assert index._used == once            # no other cell hit 8 times yet
    index.weights(t)
    prepared = index._used                # every cell hit, now 8 times
    index.weights(t)
    assert 0 < once < prepared and index._used == prepared


@pytest.mark.parametrize("case", ["uniform", "grid", "boundary", "few", "far-offset"])
def test_one_target_path_equals_reference(case):
    """One target (the node's): :func:`sectors.one_target_weights` and the interpolator's single
    call are bit for bit the reference, on ties, midpoints, sector boundaries and fiducials."""
    rng = np.random.default_rng(len(case) + 40)
    if case == "grid":
        pts = grid(17, 21)
        targets = np.concatenate([pts[::7], pts[:-1:5] + [12.5, 0.0], pts[:-1:3] + [12.5, 12.5],
                                  pts[::11] + [0.0, 1e-13], spread_targets(pts, 300, rng)])
    elif case == "boundary":
        pts = rng.uniform(0, 1, (200, 2))
        ang = np.pi / 8 + np.pi / 4 * rng.integers(0, 8, 300)
        r = rng.uniform(0.01, 0.2, 300)
        targets = pts[rng.integers(0, 200, 300)] - r[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    else:
        j = {"uniform": 1000, "few": 5, "far-offset": 300}[case]
        pts = rng.uniform(0, 1, (j, 2)) + (6.4e6 if case == "far-offset" else 0.0)
        targets = np.concatenate([spread_targets(pts, 400, rng, margin=0.5), pts[:10]])
    eps = rng.normal(size=pts.shape)
    ip = PaperInterpolator(pts, eps)
    tree = cKDTree(pts)
    tol = sectors.on_fiducial_tolerance(pts)
    for t in targets:
        ref_idx, ref_w = reference_sectors(pts, t[None])
        idx, w = sectors.one_target_weights(tree, pts, t[None], tol)
        np.testing.assert_array_equal(w, ref_w)
        np.testing.assert_array_equal(idx, ref_idx)
        np.testing.assert_array_equal(ip(t[None]).correction,
                                      np.einsum("km,kmd->kd", ref_w, eps[ref_idx]))



def test_one_target_path_with_one_or_two_fiducials():
    """The query returns scalars for one fiducial: the rule itself answers."""
    for pts in (np.array([[1.0, 2.0]]), np.array([[0.0, 0.0], [1.0, 0.5]])):
        tree = cKDTree(pts)
        for t in (np.array([[0.3, 0.1]]), pts[:1]):
            a = sectors.sector_weights(tree, pts, t)
            b = sectors.one_target_weights(tree, pts, t, sectors.on_fiducial_tolerance(pts))
            np.testing.assert_array_equal(a[0], b[0])
            np.testing.assert_array_equal(a[1], b[1])
