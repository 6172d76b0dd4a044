"""Physics checks of the single-scatterer form factors (docs/physics.md).

Every reference value here is computed independently of ``corona.model.shapes``:
analytic transforms written out in the test, brute-force angle / size
averages, real-space rasterisation, Parseval, or the shift theorem.
"""
from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from scipy import integrate, ndimage, optimize, special, stats

from corona._validation import CoronaError
from corona.model.shapes import (Circle, Ellipse, Mask, Mixture, Polygon, RandomOrientation,
                           Rectangle, RegularPolygon, Shape, SizeDistribution, SoftEdge,
                           Square)

LAM = 0.55  # µm


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def T_a(shape, d, lam=LAM):
    """Normalised lobe of docs/physics.md#the-model: ``T_a(d) = form_factor(2π d/λ)/λ²`` [1/µm² of d]."""
    return shape.form_factor(2 * np.pi * np.asarray(d) / lam) / lam**2


def integral_Ta(shape, lam=LAM, u_max=200.0, porod=None):
    """``∫ T_a d²d`` in polar d coordinates.

    Radially composite 8-point Gauss–Legendre (panels of Δu = 1, u = q R),
    angularly the trapezoidal rule over [0, 2π) with N > 2.5 u + 32 angles
    (resolves the angular harmonics of ``|Â|²``, which stop near 2 u).
    ``porod`` = P/|A| (perimeter over area): the tail beyond u_max is added
    from Porod's law ``⟨|Â|²⟩_θ → 2P/q³``, i.e. ``∫_{q>Q} = P/(π |A| Q)``.
    """
    R = shape.length_scale
    x, wt = np.polynomial.legendre.leggauss(8)
    total = 0.0
    for k in range(int(u_max)):
        u = k + 0.5 * (x + 1.0)
        d = u * lam / (2 * np.pi * R)
        wd = 0.5 * wt * lam / (2 * np.pi * R)
        if shape.isotropic:
            ring = shape.form_factor_radial(2 * np.pi * d / lam) / lam**2
        else:
            N = int(2.5 * (k + 1) + 32)
            phi = 2 * np.pi * np.arange(N) / N
            pts = d[:, None, None] * np.stack([np.cos(phi), np.sin(phi)], -1)[None]
            ring = T_a(shape, pts, lam).mean(axis=1)
        total += float(np.sum(wd * 2 * np.pi * d * ring))
    if porod is not None:
        total += porod / (np.pi * u_max / R)
    return total


def sinc(x):
    x = np.asarray(x, dtype=float)
    out = np.ones_like(x)
    nz = np.abs(x) > 1e-12
    out[nz] = np.sin(x[nz]) / x[nz]
    return out


def rect_ff(q, w, h, angle=0.0):
    """|Â|²/|A| of a w×h rectangle rotated by angle (written out independently)."""
    c, s = math.cos(angle), math.sin(angle)
    qx = c * q[..., 0] + s * q[..., 1]
    qy = -s * q[..., 0] + c * q[..., 1]
    return w * h * (sinc(qx * w / 2) * sinc(qy * h / 2)) ** 2


def rect_amp(q, w, h, center):
    """Â of an axis-aligned w×h rectangle centred at ``center`` (shift theorem)."""
    ph = q[..., 0] * center[0] + q[..., 1] * center[1]
    return w * h * sinc(q[..., 0] * w / 2) * sinc(q[..., 1] * h / 2) * np.exp(-1j * ph)


def grid(n=64, u=25.0):
    g = np.linspace(-u, u, n)
    return np.stack(np.meshgrid(g, g), axis=-1)


def antialiased_disk(R, p, n, ss=8):
    y, x = (np.mgrid[0:n, 0:n] - (n - 1) / 2) * p
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    cov = np.zeros((n, n))
    for a in sub:
        for b in sub:
            cov += np.hypot(x + a * p, y + b * p) <= R
    return cov / ss**2


L_SHAPE = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)


# ---------------------------------------------------------------------------
# normalisation: ∫ T_a d²d = 1 (binary), = ∫A²/∫A (soft)
# ---------------------------------------------------------------------------
BINARY = [
    (Circle(0.8), 2 / 0.8),
    (Ellipse(1.0, aspect=0.4, angle=17.0), None),
    (Rectangle(0.5, aspect=0.3, angle=11.0), 2 * 1.3 / 0.3),
    (Square(0.35), 4 / 0.7),
    (Polygon(L_SHAPE), 8 / 3),
    (RegularPolygon(5, 1.0, angle=6.0), None),
    (RandomOrientation(Square(0.5)), 4.0),
    (SizeDistribution(Circle(1.0), 0.2, "lognormal"), 2 / 1.04),
    (SizeDistribution(Circle(1.0), 0.2, "schulz"), 2 / 1.04),
    (Mixture([(Circle(1.0), 1.0), (Square(0.25), 3.0)]),
     (1.0 * 2 * np.pi + 3.0 * 2.0) / (1.0 * np.pi + 3.0 * 0.25)),
]


def _porod_ratio(shape, given):
    if given is not None:
        return given
    if isinstance(shape, Ellipse):       # Ramanujan's perimeter
        a, b = shape.semi_axis_x, shape.semi_axis_y
        P = np.pi * (3 * (a + b) - math.sqrt((3 * a + b) * (a + 3 * b)))
        return P / shape.area
    return shape.perimeter / shape.area


