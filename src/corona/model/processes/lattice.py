"""Square and hexagonal lattices with Gaussian jitter."""
from __future__ import annotations

import math

import numpy as np

from corona._validation import CoronaError, check_choice, check_positive, check_range
from corona.model import registry
from corona.model.processes.base import Process


def _grid_axes(q):
    """``(xs, ys)`` when ``q`` (ny, nx, 2) is the tensor grid ``q[iy, ix] = (xs[ix], ys[iy])`` with
    both axes increasing (``np.meshgrid(xs, ys)``), else None."""
    if q.ndim != 3 or q.shape[0] < 2 or q.shape[1] < 2:
        return None
    xs, ys = q[0, :, 0], q[:, 0, 1]
    if not (np.all(np.diff(xs) > 0) and np.all(np.diff(ys) > 0)):
        return None
    if (q[..., 0] != xs).any() or (q[..., 1] != ys[:, None]).any():
        return None
    return xs, ys


class Lattice(Process):
    """Square or hexagonal lattice of centres with Gaussian jitter.

    Every centre is displaced from its lattice site ``R`` by an independent
    Gaussian of rms ``δ`` per axis (``jitter``).  Then

        S(q) = 1 - e^{-q²δ²} + e^{-q²δ²} (2π)² n Σ_{G≠0} δ²(q - G)

    (Debye–Waller factor ``e^{-q²δ²}``, reciprocal lattice vectors ``G`` with
    ``G·a_i ∈ 2πℤ``, number density ``n = 1 / cell area``; e.g. Ashcroft &
    Mermin, ch. 6 & App. N; Guinier, *X-ray diffraction*, ch. 7).  A Bragg
    delta cannot be rendered, so each is broadened into a normalised 2-D
    Gaussian of rms width ``w = √(2π) / D`` per axis, ``D = domain_size``
    (default 20 spacings): the peak keeps its integrated weight
    ``(2π)² n e^{-G²δ²}`` and its height equals the Laue peak height
    ``n D²`` of a ``D × D`` crystallite.  The forward (``G = 0``) peak is left
    out.  ``S → 0`` as ``q → 0`` (a lattice is hyperuniform).

    With ``orientation="random"`` (a powder of randomly rotated domains) the
    peaks are averaged over rotation into rings: ``S`` is radial,

        S(q) = 1 - e^{-q²δ²} + Σ_shells m (2π)² n e^{-G²δ²} / (2π|G|) · g_w(q - |G|)

    with shell multiplicity ``m`` and a 1-D normalised Gaussian ``g_w``.

    Parameters
    ----------
    kind : {"square", "hexagonal"}
        Lattice type; hexagonal has primitive vectors ``a(1, 0)``,
        ``a(1/2, √3/2)``.
    spacing : float
        Nearest-neighbour distance ``a`` [µm].
    jitter : float, default 0
        rms displacement per axis ``δ`` [µm].
    domain_size : float or None
        Crystallite size ``D`` [µm] setting the peak width; None → 20·spacing.
    orientation : {"fixed", "random"}
        Fixed lattice (anisotropic ``S``) or powder average (radial ``S``).
    angle : float, default 0
        Rotation of the fixed lattice [degree], counter-clockwise (as the
        ``angle`` of :mod:`corona.model.shapes` and of the plugin).
    """

    def __init__(self, kind: str = "square", spacing: float = 1.0, jitter: float = 0.0,
                 domain_size: float | None = None, orientation: str = "fixed", angle: float = 0.0):
        self.kind = check_choice("kind", kind, ("square", "hexagonal"))
        self.spacing = check_positive("spacing", spacing, "µm")
        self.jitter = check_range("jitter", jitter, 0.0, math.inf, hi_open=True, unit="µm")
        if domain_size is None:
            domain_size = 20.0 * self.spacing
        self.domain_size = check_range("domain_size", domain_size, self.spacing, math.inf,
                                       lo_open=True, hi_open=True, unit="µm")
        self.orientation = check_choice("orientation", orientation, ("fixed", "random"))
        self.angle = check_range("angle", angle, -math.inf, math.inf, lo_open=True, hi_open=True,
                                 unit="degree")

    def __repr__(self):
        return (f"Lattice(kind={self.kind!r}, spacing={self.spacing:g}, jitter={self.jitter:g}, "
                f"domain_size={self.domain_size:g}, orientation={self.orientation!r}, "
                f"angle={self.angle:g})")

    @property
    def isotropic(self) -> bool:
        return self.orientation == "random"

    # --- geometry ------------------------------------------------------
    @property
    def lattice_vectors(self) -> np.ndarray:
        """Primitive vectors ``a_1, a_2`` as rows [µm] (rotated by ``angle``)."""
        a = self.spacing
        A = (np.array([[a, 0.0], [0.0, a]]) if self.kind == "square"
             else np.array([[a, 0.0], [0.5 * a, 0.5 * np.sqrt(3.0) * a]]))
        c, s = np.cos(np.radians(self.angle)), np.sin(np.radians(self.angle))
        return A @ np.array([[c, s], [-s, c]])

    @property
    def reciprocal_vectors(self) -> np.ndarray:
        """Primitive reciprocal vectors ``b_1, b_2`` as rows [rad/µm]
        (``a_i · b_j = 2π δ_ij``)."""
        return 2.0 * np.pi * np.linalg.inv(self.lattice_vectors).T

    @property
    def cell_area(self) -> float:
        """Area of the primitive cell [µm²]: ``a²`` or ``(√3/2) a²``."""
        return float(abs(np.linalg.det(self.lattice_vectors)))

    @property
    def number_density(self) -> float:
        """``n = 1 / cell area`` [µm⁻²]."""
        return 1.0 / self.cell_area

    @property
    def peak_width(self) -> float:
        """rms width ``w = √(2π)/D`` [rad/µm] of a broadened Bragg peak (per axis)."""
        return np.sqrt(2.0 * np.pi) / self.domain_size

    def bragg_peaks(self, q_max: float):
        """Reciprocal lattice vectors ``0 < |G| <= q_max`` and their weights.

        Returns
        -------
        G : numpy.ndarray (M, 2)
            Peak positions [rad/µm].
        weight : numpy.ndarray (M,)
            Integrated weight ``(2π)² n e^{-G²δ²}`` [rad²/µm²] of each peak.
        """
        B = self.reciprocal_vectors
        bmin = min(np.linalg.norm(B[0]), np.linalg.norm(B[1]))
        hmax = int(np.ceil(q_max * self.spacing / (2.0 * np.pi) * 2.0)) + 2
        h = np.arange(-hmax, hmax + 1)
        hk = np.stack(np.meshgrid(h, h, indexing="ij"), -1).reshape(-1, 2)
        G = hk @ B
        g = np.hypot(G[:, 0], G[:, 1])
        keep = (g > 0.5 * bmin) & (g <= q_max)
        G, g = G[keep], g[keep]
        order = np.lexsort((np.arctan2(G[:, 1], G[:, 0]), g))
        G, g = G[order], g[order]
        return G, (2.0 * np.pi) ** 2 * self.number_density * np.exp(-(g * self.jitter) ** 2)

    # --- process interface ----------------------------------------------
    def area_fraction(self, shape) -> float:
        return shape.area / self.cell_area

    def validate(self, shape) -> None:
        sd = shape.exclusion_diameter
        if sd > self.spacing * (1.0 + 1e-12):
            raise CoronaError(f"Lattice: spacing={self.spacing:g} µm is out of range for this shape; "
                              f"expected >= its exclusion diameter {sd:g} µm (neighbours would overlap)")
        fa = self.area_fraction(shape)
        if fa >= 1.0:
            raise CoronaError(f"Lattice: area fraction |A|/cell area = {fa:.4g} is out of range; "
                              "expected < 1")

    def _background(self, q2):
        dw = np.exp(-q2 * self.jitter ** 2)
        return 1.0 - dw

    def structure_factor_at(self, q, shape=None) -> np.ndarray:
        """``S(q)`` at ``q`` [rad/µm] of shape (..., 2) (radial for random orientation)."""
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 0 or q.shape[-1] != 2:
            raise CoronaError(f"q must have shape (..., 2), got {q.shape}")
        if self.isotropic:
            return self.structure_factor_radial(np.hypot(q[..., 0], q[..., 1]), shape)
        q2 = q[..., 0] ** 2 + q[..., 1] ** 2
        out = self._background(q2)
        A = self.lattice_vectors
        B = self.reciprocal_vectors
        w = self.peak_width
        amp = (2.0 * np.pi) ** 2 * self.number_density / (2.0 * np.pi * w * w)
        # fractional reciprocal coordinates: q = f_1 b_1 + f_2 b_2, f_i = q·a_i / 2π
        f = q @ A.T / (2.0 * np.pi)
        f0 = np.rint(f)
        m = max(1, int(np.ceil(0.5 + 6.0 * w * self.spacing / (2.0 * np.pi))))
        for dh in range(-m, m + 1):
            for dk in range(-m, m + 1):
                hk = f0 + np.array([dh, dk], dtype=np.float64)
                G = hk @ B
                G2 = G[..., 0] ** 2 + G[..., 1] ** 2
                d2 = (q[..., 0] - G[..., 0]) ** 2 + (q[..., 1] - G[..., 1]) ** 2
                peak = amp * np.exp(-G2 * self.jitter ** 2) * np.exp(-0.5 * d2 / (w * w))
                peak = np.where((hk[..., 0] == 0) & (hk[..., 1] == 0), 0.0, peak)
                out = out + peak
        return out

    def structure_factor_cell_mean(self, q, cell: float, shape=None) -> np.ndarray:
        """Mean of ``S`` over square cells ``[q - cell/2, q + cell/2]²``.

        The broadened Bragg peaks (rms width :attr:`peak_width`) are often
        narrower than the cells of a 2-D table; sampling ``S`` at cell centres
        then misses or overweights them.  The cell mean is exact here: the
        peaks and the Debye–Waller factor are separable Gaussians, whose cell
        means are differences of error functions.  Tables built from it keep
        every peak's integrated weight.

        Parameters
        ----------
        q : array_like (..., 2)
            Cell centres [rad/µm] (axes of the layer frame).
        cell : float
            Cell side [rad/µm].
        """
        return self.background_cell_mean(q, cell) + self.bragg_cell_mean(q, cell)

    def _check_cells(self, q, cell):
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 0 or q.shape[-1] != 2:
            raise CoronaError(f"q must have shape (..., 2), got {q.shape}")
        c = check_positive("cell", cell, "rad/µm")
        if self.isotropic:
            raise CoronaError("Lattice: cell means are for orientation='fixed'")
        return q, c

    def background_cell_mean(self, q, cell: float) -> np.ndarray:
        """Cell mean of the diffuse background ``1 - e^{-q²δ²}`` (see :meth:`structure_factor_cell_mean`)."""
        from scipy.special import erf
        q, c = self._check_cells(q, cell)
        h, d = 0.5 * c, self.jitter
        axes = _grid_axes(q)

        def factor(x):
            # √π/(2δc) [erf((x+h)δ) - erf((x-h)δ)]; for (|x|+h)δ << 1 (a tiny
            # jitter, where the quotient is 0/0 in floating point) its series
            # e^{-δ²(x² + c²/12)}
            small = (np.abs(x) + h) * d < 1e-4
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                exact = np.sqrt(np.pi) / (2.0 * d * c) * (erf((x + h) * d) - erf((x - h) * d))
            return np.where(small, np.exp(-d * d * (x * x + c * c / 12.0)), exact)
        if d <= 0.0:
            return np.zeros(q.shape[:-1])
        if axes is not None:       # a tensor grid: the product of one factor per axis
            return 1.0 - factor(axes[1])[:, None] * factor(axes[0])[None, :]
        return 1.0 - factor(q[..., 0]) * factor(q[..., 1])

    #: above this many Bragg peaks per table cell their sum is taken as smooth
    PEAKS_PER_CELL_MAX = 16.0

    def bragg_cell_mean(self, q, cell: float, peak_factor=None) -> np.ndarray:
        """Cell mean of the Bragg peaks, each scaled by ``peak_factor(G)``.

        ``Σ_G f(G) W_G ⟨g_G⟩_cell`` with ``W_G = (2π)² n e^{-G²δ²}`` the peak's
        weight and ``g_G`` its unit Gaussian; ``peak_factor`` (default 1) maps
        peak positions (M, 2) [rad/µm] to factors (M,).  A table that
        multiplies each peak by the form factor at the peak itself (not at the
        cell centre) keeps the exact weight ``f(G) W_G`` of every peak.  Where
        the peaks outnumber the cells, the peaks of a cell share the factor at
        the cell's centre; above :attr:`PEAKS_PER_CELL_MAX` peaks per cell (a
        sparse lattice, small area fraction) their sum is the cell mean of its
        smooth envelope ``e^{-q²δ²}`` (the same total weight).
        """
        from scipy.special import erf
        q, c = self._check_cells(q, cell)
        h, d = 0.5 * c, self.jitter

        def mean_gauss_1d(x, centre, sig):  # cell mean of exp(-(x-centre)²/(2 sig²)) / (√(2π) sig)
            s2 = np.sqrt(2.0) * sig
            return 0.5 * (erf((x + h - centre) / s2) - erf((x - h - centre) / s2)) / c

        A = self.lattice_vectors
        B = self.reciprocal_vectors
        w = self.peak_width
        wt = (2.0 * np.pi) ** 2 * self.number_density
        if c * c > self.PEAKS_PER_CELL_MAX * abs(np.linalg.det(B)):
            # a sparse lattice: many peaks per cell, whose cell mean is that of
            # their smooth envelope e^{-q²δ²} (total weight kept), less the
            # q = 0 peak (the coherent beam, not part of S)
            axes = _grid_axes(q)
            centre = (mean_gauss_1d(axes[1], 0.0, w)[:, None] * mean_gauss_1d(axes[0], 0.0, w)[None, :]
                      if axes is not None else mean_gauss_1d(q[..., 0], 0.0, w) * mean_gauss_1d(q[..., 1], 0.0, w))
            out = 1.0 - self.background_cell_mean(q, c) - wt * centre
            if peak_factor is not None:
                out = out * np.asarray(peak_factor(q.reshape(-1, 2)), dtype=np.float64).reshape(q.shape[:-1])
            return np.maximum(out, 0.0)
        axes = _grid_axes(q)
        if axes is None:
            f0 = np.rint(q @ A.T / (2.0 * np.pi))
        else:   # the extremes of the nearest lattice indices sit at the grid's corners
            corners = np.array([[x, y] for x in (axes[0][0], axes[0][-1]) for y in (axes[1][0], axes[1][-1])])
            f0 = np.rint(corners @ A.T / (2.0 * np.pi))
        m = max(1, int(np.ceil(0.5 + (6.0 * w + h * np.sqrt(2.0)) * self.spacing / (2.0 * np.pi))))
        factor = centre_factor = None
        if peak_factor is not None and f0.size:
            # the factor on every reciprocal lattice point the cells can reach
            lo = f0.reshape(-1, 2).min(axis=0).astype(int) - m
            hi = f0.reshape(-1, 2).max(axis=0).astype(int) + m
            if np.prod(hi - lo + 1) <= max(q.size // 2, 1024):
                if axes is not None:
                    factor = True     # the grid path evaluates the factor on its own peaks
                else:
                    hh, kk = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1),
                                         indexing="ij")
                    G_all = np.stack([hh, kk], -1).reshape(-1, 2) @ B
                    factor = np.asarray(peak_factor(G_all), dtype=np.float64).reshape(hh.shape)
            else:
                # more peaks than cells: the many peaks of a cell share the factor at its centre
                centre_factor = np.asarray(peak_factor(q.reshape(-1, 2)), dtype=np.float64).reshape(q.shape[:-1])
        if axes is not None:
            out = self._bragg_on_grid(axes[0], axes[1], c, mean_gauss_1d,
                                      None if factor is None else (lambda G: peak_factor(G)))
            return out if centre_factor is None else out * centre_factor
        out = np.zeros(q.shape[:-1])
        for dh in range(-m, m + 1):
            for dk in range(-m, m + 1):
                hk = f0 + np.array([dh, dk], dtype=np.float64)
                G = hk @ B
                G2 = G[..., 0] ** 2 + G[..., 1] ** 2
                peak = (wt * np.exp(-G2 * d * d) * mean_gauss_1d(q[..., 0], G[..., 0], w)
                        * mean_gauss_1d(q[..., 1], G[..., 1], w))
                if factor is not None:
                    ih = hk[..., 0].astype(int) - lo[0]
                    ik = hk[..., 1].astype(int) - lo[1]
                    peak = peak * factor[ih, ik]
                out = out + np.where((hk[..., 0] == 0) & (hk[..., 1] == 0), 0.0, peak)
        return out if centre_factor is None else out * centre_factor

    #: Peaks whose cell means are summed in one block of :meth:`_bragg_on_grid`.
    _PEAK_BLOCK = 32768

    def _bragg_on_grid(self, xs, ys, c, mean_gauss_1d, peak_factor=None) -> np.ndarray:
        """The sum of :meth:`bragg_cell_mean` on the tensor grid ``(xs[ix], ys[iy])`` (both increasing).

        A peak's cell mean is the product of one 1-D cell mean per axis, which
        reaches ``8 w + c/2`` at most (beyond, ``erfc(4√2) ≈ 1e-15`` of its weight),
        so every peak adds a small outer product to the cells near it: the cost
        is that of the peaks, not of (cells × neighbouring peaks).
        """
        A, B = self.lattice_vectors, self.reciprocal_vectors
        w, d = self.peak_width, self.jitter
        wt = (2.0 * np.pi) ** 2 * self.number_density
        reach = 8.0 * w + 0.5 * c
        nx, ny = xs.size, ys.size
        corners = np.array([[x, y] for x in (xs[0] - reach, xs[-1] + reach)
                            for y in (ys[0] - reach, ys[-1] + reach)])
        f = corners @ A.T / (2.0 * np.pi)
        lo, hi = np.floor(f.min(axis=0)).astype(int), np.ceil(f.max(axis=0)).astype(int)
        out = np.zeros(ny * nx)
        hs = np.arange(lo[0], hi[0] + 1)
        per_row = hi[1] - lo[1] + 1
        rows = max(1, self._PEAK_BLOCK // per_row)
        for a in range(0, hs.size, rows):
            hh, kk = np.meshgrid(hs[a:a + rows], np.arange(lo[1], hi[1] + 1), indexing="ij")
            hk = np.stack([hh.ravel(), kk.ravel()], -1)
            hk = hk[np.any(hk != 0, axis=1)]               # the forward peak is not part of S
            G = hk.astype(np.float64) @ B
            ix0 = np.searchsorted(xs, G[:, 0] - reach, side="left")
            ix1 = np.searchsorted(xs, G[:, 0] + reach, side="right")
            iy0 = np.searchsorted(ys, G[:, 1] - reach, side="left")
            iy1 = np.searchsorted(ys, G[:, 1] + reach, side="right")
            keep = (ix1 > ix0) & (iy1 > iy0)
            if not np.any(keep):
                continue
            G, ix0, ix1, iy0, iy1 = G[keep], ix0[keep], ix1[keep], iy0[keep], iy1[keep]
            amp = wt * np.exp(-(G[:, 0] ** 2 + G[:, 1] ** 2) * d * d)
            if peak_factor is not None:
                amp = amp * np.asarray(peak_factor(G), dtype=np.float64)

            def one_axis(grid, g, i0, i1):
                idx = i0[:, None] + np.arange(int((i1 - i0).max()))[None, :]
                inside = idx < i1[:, None]
                idx = np.minimum(idx, grid.size - 1)
                return idx, np.where(inside, mean_gauss_1d(grid[idx], g[:, None], w), 0.0)
            jx, mx = one_axis(xs, G[:, 0], ix0, ix1)
            jy, my = one_axis(ys, G[:, 1], iy0, iy1)
            vals = (amp[:, None, None] * my[:, :, None]) * mx[:, None, :]
            flat = jy[:, :, None] * nx + jx[:, None, :]
            out += np.bincount(flat.ravel(), weights=vals.ravel(), minlength=ny * nx)
        return out.reshape(ny, nx)

    def structure_factor_radial(self, q_abs, shape=None) -> np.ndarray:
        """Powder-averaged ``S(|q|)`` (only for ``orientation="random"``)."""
        if not self.isotropic:
            raise CoronaError("Lattice: structure_factor_radial needs orientation='random'; "
                              "a fixed lattice is anisotropic, use structure_factor_at")
        q = np.abs(np.asarray(q_abs, dtype=np.float64))
        out = self._background(q * q)
        w = self.peak_width
        qmax = float(q.max()) if q.size else 0.0
        G, weight = self.bragg_peaks(qmax + 8.0 * w)
        if len(G) == 0:
            return out
        g = np.hypot(G[:, 0], G[:, 1])
        shells, inv = np.unique(np.round(g / self.spacing ** -1, 9), return_inverse=True)
        gs = np.zeros(len(shells))
        ws = np.zeros(len(shells))
        np.add.at(ws, inv, weight)
        np.add.at(gs, inv, g)
        counts = np.bincount(inv, minlength=len(shells))
        gs /= counts
        norm = 1.0 / (np.sqrt(2.0 * np.pi) * w)
        flat = q.reshape(-1)
        res = out.reshape(-1).copy()
        for gk, wk in zip(gs, ws):
            sel = np.abs(flat - gk) < 8.0 * w
            if np.any(sel):
                res[sel] += wk / (2.0 * np.pi * gk) * norm * np.exp(-0.5 * ((flat[sel] - gk) / w) ** 2)
        return res.reshape(q.shape)


# =====================================================================
# measured point sets
# =====================================================================


def _lattice_from(kind: str):
    """The factory of ``process=lattice-<kind>``: the spacing from the area fraction (cell area
    ``|A| / F_a``); neighbours at the shape's exclusion diameter σ give the largest F_a."""
    def factory(p, shape):
        fa, name = p["area_fraction"], f"lattice-{kind}"
        sd = shape.exclusion_diameter
        fmax = shape.area / (sd * sd) if kind == "square" else 2 * shape.area / (math.sqrt(3) * sd * sd)
        if fa > fmax * (1.0 + 1e-12):
            raise CoronaError(f"area_fraction={fa:g} is out of range for process={name!r} with this shape; "
                              f"allowed (0, {fmax:.4g}] (neighbours would overlap)")
        cell = shape.area / fa
        if kind == "square":
            return Lattice("square", math.sqrt(cell), jitter=p["jitter"])
        return Lattice("hexagonal", math.sqrt(2 * cell / math.sqrt(3)), jitter=p["jitter"])
    return factory


# --- the families (corona.model.registry): process=lattice-square, lattice-hex -------------------
registry.add_process(registry.ProcessFamily("lattice-square", _lattice_from("square"),
                                            ("area_fraction", "jitter"), cls=Lattice))
registry.add_process(registry.ProcessFamily("lattice-hex", _lattice_from("hex"),
                                            ("area_fraction", "jitter"), cls=Lattice))
