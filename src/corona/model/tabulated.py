"""Dimensionless lobe tables, their sampling CDFs, and the on-disk cache.

The model's own tabulation: a material's lobe weight is its table's integral
(:attr:`corona.Material.lobe_weight`) and a Mie layer's lobe is read from its
rows, so the table types and the cache sit in the model tier.  The renderer's rows over
textured parameters are :mod:`corona.model.rows`.

The lobe of a material is tabulated once in the dimensionless wave vector
``u = q R = 2π R d / λ`` (docs/physics.md#the-model), where ``R`` is the shape's
``length_scale``.  With

    v(u) = [P(u) + C(u) (S(u) - 1)] / R²,

``P`` the form factor, ``C`` the coherent form factor (decoupling rule; equal
to ``P`` for one fixed shape) and ``S`` the structure factor, the lobe is

    lobe(d, λ) = F_a · (R/λ)² · v(2π R d / λ)            [1/sr-equivalent]

so one table serves every wavelength and the d-space pdf follows from the
u-space pdf by ``p_d = p_u · (2π R / λ)²``.

Radial tables (isotropic shape and process) sample ``u`` exactly from the
piecewise-linear ``v``: the radial density ``2π u v(u)`` is a quadratic in
each bin, its CDF a cubic, inverted by safeguarded Newton iterations.
2D tables (anisotropic lobes) are bilinear and sampled exactly (marginal in
y, conditional in x, each piecewise linear).

Tables are cached under a content-addressed key (all parameters plus
``FORMAT_VERSION``) in :func:`cache_dir`, written atomically (temporary file
+ ``os.replace``) under a file lock, with a checksum that detects damaged
files, which are rebuilt.  A cache that cannot be written (read-only, full,
a lock path that is a folder) builds tables in memory with one warning.
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import tempfile
import threading
import warnings
from dataclasses import dataclass, field

import numpy as np

FORMAT_VERSION = 3   # 2: lattice tables weight each Bragg peak by C at the peak;
#                      3: renderer's lobe (S - 1, form-factor grids, warped sampling table, form_total)

#: Shortest and longest wavelength the tables are built for [nm].
WAVELENGTH_MIN = 360.0
WAVELENGTH_MAX = 830.0

#: Largest projected offset reachable by two unit vectors: |(wo + wi).xy| <= 2.
D_MAX = 2.0

RADIAL_DU = 0.01           # target step in u for radial tables
RADIAL_MAX_SAMPLES = 2**18  # cap; the step grows beyond it
RADIAL_MIN_UMAX = 32.0
#: Table builds longer than this [s] show a progress bar on stderr.
PROGRESS_DELAY = 2.0
#: Largest relative change of the lobe from interpolating between area-fraction rows
#: (:meth:`corona.Material.area_fraction_rows`).
ROW_TOLERANCE = 0.001
GRID2D_SIZE = 512           # default N of an N×N table


def bisect_rows(rows: dict, values_of, error, tolerance: float, max_rows: int):
    """Refine rows of a table in one parameter until linear interpolation between them is exact
    to ``tolerance``.

    Every interval whose midpoint value differs from the mean of its ends by more than
    ``tolerance`` (``error(mean of the ends, value at the midpoint) -> float``) is halved, until
    none is left or ``max_rows`` rows are made.

    Parameters
    ----------
    rows : dict
        ``{x: values}`` of the starting rows (refined in place).
    values_of : callable
        ``values_of([x, ...]) -> [values, ...]``: the exact rows at new points.
    error, tolerance, max_rows
        As above.

    Returns
    -------
    keys : list of float
        The rows' ``x`` in increasing order, distinct in float32 too.
    worst : float
        The largest midpoint error of the accepted intervals; ``inf`` when ``max_rows`` stopped
        the refinement first.
    """
    xs = sorted(rows)
    todo = list(zip(xs[:-1], xs[1:]))
    worst = 0.0
    while todo and len(rows) < max_rows:
        mids = [0.5 * (a + b) for a, b in todo]
        split = []
        for (a, b), m, e in zip(todo, mids, values_of(mids)):
            err = float(error(0.5 * (rows[a] + rows[b]), e))
            if err > tolerance:
                rows[m] = e
                split += [(a, m), (m, b)]
            else:
                worst = max(worst, err)
        todo = split
    xs = sorted(rows)
    keys = [k for i, k in enumerate(xs) if i == 0 or np.float32(k) != np.float32(xs[i - 1])]
    return keys, (worst if not todo else np.inf)


def u_max_for(length_scale: float, wavelength_min: float = WAVELENGTH_MIN) -> float:
    """Largest u reachable for |d| <= 2 at the shortest wavelength [dimensionless]."""
    return max(RADIAL_MIN_UMAX, 1.05 * 2.0 * np.pi * length_scale * D_MAX / (wavelength_min * 1e-3))


def warp_for(t_range: float, u_max: float) -> float:
    """The scale ``c`` with ``t_range / (1 - t_range / c) = u_max`` (0 when ``u_max <= t_range``):
    a warped :class:`GridTable` whose outer vertices sit at ``t_range`` in t then reaches ``u_max``."""
    if u_max <= t_range * (1 + 1e-12):
        return 0.0
    return t_range / (1.0 - t_range / u_max)


# --------------------------------------------------------------------------
# Radial table
# --------------------------------------------------------------------------
@dataclass
class RadialTable:
    """``v(u)`` on the uniform grid ``u_i = i·du`` (zero beyond the last node).

    Attributes
    ----------
    du : float
        Grid step in u.
    values : ndarray (n,)
        ``v(u_i) >= 0``.
    bin_mass : ndarray (n-1,)
        ``∫_{bin} 2π u v_lin(u) du`` of each bin (exact for linear ``v``).
    cdf : ndarray (n,)
        Cumulative ``bin_mass`` starting at 0; ``cdf[-1]`` is the total
        ``∫ v d²u`` over the table.
    """

    du: float
    values: np.ndarray
    bin_mass: np.ndarray = field(init=False)
    cdf: np.ndarray = field(init=False)

    def __post_init__(self):
        v = np.maximum(np.asarray(self.values, dtype=np.float64), 0.0)
        self.values = v
        n = v.size
        u0 = np.arange(n - 1) * self.du
        a, b = v[:-1], v[1:] - v[:-1]
        # ∫_0^1 2π (u0 + t du)(a + b t) du dt
        self.bin_mass = 2 * np.pi * self.du * (u0 * a + (u0 * b + self.du * a) / 2 + self.du * b / 3)
        self.cdf = np.concatenate([[0.0], np.cumsum(self.bin_mass)])

    @property
    def u_max(self) -> float:
        return (self.values.size - 1) * self.du

    @property
    def total(self) -> float:
        """``∫ v(u) d²u`` over the table."""
        return float(self.cdf[-1])

    def eval(self, u) -> np.ndarray:
        """Linear interpolation of ``v`` at ``|u|`` (0 beyond the table)."""
        u = np.asarray(u, dtype=np.float64)
        grid_u = np.arange(self.values.size) * self.du
        return np.interp(u, grid_u, self.values, right=0.0)

    def pdf(self, u) -> np.ndarray:
        """Density in the u plane of :meth:`sample` at points of radius ``|u|``."""
        return self.eval(u) / self.total

    def sample_radius(self, xi) -> np.ndarray:
        """Invert the radial CDF: ``xi`` in [0, 1) -> ``|u|``."""
        xi = np.asarray(xi, dtype=np.float64)
        target = xi * self.total
        i = np.clip(np.searchsorted(self.cdf, target, side="right") - 1, 0, self.bin_mass.size - 1)
        rest = target - self.cdf[i]
        u0 = i * self.du
        a = self.values[i]
        b = self.values[i + 1] - a
        du = self.du
        # C(t) = 2π du [u0 a t + (u0 b + du a) t²/2 + du b t³/3]; solve C(t) = rest
        c1 = 2 * np.pi * du * u0 * a
        c2 = 2 * np.pi * du * (u0 * b + du * a) / 2
        c3 = 2 * np.pi * du * du * b / 3
        mass = np.maximum(self.bin_mass[i], 1e-300)
        t = np.clip(rest / mass, 0.0, 1.0)
        lo, hi = np.zeros_like(t), np.ones_like(t)
        for _ in range(30):
            f = ((c3 * t + c2) * t + c1) * t - rest
            lo = np.where(f < 0, t, lo)
            hi = np.where(f >= 0, t, hi)
            df = (3 * c3 * t + 2 * c2) * t + c1
            with np.errstate(divide="ignore", invalid="ignore"):
                t_new = t - f / df
            bad = ~np.isfinite(t_new) | (t_new <= lo) | (t_new >= hi)
            t = np.where(bad, 0.5 * (lo + hi), t_new)
        return u0 + np.clip(t, 0.0, 1.0) * du

    def sample(self, xi) -> np.ndarray:
        """``xi`` (..., 2) in [0,1)² -> points ``u`` (..., 2) with density :meth:`pdf`."""
        xi = np.asarray(xi, dtype=np.float64)
        r = self.sample_radius(xi[..., 0])
        phi = 2 * np.pi * xi[..., 1]
        return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)

    def arrays(self) -> dict:
        return {"kind": np.array("radial"), "du": np.array(self.du), "values": self.values}



#: Elements per block of :func:`radial_cdfs` (its five working arrays stay in the caches).
RADIAL_CDF_BLOCK = 1 << 15


def radial_totals(du: float, values) -> np.ndarray:
    """:attr:`RadialTable.total` of many rows at once: ``values`` (J, n) -> (J,), float64.

    ``Σ_i bin_mass_i = v[:-1] · w_a + v[1:] · w_b`` with ``w_a = 2π du (u0/2 + du/6)``,
    ``w_b = 2π du (u0/2 + du/3)`` (``u0 = i du``, ``v`` clipped at 0): two matrix-vector
    products; equal to the rows' :attr:`RadialTable.total` to rounding (summed in another order).

    >>> rows = np.array([[1.0, 0.5, 0.0], [0.2, -1.0, 0.3]])
    >>> bool(np.allclose(radial_totals(0.1, rows), [RadialTable(0.1, r).total for r in rows], rtol=1e-14))
    True
    """
    v = np.maximum(np.asarray(values, dtype=np.float64), 0.0)
    if v.ndim != 2:
        raise ValueError(f"values of shape {v.shape}: rows (J, n) expected")
    u0 = np.arange(v.shape[1] - 1) * du
    # bin_mass = 2π du [u0 a + (u0 b + du a)/2 + du b/3], a = v_i, b = v_{i+1} - v_i
    w_a = 2 * np.pi * du * (u0 / 2 + du / 6)
    w_b = 2 * np.pi * du * (u0 / 2 + du / 3)
    return v[:, :-1] @ w_a + v[:, 1:] @ w_b

def radial_cdfs(du: float, values) -> np.ndarray:
    """:attr:`RadialTable.cdf` of many rows at once: ``values`` (J, n) -> CDFs (J, n), float64.

    The same sums as :class:`RadialTable` row by row (``v`` clipped at 0, the exact mass of each
    bin of a linear ``v``, cumulated along the row), in blocks of rows that stay in the caches
    (the same operations in the same order: the same bits as one pass over the whole array); the
    totals (:attr:`RadialTable.total`) are the last column.

    >>> rows = np.array([[1.0, 0.5, 0.0], [0.2, -1.0, 0.3]])
    >>> bool(np.array_equal(radial_cdfs(0.1, rows)[1], RadialTable(0.1, rows[1]).cdf))
    True
    """
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2:
        raise ValueError(f"values of shape {values.shape}: rows (J, n) expected")
    J, n = values.shape
    u0 = np.arange(n - 1) * du
    scale = 2 * np.pi * du
    out = np.empty((J, n))
    out[:, 0] = 0.0
    step = max(1, RADIAL_CDF_BLOCK // max(n, 1))
    v, a, b, t = (np.empty((min(step, J), m)) for m in (n, n - 1, n - 1, n - 1))
    for r0 in range(0, J, step):
        r1 = min(r0 + step, J)
        vv, aa, bb, tt = v[:r1 - r0], a[:r1 - r0], b[:r1 - r0], t[:r1 - r0]
        np.maximum(values[r0:r1], 0.0, out=vv)
        # bin_mass = 2π du (u0 a + (u0 b + du a) / 2 + du b / 3), a = v_i, b = v_{i+1} - v_i
        np.subtract(vv[:, 1:], vv[:, :-1], out=bb)
        np.multiply(u0, bb, out=tt)
        np.multiply(du, vv[:, :-1], out=aa)
        tt += aa
        tt /= 2
        np.multiply(u0, vv[:, :-1], out=aa)
        aa += tt
        np.multiply(du, bb, out=tt)
        tt /= 3
        aa += tt
        aa *= scale
        np.cumsum(aa, axis=1, out=out[r0:r1, 1:])
    return out


# --------------------------------------------------------------------------
# 2D table
# --------------------------------------------------------------------------
def _linear_segment_inverse(a, b, r):
    """Solve ``a s + (b - a) s²/2 = r`` for s in [0, 1] (density a → b on a unit segment)."""
    disc = np.maximum(a * a + 2.0 * (b - a) * r, 0.0)
    denom = a + np.sqrt(disc)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 0, 2.0 * r / denom, 0.5)
    return np.clip(s, 0.0, 1.0)


@dataclass
class GridTable:
    """``v(u_x, u_y)`` at the vertices of an N×N grid, bilinear in between.

    The vertices sit at ``-U + (i + ½)·cell`` (cell = 2U/N), so the lobe is
    defined on the square spanned by the outer vertices and is 0 outside.
    Sampling is exact for the bilinear density (marginal in y, conditional
    in x, each piecewise linear, inverted in closed form), so
    :meth:`pdf` ∝ :meth:`eval` — the same scheme as Mitsuba's
    ``MarginalContinuous2D0`` that the plugin uses.

    With ``warp = c > 0`` the grid is uniform in ``t = u / (1 + |u|/c)`` per
    axis (cells of ``cell`` near u = 0, growing as ``(1 + |u|/c)²``), so one
    N×N table reaches far (``U`` is then the range in t, ``U < c``):
    ``values`` is the density in t, ``v(u(t)) · J`` with the Jacobian
    ``J = (1 + |u_x|/c)² (1 + |u_y|/c)²``, the bilinear density is sampled in
    t and mapped to ``u = t / (1 - |t|/c)``, and :meth:`eval` returns
    ``table(t(u)) / J``, the density in u.
    """

    u_range: float
    values: np.ndarray  # (N, N), index [iy, ix]
    warp: float = 0.0

    def to_t(self, u):
        """Grid coordinate ``t = u / (1 + |u|/c)`` (``t = u`` without warp)."""
        u = np.asarray(u, dtype=np.float64)
        return u / (1.0 + np.abs(u) / self.warp) if self.warp > 0 else u

    def to_u(self, t):
        """``u = t / (1 - |t|/c)``."""
        t = np.asarray(t, dtype=np.float64)
        return t / (1.0 - np.abs(t) / self.warp) if self.warp > 0 else t

    def jacobian(self, u) -> np.ndarray:
        """``d²u / d²t`` at u (..., 2)."""
        u = np.asarray(u, dtype=np.float64)
        if self.warp <= 0:
            return np.ones(u.shape[:-1])
        return ((1.0 + np.abs(u[..., 0]) / self.warp) * (1.0 + np.abs(u[..., 1]) / self.warp)) ** 2

    @property
    def reach(self) -> float:
        """Largest ``|u_x|``, ``|u_y|`` covered (the outer vertices)."""
        return float(self.to_u(self.lo + (self.n - 1) * self.cell))

    def __post_init__(self):
        self.values = np.maximum(np.asarray(self.values, dtype=np.float64), 0.0)

    @functools.cached_property
    def row_cdf(self) -> np.ndarray:
        """(N, N): ``∫_0^{x_i} v(x, y_j) dx`` per vertex row (trapezoids; built when first used)."""
        v, h = self.values, self.cell
        seg = 0.5 * h * (v[:, 1:] + v[:, :-1])                       # trapezoids along x
        return np.concatenate([np.zeros((v.shape[0], 1)), np.cumsum(seg, axis=1)], axis=1)

    @functools.cached_property
    def marg_cdf(self) -> np.ndarray:
        """(N,): ``∫_0^{y_j} m(y) dy`` with ``m(y_j) = ∫ v dx`` the rows' integrals."""
        m = self.row_cdf[:, -1]
        return np.concatenate([[0.0], np.cumsum(0.5 * self.cell * (m[1:] + m[:-1]))])

    @property
    def n(self) -> int:
        return self.values.shape[0]

    @property
    def cell(self) -> float:
        return 2 * self.u_range / self.n

    @property
    def lo(self) -> float:
        """Coordinate of the first vertex."""
        return -self.u_range + 0.5 * self.cell

    @property
    def total(self) -> float:
        """``∫ v d²u`` of the bilinear interpolant (``∫ table d²t`` when warped)."""
        return float(self.marg_cdf[-1])

    def centres(self) -> np.ndarray:
        """Vertex coordinates (in t when warped)."""
        return self.lo + np.arange(self.n) * self.cell

    def eval(self, u) -> np.ndarray:
        """Bilinear interpolation at ``u`` (..., 2); 0 outside the vertex square
        (with a warp: in t, divided by the Jacobian)."""
        u = np.asarray(u, dtype=np.float64)
        if self.warp > 0:
            t = self.to_t(u)
            return self.eval_grid(t) / self.jacobian(u)
        return self.eval_grid(u)

    def eval_grid(self, u) -> np.ndarray:
        """Bilinear interpolation of the nodes at ``u`` (..., 2) in the grid's own coordinate (``t``
        where warped; no Jacobian); 0 outside the vertex square."""
        fx = (u[..., 0] - self.lo) / self.cell
        fy = (u[..., 1] - self.lo) / self.cell
        inside = (fx >= 0) & (fx <= self.n - 1) & (fy >= 0) & (fy <= self.n - 1)
        x0 = np.clip(np.floor(fx).astype(np.int64), 0, self.n - 2)
        y0 = np.clip(np.floor(fy).astype(np.int64), 0, self.n - 2)
        tx = np.clip(fx - x0, 0.0, 1.0)
        ty = np.clip(fy - y0, 0.0, 1.0)
        v = self.values
        out = ((1 - tx) * (1 - ty) * v[y0, x0] + tx * (1 - ty) * v[y0, x0 + 1]
               + (1 - tx) * ty * v[y0 + 1, x0] + tx * ty * v[y0 + 1, x0 + 1])
        return np.where(inside, out, 0.0)

    def eval_scaled(self, d, scales) -> np.ndarray:
        """:meth:`eval` at ``d * s`` for every ``s`` of ``scales``: (..., len(scales)).

        One pass over all scales (the designer's picture: ``u = 2π R d / λ`` at
        each wavelength), the same bilinear interpolant as :meth:`eval` (0
        outside the vertex square) with four gathers from the flat table.
        """
        d = np.asarray(d, dtype=np.float64)
        scales = np.asarray(scales, dtype=np.float64)
        if self.warp > 0:
            return np.stack([self.eval(d * s) for s in scales], -1)
        n, inv = self.n, 1.0 / self.cell
        flat = self.values.ravel()
        sx, off = scales * inv, -self.lo * inv
        pts = d.reshape(-1, 2)
        out = np.empty((pts.shape[0], scales.size))
        step = max(1, 65536 // max(scales.size, 1))      # blocks that stay in the cache
        for a in range(0, pts.shape[0], step):
            p = pts[a:a + step]
            fx = p[:, 0, None] * sx
            fx += off
            fy = p[:, 1, None] * sx
            fy += off
            inside = (fx >= 0) & (fx <= n - 1)
            inside &= fy >= 0
            inside &= fy <= n - 1
            ix = fx.astype(np.intp)                      # floor where inside
            np.clip(ix, 0, n - 2, out=ix)
            iy = fy.astype(np.intp)
            np.clip(iy, 0, n - 2, out=iy)
            fx -= ix
            fy -= iy
            iy *= n
            iy += ix                                     # the flat index of the lower-left vertex
            v00, v01 = np.take(flat, iy), np.take(flat, iy + 1)
            iy += n
            v10, v11 = np.take(flat, iy), np.take(flat, iy + 1)
            v01 -= v00
            v01 *= fx
            v00 += v01                                   # along x on the lower row
            v11 -= v10
            v11 *= fx
            v10 += v11                                   # along x on the upper row
            v10 -= v00
            v10 *= fy
            v00 += v10
            v00 *= inside                                # 0 outside the vertex square
            out[a:a + step] = v00
        return out.reshape(d.shape[:-1] + (scales.size,))

    def pdf(self, u) -> np.ndarray:
        """Density in the u plane of :meth:`sample`: ``eval / total``."""
        return self.eval(u) / self.total

    def sample(self, xi) -> np.ndarray:
        """``xi`` (..., 2) in [0,1)² -> ``u`` (..., 2) with density :meth:`pdf`."""
        xi = np.asarray(xi, dtype=np.float64)
        flat = xi.reshape(-1, 2)
        chunk = 8192  # the conditional step holds (chunk, N) arrays
        out = np.concatenate([self._sample(flat[k:k + chunk]) for k in range(0, len(flat), chunk)]
                             or [np.zeros((0, 2))])
        return out.reshape(xi.shape)

    def _sample(self, xi) -> np.ndarray:
        h, n = self.cell, self.n
        m = self.row_cdf[:, -1]
        # marginal in y: piecewise linear m(y) between vertex rows
        target = xi[..., 0] * self.marg_cdf[-1]
        j = np.clip(np.searchsorted(self.marg_cdf, target, side="right") - 1, 0, n - 2)
        ty = _linear_segment_inverse(m[j] * h, m[j + 1] * h, target - self.marg_cdf[j])
        # conditional in x: the row at y interpolates the rows' CDFs linearly
        c0, c1 = self.row_cdf[j], self.row_cdf[j + 1]                 # (..., N)
        crow = (1 - ty)[..., None] * c0 + ty[..., None] * c1
        tx_target = xi[..., 1] * crow[..., -1]
        i = np.clip((crow <= tx_target[..., None]).sum(axis=-1) - 1, 0, n - 2)
        take = lambda a, k: np.take_along_axis(a, k[..., None], axis=-1)[..., 0]
        vrow0 = (1 - ty) * self.values[j, i] + ty * self.values[j + 1, i]
        vrow1 = (1 - ty) * self.values[j, i + 1] + ty * self.values[j + 1, i + 1]
        tx = _linear_segment_inverse(vrow0 * h, vrow1 * h, tx_target - take(crow, i))
        return self.to_u(np.stack([self.lo + (i + tx) * h, self.lo + (j + ty) * h], axis=-1))

    def arrays(self) -> dict:
        return {"kind": np.array("grid"), "u_range": np.array(self.u_range), "values": self.values,
                "warp": np.array(self.warp)}


def table_from_arrays(arrays) -> RadialTable | GridTable:
    kind = str(arrays["kind"])
    if kind == "radial":
        return RadialTable(float(arrays["du"]), np.array(arrays["values"]))
    if kind == "grid":
        warp = float(arrays["warp"]) if "warp" in arrays else 0.0
        return GridTable(float(arrays["u_range"]), np.array(arrays["values"]), warp)
    raise ValueError(f"unknown table kind {kind!r}")


# --------------------------------------------------------------------------
# Cache
# --------------------------------------------------------------------------
#: Names of the files the cache writes: ``<key>.npz``, its lock ``<key>.npz.lock`` and
#: the temporary files of a writer ``.tmp-<key>-<random>.npz`` (key: 32 hex digits).
#: ``cache_clear`` deletes these and nothing else.
CACHE_FILE = re.compile(r"^(?:[0-9a-f]{32}\.npz(?:\.lock)?|\.tmp-[0-9a-f]{32}-[A-Za-z0-9_]+\.npz)$")
TABLE_FILE = re.compile(r"^[0-9a-f]{32}\.npz$")

_warned_folders: set = set()


def cache_dir() -> str:
    """Folder of cached tables: ``$CORONA_CACHE_DIR`` or the user cache dir.

    Created if missing; one :class:`corona.CoronaError` line if it is not a
    folder or cannot be created, or if ``CORONA_CACHE_DIR`` is set but empty (never
    taken as the default: ``CORONA_CACHE_DIR= corona tables clear`` cleared the user's cache).
    """
    from corona._validation import CoronaError
    path = os.environ.get("CORONA_CACHE_DIR")
    if path is not None and not path.strip():
        # an empty value is a mistake (an unset shell variable), not a request for the default:
        # `CORONA_CACHE_DIR= corona tables clear` must never clear the user's real cache
        raise CoronaError(f"CORONA_CACHE_DIR={path!r} is empty; allowed a folder path, or unset it "
                          "for the user cache folder")
    source = "CORONA_CACHE_DIR" if path else "the user cache folder"
    if not path:
        import platformdirs
        path = platformdirs.user_cache_dir("corona")
    if os.path.exists(path) and not os.path.isdir(path):
        raise CoronaError(f"table cache {path!r} ({source}) is not a folder")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        raise CoronaError(f"table cache {path!r} ({source}) cannot be created: "
                          f"{err.strerror or err}") from None
    return path


def _warn_once(folder: str, why: str) -> None:
    """One RuntimeWarning per cache folder and process: tables are built in memory."""
    if folder in _warned_folders:
        return
    _warned_folders.add(folder)
    warnings.warn(f"corona: table cache unusable: {folder} ({why}); building tables in memory "
                  "(warned once)", RuntimeWarning, stacklevel=3)


def cache_key(params: dict) -> str:
    """Content-addressed key of a table: sha256 of its parameters and the format version."""
    blob = json.dumps({"format": FORMAT_VERSION, **params}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def code_key(*functions) -> str:
    """A fingerprint of the code of ``functions`` (their bytecode, constants and names, nested
    functions too), for the cache key of a table derived by them: a change of that code is a
    new key, so no table made by the old code is read back.  Python versions may differ."""
    import types
    h = hashlib.sha256()

    def add(code):
        h.update(code.co_code)
        h.update(repr(code.co_names).encode())
        for c in code.co_consts:
            if isinstance(c, types.CodeType):
                add(c)
            else:
                h.update(repr(c).encode())
    for f in functions:
        add(getattr(f, "__func__", f).__code__)
    return h.hexdigest()[:16]


def identity(obj) -> dict:
    """The cache key of a shape or a process: ``obj.key()`` and, for a class defined outside corona
    (a user's family, or a user's subclass of a built-in, whose ``key`` may be the parent's), its
    qualified name and a fingerprint of the code its classes outside corona define (methods,
    properties, plain class constants: :func:`code_key`), so that a table made by another or an
    earlier version of that class is not read back.  (Code it calls elsewhere is not covered: a
    user who changes such a helper clears the cache, ``corona tables clear``.)"""
    key = obj.key()
    cls = type(obj)
    if cls.__module__.split(".")[0] == "corona":
        return key
    functions, constants = [], []
    for c in cls.__mro__:
        if c is object or c.__module__.split(".")[0] == "corona":
            continue
        for name, v in sorted(vars(c).items()):
            v = getattr(v, "fget", None) or getattr(v, "func", None) or getattr(v, "__func__", None) or v
            if hasattr(v, "__code__"):
                functions.append(v)
            elif isinstance(v, (bool, int, float, str, tuple)) and not name.startswith("__"):
                constants.append((c.__qualname__, name, v))
    h = hashlib.sha256((code_key(*functions) + repr(constants)).encode()).hexdigest()[:16]
    return {**key, "class": f"{cls.__module__}.{cls.__qualname__}", "code": h}


def _checksum(arrays: dict) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(name.encode())
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.reshape(-1).view(np.uint8))     # the bytes of a.tobytes(), without the copy
    return h.hexdigest()


#: a cached table at least this large is mapped from its file (:func:`_load_mapped`), not copied
MAP_BYTES = 32 << 20


def _load_mapped(path: str) -> dict:
    """The arrays of an uncompressed ``.npz`` (what :func:`_write_atomic` writes), mapped from the
    file copy-on-write instead of read into fresh memory: a large table's pages come from the
    system's file cache (no copy, no zip CRC pass: the checksum of :func:`_read` is the check), and
    the arrays stay writable without touching the file.  A file replaced later
    (:func:`_write_atomic`'s rename) leaves the mapping on the old one.  Raises on anything it does
    not recognise (the caller treats the file as damaged)."""
    import io
    import mmap
    import struct
    import zipfile

    from numpy.lib import format as npformat
    with open(path, "rb") as fh:
        with zipfile.ZipFile(fh) as z:
            infos = z.infolist()
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_COPY)
    out = {}
    for info in infos:
        if info.compress_type != zipfile.ZIP_STORED or not info.filename.endswith(".npy"):
            raise ValueError(f"{info.filename}: not a stored .npy member")
        at = info.header_offset
        if mm[at:at + 4] != b"PK\x03\x04":
            raise ValueError(f"{info.filename}: no local header")
        n_name, n_extra = struct.unpack("<HH", mm[at + 26:at + 30])
        start = at + 30 + n_name + n_extra
        head = io.BytesIO(mm[start:start + min(info.file_size, 1 << 17)])
        version = npformat.read_magic(head)
        shape, fortran, dtype = (npformat.read_array_header_1_0(head) if version == (1, 0)
                                 else npformat.read_array_header_2_0(head))
        if dtype.hasobject:
            raise ValueError(f"{info.filename}: an object array")
        offset = start + head.tell()
        if offset + dtype.itemsize * int(np.prod(shape)) > start + info.file_size:
            raise ValueError(f"{info.filename}: truncated")
        # (a member's data need not be aligned to its item size: numpy and Dr.Jit read such arrays)
        out[info.filename[:-4]] = np.ndarray(shape, dtype=dtype, buffer=mm, offset=offset,
                                             order="F" if fortran else "C")
    return out