@pytest.mark.parametrize("shape,porod", BINARY, ids=lambda v: repr(v)[:40])
def test_lobe_integrates_to_one(shape, porod):
    assert shape.self_overlap == 1.0 or abs(shape.self_overlap - 1.0) < 1e-12
    val = integral_Ta(shape, porod=_porod_ratio(shape, porod))
    assert abs(val - 1.0) < 1e-3, val


def test_lobe_integral_is_wavelength_independent():
    sq = Square(0.35)
    vals = [integral_Ta(sq, lam=lam, u_max=60, porod=4 / 0.7) for lam in (0.4, 0.7)]
    assert abs(vals[0] - vals[1]) < 1e-10


def test_mask_lobe_integrates_to_one_over_band():
    p, R = 0.05, 1.0
    n = 48
    y, x = (np.mgrid[0:n, 0:n] - (n - 1) / 2) * p
    binary = (np.hypot(x, y) <= R).astype(float)
    grey = antialiased_disk(R, p, n)
    for img, expect in ((binary, 1.0), (grey, float(np.sum(grey**2) / np.sum(grey)))):
        m = Mask(img, p)
        assert m.self_overlap == pytest.approx(expect, rel=1e-12)
        # T_a is 0 outside the band |q_x|, |q_y| <= π/p: integrate over it in d
        dmax = LAM / (2 * p)
        N = 500
        g = (np.arange(N) + 0.5) / N * 2 * dmax - dmax
        D = np.stack(np.meshgrid(g, g), -1)
        val = T_a(m, D).sum() * (2 * dmax / N) ** 2
        assert abs(val - expect) < 1e-3, (val, expect)
    # and nothing outside the band
    q = np.array([[np.pi / p * 1.01, 0.0], [0.0, -np.pi / p * 1.2], [50.0, 70.0]])
    assert np.all(m.form_factor(q) == 0.0)


# ---------------------------------------------------------------------------
# circle / ellipse
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("shape", [Circle(1.3), SoftEdge(Circle(1.3), 0.1)], ids=repr)
def test_airy_zeros(shape):
    zeros = []
    for guess in (3.8, 7.0, 10.2):
        res = optimize.minimize_scalar(lambda u: shape.table_radial(np.array([u]))[0],
                                       bounds=(guess - 0.5, guess + 0.5), method="bounded",
                                       options={"xatol": 1e-7})
        zeros.append(res.x)
    assert zeros == pytest.approx([3.8317, 7.0156, 10.1735], abs=2e-4)


def test_circle_peak_and_formula():
    R = 0.9
    c = Circle(R)
    # T_a(0) = π R² / λ²  (docs/physics.md#the-model)
    assert T_a(c, np.zeros((1, 2)))[0] == pytest.approx(np.pi * R**2 / LAM**2, rel=1e-14)
    u = np.linspace(0.1, 30, 50)
    d = u * LAM / (2 * np.pi * R)
    ref = np.pi * R**2 / LAM**2 * (2 * special.j1(u) / u) ** 2
    got = T_a(c, np.stack([d * 0.6, d * 0.8], -1))
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-16)


def test_ellipse_matches_polygon_approximation_and_axis_zeros():
    a, b, ang = 1.2, 0.5, 0.4
    e = Ellipse(a, aspect=b / a, angle=math.degrees(ang))
    n = 3000
    t = 2 * np.pi * np.arange(n) / n
    c, s = math.cos(ang), math.sin(ang)
    x, y = a * np.cos(t), b * np.sin(t)
    poly = Polygon(np.stack([c * x - s * y, s * x + c * y], -1))
    q = grid(41, 12.0)
    np.testing.assert_allclose(e.form_factor(q), poly.form_factor(q), atol=1e-5 * e.area)
    # first zero along the ellipse's own x axis at q = 3.8317 / a
    qs = np.linspace(2.5, 4.5, 20001) / a
    ff = e.form_factor(qs[:, None] * np.array([c, s]))
    assert qs[np.argmin(ff)] * a == pytest.approx(3.8317, abs=2e-4)
    assert Ellipse(0.7).isotropic and Ellipse(0.7, aspect=1.0).isotropic and not e.isotropic
    np.testing.assert_allclose(Ellipse(0.7, angle=57.0).form_factor(q), Circle(0.7).form_factor(q),
                               rtol=1e-12, atol=1e-15)
    assert e.length_scale == a and e.exclusion_diameter == 2 * a


# ---------------------------------------------------------------------------
# rectangles and polygons
# ---------------------------------------------------------------------------
def test_square_against_sinc2():
    for side, ang in ((1.0, 0.0), (0.6, 0.35)):
        sq = Square(side / 2, angle=math.degrees(ang))
        q = grid(64, 40.0)
        np.testing.assert_allclose(sq.form_factor(q), rect_ff(q, side, side, ang),
                                   rtol=1e-12, atol=1e-14)
        assert sq.area == pytest.approx(side**2)
        assert sq.length_scale == pytest.approx(side / math.sqrt(2))
        assert sq.exclusion_diameter == pytest.approx(side * math.sqrt(2))
    r = Rectangle(0.7, aspect=0.3 / 1.4, angle=math.degrees(-0.2))
    q = grid(64, 40.0)
    np.testing.assert_allclose(r.form_factor(q), rect_ff(q, 1.4, 0.3, -0.2), rtol=1e-12, atol=1e-14)


