"""Dr.Jit kernels of the renderer's lobe for anisotropic materials.

The plugin (:mod:`corona.mitsuba.bsdf`) evaluates, samples and gives the pdf
of the lobe ``v(u)`` of :class:`corona.model.render_lobe.RenderLobe` through
:class:`LobeKernel` whenever the lobe is not radial.  Everything inside the
methods is Dr.Jit (float32), traced once per variant; Python loops run over
the (few) outlines and polygon edges only, never over lanes.

* ``analytic``: ``Â`` of circles (Airy; ``J1`` by Abramowitz & Stegun 9.4.4
  and 9.4.6, |error| < 4e-8), ellipses (Airy of the scaled wave vector),
  rectangles (sinc × sinc) and polygons (edge sum; Taylor series of order
  :data:`corona.model.render_lobe.TAYLOR_ORDER` near q = 0), times the Gaussian of
  a soft edge, combined as ``P = Σ w_i |Â_i|² / ⟨|A|⟩``, ``C = |Σ w_i Â_i|² /
  ⟨|A|⟩``;
* ``grid``: ``P`` (and ``C``) by a 4×4-tap cubic B-spline of the prefiltered
  grid (mirror boundary, as :func:`scipy.ndimage.map_coordinates`);
* both times ``1 + (S - 1)`` from the radial ``S - 1`` table (linear);
* ``table``: the bilinear table (lattices).

Sines and cosines are :func:`corona.mitsuba.common.sincos` (the argument reduced to [-π, π], Dr.Jit's
polynomial): ``dr.sin`` / ``dr.cos`` are the GPU's approximate instructions on CUDA, whose absolute
error (2^-21.4) is a relative 1e-4 of a sinc near its peak.

Sampling: the bilinear table of ``v`` (uniform in u, or in ``t = u / (1 + |u|/c)``
for lobes reaching beyond it) sampled exactly, a cell by two alias tables (:func:`alias_tables`), a
corner of it and the product of two linear ramps (:meth:`LobeKernel._sample_cell`);
the pdf is the exact density of that table (divided by the Jacobian ``d²u/d²t``).

References
----------
M. Abramowitz, I. A. Stegun, *Handbook of Mathematical Functions* (1964),
9.4.4 and 9.4.6 (polynomial approximations of J1).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from corona._validation import CoronaError, check_range
from corona.mitsuba.common import array as _array, gather as _gather, gather4
from corona.mitsuba.common import cos as _cos, sin as _sin, sincos as _sincos
from corona.model.render_lobe import TAYLOR_ORDER, TAYLOR_U

# Abramowitz & Stegun 9.4.4: x⁻¹ J1(x) = Σ a_k (x/3)^{2k}, |x| <= 3
_J1_SMALL = (0.5, -0.56249985, 0.21093573, -0.03954289, 0.00443319, -0.00031761, 0.00001109)
# 9.4.6: J1(x) = x^{-1/2} f1 cos θ1, x >= 3, in powers of 3/x
_J1_F1 = (0.79788456, 0.00000156, 0.01659667, 0.00017105, -0.00249511, 0.00113653, -0.00020033)
_J1_TH = (-2.35619449, 0.12499612, 0.00005650, -0.00637879, 0.00074348, 0.00079824, -0.00029166)


#: sinc(x) = Σ (-x²)^i / (2i + 1)!, i = 0 .. 5 (in x²)
#: The outlines the kernel evaluates in closed form (:class:`corona.model.render_lobe.Term`'s ``kind``,
#: given by the shapes' ``kernel_terms``: circle; ellipse; rect for rectangles and squares; polygon).
TERM_KINDS = ("circle", "ellipse", "rect", "polygon")
_SINC_SERIES = tuple((-1.0) ** i / math.factorial(2 * i + 1) for i in range(6))


def _poly(coeffs, x):
    acc = mi.Float(coeffs[-1])
    for c in coeffs[-2::-1]:
        acc = dr.fma(acc, x, c)
    return acc


def airy(v):
    """``2 J1(v)/v`` (limit 1 at v = 0), Abramowitz & Stegun 9.4.4 / 9.4.6."""
    x = dr.abs(v)
    small = 2.0 * _poly(_J1_SMALL, dr.square(x * (1.0 / 3.0)))
    xb = dr.maximum(x, 3.0)
    t = 3.0 / xb
    f1 = _poly(_J1_F1, t)
    th = xb + _poly(_J1_TH, t)
    big = 2.0 * f1 * _cos(th) * dr.rsqrt(xb) / xb
    return dr.select(x <= 3.0, small, big)


def sinc(x):
    """``sin(x)/x`` (limit 1 at 0)."""
    tiny = dr.abs(x) < 1e-3
    xs = dr.select(tiny, 1.0, x)
    return dr.select(tiny, 1.0 - dr.square(x) * (1.0 / 6.0), _sin(xs) / xs)


def sinc_product(x, y):
    """``sinc(x) sinc(y)`` (:func:`sinc`) as one quotient ``(sin x sin y) / (x y)``: one division
    instead of two (a vector division costs as much as a dozen multiplications)."""
    tiny_x, tiny_y = dr.abs(x) < 1e-3, dr.abs(y) < 1e-3
    xs, ys = dr.select(tiny_x, 1.0, x), dr.select(tiny_y, 1.0, y)
    nx = dr.select(tiny_x, 1.0 - dr.square(x) * (1.0 / 6.0), _sin(xs))
    ny = dr.select(tiny_y, 1.0 - dr.square(y) * (1.0 / 6.0), _sin(ys))
    return (nx * ny) / (xs * ys)


#: Most denominators :func:`reciprocals` inverts with one division (their product stays far
#: inside float32's range: each is at most ~1e4 in the kernels).
RECIPROCAL_GROUP = 4


def reciprocals(ds):
    """``[1/d for d in ds]`` with one division per :data:`RECIPROCAL_GROUP` of them:
    ``1/d_k = (Π_{j≠k} d_j) / Π_j d_j`` (prefix and suffix products), a few ulps from the
    quotients themselves; every ``d`` must be nonzero (the callers put 1 where a term is not
    divided)."""
    out = []
    for g in range(0, len(ds), RECIPROCAL_GROUP):
        grp = ds[g:g + RECIPROCAL_GROUP]
        if len(grp) == 1:
            out.append(dr.rcp(grp[0]))
            continue
        prefix = [None, grp[0]]                      # prefix[k] = Π_{j<k} d_j (k >= 1)
        for d in grp[1:-1]:
            prefix.append(prefix[-1] * d)
        suffix = [None] * len(grp)                   # suffix[k] = Π_{j>k} d_j (k <= n - 2)
        suffix[-2] = grp[-1]
        for k in range(len(grp) - 3, -1, -1):
            suffix[k] = suffix[k + 1] * grp[k + 1]
        r = dr.rcp(prefix[-1] * grp[-1])
        for k in range(len(grp)):
            others = suffix[0] if k == 0 else (prefix[k] if k == len(grp) - 1 else prefix[k] * suffix[k])
            out.append(r * others)
    return out


def alias_tables(weights):
    """Walker's alias tables (Vose's construction) of each row of ``weights``, all rows at once.

    Picking ``i`` uniformly from a row and keeping it with probability ``prob[i]`` (else taking
    ``alias[i]``) draws ``i`` with probability ``weights[i] / Σ weights``, exactly up to rounding:
    ``P(i) = (prob[i] + Σ_{j: alias[j] = i} (1 - prob[j])) / n``.  The rows' stacks of entries
    below and above the mean are worked in lockstep (at most ``n`` numpy steps for all rows).

    Parameters
    ----------
    weights : array_like, shape (rows, n)
        Non-negative weights; a row of total 0 is drawn uniformly.

    Returns
    -------
    prob : ndarray of float32, shape (rows, n)
    alias : ndarray of uint32, shape (rows, n)

    References
    ----------
    A. J. Walker, ACM TOMS 3 (1977) 253; M. D. Vose, IEEE TSE 17 (1991) 972.
    """
    w = np.asarray(weights, dtype=np.float64)
    rows, n = w.shape
    total = w.sum(axis=1, keepdims=True)
    p = np.where(total > 0, w * n / np.where(total > 0, total, 1.0), 1.0)
    prob = np.ones((rows, n))
    alias = np.tile(np.arange(n), (rows, 1))
    # per row, a stack of the entries below 1 and one of those at or above 1, processed in lockstep
    small_first = np.argsort(p >= 1.0, axis=1, kind="stable")            # entries < 1 first
    n_small = np.sum(p < 1.0, axis=1)
    small = np.full((rows, n), -1)
    large = np.full((rows, n), -1)
    idx = np.arange(n)[None, :]
    small[idx < n_small[:, None]] = small_first[idx < n_small[:, None]]
    n_large = n - n_small
    large_rev = small_first[:, ::-1]                                      # entries >= 1 first
    large[idx < n_large[:, None]] = large_rev[idx < n_large[:, None]]
    r = np.arange(rows)
    while True:
        go = (n_small > 0) & (n_large > 0)
        if not np.any(go):
            break
        g = r[go]
        i_s = small[g, n_small[g] - 1]
        i_l = large[g, n_large[g] - 1]
        n_small[g] -= 1
        prob[g, i_s] = p[g, i_s]
        alias[g, i_s] = i_l
        p[g, i_l] -= 1.0 - p[g, i_s]
        moved = p[g, i_l] < 1.0                  # the large entry drops below 1: a small one now
        gm = g[moved]
        n_large[gm] -= 1
        small[gm, n_small[gm]] = i_l[moved]
        n_small[gm] += 1
    # what is left (at 1 up to rounding) keeps itself: prob 1, alias itself (set above)
    return prob.astype(np.float32), alias.astype(np.uint32)


def _alias_packed(prob, alias):
    """:func:`alias_tables`' ``prob`` and ``alias`` interleaved, an entry's two in one 8-byte
    packet (``alias`` as the bits of a float32): one gather an entry (:func:`_alias_pick`)."""
    bits = np.stack([np.asarray(prob, dtype=np.float32).ravel().view(np.uint32),
                     np.asarray(alias, dtype=np.uint32).ravel()], -1).ravel()
    if not dr.is_array_v(mi.Float):
        return bits
    # (written as integers: a float kernel would flush the aliases' bits, denormal floats, to 0)
    out = dr.reinterpret_array(mi.Float, _array(mi.UInt32, bits))
    dr.eval(out)
    return out


def _alias_pick(table, n, offset, xi, active):
    """An entry of row ``offset / n`` of :func:`alias_tables` (packed by :func:`_alias_packed`) from
    ``xi`` in [0, 1) (Dr.Jit), and what is left of ``xi``, uniform in [0, 1) again: ``(entry, rest)``."""
    x = xi * n
    i = dr.minimum(mi.UInt32(x), n - 1)
    f = dr.clip(x - mi.Float(i), 0.0, 1.0)
    if dr.is_array_v(mi.Float):     # the entry's probability and alias in one packet gather
        r = dr.gather(mi.ArrayXf, table, offset + i, active, shape=(2, dr.width(i)))
        keep, other = r[0], dr.reinterpret_array(mi.UInt32, r[1])
    else:                           # scalar variants: the packed integers (numpy)
        k = 2 * int(offset + i)
        keep = float(table[k:k + 1].view(np.float32)[0]) if active else 0.0
        other = int(table[k + 1]) if active else 0
    stay = f < keep
    rest = dr.select(stay, f / dr.maximum(keep, 1e-30), (f - keep) / dr.maximum(1.0 - keep, 1e-30))
    return dr.select(stay, i, other), dr.clip(rest, 0.0, 0.99999994)


#: Nodes a side of the anisotropic layers' sampling table (:meth:`LobeKernel.use_sampling_table`):
#: the material's 512² table resampled to 256² (its interpolant at the new nodes): a quarter of
#: the memory the pdf reads at each wavelength, the same noise (benchmarks/bench_sampling_table.py)
SAMPLING_NODES = 256


class LobeKernel:
    """The renderer's lobe of a non-radial material in Dr.Jit (see the module docstring)."""

    def __init__(self, material, sampling_n=SAMPLING_NODES):
        rl = material.render_lobe
        self.kind = rl.kind
        self.R = float(rl.R)
        self.inv_area_R2 = 1.0 / (float(rl.area) * self.R**2)
        # --- S - 1 (radial) ----------------------------------------------------
        self.has_s = rl.kind in ("analytic", "grid") and rl.s_minus_one is not None
        if self.has_s:
            self.s_du = float(rl.s_du)
            self.s_n = int(rl.s_minus_one.size)
            self.s_values = _array(mi.Float, rl.s_minus_one)
        # --- analytic outlines ----------------------------------------------------
        self.terms = []
        if rl.kind == "analytic":
            for t in rl.terms:
                if t.kind not in TERM_KINDS:
                    raise CoronaError(f"corona BSDF: a kernel term of kind {t.kind!r} ({t.shape!r}) has no "
                                      f"kernel; allowed {', '.join(TERM_KINDS)} (a shape without one returns "
                                      "None from kernel_terms: the form factor is tabulated)")
                p = dict(t.params)
                if "angle" in p:
                    p["cos"], p["sin"] = math.cos(p["angle"]), math.sin(p["angle"])
                if t.kind == "polygon":
                    self._polygon_setup(p)
                self.terms.append((t.kind, p, float(t.weight), float(t.area), float(t.blur)))
        # --- form-factor grids --------------------------------------------------------
        if rl.kind == "grid":
            self.g_n = int(rl.P.n)
            self.g_lo = float(rl.P.lo)
            self.g_cell = float(rl.P.cell)
            coefs = [rl.P.coef] + ([] if rl.C is None else [rl.C.coef])
            # the grids' symmetry (:meth:`_grid_fold`): u is folded into the quadrant u_x, u_y >= 0
            # ("quadrant") or the half plane u_y >= 0 ("half"), and only the taps that part reads
            # are kept: a quarter (half) of the memory, and of the cache lines the lookups touch
            self.g_fold = self._grid_fold(coefs, self.g_n, self.g_lo, self.g_cell)
            n, h = self.g_n, max((self.g_n - 1) // 2 - 1, 0)     # (one node of margin for rounding)
            self.g_x0 = h if self.g_fold == "quadrant" else 0    # first packet column kept
            self.g_y0 = h if self.g_fold in ("quadrant", "half") else 0       # first padded row kept
            self.g_w = n - self.g_x0                              # packets a kept row
            # coefficients padded by their mirror images (1 before, 2 after each
            # axis): the 4×4 taps of any point inside index the array directly
            padded = [self._padded(c) for c in coefs]
            self.g_P = self._taps(padded[0], self.g_y0, self.g_x0)
            self.g_C = None if rl.C is None else self._taps(padded[1], self.g_y0, self.g_x0)
            # a row's four taps of all the grids side by side (vectorised variants): one packet
            # gather of 4 × grids floats a row of taps (four a lookup), 4 × grids floats a cell
            # of the padded grids (a 4×4 block of all taps a cell would hold 16 × grids)
            self.g_rows = self._row_taps(padded, self.g_y0, self.g_x0) if dr.is_array_v(mi.Float) else None
        # --- the sampling table (bilinear, in u or in the warped t) -----------------------
        self.sampling_n = None if sampling_n is None else int(sampling_n)
        self.use_sampling_table(material.table)

    def use_sampling_table(self, table, n=None):
        """Sample (:meth:`sample`, :meth:`pdf`) from the bilinear table ``table``
        (:class:`corona.model.tabulated.GridTable`): with ``n`` (default :attr:`sampling_n`,
        :data:`SAMPLING_NODES` unless the kernel was made with another; None: the table's own
        nodes) below the table's nodes, on ``n`` nodes a side spanning the same square
        (:meth:`resampled`).  A lattice's table (``kind == "table"``), the lobe's value too,
        keeps its nodes."""
        n = self.sampling_n if n is None else int(n)
        if self.kind == "table":        # a lattice's table is its value too: sampled on its own nodes
            n = None
        self.sampling_source = table
        values, cell, total = table.values, float(table.cell), float(table.total)
        if n is not None and n < int(table.n):          # (never finer than the material's own)
            values, cell, total = self.resampled(table, n)
        else:
            n = int(table.n)
        self.near = dict(n=n, lo=float(table.lo), cell=cell, span=float(cell * (n - 1)),
                         total=total, values=self.corners(values))
        self.warp = float(table.warp)
        self.set_sampling_table(values)

    @staticmethod
    def resampled(table, n):
        """The bilinear sampling table ``table`` (:class:`corona.model.tabulated.GridTable`) on ``n``
        nodes a side spanning the same vertex square (its interpolant at the new nodes):
        ``(values, cell, total)``, ``total`` the new interpolant's integral (in t when warped)."""
        n = int(check_range("sampling_n", n, 2, table.n))
        span = table.cell * (table.n - 1)
        cell = span / (n - 1)
        c = table.lo + np.arange(n) * cell
        c[-1] = table.lo + span * (1.0 - 1e-12)            # inside the fine table's last cell
        gx, gy = np.meshgrid(c, c)                          # index [iy, ix]
        values = np.maximum(table.eval_grid(np.stack([gx, gy], -1)), 0.0)
        seg = 0.5 * cell * (values[:, 1:] + values[:, :-1]).sum(axis=1)
        total = float(0.5 * cell * (seg[1:] + seg[:-1]).sum())
        return values, float(cell), total

    def set_sampling_table(self, values):
        """Sample the bilinear table ``values`` ``(n, n)`` (:meth:`sample`): alias tables
        (:func:`alias_tables`) of its rows of cells and, in each row, of its cells, a cell's
        weight the mean of its corners (its integral)."""
        v = np.maximum(np.asarray(values, dtype=np.float64), 0.0)
        cells = 0.25 * (v[:-1, :-1] + v[:-1, 1:] + v[1:, :-1] + v[1:, 1:])        # (n - 1, n - 1)
        rows_p, rows_a = alias_tables(cells.sum(axis=1)[None, :])
        cols_p, cols_a = alias_tables(cells)
        self.s_rows_alias = _alias_packed(rows_p, rows_a)
        self.s_cols_alias = _alias_packed(cols_p, cols_a)

    @staticmethod
    def corners(values):
        """A bilinear table ``(n, n)`` as one packet per cell, ``(v[y, x], v[y, x + 1], v[y + 1, x],
        v[y + 1, x + 1])`` for ``x, y < n - 1`` (row-major cells): one packet gather a lookup."""
        v = np.asarray(values, dtype=np.float32)
        return _array(mi.Float, np.stack([v[:-1, :-1], v[:-1, 1:], v[1:, :-1], v[1:, 1:]], -1).ravel())

    @staticmethod
    def _grid_fold(coefs, n, lo, cell):
        """The symmetry the coefficient grids ``coefs`` (``[iy, ix]``, nodes ``lo + i cell`` on both
        axes) all share, for folding u before a lookup: ``"quadrant"`` (mirror images in u_x and in
        u_y: the B-spline at ``(|u_x|, |u_y|)`` is the one at u), ``"half"`` (the inversion
        ``u -> -u`` only: every real aperture's ``|Â|²`` and ``|Σ w Â|²``, Friedel's law) or None
        (nodes not symmetric about 0, or a grid that is not).  Symmetric means equal to 1e-12 of the
        grid's largest coefficient (far below float32's rounding, so the folded lookup reads
        the same float32 taps)."""
        if abs(lo + 0.5 * (n - 1) * cell) > 1e-9 * cell:
            return None

        def same(flip):
            return all(np.max(np.abs(c - flip(c))) <= 1e-12 * np.max(np.abs(c)) for c in coefs)
        if same(lambda c: c[:, ::-1]) and same(lambda c: c[::-1, :]):
            return "quadrant"
        return "half" if same(lambda c: c[::-1, ::-1]) else None

    @staticmethod
    def _taps(padded, y0=0, x0=0):
        """A padded coefficient grid ``(m, m)`` as packets of four neighbours along x:
        ``packet[y - y0, x - x0] = padded[y, x : x + 4]`` (``y >= y0``, ``x0 <= x < m - 3``), one packet
        gather a row of 4×4 taps."""
        m = padded.shape[0]
        return _array(mi.Float, np.stack([padded[y0:, x0 + a:m - 3 + a] for a in range(4)], -1).ravel())

    @staticmethod
    def _row_taps(padded, y0=0, x0=0):
        """Padded coefficient grids ``(m, m)`` as one packet per padded row ``y >= y0`` and column
        ``x0 <= x < m - 3`` (row-major from ``(y0, x0)``): ``packet[g, a] = padded_g[y, x + a]``,
        ``4 × len(padded)`` floats: one packet gather reads a row of 4 taps of every grid."""
        m = padded[0].shape[0]
        win = [np.lib.stride_tricks.sliding_window_view(p, 4, axis=1)[y0:, x0:m - 3] for p in padded]
        return _array(mi.Float, np.stack(win, axis=2).ravel())          # (y, x, grid, a)

    @staticmethod
    def _padded(coef):
        n = coef.shape[0]
        idx = np.arange(-1, n + 2)
        idx = np.where(idx < 0, -idx, idx)
        idx = np.where(idx > n - 1, 2 * (n - 1) - idx, idx)
        return np.ascontiguousarray(coef[np.ix_(idx, idx)])

    # ------------------------------------------------------------------
    # pieces
    # ------------------------------------------------------------------
    @staticmethod
    def _bilinear(tb, ux, uy, active):
        n = tb["n"]
        fx = (ux - tb["lo"]) / tb["cell"]
        fy = (uy - tb["lo"]) / tb["cell"]
        inside = active & (fx >= 0) & (fx <= n - 1) & (fy >= 0) & (fy <= n - 1)
        x0 = dr.clip(dr.floor(fx), 0, n - 2)
        y0 = dr.clip(dr.floor(fy), 0, n - 2)
        tx = fx - x0                    # in [0, 1] where inside (the select below zeroes the rest)
        ty = fy - y0
        q = gather4(tb["values"], mi.UInt32(y0) * (n - 1) + mi.UInt32(x0), inside)   # the cell's corners
        v = dr.lerp(dr.lerp(q.x, q.y, tx), dr.lerp(q.z, q.w, tx), ty)
        return dr.select(inside, dr.maximum(v, 0.0), 0.0)

    def set_structure_rows(self, s_rows, s_slopes):
        """Rows of ``S - 1`` over the area fraction (``(n_rows, s_n)``, :func:`corona.model.rows.structure_rows`)
        and their slopes in ``F_a``: :meth:`value` then takes the row and Hermite weights of each lane."""
        rows, slopes = np.asarray(s_rows, dtype=np.float64), np.asarray(s_slopes, dtype=np.float64)
        # one packet per row and node i: S(i), S(i + 1), dS(i), dS(i + 1)
        self.s_rows = _array(mi.Float, np.stack([rows[:, :-1], rows[:, 1:], slopes[:, :-1], slopes[:, 1:]],
                                                -1).ravel())

    def set_structure_centre(self, s1, ds1):
        """One row of ``S - 1`` (``s_n``) at a layer's uniform F_a and its slope in F_a:
        :meth:`value` then takes ``dfa`` (the lane's F_a minus that one: 0 in value)."""
        s1, ds1 = np.asarray(s1, dtype=np.float64), np.asarray(ds1, dtype=np.float64)
        # one packet per node i: S(i), dS(i), S(i + 1), dS(i + 1); and the row alone, read where no
        # derivative flows through ``dfa`` (two plain gathers: the slope's lerp and fma are 0 there)
        self.s_centre = _array(mi.Float, np.stack([s1[:-1], ds1[:-1], s1[1:], ds1[1:]], -1).ravel())
        self.s_centre_values = _array(mi.Float, s1)

    def _s_minus_one(self, ux, uy, active, srow=None, dfa=None, r=None):
        """``S - 1`` at ``|u|`` (``r`` when given, else from ``ux``, ``uy``): linear in ``|u|``; with
        ``srow = (j, h00, h10, h01, h11)`` the cubic Hermite in ``F_a`` between rows ``j`` and ``j + 1``
        (``h10``, ``h11`` times the rows' spacing)."""
        x = (dr.sqrt(dr.fma(ux, ux, uy * uy)) if r is None else r) * (1.0 / self.s_du)
        i = dr.minimum(mi.UInt32(dr.maximum(dr.floor(x), 0)), self.s_n - 2)
        t = x - mi.Float(i)
        inside = active & (x <= self.s_n - 1)
        if dfa is not None and dr.grad_enabled(dfa):         # the centre row and its slope in F_a
            q = gather4(self.s_centre, i, inside)
            return dr.select(inside, dr.fma(dfa, dr.lerp(q.y, q.w, t), dr.lerp(q.x, q.z, t)), 0.0)
        if dfa is not None or srow is None:     # one row: the centre's (dfa = 0 in value), else the material's
            row = self.s_values if dfa is None else self.s_centre_values
            v0 = _gather(mi.Float, row, i, inside)
            v1 = _gather(mi.Float, row, i + 1, inside)
            return dr.select(inside, dr.lerp(v0, v1, t), 0.0)
        j, h00, h10, h01, h11 = srow
        k = j * (self.s_n - 1) + i
        q0 = gather4(self.s_rows, k, inside)
        q1 = gather4(self.s_rows, k + (self.s_n - 1), inside)
        v = (h00 * dr.lerp(q0.x, q0.y, t) + h01 * dr.lerp(q1.x, q1.y, t)
             + h10 * dr.lerp(q0.z, q0.w, t) + h11 * dr.lerp(q1.z, q1.w, t))
        return dr.select(inside, v, 0.0)

    def _cubic(self, grids, ux, uy, active):
        """Cubic B-splines of the padded grids ``grids`` at u (the same 4×4 taps
        and weights for all; mirror boundary by the padding); 0 outside.  u is first folded
        by the grids' symmetry (:meth:`_grid_fold`) into the part whose taps are kept."""
        n = self.g_n
        if self.g_fold == "quadrant":
            ux, uy = dr.abs(ux), dr.abs(uy)
        elif self.g_fold == "half":                  # u -> -u where u_y < 0
            flip = uy < 0
            ux, uy = dr.select(flip, -ux, ux), dr.abs(uy)
        fx = (ux - self.g_lo) / self.g_cell
        fy = (uy - self.g_lo) / self.g_cell
        inside = active & (fx >= 0) & (fx <= n - 1) & (fy >= 0) & (fy <= n - 1)
        ix = dr.clip(dr.floor(fx), 0, n - 1)
        iy = dr.clip(dr.floor(fy), 0, n - 1)
        tx = fx - ix
        ty = fy - iy

        def weights(t):
            t2 = t * t
            t3 = t2 * t
            return ((1.0 - t) * (1.0 - t) * (1.0 - t) * (1.0 / 6.0),
                    (4.0 - 6.0 * t2 + 3.0 * t3) * (1.0 / 6.0),
                    (1.0 + 3.0 * t + 3.0 * t2 - 3.0 * t3) * (1.0 / 6.0),
                    t3 * (1.0 / 6.0))

        wx, wy = weights(tx), weights(ty)
        m = self.g_w                                # packets a kept row of the padded array
        # taps (-1 .. 2, -1) in the padded array, from its kept part's corner (g_y0, g_x0): the fold
        # leaves iy >= g_y0, ix >= g_x0 inside (the max only guards rounding)
        base = (mi.UInt32(dr.maximum(iy - self.g_y0, 0)) * m + mi.UInt32(dr.maximum(ix - self.g_x0, 0)))
        acc = [mi.Float(0.0) for _ in grids]
        ng = len(grids)
        # a row's taps of every grid in one gather where the packets hold exactly these grids,
        # else a packet of the row's four taps a grid
        packed = self.g_rows is not None and ng == dr.width(self.g_rows) // (4 * m * (n + 3 - self.g_y0))
        for b in range(4):
            if packed:
                taps = dr.gather(mi.ArrayXf, self.g_rows, base + b * m, inside, shape=(4 * ng, dr.width(base)))
                rows = [[taps[4 * g + c] for c in range(4)] for g in range(ng)]
            else:
                rows = [(q.x, q.y, q.z, q.w) for q in (gather4(coef, base + b * m, inside) for coef in grids)]
            for g, r in enumerate(rows):
                racc = dr.fma(wx[0], r[0], dr.fma(wx[1], r[1], dr.fma(wx[2], r[2], wx[3] * r[3])))
                acc[g] = dr.fma(wy[b], racc, acc[g])
        return [dr.select(inside, x, 0.0) for x in acc]

    def _term_amplitude(self, term, dx, dy, sq):
        """(re, im) of ``Â`` of one outline at ``q = sq d`` [rad/µm] (im None when real): what
        depends on ``d`` alone is written apart from the scale ``sq`` (:meth:`value`)."""
        kind, p, _, area, blur = term
        if "cos" in p:
            c, s = p["cos"], p["sin"]
            dxr, dyr = c * dx + s * dy, -s * dx + c * dy
        else:
            dxr, dyr = dx, dy
        im = None
        if kind == "circle":
            re = area * airy(dr.sqrt(dr.fma(dx, dx, dy * dy)) * (sq * p["radius"]))
        elif kind == "ellipse":
            ax, by = p["a"] * dxr, p["b"] * dyr
            re = area * airy(dr.sqrt(dr.fma(ax, ax, by * by)) * sq)
        elif kind == "rect":
            re = area * sinc_product(sq * (0.5 * p["width"] * dxr), sq * (0.5 * p["height"] * dyr))
        else:
            re, im = self._polygon(p, dx, dy, sq)
        if blur > 0:
            g = dr.exp((-0.5 * blur * blur) * dr.square(sq) * dr.fma(dx, dx, dy * dy))
            re = re * g
            im = None if im is None else im * g
        return re, im

    @staticmethod
    def _polygon_setup(p):
        """Constants of :meth:`_polygon` (in ``p``): the vertices whose half phases the edge sum
        needs, the edges, their cross products with q's coefficients, and the Taylor series'
        homogeneous polynomials in ``(q_x, q_y)``."""
        v = np.asarray(p["vertices"], dtype=np.float64)
        n = len(v)
        p["circumradius"] = float(np.max(np.hypot(v[:, 0], v[:, 1])))
        # centrosymmetric (v_{k+n/2} = -v_k): Â is real, and edge k+n/2 doubles edge k's sine
        # term (and cancels its cosine term); the edges k < n/2 need vertices 0 .. n/2 (v_{n/2} = -v_0)
        h = n // 2
        p["centrosymmetric"] = bool(n % 2 == 0 and np.allclose(
            v[h:], -v[:h], rtol=0.0, atol=1e-9 * p["circumradius"]))
        m = h if p["centrosymmetric"] else n           # edges summed
        p["phase_vertices"] = v[:m].tolist()           # (the closing vertex: -v_0 or v_0, no new phase)
        # a vertex that is the sum or difference of two earlier ones (a regular hexagon's v_2 = v_1 - v_0)
        # takes its half phase's sine and cosine from theirs by the angle-sum formulas: (k, a, b, ±1)
        p["phase_sums"] = {}
        for k in range(2, m):
            for a in range(k):
                for b in range(a):
                    for sign in (1.0, -1.0):
                        if k not in p["phase_sums"] and np.allclose(v[k], v[a] + sign * v[b], rtol=0.0,
                                                                    atol=1e-9 * p["circumradius"]):
                            p["phase_sums"][k] = (a, b, sign)
        p["edges"] = (np.roll(v, -1, axis=0) - v)[:m].tolist()
        # the Taylor series of the fan of triangles (0, v_k, v_{k+1}), Σ_j (-i)^j c_j(q), c_j the
        # homogeneous polynomial Σ_k 2|T_k| / (j + 2)! Σ_{a+b=j} (q·v_k)^a (q·v_{k+1})^b, as its
        # coefficients of q_x^i q_y^(j-i) (index i), in float64 from all n triangles
        w = np.roll(v, -1, axis=0)
        cross = v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]
        taylor = []
        for j in range(TAYLOR_ORDER + 1):
            c = np.zeros(j + 1)
            for (ax, ay), (bx, by), cr in zip(v, w, cross):
                for a in range(j + 1):
                    poly = np.array([1.0])
                    for _ in range(a):
                        poly = np.convolve(poly, [ay, ax])     # q·v_k: index = power of q_x
                    for _ in range(j - a):
                        poly = np.convolve(poly, [by, bx])
                    c += cr / math.factorial(j + 2) * poly
            taylor.append(c.tolist())
        p["taylor"] = taylor

    @staticmethod
    def _polygon(p, dx, dy, sq):
        """``Â`` of a polygon at ``q = sq d``: the edge sum ``(i/|q|²) Σ (q × e) sinc(q·e/2) e^{-i q·m}``
        (Lee & Mittra 1983), and its Taylor series near q = 0.

        An edge from ``v_k`` to ``v_{k+1}`` has ``q·m = ψ_k + ψ_{k+1}`` and ``q·e/2 = ψ_{k+1} - ψ_k``
        with the vertices' half phases ``ψ_k = q·v_k/2``, so one ``sincos`` a vertex gives both
        sines by the angle-sum formulas (instead of two trigonometric calls an edge), and none for
        a vertex that is the sum or difference of two others (a regular hexagon's third);
        ``sinc(q·e/2)`` is its Maclaurin series below 1 (with ``q·e/2`` itself, so no cancellation
        where q is nearly normal to an edge).  Near q = 0 the Taylor series of the fan of
        triangles ``Σ_j (-i)^j c_j(q)``, its homogeneous polynomials ``c_j`` precomputed
        (:meth:`_polygon_setup`; odd ones vanish for centrosymmetric polygons).  Every dot and
        cross product is taken with ``d`` and then scaled (``q·v = sq (d·v)``, ``c_j(q) = sq^j c_j(d)``),
        so a loop over wavelengths (one ``d``, a scale each) computes them once."""
        sq2 = dr.square(sq)
        qq = sq2 * dr.fma(dx, dx, dy * dy)
        small = qq * (p["circumradius"] ** 2) < TAYLOR_U**2
        sym = p["centrosymmetric"]
        phases = []
        for k, (vx, vy) in enumerate(p["phase_vertices"]):
            if k in p["phase_sums"]:            # ψ_k = ψ_a ± ψ_b
                a, b, sign = p["phase_sums"][k]
                (sa, ca), (sb, cb) = phases[a], phases[b]
                sb = sign * sb
                phases.append((dr.fma(sa, cb, ca * sb), dr.fma(ca, cb, -(sa * sb))))
            else:
                phases.append(_sincos(sq * dr.fma(dx, 0.5 * vx, dy * (0.5 * vy))))
        s0, c0 = phases[0]
        phases.append((-s0, c0) if sym else (s0, c0))      # the closing vertex: -v_0 or v_0
        # the edges' β = q·e/2, and 1/β (where |β| >= 1) with 1/|q|² from shared divisions
        betas = [sq * dr.fma(dx, 0.5 * ex, dy * (0.5 * ey)) for ex, ey in p["edges"]]
        b2s = [dr.square(beta) for beta in betas]
        inv_q, *inv_beta = reciprocals([dr.select(small, 1.0, qq)]
                                       + [dr.select(b2 < 1.0, 1.0, beta) for beta, b2 in zip(betas, b2s)])
        sw = mi.Float(0.0)   # Σ w sin φ
        cw = mi.Float(0.0)   # Σ w cos φ
        for k, (ex, ey) in enumerate(p["edges"]):
            (sa, ca), (sb, cb) = phases[k], phases[k + 1]
            b2 = b2s[k]
            # sinc(β): Σ (-β²)^i / (2i + 1)! to β^10 below |β| = 1 (|error| < 2e-10), else sin β / β
            series = _poly(_SINC_SERIES, b2)
            sin_beta = dr.fma(sb, ca, -(cb * sa))
            sinc_beta = dr.select(b2 < 1.0, series, sin_beta * inv_beta[k])
            w = (sq * dr.fma(dx, ey, -(dy * ex))) * sinc_beta
            sw = dr.fma(w, dr.fma(sa, cb, ca * sb), sw)                 # sin(ψ_k + ψ_{k+1})
            if not sym:
                cw = dr.fma(w, dr.fma(ca, cb, -(sa * sb)), cw)             # cos(ψ_k + ψ_{k+1})
        inv = (2.0 if sym else 1.0) * inv_q
        re_e, im_e = sw * inv, cw * inv
        # Taylor: Σ_j (-i)^j sq^j c_j(d), (-i)^j cycling 1, -i, -1, i: the real part Σ_i (-1)^i sq^2i c_2i(d)
        # and the imaginary -sq Σ_i (-1)^i sq^2i c_2i+1(d), Horner in sq²; c_j(d) by Horner in d_x
        # with the powers of d_y (of d alone)
        dy_pow = [1.0, dy]
        for _ in range(TAYLOR_ORDER - 1):
            dy_pow.append(dy_pow[-1] * dy)

        def c_of_d(j):
            coef = p["taylor"][j]
            acc = mi.Float(coef[j])
            for i in range(j - 1, -1, -1):
                acc = dr.fma(acc, dx, coef[i] * dy_pow[j - i])
            return acc

        def series(js):              # Σ_i (-1)^i sq^2i c_js[i](d), Horner in sq²
            acc = None
            for i in range(len(js) - 1, -1, -1):
                c = c_of_d(js[i]) if js[i] > 0 else mi.Float(p["taylor"][0][0])
                c = -c if i % 2 else c
                acc = c if acc is None else dr.fma(acc, sq2, c)
            return acc
        re_t = series(list(range(0, TAYLOR_ORDER + 1, 2)))
        im_t = None if sym else -sq * series(list(range(1, TAYLOR_ORDER + 1, 2)))
        if sym:
            return dr.select(small, re_t, re_e), None
        return dr.select(small, re_t, re_e), dr.select(small, im_t, im_e)

    # ------------------------------------------------------------------
    # interface
    # ------------------------------------------------------------------
    def value(self, ux, uy, active, srow=None, dfa=None, scale=None):
        """The renderer's ``v(u)`` (>= 0); ``srow`` picks rows of ``S - 1`` (:meth:`_s_minus_one`).

        With ``scale``, ``(ux, uy)`` is a direction ``d`` and ``u = scale d``: what depends on
        ``d`` alone (its length, an outline's dot products and Taylor polynomials) is written
        apart from the scale, so that in the plugin's loop over a lane's wavelengths (one ``d``, a
        scale ``2π L/λ`` each) the compiler computes it once, before the loop."""
        dx, dy = ux, uy
        sq = 1.0 / self.R if scale is None else scale * (1.0 / self.R)      # q = sq d [rad/µm]
        r = None
        if scale is not None:
            r = scale * dr.sqrt(dr.fma(dx, dx, dy * dy))                      # |u|
            ux, uy = scale * dx, scale * dy
        if self.kind == "table":
            return self._bilinear(self.near, ux, uy, active)
        if self.kind == "grid":
            if not self.has_s or self.g_C is None:      # v = P (S = 1) or P S (C = P)
                P = C = self._cubic([self.g_P], ux, uy, active)[0]
                if not self.has_s:
                    return dr.select(active, dr.maximum(P, 0.0), 0.0)
            else:
                P, C = self._cubic([self.g_P, self.g_C], ux, uy, active)
        else:
            inten = mi.Float(0.0)
            re = mi.Float(0.0)
            im = mi.Float(0.0)
            for term in self.terms:
                a_re, a_im = self._term_amplitude(term, dx, dy, sq)
                w = term[2]
                if a_im is None:
                    inten = dr.fma(w * a_re, a_re, inten)
                else:
                    inten = dr.fma(w * a_re, a_re, dr.fma(w * a_im, a_im, inten))
                    im = dr.fma(w, a_im, im)
                re = dr.fma(w, a_re, re)
            P = inten * self.inv_area_R2
            C = dr.fma(re, re, im * im) * self.inv_area_R2
        s1 = self._s_minus_one(ux, uy, active, srow, dfa, r) if self.has_s else 0.0
        return dr.select(active, dr.maximum(P + C * s1, 0.0), 0.0)

    def pdf(self, ux, uy, active):
        """Density in the u plane of :meth:`sample`."""
        if self.warp == 0.0:
            return self._bilinear(self.near, ux, uy, active) * (1.0 / self.near["total"])
        inv_c = 1.0 / self.warp
        gx = dr.fma(dr.abs(ux), inv_c, 1.0)         # 1 + |u|/c = du/dt^(1/2)
        gy = dr.fma(dr.abs(uy), inv_c, 1.0)
        rx, ry = reciprocals([gx, gy])
        p = self._bilinear(self.near, ux * rx, uy * ry, active)      # t = u / (1 + |u|/c)
        return p * (1.0 / self.near["total"]) * dr.square(rx * ry)

    def _sample_cell(self, s, active):
        """``s`` (Point2f in [0, 1)²) -> a point in [0, 1]² of the sampling table with the density of
        its bilinear interpolant (exactly): the row of cells by ``s.x``, the cell in it by ``s.y``
        (alias tables: two independent gathers each, no search), one of the cell's four corners
        with probability ∝ its value (what is left of ``s.x``), then the product of the two linear ramps that vanish at the opposite
        edges (``√ξ``; ``ξ``: what is left of each): the mixture of the corners' ramps weighted by
        their values is the bilinear interpolant of the cell, and the cell's probability its integral."""
        n1 = self.near["n"] - 1
        y0, ry = _alias_pick(self.s_rows_alias, n1, mi.UInt32(0), s.x, active)
        x0, rx = _alias_pick(self.s_cols_alias, n1, y0 * n1, s.y, active)
        q = gather4(self.near["values"], y0 * n1 + x0, active)      # v00, v01 (x + 1), v10 (y + 1), v11
        q0, q1, q2, q3 = (dr.maximum(q.x, 0.0), dr.maximum(q.y, 0.0), dr.maximum(q.z, 0.0),
                          dr.maximum(q.w, 0.0))
        c1 = q0 + q1
        c2 = c1 + q2
        total = dr.maximum(c2 + q3, 1e-30)
        target = ry * total
        hi_x = ((target >= q0) & (target < c1)) | (target >= c2)       # corners 01 and 11
        hi_y = target >= c1                                            # corners 10 and 11
        start = dr.select(target < q0, 0.0, dr.select(target < c1, q0, dr.select(target < c2, c1, c2)))
        width = dr.select(target < q0, q0, dr.select(target < c1, q1, dr.select(target < c2, q2, q3)))
        ry2 = dr.clip((target - start) / dr.maximum(width, 1e-30), 0.0, 1.0)
        fx = dr.select(hi_x, dr.safe_sqrt(rx), 1.0 - dr.safe_sqrt(1.0 - rx))   # density 2x or 2(1 - x)
        fy = dr.select(hi_y, dr.safe_sqrt(ry2), 1.0 - dr.safe_sqrt(1.0 - ry2))
        return mi.Point2f((mi.Float(x0) + fx) * (1.0 / n1), (mi.Float(y0) + fy) * (1.0 / n1))

    def sample(self, s, active):
        """``s`` (Point2f in [0, 1)²) -> u (Vector2f) with density :meth:`pdf`."""
        tb = self.near
        p01 = self._sample_cell(s, active)
        tx, ty = tb["lo"] + p01.x * tb["span"], tb["lo"] + p01.y * tb["span"]
        if self.warp == 0.0:
            return mi.Vector2f(tx, ty)
        inv_c = 1.0 / self.warp        # u = t / (1 - |t|/c)
        return mi.Vector2f(tx / (1.0 - dr.abs(tx) * inv_c), ty / (1.0 - dr.abs(ty) * inv_c))
