"""Target corrections: the paper's interpolation (eq. 5) and kriging."""

import numpy as np
import pytest
from scipy.spatial import Delaunay

from rbc_registration.core.interpolation.paper import HullTest, PaperInterpolator
from rbc_registration.core.interpolation.kriging import KrigingInterpolator


def grid3():
    return np.stack(np.meshgrid(*[np.arange(5.0)] * 3, indexing="ij"), -1).reshape(-1, 3)


def linear(p):
    return p @ np.array([[0.1, 0.2, 0.3], [0.0, 0.1, 0.0], [0.2, 0.0, 0.1]]) + 0.05


def test_tetrahedron_weights_reproduce_a_linear_field():
    pts = grid3()
    ip = PaperInterpolator(pts, linear(pts))
    t = np.random.default_rng(0).uniform(0.2, 3.8, (50, 3))
    res = ip(t)
    assert res.inside_hull.all()
    np.testing.assert_allclose(res.correction, linear(t), atol=1e-9)
    idx, w, _ = ip.weights(t)
    assert idx.shape == (50, 4)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    assert (w > -1e-9).all()                     # barycentric: inside the tetrahedron
    assert np.isnan(res.expected_error).all()


def test_2d_uses_the_8_surrounding_grid_holes():
    holes = np.stack(np.meshgrid(np.arange(9.0), np.arange(9.0), indexing="ij"), -1
                     ).reshape(-1, 2) * 25.0
    target = 40                                   # hole (4, 4), removed from the fiducials
    fid = np.delete(holes, target, axis=0)
    ip = PaperInterpolator(fid, np.zeros_like(fid))
    idx, w, inside = ip.weights(holes[target:target + 1])
    used = fid[idx[0][w[0] > 0]]
    dist = np.linalg.norm(used - holes[target], axis=1)
    assert len(used) == 8 and inside[0]
    assert sorted(np.round(dist, 6)) == sorted([25.0] * 4 + [round(25 * np.sqrt(2), 6)] * 4)
    assert w[0].sum() == pytest.approx(1.0)


def test_target_on_a_fiducial_gets_its_correction():
    pts = grid3()
    eps = np.random.default_rng(1).normal(size=pts.shape)
    grid2 = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0)), -1).reshape(-1, 2)
    for ip_pts in (pts, grid2):
        e = eps[:len(ip_pts), :ip_pts.shape[1]]
        ip = PaperInterpolator(ip_pts, e)
        np.testing.assert_allclose(ip(ip_pts[7:8]).correction, e[7:8], atol=1e-9)


def test_outside_hull_is_flagged_with_idw_fallback():
    pts = grid3()
    ip = PaperInterpolator(pts, np.ones_like(pts))
    res = ip(np.array([[10.0, 2.0, 2.0], [2.0, 2.0, 2.0]]))
    assert list(res.inside_hull) == [False, True]
    np.testing.assert_allclose(res.correction, 1.0)     # weights still normalised


def test_interpolation_validation():
    with pytest.raises(ValueError, match="at least 4"):
        PaperInterpolator(np.eye(3), np.eye(3))
    ip = PaperInterpolator(grid3(), grid3())
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        ip(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="NaN"):
        ip(np.array([[np.nan, 0, 0]]))
    flat = np.unique(np.c_[grid3()[:, :2], np.zeros(125)], axis=0)
    with pytest.raises(ValueError, match="coplanar.*kriging"):
        PaperInterpolator(flat, np.zeros_like(flat))


def test_coplanar_3d_fiducials_work_with_kriging():
    flat = np.unique(np.c_[grid3()[:, :2], np.zeros(125)], axis=0)
    ip = KrigingInterpolator(flat, 1e-3 * np.sin(flat), sigma=1e-5)
    res = ip(np.array([[1.5, 1.5, 0.0], [1.5, 1.5, 0.3], [9.0, 1.0, 0.0]]))
    assert list(res.inside_hull) == [True, False, False]