def test_polygon_of_rectangle_equals_rectangle():
    w, h, ang = 1.3, 0.45, 0.7
    c, s = math.cos(ang), math.sin(ang)
    corners = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    rot = corners @ np.array([[c, s], [-s, c]]) + np.array([3.0, -7.0])  # rotated + translated
    poly = Polygon(rot)
    rect = Rectangle(w / 2, aspect=h / w, angle=math.degrees(ang))
    assert poly.area == pytest.approx(rect.area, rel=1e-13)
    assert poly.length_scale == pytest.approx(rect.length_scale, rel=1e-13)
    q = np.concatenate([grid(50, 30.0).reshape(-1, 2),
                        # along and across the edges (q ∥ edge), and tiny |q|
                        np.outer(np.linspace(0, 40, 200), [c, s]),
                        np.outer(np.linspace(0, 40, 200), [-s, c]),
                        np.outer(np.geomspace(1e-9, 1e-1, 200), [0.3, 0.9])])
    a_poly = poly.amplitude(q)
    assert np.all(np.isfinite(a_poly))
    np.testing.assert_allclose(a_poly, rect.amplitude(q), atol=1e-12 * rect.area)


def test_polygon_invariances():
    rng = np.random.default_rng(1)
    base = Polygon(L_SHAPE)
    q = rng.normal(scale=8.0, size=(300, 2))
    ref = base.amplitude(q)
    variants = [L_SHAPE[::-1], np.roll(L_SHAPE, 2, axis=0), L_SHAPE + [5.0, -2.5],
                np.roll(L_SHAPE[::-1], 3, axis=0) - [1e3, 2e3],
                np.vstack([L_SHAPE, L_SHAPE[:1]])]  # explicit closing vertex
    for v in variants:
        np.testing.assert_allclose(Polygon(v).amplitude(q), ref, atol=1e-11 * base.area)
    assert Polygon(L_SHAPE[::-1]).key() == base.key()


def test_nonconvex_polygon_by_shift_theorem():
    # L = [0,2]x[0,1] ∪ [0,1]x[1,2]; centroid (5/6, 5/6)
    poly = Polygon(L_SHAPE)
    c0 = np.array([5 / 6, 5 / 6])
    rng = np.random.default_rng(2)
    q = np.concatenate([rng.normal(scale=10.0, size=(400, 2)),
                        np.outer(np.geomspace(1e-7, 1.0, 300), [1.0, 0.0]),   # ∥ edges
                        np.outer(np.geomspace(1e-7, 1.0, 300), [0.6, -0.8]),
                        np.zeros((1, 2))])
    ref = rect_amp(q, 2.0, 1.0, np.array([1.0, 0.5]) - c0) + \
        rect_amp(q, 1.0, 1.0, np.array([0.5, 1.5]) - c0)
    got = poly.amplitude(q)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, ref, atol=1e-12 * 3.0)
    assert poly.area == pytest.approx(3.0)
    assert np.allclose(poly.vertices.mean(axis=0) * 0, 0)
    # continuity across the small-q branch switch (q R = 0.02): both branches
    # agree with the reference to round-off on either side
    R = poly.length_scale
    qs = np.outer(np.linspace(0.019, 0.021, 2001) / R, [0.8, 0.6])
    ref = rect_amp(qs, 2.0, 1.0, np.array([1.0, 0.5]) - c0) + \
        rect_amp(qs, 1.0, 1.0, np.array([0.5, 1.5]) - c0)
    np.testing.assert_allclose(poly.amplitude(qs), ref, atol=1e-13 * 3.0, rtol=0)


def test_regular_polygon_limits():
    # many sides → circle of equal area
    n, Rc = 400, 1.0
    r = Rc * math.sqrt(2 * math.pi / (n * math.sin(2 * math.pi / n)))
    poly = RegularPolygon(n, r, angle=7.0)
    circ = Circle(Rc)
    assert poly.area == pytest.approx(circ.area, rel=1e-12)
    u = np.linspace(0, 20, 300)
    q = np.stack([u * 0.28, u * 0.96], -1)
    np.testing.assert_allclose(poly.form_factor(q), circ.form_factor(q), atol=1e-4 * circ.area)
    # 4 sides with a vertex at 45° = axis-aligned square of side r√2
    sq = RegularPolygon(4, 1.0, angle=45.0)
    q = grid(40, 20.0)
    np.testing.assert_allclose(sq.form_factor(q), rect_ff(q, math.sqrt(2), math.sqrt(2)),
                               atol=1e-12)
    assert sq.length_scale == 1.0
    tri = RegularPolygon(3, 2.0)
    assert tri.area == pytest.approx(3 * math.sqrt(3) / 4 * 4.0)


# ---------------------------------------------------------------------------
# masks
# ---------------------------------------------------------------------------
def test_mask_rasterised_circle_matches_airy():
    R, p, n = 1.0, 0.05, 64
    m = Mask(antialiased_disk(R, p, n), p)
    c = Circle(R)
    assert m.area == pytest.approx(c.area, rel=1e-3)
    # main lobe (u < 3.83) in several directions: within 0.2 % of the peak
    u = np.linspace(0, 3.83, 100)
    for ang in (0.0, 0.4, math.pi / 4):
        q = np.outer(u / R, [math.cos(ang), math.sin(ang)])
        np.testing.assert_allclose(m.form_factor(q), c.form_factor(q), atol=2e-3 * c.area)
    # and the first rings within 1 % of the peak
    u = np.linspace(3.83, 12, 200)
    q = np.outer(u / R, [0.6, 0.8])
    np.testing.assert_allclose(m.form_factor(q), c.form_factor(q), atol=1e-2 * c.area)