def _read(path: str, key: str) -> dict | None:
    try:
        # mapped where large (not on Windows, where a mapped file cannot be replaced; small tables
        # read: each mapping holds a file descriptor while its arrays live)
        if os.name != "nt" and os.path.getsize(path) >= MAP_BYTES:
            data = _load_mapped(path)
        else:
            with np.load(path, allow_pickle=False) as f:
                data = {k: f[k] for k in f.files}
        meta = json.loads(str(data.pop("__meta__")))
        if meta.get("format") != FORMAT_VERSION or meta.get("key") != key:
            return None
        if meta.get("checksum") != _checksum(data):
            return None
        return data
    except Exception:
        return None


def _write_atomic(path: str, key: str, arrays: dict, checksum: str | None = None) -> None:
    """Write the table under a temporary name, then rename it over ``path`` (atomic): a reader sees
    the old file or the whole new one.  No ``fsync``: a file that a crash of the system leaves
    incomplete fails its checksum (:func:`_read`) and is rebuilt, never served.  ``checksum``: the
    arrays' (:func:`_checksum`), taken when they were built (by default now)."""
    checksum = _checksum(arrays) if checksum is None else checksum
    meta = json.dumps({"format": FORMAT_VERSION, "key": key, "checksum": checksum})
    folder = os.path.dirname(path)
    fd, tmp = tempfile.mkstemp(prefix=f".tmp-{key}-", suffix=".npz", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, __meta__=np.array(meta), **arrays)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _write_or_warn(folder: str, path: str, key: str, arrays: dict, checksum: str | None = None) -> None:
    """:func:`_write_atomic`; a full or read-only cache must not stop rendering: one warning."""
    try:
        _write_atomic(path, key, arrays, checksum)
    except OSError as err:
        _warn_once(folder, f"could not write {os.path.basename(path)}: {err.strerror or err}")