def smooth(p):
    return 0.01 * np.c_[np.sin(p[:, 0] / 2), np.cos(p[:, 1] / 3), np.sin(p[:, 2] / 2.5)]


def test_kriging_follows_a_clean_field():
    pts = grid3()
    ip = KrigingInterpolator(pts, smooth(pts), sigma=1e-6)
    t = np.random.default_rng(2).uniform(0.5, 3.5, (40, 3))
    res = ip(t)
    paper = PaperInterpolator(pts, smooth(pts))(t)
    err_k = np.linalg.norm(res.correction - smooth(t), axis=1)
    err_p = np.linalg.norm(paper.correction - smooth(t), axis=1)
    assert np.median(err_k) < np.median(err_p)
    assert (res.expected_error > 0).all() and res.inside_hull.all()


def test_kriging_shrinks_pure_noise_toward_zero():
    pts = grid3()
    noise = np.random.default_rng(3).normal(scale=0.01, size=pts.shape)   # no field at all
    ip = KrigingInterpolator(pts, noise, sigma=0.01 * np.sqrt(3))
    t = np.random.default_rng(4).uniform(0.5, 3.5, (40, 3))
    k = np.linalg.norm(ip(t).correction, axis=1)
    p = np.linalg.norm(PaperInterpolator(pts, noise)(t).correction, axis=1)
    assert np.median(k) < 0.3 * np.median(p)


def test_kriging_fits_unknown_noise():
    pts = grid3()
    rng = np.random.default_rng(5)
    eps = smooth(pts) + rng.normal(scale=0.002, size=pts.shape)
    ip = KrigingInterpolator(pts, eps, sigma=None)
    assert ip.hyper.noise_fitted
    assert ip.hyper.noise_std == pytest.approx(0.002 * np.sqrt(3), rel=0.5)


def test_kriging_reuses_hyperparameters_and_validates():
    pts = grid3()
    a = KrigingInterpolator(pts, smooth(pts), sigma=1e-4)
    b = KrigingInterpolator(pts, smooth(pts), hyperparameters=a.hyper)
    assert b.hyper == a.hyper
    with pytest.raises(ValueError, match="repeats"):
        KrigingInterpolator(pts, smooth(pts), sigma=1e-4, repeats=np.zeros(125))
    with pytest.raises(ValueError, match="sigma"):
        KrigingInterpolator(pts, smooth(pts), sigma=-1.0)