def test_mask_is_centred_and_deterministic():
    img = np.zeros((40, 50))
    img[5:15, 8:30] = 1.0
    img[15:25, 8:14] = 0.5
    shifted = np.roll(img, (11, 13), axis=(0, 1))
    q = np.random.default_rng(3).normal(scale=6.0, size=(200, 2))
    a, b = Mask(img, 0.1), Mask(shifted, 0.1)
    np.testing.assert_allclose(a.amplitude(q), b.amplitude(q), atol=1e-12)
    np.testing.assert_allclose(a.coherent_form_factor(q), a.form_factor(q), rtol=1e-14)
    # image rows run downward, y upward: a bar along the image rows (vertical on screen)
    # diffracts along q_x
    bar = np.zeros((64, 64))
    bar[:, 30:34] = 1.0
    mb = Mask(bar, 0.1)
    assert mb.form_factor(np.array([3.0, 0.0])) > 10 * mb.form_factor(np.array([0.0, 3.0]))
    # integer rectangle in the image: Â = DTFT of the samples (Dirichlet kernels)
    rect = np.zeros((30, 30))
    rect[10:14, 5:25] = 1.0          # 4 rows × 20 columns
    mr, p = Mask(rect, 0.2), 0.2
    qq = np.random.default_rng(4).uniform(-np.pi / p, np.pi / p, size=(50, 2))

    def dirichlet(x, n):
        s = np.sin(n * x / 2)
        d = np.sin(x / 2)
        out = np.full_like(x, float(n))
        nz = np.abs(d) > 1e-12
        out[nz] = s[nz] / d[nz]
        return out
    ref = p**4 * (dirichlet(qq[:, 0] * p, 20) * dirichlet(qq[:, 1] * p, 4)) ** 2 / mr.area
    np.testing.assert_allclose(mr.form_factor(qq), ref, atol=2e-3 * mr.area)


def test_mask_orientation_matches_polygon():
    # L shape (y up) rasterised with row 0 at the top of the image
    p, n = 0.02, 60
    scale = 0.5
    img = np.zeros((n, n))
    yc = (n - 1 - np.arange(n))[:, None] * p + p / 2 - 0.1     # row → y (up)
    xc = np.arange(n)[None, :] * p + p / 2 - 0.1
    X, Y = np.broadcast_arrays(xc, yc)
    inside = ((X > 0) & (X < 2 * scale) & (Y > 0) & (Y < scale)) | \
        ((X > 0) & (X < scale) & (Y > 0) & (Y < 2 * scale))
    img[inside] = 1.0
    m = Mask(img, p)
    poly = Polygon(L_SHAPE * scale)
    assert m.area == pytest.approx(poly.area, rel=1e-12)
    q = grid(41, 12.0)
    diff = np.abs(m.form_factor(q) - poly.form_factor(q))
    assert diff.max() < 2e-3 * poly.area
    # a y flip (the wrong image convention) is clearly detected
    flipped = Polygon(L_SHAPE * [scale, -scale])
    assert np.abs(m.form_factor(q) - flipped.form_factor(q)).max() > 0.1 * poly.area


def test_mask_from_image_files(tmp_path):
    import imageio.v3 as iio
    img = np.zeros((32, 32), np.uint8)
    img[8:24, 10:20] = 255
    f = tmp_path / "slit.png"
    iio.imwrite(f, img)
    m_file = Mask(f, 0.1)
    m_arr = Mask(img / 255.0, 0.1)
    q = grid(9, 20.0)
    np.testing.assert_allclose(m_file.form_factor(q), m_arr.form_factor(q), rtol=1e-12)
    assert m_file.key() == m_arr.key()
    # RGB is converted to grey
    rgb = np.repeat(img[..., None], 3, axis=-1)
    f2 = tmp_path / "slit_rgb.png"
    iio.imwrite(f2, rgb)
    np.testing.assert_allclose(Mask(f2, 0.1).form_factor(q), m_arr.form_factor(q), rtol=1e-9)
    # grey levels + threshold
    grey = np.clip(img / 255.0 * 0.7, 0, 1)
    mt = Mask(grey, 0.1, threshold=0.5)
    np.testing.assert_allclose(mt.form_factor(q), m_arr.form_factor(q), rtol=1e-12)
    # bad files
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    with pytest.raises(CoronaError, match="image"):
        Mask(empty, 0.1)
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"this is not an image")
    with pytest.raises(CoronaError, match="image"):
        Mask(junk, 0.1)
    black = tmp_path / "black.png"
    iio.imwrite(black, np.zeros((8, 8), np.uint8))
    with pytest.raises(CoronaError, match="image"):
        Mask(black, 0.1)
    with pytest.raises(CoronaError, match="image"):
        Mask(tmp_path / "missing.png", 0.1)


# ---------------------------------------------------------------------------
# soft edges: ∫T_a = ∫A²/∫A
# ---------------------------------------------------------------------------
def blurred_disk_overlap(R, w):
    """∫A²/∫A for A = disk * Gaussian(w), from the radial profile (real space)."""
    def profile(r):
        def f(rho):
            return rho / w**2 * np.exp(-(r - rho) ** 2 / (2 * w**2)) * special.i0e(r * rho / w**2)
        return integrate.quad(f, 0, R, epsabs=1e-13, epsrel=1e-11, limit=200)[0]
    rs = np.linspace(0, R + 9 * w, 1201)
    A = np.array([profile(r) for r in rs])
    assert A.max() <= 1.0 + 1e-12 and A.min() >= 0.0
    return integrate.simpson(2 * np.pi * rs * A**2, x=rs) / (np.pi * R**2)


