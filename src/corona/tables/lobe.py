"""What the renderer evaluates: the lobe ``v(u)`` as exact as the model.

The model's dimensionless lobe (:mod:`corona.tables`) is

    v(u) = [P(u) + C(u) (S(|u|) - 1)] / R²,

``P`` the form factor, ``C`` the coherent form factor and ``S`` the structure
factor, all at ``q = u / R``.  A bilinear table of ``v`` on cells of 0.25 in u
is 3–5 % RMS off ``v`` for anisotropic shapes (it fills the zeros of sinc² and
misses the peaks), so the renderer evaluates instead, by kind:

``"radial"``
    isotropic shape and process: the radial table of ``v`` (step 0.01 in u,
    linear), as before — within 1e-4 of the model.
``"analytic"``
    deterministic shapes with closed-form transforms (circle, ellipse,
    rectangle, square, polygons of at most :data:`EDGE_MAX` edges, soft edges
    of these, mixtures of these) with an isotropic process: ``Â`` in closed
    form in the kernel (Airy, sinc, the polygon edge sum), ``P = Σ w_i |Â_i|²
    / ⟨|A|⟩``, ``C = |Σ w_i Â_i|² / ⟨|A|⟩``, times the radial
    ``S(|u|) - 1`` tabulated on the radial tables' step (0.01 in u, linear).
    Exact everywhere up to float32 and the ``S`` table.
``"grid"``
    other shapes (masks, size distributions, polygons with many edges,
    mixtures holding these) with an isotropic process: ``P`` and ``C`` on the
    2-D grid of the sampling table (cells <= 0.25 in u), interpolated by
    cubic B-splines (prefiltered, exact at the vertices, fourth-order
    accurate: ~1e-4 relative where ``v`` is above 1e-3 of its peak), times
    the same radial ``S - 1``; zero beyond the grid (``|u_x|, |u_y| <= 64``).
``"table"``
    anisotropic processes (a lattice in fixed orientation): the bilinear
    table of cell means of ``v`` (Bragg peaks narrower than a cell keep
    their exact weight but not their point values), as before.

Sampling stays on the bilinear N×N table of ``v`` (:class:`corona.tables.GridTable`,
exact with respect to its own density, so ``eval / pdf`` is unbiased).  Where
the analytic lobe reaches beyond a uniform grid of cells <= 0.25
(``u_max > 64``, scatterers larger than ~1.75 µm), the table is uniform in
``t = u / (1 + |u|/c)`` instead (``c`` such that its outer vertices sit at ``u_max``:
cells of 0.25 near ``u = 0`` growing as ``(1 + |u|/c)²``), its vertices the
local means of the density over their cells (:data:`SUPERSAMPLE`² points),
so the sampled region covers every evaluated direction.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

#: Polygons with more edges go to the form-factor grid (the edge sum costs one
#: sincos per edge and wavelength in the kernel).
EDGE_MAX = 16
#: Sub-samples per axis of each vertex's local mean in warped sampling tables.
SUPERSAMPLE = 2
#: Below ``|q| R_c`` (R_c the circumradius) the polygon kernel uses the Taylor
#: series of ``Â`` (order :data:`TAYLOR_ORDER`) instead of the edge sum, whose
#: terms cancel to O(q²) there (float32).
TAYLOR_U = 0.1
TAYLOR_ORDER = 5


# --------------------------------------------------------------------------
# analytic terms
# --------------------------------------------------------------------------
@dataclass
class Term:
    """One deterministic outline of the kernel.

    ``kind`` is ``"circle"`` (``radius``), ``"ellipse"`` (semi-axes ``a``,
    ``b``, ``angle``), ``"rect"`` (``width``, ``height``, ``angle``; the
    kernel's ``angle`` in radians) or
    ``"polygon"`` (``vertices`` (n, 2), centred on the centroid,
    counter-clockwise); ``weight`` is the number weight, ``area`` [µm²] the
    outline's area, ``blur`` [µm] the rms width of the Gaussian soft edge
    (``Â`` times ``exp(-q² blur² / 2)``).
    """

    kind: str
    params: dict
    weight: float = 1.0
    area: float = 0.0
    blur: float = 0.0

    def key(self):
        p = {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v) for k, v in self.params.items()}
        return {"kind": self.kind, "params": p, "weight": self.weight, "blur": self.blur}


def analytic_terms(shape) -> list[Term] | None:
    """The shape as a list of closed-form outlines, or None when it has none.

    Mixtures of deterministic outlines give one term per component (their
    number weights); :class:`SoftEdge` multiplies the amplitudes by its
    Gaussian; a :class:`SizeDistribution` of zero spread is its shape.  Random
    shapes (orientation, size), masks and polygons of more than
    :data:`EDGE_MAX` edges return None.
    """
    from corona.model.shapes import Circle, Ellipse, Mixture, Polygon, Rectangle, SizeDistribution, SoftEdge
    if isinstance(shape, SoftEdge):
        inner = analytic_terms(shape.shape)
        if inner is None:
            return None
        return [Term(t.kind, t.params, t.weight, t.area, math.hypot(t.blur, shape.edge_width)) for t in inner]
    if isinstance(shape, SizeDistribution):
        return analytic_terms(shape.shape) if shape.spread == 0.0 else None
    if isinstance(shape, Mixture):
        out = []
        for sh, w in shape.components:
            inner = analytic_terms(sh)
            if inner is None:
                return None
            out += [Term(t.kind, t.params, t.weight * w, t.area, t.blur) for t in inner if w > 0]
        return out
    if type(shape) is Circle:
        return [Term("circle", {"radius": shape.radius}, 1.0, shape.area)]
    if type(shape) is Ellipse:
        return [Term("ellipse", {"a": shape.semi_axis_x, "b": shape.semi_axis_y,
                                 "angle": math.radians(shape.angle)},
                     1.0, shape.area)]
    if isinstance(shape, Rectangle):
        return [Term("rect", {"width": shape.width, "height": shape.height,
                                  "angle": math.radians(shape.angle)},
                     1.0, shape.area)]
    if isinstance(shape, Polygon) and len(shape.vertices) <= EDGE_MAX:
        return [Term("polygon", {"vertices": np.array(shape.vertices)}, 1.0, shape.area)]
    return None


def terms_amplitudes(terms: list[Term], q) -> tuple[np.ndarray, np.ndarray]:
    """(``Σ w_i |Â_i|²``, ``Σ w_i Â_i``) at q (..., 2) [rad/µm], float64.

    The numpy twin of the kernel (:mod:`corona.mitsuba.kernels`), from the
    shapes' own closed forms; used to check the kernel and by
    :meth:`RenderLobe.eval`.
    """
    from corona.model.shapes import Circle, Ellipse, Polygon, Rectangle
    q = np.asarray(q, dtype=np.float64)
    inten = np.zeros(q.shape[:-1])
    amp = np.zeros(q.shape[:-1], dtype=np.complex128)
    for t in terms:
        p = t.params
        if t.kind == "circle":
            a = Circle(p["radius"]).amplitude(q)
        elif t.kind == "ellipse":
            a = Ellipse(p["a"], aspect=p["b"] / p["a"], angle=math.degrees(p["angle"])).amplitude(q)
        elif t.kind == "rect":
            a = Rectangle(0.5 * p["width"], aspect=p["height"] / p["width"],
                          angle=math.degrees(p["angle"])).amplitude(q)
        else:
            a = Polygon(p["vertices"]).amplitude(q)
        if t.blur > 0:
            a = a * np.exp(-0.5 * (q[..., 0] ** 2 + q[..., 1] ** 2) * t.blur**2)
        inten += t.weight * np.abs(a) ** 2
        amp += t.weight * a
    return inten, amp


# --------------------------------------------------------------------------
# cubic B-spline grids
# --------------------------------------------------------------------------
@dataclass
class CubicGrid:
    """A function on the vertices ``lo + i·cell`` (i = 0 … n-1, both axes),
    interpolated by the cubic B-spline through them (``coef`` the prefiltered
    coefficients, mirror boundary as :func:`scipy.ndimage.spline_filter`),
    zero outside the vertex square."""

    lo: float
    cell: float
    coef: np.ndarray  # (n, n), index [iy, ix]

    @classmethod
    def from_values(cls, lo, cell, values):
        coef = ndimage.spline_filter(np.asarray(values, dtype=np.float64), order=3, mode="mirror")
        return cls(float(lo), float(cell), coef)

    @property
    def n(self) -> int:
        return self.coef.shape[0]

    def eval(self, u) -> np.ndarray:
        u = np.asarray(u, dtype=np.float64)
        fx = (u[..., 0] - self.lo) / self.cell
        fy = (u[..., 1] - self.lo) / self.cell
        inside = (fx >= 0) & (fx <= self.n - 1) & (fy >= 0) & (fy <= self.n - 1)
        out = ndimage.map_coordinates(self.coef, [np.ravel(fy), np.ravel(fx)], order=3,
                                      mode="mirror", prefilter=False).reshape(fx.shape)
        return np.where(inside, out, 0.0)


# --------------------------------------------------------------------------
# the renderer's lobe
# --------------------------------------------------------------------------
@dataclass
class RenderLobe:
    """The lobe ``v(u)`` as the renderer evaluates it (see the module docstring).

    Attributes
    ----------
    kind : {"radial", "analytic", "grid", "table"}
    R : float
        ``length_scale`` [µm] (``q = u / R``).
    area : float
        ``⟨|A|⟩`` [µm²].
    terms : list of Term
        (analytic) the outlines.
    s_du, s_minus_one : float, ndarray
        (analytic, grid) ``S(|u|/R) - 1`` at ``|u| = i·s_du``, linear in
        between, 0 beyond; None for Poisson (S = 1).
    P, C : CubicGrid
        (grid) ``P/R²`` and ``C/R²`` (C None for deterministic shapes: C = P).
    """

    kind: str
    R: float
    area: float = 1.0
    terms: list = field(default_factory=list)
    s_du: float = 0.0
    s_minus_one: np.ndarray | None = None
    P: CubicGrid | None = None
    C: CubicGrid | None = None
    radial: object = None   # RadialTable (radial)
    table: object = None    # GridTable (table)

    def s1(self, u_abs) -> np.ndarray:
        """``S - 1`` at ``|u|`` from the radial table (linear; 0 beyond)."""
        if self.s_minus_one is None:
            return np.zeros_like(np.asarray(u_abs, dtype=np.float64))
        grid = np.arange(self.s_minus_one.size) * self.s_du
        return np.interp(u_abs, grid, self.s_minus_one, right=0.0)

    def eval(self, u) -> np.ndarray:
        """``v(u)`` at u (..., 2) as the renderer evaluates it (float64)."""
        u = np.asarray(u, dtype=np.float64)
        ua = np.hypot(u[..., 0], u[..., 1])
        if self.kind == "radial":
            return self.radial.eval(ua)
        if self.kind == "table":
            return self.table.eval(u)
        if self.kind == "analytic":
            inten, amp = terms_amplitudes(self.terms, u / self.R)
            P = inten / self.area / self.R**2
            C = np.abs(amp) ** 2 / self.area / self.R**2
        else:
            P = self.P.eval(u)
            C = P if self.C is None else self.C.eval(u)
        return np.maximum(P + C * self.s1(ua), 0.0)


def region_points(material, n: int = 100_000, frac: float = 1e-3, scan: int = 401, seed: int = 0):
    """Points where the renderer's lobe is checked against the model.

    Uniform points in the u plane over the part of the reachable disk
    (``|u| <= 2π R · 2 / 360 nm``: every ``|d| <= 2`` at every wavelength)
    where the exact lobe ``v`` (:meth:`corona.Material.lobe_dimensionless`)
    is at least ``frac`` times its peak.  The bounding box comes from a
    ``scan × scan`` grid of the exact lobe (at a fifth of the threshold, two
    cells of margin).  Returns ``u`` (m, 2) and the exact ``v`` there.
    """
    from corona import tables
    reach = 2 * np.pi * material.length_scale * tables.D_MAX / (tables.WAVELENGTH_MIN * 1e-3)
    c = np.linspace(-reach, reach, scan)
    ux, uy = np.meshgrid(c, c, indexing="xy")
    v = material.lobe_dimensionless(np.stack([ux, uy], -1))
    peak = float(v.max())
    sel = v >= 0.2 * frac * peak
    h = c[1] - c[0]
    bx = min(float(np.abs(ux[sel]).max()) + 2 * h, reach)
    by = min(float(np.abs(uy[sel]).max()) + 2 * h, reach)
    rng = np.random.default_rng(seed)
    u = np.stack([rng.uniform(-bx, bx, n), rng.uniform(-by, by, n)], -1)
    u = u[np.hypot(u[:, 0], u[:, 1]) <= reach]
    ve = material.lobe_dimensionless(u)
    peak = max(peak, float(ve.max()))
    keep = ve >= frac * peak
    return u[keep], ve[keep]


def relative_error(approx, exact) -> dict:
    """RMS and largest ``|approx / exact - 1|``."""
    r = np.asarray(approx, dtype=np.float64) / np.asarray(exact, dtype=np.float64) - 1.0
    return {"rms": float(np.sqrt(np.mean(r * r))), "max": float(np.max(np.abs(r))), "points": int(r.size)}


# --------------------------------------------------------------------------
# rows over the area fraction of anisotropic lobes
# --------------------------------------------------------------------------
def row_slopes(x, y) -> np.ndarray:
    """``dy/dx`` at the rows ``x`` (n,) of ``y`` (n, ...): the derivative of the parabola through
    each row and its two neighbours (one-sided at the ends; the secant for two rows).

    The tangents of the cubic Hermite interpolation between rows, which makes an
    interpolated table continuously differentiable in ``x`` (its derivative is
    second-order accurate in the row spacing, where a linear interpolation's is
    a secant's, first-order).
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    n = x.size
    if n < 2:
        return np.zeros_like(y)
    h = np.diff(x).reshape((-1,) + (1,) * (y.ndim - 1))
    s = np.diff(y, axis=0) / h                       # secants
    if n == 2:
        return np.concatenate([s, s])
    h0, h1 = h[:-1], h[1:]
    inner = (h1 * s[:-1] + h0 * s[1:]) / (h0 + h1)
    first = ((2 * h[0] + h[1]) * s[0] - h[0] * s[1]) / (h[0] + h[1])
    last = ((2 * h[-1] + h[-2]) * s[-1] - h[-1] * s[-2]) / (h[-1] + h[-2])
    return np.concatenate([first[None], inner, last[None]])


def structure_rows(material, lo: float, hi: float, include=(), tolerance: float | None = None,
                   max_rows: int = 160):
    """``S(|u|/R) - 1`` of an anisotropic material's process at rows of area fraction.

    The anisotropic lobe ``v = [P + C (S - 1)] / R²`` depends on ``F_a`` only
    through ``S`` (:mod:`corona.tables.lobe`), so a layer whose ``F_a`` varies
    needs rows of the radial ``S - 1`` alone, on the step of
    :attr:`RenderLobe.s_du`.  The rows start at the process's tabulation nodes
    and ``include`` and are bisected until the linear interpolation of ``S``
    at every interval's midpoint is within ``tolerance`` (relative, default
    :data:`corona.model.material.ROW_TOLERANCE`) of the exact one; since
    ``|Δv| <= C |ΔS|`` and ``v >= C S`` (``P >= C``), that bounds the lobe's
    relative change too.  ``F_a = 0`` is ``S = 1``.

    Returns
    -------
    area_fractions : ndarray (n_rows,)
    s_minus_one : ndarray (n_rows, n_s)
        float64, at ``|u| = i · s_du``.
    s_du : float
    error : float
        The largest relative midpoint error of the final rows.
    """
    from corona import tables
    from corona.tables import ROW_TOLERANCE
    tolerance = ROW_TOLERANCE if tolerance is None else tolerance
    rl = material.render_lobe
    process, shape = material.process, material.shape
    R = float(rl.R)
    ns = int(rl.s_minus_one.size)
    s_du = float(rl.s_du)
    q = np.arange(ns) * s_du / R
    limit = float(process.area_fraction_limit(shape))
    hi = min(float(hi), limit)
    lo = max(0.0, min(float(lo), hi))
    include = sorted(float(f) for f in include if lo <= f <= hi)

    def s_of(fa):
        return np.zeros(ns) if fa <= 0.0 else process.with_area_fraction(float(fa)).structure_factor_radial(
            q, shape) - 1.0

    def build():
        nodes = np.concatenate([process.area_fraction_nodes(shape), include]).astype(np.float64)
        inner = nodes[(nodes > lo) & (nodes < hi)]
        fas = np.unique(np.concatenate([[lo, hi], inner]))
        rows = {f: s_of(f) for f in fas.tolist()}
        keys, worst = tables.bisect_rows(
            rows, lambda mids: [s_of(m) for m in mids],
            lambda lerp, e: np.max(np.abs(lerp - e) / np.maximum(e + 1.0, 1e-6)), tolerance, max_rows)
        return {"area_fraction": np.array(keys), "s_minus_one": np.stack([rows[k] for k in keys]),
                "error": np.array(worst)}

    arrays = tables.cached({**material.table_params(), "s_rows": [lo, hi], "tolerance": tolerance,
                            "max_rows": max_rows, "include": include}, build, use_cache=material.use_cache)
    return (np.asarray(arrays["area_fraction"], dtype=np.float64),
            np.asarray(arrays["s_minus_one"], dtype=np.float64), s_du, float(arrays["error"]))


def row_energy_changes(material, s_rows: np.ndarray, s_du: float, n_phi: int = 64) -> np.ndarray:
    """``∫ C(u) [S_j(|u|) - S(|u|)] d²u / R²`` for each row ``j`` of :func:`structure_rows`.

    The change of the lobe's integral ``∫ v d²u`` from the material's own ``S``
    to row ``j``'s: ``∫ c̄(ρ) ΔS(ρ) 2πρ dρ`` with ``c̄`` the azimuthal mean of
    ``C/R²`` (``n_phi`` azimuths) on the rows' radii (trapezoid in ρ).
    """
    rl = material.render_lobe
    ns = s_rows.shape[1]
    rho = np.arange(ns) * s_du
    # C is even, C(-u) = C(u) (a real profile): for an even n_phi the azimuths phi + π repeat
    # those in [0, π), so the mean over the first half is the mean over all
    phi = (np.arange(n_phi // 2 if n_phi % 2 == 0 else n_phi) + 0.5) * 2 * np.pi / n_phi
    cbar = np.zeros(ns)
    for a in range(0, ns, 1024):
        r = rho[a:a + 1024, None]
        u = np.stack([r * np.cos(phi), r * np.sin(phi)], -1)
        if rl.kind == "analytic":
            _, amp = terms_amplitudes(rl.terms, u / rl.R)
            C = np.abs(amp) ** 2 / rl.area / rl.R**2
        else:
            C = (rl.P if rl.C is None else rl.C).eval(u)
        cbar[a:a + 1024] = C.mean(axis=1)
    own = np.zeros(ns) if rl.s_minus_one is None else rl.s_minus_one
    w = 2 * np.pi * rho * s_du
    w[0] *= 0.5
    w[-1] *= 0.5
    return np.array([float(np.sum(w * cbar * (row - own))) for row in s_rows])
