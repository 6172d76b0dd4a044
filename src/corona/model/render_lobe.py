"""What the renderer evaluates: the lobe ``v(u)`` as exact as the model.

The model's dimensionless lobe (:mod:`corona.model.tabulated`) is

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

Sampling stays on the bilinear N×N table of ``v`` (:class:`corona.model.tabulated.GridTable`,
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
import scipy   # scipy.ndimage: loaded on first use (scipy imports its submodules lazily)

from corona.model.layer import decoupled_lobe
from corona.model.shapes.base import Term
from corona.model.shapes.polygon import EDGE_MAX

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
def analytic_terms(shape) -> list[Term] | None:
    """The shape as a list of closed-form outlines, or None when it has none.

    Each shape family gives its own (``Shape.kernel_terms``, :mod:`corona.model.registry`):
    the outlines with closed forms (circle, ellipse, rectangle, polygons of at most
    :data:`EDGE_MAX` edges); mixtures of them one term per component (their number weights);
    :class:`SoftEdge` multiplies the amplitudes by its Gaussian; a :class:`SizeDistribution` of
    zero spread is its shape.  Random shapes (orientation, size), masks, polygons of more than
    :data:`EDGE_MAX` edges and shapes without a kernel term return None.
    """
    return shape.kernel_terms()


def _outline(t: Term):
    """The outline of a term made without its shape (by its kind and parameters)."""
    from corona.model.shapes import Circle, Ellipse, Polygon, Rectangle
    p = t.params
    if t.kind == "circle":
        return Circle(p["radius"])
    if t.kind == "ellipse":
        return Ellipse(p["a"], aspect=p["b"] / p["a"], angle=math.degrees(p["angle"]))
    if t.kind == "rect":
        return Rectangle(0.5 * p["width"], aspect=p["height"] / p["width"], angle=math.degrees(p["angle"]))
    return Polygon(p["vertices"])


def terms_amplitudes(terms: list[Term], q) -> tuple[np.ndarray, np.ndarray]:
    """(``Σ w_i |Â_i|²``, ``Σ w_i Â_i``) at q (..., 2) [rad/µm], float64.

    The numpy twin of the kernel (:mod:`corona.mitsuba.kernels`), from the
    shapes' own closed forms; used to check the kernel and by
    :meth:`RenderLobe.eval`.
    """
    q = np.asarray(q, dtype=np.float64)
    inten = np.zeros(q.shape[:-1])
    amp = np.zeros(q.shape[:-1], dtype=np.complex128)
    for t in terms:
        a = (t.shape if t.shape is not None else _outline(t)).amplitude(q)
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
        coef = scipy.ndimage.spline_filter(np.asarray(values, dtype=np.float64), order=3, mode="mirror")
        return cls(float(lo), float(cell), coef)

    @property
    def n(self) -> int:
        return self.coef.shape[0]

    def eval(self, u) -> np.ndarray:
        u = np.asarray(u, dtype=np.float64)
        fx = (u[..., 0] - self.lo) / self.cell
        fy = (u[..., 1] - self.lo) / self.cell
        inside = (fx >= 0) & (fx <= self.n - 1) & (fy >= 0) & (fy <= self.n - 1)
        out = scipy.ndimage.map_coordinates(self.coef, [np.ravel(fy), np.ravel(fx)], order=3,
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
        return decoupled_lobe(P, C, 1.0 + self.s1(ua))    # P, C already over R²