@pytest.mark.parametrize("dim", [2, 3])
def test_minimal_fiducial_count_is_one_simplex(dim):
    """d + 1 fiducials (the fewest a model accepts) interpolate linearly inside their simplex."""
    pts = np.vstack([np.zeros(dim), np.eye(dim) * 2.0])
    def field(p):
        return p @ np.arange(1.0, dim * dim + 1).reshape(dim, dim) * 0.01 + 0.5

    ip = PaperInterpolator(pts, field(pts))
    t = np.full((1, dim), 0.3)
    res = ip(t)
    assert res.inside_hull.all()
    if dim == 3:                                  # barycentric: exact for a linear field
        np.testing.assert_allclose(res.correction, field(t), atol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_the_hull_computes_its_transforms_with_the_triangulation(dim):
    """find_simplex needs the barycentric transforms of all simplices: the hull computes them when
    it is built, so the first answer of a new model (in the node's executor) does not pay for
    them; locating is the same as with scipy's own transforms."""
    rng = np.random.default_rng(dim)
    pts = rng.uniform(0, 1, (200, dim))
    hull = HullTest(pts)
    assert "_rbc_transform" in vars(hull.tri)
    t = rng.uniform(-0.2, 1.2, (500, dim))
    centre = pts.mean(axis=0)
    np.testing.assert_array_equal(hull.simplices(t),
                                  Delaunay(pts - centre, qhull_options="QJ").find_simplex(
                                      t - centre, tol=1e-9))


def _cells(dim):
    """Fiducial sets whose triangulations have regular, degenerate and sliver simplices."""
    rng = np.random.default_rng(10 + dim)
    grid = np.array(np.meshgrid(*[np.arange(8.0 if dim == 3 else 20.0)] * dim)).reshape(dim, -1).T
    return {"random": rng.uniform(0, 1, (800, dim)),
            "grid": grid,                                          # QJ leaves degenerate simplices
            "noisy grid": grid + rng.normal(0, 1e-6, grid.shape),
            "slab": rng.uniform(0, 1, (600, dim)) * np.r_[np.ones(dim - 1), 1e-4],
            "clusters": np.vstack([rng.normal(0, 1e-3, (300, dim)),   # slivers between them
                                   rng.normal(5, 1, (300, dim))])}


def _exact_inverse(t):
    """T^-1 of a 2x2 or 3x3 float matrix in rational arithmetic, rounded once."""
    from fractions import Fraction
    m = [[Fraction(float(x)) for x in row] for row in t]
    d = len(m)
    if d == 2:
        det = m[0][0] * m[1][1] - m[0][1] * m[1][0]
        adj = [[m[1][1], -m[0][1]], [-m[1][0], m[0][0]]]
    else:
        adj = [[m[(j + 1) % 3][(i + 1) % 3] * m[(j + 2) % 3][(i + 2) % 3]
                - m[(j + 1) % 3][(i + 2) % 3] * m[(j + 2) % 3][(i + 1) % 3] for j in range(3)]
               for i in range(3)]
        det = sum(m[0][k] * adj[k][0] for k in range(3))
    return np.array([[float(x / det) for x in row] for row in adj])


@pytest.mark.parametrize("dim", [2, 3])
def test_barycentric_transforms_are_scipys_to_rounding(dim):
    """The vectorised transforms against scipy's (one LAPACK solve per simplex): the same
    degenerate simplices (NaN), the same numbers to rounding, as accurate as LU against the exact
    inverse in the worst-conditioned simplices, and the same simplex found for every target."""
    from rbc_registration.core.interpolation.paper import barycentric_transforms
    rng = np.random.default_rng(dim)
    for name, pts in _cells(dim).items():
        tri = Delaunay(pts - pts.mean(axis=0), qhull_options="QJ")
        ref = tri.transform
        got = barycentric_transforms(tri.points, tri.simplices)
        assert got.shape == ref.shape and got.flags.c_contiguous
        np.testing.assert_array_equal(np.isnan(got), np.isnan(ref), err_msg=name)
        ok = ~np.isnan(ref[:, 0, 0])
        scale = np.abs(ref[ok]).max(axis=(1, 2))
        assert (np.abs(got[ok] - ref[ok]).max(axis=(1, 2)) <= 1e-10 * scale).all(), name
        np.testing.assert_array_equal(got[ok, dim], tri.points[tri.simplices[ok, dim]])
        t = tri.points[tri.simplices[ok][:, :dim]] - tri.points[tri.simplices[ok][:, dim:]]
        cond = np.linalg.cond(np.transpose(t, (0, 2, 1)))
        for s in np.argsort(-cond)[:4]:
            exact = _exact_inverse(t[s].T)
            err = np.abs(got[ok][s, :dim] - exact).max() / np.abs(exact).max()
            err_lu = np.abs(ref[ok][s, :dim] - exact).max() / np.abs(exact).max()
            assert err <= 20 * err_lu + 1e-14, (name, cond[s], err, err_lu)
        lo, hi = tri.points.min(axis=0), tri.points.max(axis=0)
        q = np.vstack([rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), (3000, dim)),
                       tri.points[:300], (tri.points[:300] + tri.points[1:301]) / 2])
        hull = HullTest(pts)
        np.testing.assert_array_equal(hull.simplices(q + pts.mean(axis=0)),
                                      tri.find_simplex(q, tol=1e-9), err_msg=name)