_writer = None
_writer_lock = threading.Lock()


def _background_writer():
    """The process's one cache-writer thread (:func:`cached` with ``background=True``; made once,
    whichever thread asks first); Python joins it at exit, so a table handed to it is written
    before the interpreter ends."""
    global _writer
    with _writer_lock:
        if _writer is None:
            from concurrent.futures import ThreadPoolExecutor
            _writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="corona-cache-writer")
        return _writer


def _write_and_release(lock, folder: str, path: str, key: str, arrays: dict, checksum: str) -> None:
    """:func:`_write_or_warn` on the writer thread, then release the key's lock (taken by the builder)."""
    try:
        _write_or_warn(folder, path, key, arrays, checksum)
    finally:
        lock.release()


def wait_for_writes() -> None:
    """Block until every table handed to the background writer (:func:`cached`) is on disk."""
    if _writer is not None:
        _writer.submit(lambda: None).result()


def cached(params: dict, build, *, use_cache: bool = True, background: bool = False) -> dict:
    """Return the arrays of the table ``params``, building them with ``build()`` on a miss.

    Concurrent builders of one key serialise on a file lock; a damaged,
    truncated or older-format file is detected by its checksum and rebuilt.
    ``background``: a built table is written to disk by a writer thread while the caller goes on
    (large tables of a cold scene load); its checksum is taken here, before the caller may touch
    the arrays, and the key's lock is held until the file is in place, so a reader of the key in
    this or another process waits for it, and a table changed meanwhile fails its checksum when
    read (rebuilt, never served).  The caller must not write to the returned arrays.
    """
    if not use_cache:
        return _build_logged(params, build)
    from filelock import FileLock

    from corona._validation import CoronaError
    key = cache_key(params)
    try:
        folder = cache_dir()
    except CoronaError as err:  # an unusable cache folder must not stop rendering either
        _warn_once(os.environ.get("CORONA_CACHE_DIR") or "user cache", str(err))
        return build()
    path = os.path.join(folder, f"{key}.npz")
    data = _read(path, key) if os.path.isfile(path) else None
    if data is not None:
        return data
    # a read-only cache (or a lock path that is not a file) must not stop rendering:
    # try the lock file first (FileLock would retry until its timeout on some errors)
    try:
        os.close(os.open(path + ".lock", os.O_RDWR | os.O_CREAT, 0o644))
    except OSError as err:
        _warn_once(folder, f"{os.path.basename(path)}.lock: {err.strerror or err}")
        return build()
    # (not thread-local: the writer thread releases what this thread acquired)
    lock = FileLock(path + ".lock", timeout=600, thread_local=False)
    lock.acquire()
    handed = False
    try:
        data = _read(path, key) if os.path.isfile(path) else None
        if data is not None:
            return data
        _remove_stale_temporaries(folder, key)
        arrays = _build_logged(params, build)
        if background:
            _background_writer().submit(_write_and_release, lock, folder, path, key, arrays, _checksum(arrays))
            handed = True
            return arrays
        _write_or_warn(folder, path, key, arrays)
        return arrays
    finally:
        if not handed:
            lock.release()