def blurred_rect_overlap(w_, h_, s):
    def one(L):
        x = np.linspace(-L / 2 - 9 * s, L / 2 + 9 * s, 20001)
        A = 0.5 * (special.erf((x + L / 2) / (math.sqrt(2) * s))
                   - special.erf((x - L / 2) / (math.sqrt(2) * s)))
        return integrate.simpson(A**2, x=x)
    return one(w_) * one(h_) / (w_ * h_)


def rasterised_overlap(inside, extent, w, h=0.004, ss=4):
    """∫A²/∫A with A = (anti-aliased raster of ``inside``) * Gaussian(w)."""
    n = int(round(2 * extent / h))
    sub = (np.arange(ss) + 0.5) / ss
    cov = np.zeros((n, n))
    base = -extent + h * np.arange(n)
    for a in sub:
        for b in sub:
            X, Y = np.meshgrid(base + a * h, base + b * h)
            cov += inside(X, Y)
    cov /= ss * ss
    A = ndimage.gaussian_filter(cov, w / h, mode="constant", truncate=7.0)
    return float(np.sum(A**2) / np.sum(cov))


def in_triangle(V):
    def f(X, Y):
        s = np.ones(X.shape, bool)
        for i in range(3):
            (x0, y0), (x1, y1) = V[i], V[(i + 1) % 3]
            s &= (x1 - x0) * (Y - y0) - (y1 - y0) * (X - x0) >= 0
        return s
    return f


def test_soft_edge_self_overlap_against_real_space():
    R, w = 1.0, 0.08
    se = SoftEdge(Circle(R), w)
    ref = blurred_disk_overlap(R, w)
    assert se.self_overlap == pytest.approx(ref, abs=1e-6)
    assert se.self_overlap < 1.0
    # small-w expansion 1 - w P/(√π |A|)
    small = SoftEdge(Circle(R), 1e-3)
    assert 1 - small.self_overlap == pytest.approx(1e-3 * 2 / math.sqrt(math.pi), rel=1e-2)

    sr = SoftEdge(Rectangle(0.5, aspect=0.4, angle=17.0), 0.05)
    assert sr.self_overlap == pytest.approx(blurred_rect_overlap(1.0, 0.4, 0.05), abs=1e-7)

    V = np.array([[0.0, 0.0], [1.2, 0.1], [0.3, 0.9]])
    st = SoftEdge(Polygon(V), 0.05)
    ref = rasterised_overlap(in_triangle(V), 1.5, 0.05)
    assert st.self_overlap == pytest.approx(ref, abs=1e-3)


def test_soft_edge_lobe_integrates_to_self_overlap():
    for sh in (SoftEdge(Circle(1.0), 0.1), SoftEdge(Square(0.5, angle=11.0), 0.05),
               SoftEdge(Polygon(L_SHAPE), 0.1),
               SoftEdge(SizeDistribution(Circle(1.0), 0.2, "schulz"), 0.08)):
        val = integral_Ta(sh, u_max=120)          # Gaussian kills the tail
        assert val == pytest.approx(sh.self_overlap, abs=1e-4)
        assert 0.5 < sh.self_overlap < 1.0
    # Gaussian factor on the amplitude
    q = grid(15, 10.0)
    base, se = Square(0.5, angle=11.0), SoftEdge(Square(0.5, angle=11.0), 0.05)
    g = np.exp(-0.5 * np.sum(q**2, -1) * 0.05**2)
    np.testing.assert_allclose(se.amplitude(q), base.amplitude(q) * g, rtol=1e-14)
    np.testing.assert_allclose(se.form_factor(q), base.form_factor(q) * g**2, rtol=1e-14)
    assert SoftEdge(Circle(1.0), 0.0).self_overlap == pytest.approx(1.0, abs=1e-14)


def test_soft_mask_overlap_against_pixel_blur():
    p, n = 0.05, 64
    y, x = (np.mgrid[0:n, 0:n] - (n - 1) / 2) * p
    img = ((np.abs(x) < 0.8) & (np.abs(y) < 0.5)).astype(float)
    w = 3 * p
    se = SoftEdge(Mask(img, p), w)
    A = ndimage.gaussian_filter(np.pad(img, 20), w / p, mode="constant", truncate=8.0)
    ref = float(np.sum(A**2) / np.sum(img))
    assert se.self_overlap == pytest.approx(ref, abs=1e-3)
    # nested soft edges add in quadrature, and mixtures average
    nested = SoftEdge(SoftEdge(Circle(1.0), 0.06), 0.08)
    assert nested.self_overlap == pytest.approx(SoftEdge(Circle(1.0), 0.1).self_overlap, rel=1e-12)


# ---------------------------------------------------------------------------
# random orientation
# ---------------------------------------------------------------------------
def test_random_orientation_is_radial_and_matches_brute_force():
    side = 1.0
    ro = RandomOrientation(Square(side / 2))
    assert ro.isotropic
    q = np.linspace(0, 90, 400)
    for ang in (0.0, 0.3, 1.1, 2.9):
        q2 = np.outer(q, [math.cos(ang), math.sin(ang)])
        np.testing.assert_allclose(ro.form_factor(q2), ro.form_factor_radial(q), rtol=1e-13)
    phi = 2 * np.pi * np.arange(4096) / 4096
    pts = q[:, None, None] * np.stack([np.cos(phi), np.sin(phi)], -1)[None]
    brute = rect_ff(pts, side, side).mean(axis=1)
    np.testing.assert_allclose(ro.form_factor_radial(q), brute, rtol=1e-9, atol=1e-14)
    u = q * ro.length_scale
    np.testing.assert_allclose(ro.table_radial(u), brute / ro.length_scale**2, rtol=1e-9,
                               atol=1e-14)
    # coherent part: angle average of the amplitude
    amp = (side**2 * sinc(pts[..., 0] * side / 2) * sinc(pts[..., 1] * side / 2)).mean(axis=1)
    np.testing.assert_allclose(ro.coherent_form_factor_radial(q), amp**2 / side**2,
                               rtol=1e-9, atol=1e-14)
    assert np.all(ro.coherent_form_factor_radial(q) <= ro.form_factor_radial(q) * (1 + 1e-12))


def test_random_orientation_odd_symmetry_and_isotropic_base():
    tri = RegularPolygon(3, 1.0, angle=11.0)
    ro = RandomOrientation(tri)
    q = np.linspace(0, 40, 120)
    phi = 2 * np.pi * np.arange(2048) / 2048
    pts = q[:, None, None] * np.stack([np.cos(phi), np.sin(phi)], -1)[None]
    np.testing.assert_allclose(ro.amplitude_radial(q), tri.amplitude(pts).mean(axis=1),
                               atol=1e-12)
    np.testing.assert_allclose(ro.form_factor_radial(q), tri.form_factor(pts).mean(axis=1),
                               rtol=1e-10, atol=1e-14)
    c = Circle(0.7)
    np.testing.assert_allclose(RandomOrientation(c).form_factor_radial(q), c.form_factor_radial(q))


def test_radial_and_grid_tables_are_finite():
    """Every kind of shape table builds, with its shape and finite values (the build
    times are measured by benchmarks/bench_tables.py, not asserted here)."""
    u = np.linspace(0, 100, 2048)
    for sh in (Circle(1.0), RandomOrientation(Square(0.5)), SizeDistribution(Circle(1.0), 0.2)):
        tab = sh.table_radial(u)
        assert tab.shape == u.shape and np.all(np.isfinite(tab)), sh
    uu = grid(512, 50.0)
    for sh in (Square(0.5, angle=17.0), RegularPolygon(6, 1.0), Ellipse(1.0, aspect=0.5)):
        tab = sh.table(uu)
        assert tab.shape == uu.shape[:-1] and np.all(np.isfinite(tab)), sh


# ---------------------------------------------------------------------------
# scaling with wavelength and size (docs/physics.md#the-model)
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("make", [lambda s: Circle(s), lambda s: Square(s / 2, angle=17.0),
                                  lambda s: Polygon(L_SHAPE * s),
                                  lambda s: RandomOrientation(Rectangle(s / 2, aspect=0.4)),
                                  lambda s: SoftEdge(Ellipse(s, aspect=0.5), 0.1 * s)],
                         ids=["circle", "square", "polygon", "random-rect", "soft-ellipse"])
def test_lobe_scales_with_wavelength_and_size(make):
    unit = make(1.0)
    rng = np.random.default_rng(5)
    d = rng.normal(scale=0.3, size=(50, 2))
    for lam, alpha in ((0.45, 2.0), (0.65, 0.37)):
        # d and λ scaled together: T_a(α d; α λ) = T_a(d; λ) / α²
        np.testing.assert_allclose(T_a(unit, alpha * d, alpha * lam),
                                   T_a(unit, d, lam) / alpha**2, rtol=1e-10, atol=1e-300)
        # one table serves every size: T_a = (R²/λ²) table(2π R d / λ)
        sh = make(alpha)
        R = sh.length_scale
        assert R == pytest.approx(alpha * unit.length_scale, rel=1e-12)
        ref = R**2 / lam**2 * unit.table(2 * np.pi * R * d / lam)
        np.testing.assert_allclose(T_a(sh, d, lam), ref, rtol=1e-9, atol=1e-12 * ref.max())


# ---------------------------------------------------------------------------
# size distributions and mixtures
# ---------------------------------------------------------------------------
def _moments(dist, spread):
    if dist == "lognormal":
        m2 = 1 + spread**2
        return m2, m2**6
    k = 1 / spread**2
    return (k + 1) / k, (k + 1) * (k + 2) * (k + 3) / k**3


@pytest.mark.slow
@pytest.mark.parametrize("dist", ["lognormal", "schulz"])
def test_size_distribution(dist):
    c = Circle(1.0)
    spread = 0.25
    sd = SizeDistribution(c, spread, dist)
    m2, m4 = _moments(dist, spread)
    zero = np.zeros(1)
    # q = 0: ⟨|A|²⟩/⟨|A|⟩ and ⟨|A|⟩
    assert sd.area == pytest.approx(c.area * m2, rel=1e-12)
    assert sd.form_factor_radial(zero)[0] == pytest.approx(c.area * m4 / m2, rel=1e-9)
    assert sd.coherent_form_factor_radial(zero)[0] == pytest.approx(c.area * m2, rel=1e-9)
    q = np.linspace(0, 60, 500)
    ff, cf = sd.form_factor_radial(q), sd.coherent_form_factor_radial(q)
    assert np.all(cf <= ff * (1 + 1e-12))
    # against direct integration over s, including large q R (many oscillations per width)
    if dist == "lognormal":
        s2 = math.log1p(spread**2)
        pdf = stats.lognorm(math.sqrt(s2), scale=math.exp(-s2 / 2))
    else:
        k = 1 / spread**2
        pdf = stats.gamma(k, scale=1 / k)
    lo, hi = pdf.ppf(1e-15), pdf.isf(1e-15)
    s = np.linspace(lo, hi, 200001)
    for qv in (0.0, 2.0, 7.5, 40.0, 150.0):
        I = np.trapezoid(pdf.pdf(s) * s**4 * c.form_factor_radial(s * qv) * c.area, s)
        A = np.trapezoid(pdf.pdf(s) * s**2 * c.amplitude_radial(s * qv).real, s)
        got_I = sd.form_factor_radial(np.array([qv]))[0] * sd.area
        got_A = sd.amplitude_radial(np.array([qv]))[0]
        assert got_I == pytest.approx(I, rel=1e-6)
        assert abs(got_A - A) < 1e-7 * c.area
    # spread → 0 reproduces the base shape; spread = 0 exactly
    np.testing.assert_allclose(SizeDistribution(c, 0.0, dist).form_factor_radial(q),
                               c.form_factor_radial(q), rtol=1e-14, atol=1e-300)
    tiny = SizeDistribution(c, 1e-4, dist)
    np.testing.assert_allclose(tiny.form_factor_radial(q), c.form_factor_radial(q),
                               atol=1e-5 * c.area)
    np.testing.assert_allclose(tiny.coherent_form_factor_radial(q), c.form_factor_radial(q),
                               atol=1e-5 * c.area)
    assert sd.length_scale == 1.0 and sd.exclusion_diameter == 2.0 and sd.isotropic