def _build_logged(params: dict, build) -> dict:
    """``build()``; with ``$CORONA_TABLE_LOG`` set (a file path), one JSON line per build appended
    to it: the seconds it took, the process, the test that asked (``$PYTEST_CURRENT_TEST``) and
    the table's parameters (how the tests' suite attributes its cold time to tables)."""
    log = os.environ.get("CORONA_TABLE_LOG")
    if not log:
        return build()
    import time
    start = time.perf_counter()
    arrays = build()
    line = json.dumps({"seconds": round(time.perf_counter() - start, 3), "pid": os.getpid(),
                       "test": os.environ.get("PYTEST_CURRENT_TEST", ""), "params": params},
                      sort_keys=True, default=str)
    try:
        with open(log, "a") as f:
            f.write(line + "\n")
    except OSError:
        pass
    return arrays


def _remove_stale_temporaries(folder: str, key: str) -> None:
    """Delete temporary files of ``key`` left by a writer that was killed.

    Called under the key's lock: every writer of this key holds it while
    writing, so no live writer owns one of these files.
    """
    prefix = f".tmp-{key}-"
    for name in os.listdir(folder):
        if name.startswith(prefix):
            try:
                os.unlink(os.path.join(folder, name))
            except OSError:
                pass


def _cache_files(folder: str) -> list[str]:
    """The names in ``folder`` that the cache itself writes (:data:`CACHE_FILE`)."""
    from corona._validation import CoronaError
    try:
        return sorted(f for f in os.listdir(folder) if CACHE_FILE.match(f))
    except OSError as err:
        raise CoronaError(f"table cache {folder!r} cannot be read: {err.strerror or err}") from None


def cache_info() -> dict:
    """Location, number of tables and total size [bytes] of the cache."""
    folder = cache_dir()
    files = [f for f in _cache_files(folder) if TABLE_FILE.match(f)]
    size = 0
    for f in files:
        try:
            size += os.path.getsize(os.path.join(folder, f))
        except OSError:
            pass
    return {"path": folder, "tables": len(files), "bytes": size, "format": FORMAT_VERSION}


def cache_clear() -> int:
    """Delete the cached tables (and their locks and temporaries); return how many tables.

    Only names the cache writes are touched (:data:`CACHE_FILE`): other files in
    the folder, e.g. a user's own ``data.npz``, stay.  A file that cannot be
    removed (read-only cache) is one :class:`corona.CoronaError`.
    """
    from corona._validation import CoronaError
    folder = cache_dir()
    n = 0
    for f in _cache_files(folder):
        try:
            os.unlink(os.path.join(folder, f))
        except FileNotFoundError:
            continue
        except OSError as err:
            raise CoronaError(f"table cache {folder!r}: cannot remove {f}: {err.strerror or err}") from None
        n += bool(TABLE_FILE.match(f))
    return n