def test_size_distribution_of_anisotropic_shape():
    sq = Square(0.5, angle=math.degrees(0.2))
    sd = SizeDistribution(sq, 0.15, "schulz")
    assert not sd.isotropic
    q = grid(31, 20.0)
    ff, cf = sd.form_factor(q), sd.coherent_form_factor(q)
    assert np.all(cf <= ff * (1 + 1e-12))
    # Gauss–Laguerre reference (independent quadrature rule) at moderate q
    k = 1 / 0.15**2
    x, w = special.roots_genlaguerre(60, k - 1)
    s = x / k
    w = w / w.sum()
    ref = sum(wi * si**4 * rect_ff(si * q, 1.0, 1.0, 0.2) for si, wi in zip(s, w))
    ref /= sum(wi * si**2 for si, wi in zip(s, w))
    np.testing.assert_allclose(ff, ref, rtol=1e-6, atol=1e-12)
    ro = RandomOrientation(sd)
    qa = np.linspace(0, 30, 50)
    phi = 2 * np.pi * np.arange(1024) / 1024
    pts = qa[:, None, None] * np.stack([np.cos(phi), np.sin(phi)], -1)[None]
    np.testing.assert_allclose(ro.form_factor_radial(qa), sd.form_factor(pts).mean(axis=1),
                               rtol=1e-8)


def test_mixture():
    a, b = Circle(1.0), Circle(0.5)
    mix = Mixture([(a, 2.0), (b, 6.0)])
    w = np.array([0.25, 0.75])
    assert mix.isotropic
    assert mix.length_scale == 1.0 and mix.exclusion_diameter == 2.0
    areas = np.array([a.area, b.area])
    assert mix.area == pytest.approx(w @ areas)
    zero = np.zeros(1)
    assert mix.form_factor_radial(zero)[0] == pytest.approx(w @ areas**2 / (w @ areas))
    assert mix.coherent_form_factor_radial(zero)[0] == pytest.approx(w @ areas)
    q = np.linspace(0, 30, 300)
    ff, cf = mix.form_factor_radial(q), mix.coherent_form_factor_radial(q)
    ref_ff = (w[0] * a.area * a.form_factor_radial(q) + w[1] * b.area * b.form_factor_radial(q)) \
        / (w @ areas)
    ref_A = w[0] * a.area * Circle.airy(q) + w[1] * b.area * Circle.airy(0.5 * q)
    np.testing.assert_allclose(ff, ref_ff, rtol=1e-13)
    np.testing.assert_allclose(cf, ref_A**2 / (w @ areas), rtol=1e-12, atol=1e-15)
    assert np.all(cf <= ff * (1 + 1e-12))
    assert np.any(cf < 0.9 * ff)
    # equal shapes: coherent = incoherent (no size/type fluctuation)
    same = Mixture([(Square(0.5, angle=17.0), 1.0), (Square(0.5, angle=17.0), 5.0)])
    qq = grid(21, 20.0)
    np.testing.assert_allclose(same.coherent_form_factor(qq), same.form_factor(qq), rtol=1e-12)
    np.testing.assert_allclose(same.form_factor(qq), Square(0.5, angle=17.0).form_factor(qq), rtol=1e-12)
    # anisotropic mixture
    ani = Mixture([(Square(0.5), 1.0), (Circle(0.3), 1.0)])
    assert not ani.isotropic
    assert np.all(ani.coherent_form_factor(qq) <= ani.form_factor(qq) * (1 + 1e-12))
    assert ani.length_scale == pytest.approx(1 / math.sqrt(2))
    # self-overlap averages ∫A² and ∫A
    se = SoftEdge(Circle(1.0), 0.1)
    m2 = Mixture([(se, 1.0), (Circle(0.5), 3.0)])
    expect = (se.self_overlap * se.area + 3 * Circle(0.5).area) / (se.area + 3 * Circle(0.5).area)
    assert m2.self_overlap == pytest.approx(expect, rel=1e-12)
    porod = 3 * 2 * np.pi * 0.5 / (se.area + 3 * Circle(0.5).area)   # only the sharp circles
    assert integral_Ta(m2, u_max=200, porod=porod) == pytest.approx(expect, abs=1e-3)


# ---------------------------------------------------------------------------
# keys, reprs, bad input
# ---------------------------------------------------------------------------
def test_keys_and_reprs():
    img = np.zeros((8, 8))
    img[2:5, 3:6] = 1
    shapes = [Circle(1.0), Ellipse(1.0, aspect=0.5), Rectangle(1.0, aspect=0.5), Square(1.0),
              Polygon(L_SHAPE), RegularPolygon(6, 1.0), Mask(img, 0.1), Mask(img.T, 0.1),
              SoftEdge(Polygon(L_SHAPE), 0.1), RandomOrientation(Square(1.0)),
              SizeDistribution(Circle(1.0), 0.1), SizeDistribution(Circle(1.0), 0.1, "schulz"),
              Mixture([(Circle(1.0), 1.0), (SoftEdge(Square(1.0), 0.05), 2.0)])]
    keys = [json.dumps(s.key(), sort_keys=True) for s in shapes]
    assert len(set(keys)) == len(keys)
    assert json.dumps(Square(1.0).key()) == json.dumps(Square(1.0).key())
    assert Square(1.0).key() != Rectangle(1.0).key()
    assert Mixture([(Circle(1.0), 1.0), (Circle(2.0), 1.0)]).key() == \
        Mixture([(Circle(1.0), 3.0), (Circle(2.0), 3.0)]).key()
    for s in shapes:
        assert isinstance(s, Shape)
        assert type(s).__name__ in repr(s)
        assert s.exclusion_diameter == pytest.approx(2 * s.length_scale)


BAD = [
    (lambda: Circle(-1.0), "radius"),
    (lambda: Ellipse(0.0), "radius"),
    (lambda: Ellipse(1.0, aspect=-1.0), "aspect"),
    (lambda: Ellipse(1.0, angle=float("nan")), "angle"),
    (lambda: Rectangle(1.0, aspect=0.0), "aspect"),
    (lambda: Rectangle("a"), "radius"),
    (lambda: Square(-2.0), "radius"),
    (lambda: Square(1.0, angle=float("inf")), "angle"),
    (lambda: RegularPolygon(5, 1.0, angle=float("nan")), "angle"),
    (lambda: Polygon([[0, 0], [1, 1]]), "vertices"),
    (lambda: Polygon([[0, 0], [1, 1], [1, 0], [0, 1]]), "vertices"),       # bow tie
    (lambda: Polygon([[0, 0], [1, 0], [2, 0]]), "vertices"),               # zero area
    (lambda: Polygon(np.ones((4, 3))), "vertices"),
    (lambda: Polygon([[0, 0], [1, 0], [np.nan, 1]]), "vertices"),
    (lambda: RegularPolygon(2, 1.0), "sides"),
    (lambda: RegularPolygon(4.5, 1.0), "sides"),
    (lambda: RegularPolygon(5, 0.0), "radius"),
    (lambda: Mask(np.zeros((4, 4)), 1.0), "image"),
    (lambda: Mask(np.ones(4), 1.0), "image"),
    (lambda: Mask(np.ones((2, 3, 4)), 1.0), "image"),
    (lambda: Mask(np.zeros((0, 4)), 1.0), "image"),
    (lambda: Mask(2 * np.ones((4, 4)), 1.0), "image"),
    (lambda: Mask(np.ones((4, 4)), 0.0), "pixel_size"),
    (lambda: Mask(np.ones((4, 4)), 1.0, threshold=1.5), "threshold"),
    (lambda: Mask(np.full((4, 4), 0.3), 1.0, threshold=0.5), "image"),
    (lambda: SoftEdge(Circle(1.0), -0.1), "edge_width"),
    (lambda: SoftEdge("circle", 0.1), "shape"),
    (lambda: RandomOrientation(3.0), "shape"),
    (lambda: SizeDistribution(Circle(1.0), -0.1), "spread"),
    (lambda: SizeDistribution(Circle(1.0), 0.1, "gauss"), "distribution"),
    (lambda: SizeDistribution(Circle(1.0), 0.1, n_nodes=2), "n_nodes"),
    (lambda: SizeDistribution(None, 0.1), "shape"),
    (lambda: Mixture([]), "components"),
    (lambda: Mixture([Circle(1.0)]), "components"),
    (lambda: Mixture([(Circle(1.0), -1.0)]), "components[0] weight"),
    (lambda: Mixture([(Circle(1.0), 0.0)]), "components"),
    (lambda: Mixture([(Circle(1.0), 1.0), ("x", 1.0)]), "components[1] shape"),
    (lambda: Square(1.0).form_factor(np.ones(3)), "q"),
]


@pytest.mark.parametrize("make,name", BAD, ids=[b[1] + f"-{i}" for i, b in enumerate(BAD)])
def test_bad_input_names_the_parameter(make, name):
    with pytest.raises(CoronaError, match=re.escape(name)):
        make()


@pytest.mark.parametrize("spread", [1e-300, 9e-278, 1e-30])
def test_a_vanishing_size_spread_is_the_single_size(spread):
    """A spread so small that the log grid's step underflows (σ_y / points per σ_y -> 0) used to
    raise OverflowError building a radial table (a property-test draw, 9e-278): it must give the
    single size's form factor."""
    from corona.model.shapes import Circle, SizeDistribution
    q = np.geomspace(1e-3, 400.0, 3000)
    one = Circle(1.0)._both_radial(q)
    many = SizeDistribution(Circle(1.0), spread=spread)._both_radial(q)
    for a, b in zip(many, one):
        assert np.all(np.isfinite(a))
        assert np.max(np.abs(a - b)) <= 1e-9 * np.max(np.abs(b))
