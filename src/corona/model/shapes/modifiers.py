"""Modifiers and ensembles of shapes: soft edge, random orientation, size distribution, mixture."""
from __future__ import annotations

import math
import os
from functools import reduce

import numpy as np
import scipy   # scipy.special: loaded on first use (scipy imports its submodules lazily)

from corona._validation import CoronaError, check_choice, check_range
from corona.model.shapes.base import (_ORIENTATION_MAX_POINTS, _TWO_PI, Shape, Term, _check_int, _check_shape, _groups,
                   _orientation_average, _q_array, _radial_array)


class Modifier(Shape):
    """A shape made from one other shape, ``self.shape``.

    The geometry (area, length scale, exclusion diameter, self-overlap,
    symmetry) is that of ``shape`` unless a subclass says otherwise.
    """

    def __init__(self, shape: Shape):
        self.shape = _check_shape("shape", shape)

    @property
    def isotropic(self) -> bool:
        return self.shape.isotropic

    @property
    def _symmetry(self):
        return self.shape._symmetry

    @property
    def _deterministic(self):
        return self.shape._deterministic

    @property
    def _support(self):
        return self.shape._support

    @property
    def _cost(self):
        return self.shape._cost

    @property
    def area(self) -> float:
        return self.shape.area

    @property
    def length_scale(self) -> float:
        return self.shape.length_scale

    @property
    def exclusion_diameter(self) -> float:
        return self.shape.exclusion_diameter

    @property
    def self_overlap(self) -> float:
        return self.shape.self_overlap

    def _overlap_sum(self, widths, coeffs) -> float:
        return self.shape._overlap_sum(widths, coeffs)


class SoftEdge(Modifier):
    """A shape whose profile is blurred by a normalised Gaussian.

    ``A = B * G_w`` with ``G_w(x) = exp(-|x|²/2w²)/(2πw²)``, so values stay in
    [0, 1], ``∫A = ∫B`` and

        ``Â(q) = B̂(q) · exp(-|q|² w² / 2)``,  ``form_factor = F_B · exp(-|q|² w²)``.

    The lobe integrates to ``self_overlap = ∫A²/∫A < 1`` (not 1): the soft
    edge removes energy from the diffraction.  ``self_overlap`` is evaluated
    in closed form for circles (covariogram integral) and rectangles (erf),
    on the FFT grid for masks, and by Parseval on the form factor otherwise.
    For small w, ``self_overlap ≈ 1 - w P / (√π |B|)`` (P the perimeter).

    Parameters
    ----------
    shape : Shape
        The sharp profile B (any shape, also random ones).
    edge_width : float
        Gaussian standard deviation w >= 0 [µm].

    Notes
    -----
    ``length_scale`` and ``exclusion_diameter`` are those of ``shape`` (the
    blur tail extends a few w beyond).

    References
    ----------
    W. Ruland, "Small-angle scattering of two-phase systems: determination
    and significance of systematic deviations from Porod's law",
    J. Appl. Cryst. 4, 70–73 (1971) (Gaussian-smoothed interfaces).
    """

    def __init__(self, shape: Shape, edge_width: float):
        super().__init__(shape)
        self.edge_width = check_range("edge_width", edge_width, 0.0, math.inf, unit="µm")
        self._so = None

    def __repr__(self):
        return f"SoftEdge({self.shape!r}, edge_width={self.edge_width:g})"

    @property
    def self_overlap(self) -> float:
        if self._so is None:

            self._so = self.shape._blurred_overlap(self.edge_width) / self.shape.area
        return self._so

    def _overlap_sum(self, widths, coeffs) -> float:
        return self.shape._overlap_sum(np.hypot(self.edge_width, np.asarray(widths, float)), coeffs)

    def _gauss(self, q2):
        return np.exp(-0.5 * q2 * self.edge_width**2)

    def _both(self, q):
        q = _q_array(q)
        g = self._gauss(q[..., 0] ** 2 + q[..., 1] ** 2)
        i, a = self.shape._both(q)
        return i * g * g, a * g

    def _both_radial(self, q_abs):
        q_abs = _radial_array(q_abs)
        g = self._gauss(q_abs**2)
        i, a = self.shape._both_radial(q_abs)
        return i * g * g, a * g

    def kernel_terms(self):
        """The inner shape's kernel terms with the Gaussian edge (``blur``), or None."""
        inner = self.shape.kernel_terms()
        if inner is None:
            return None
        return [Term(t.kind, t.params, t.weight, t.area, math.hypot(t.blur, self.edge_width), shape=t.shape)
                for t in inner]

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.shape.amplitude(q) * self._gauss(q[..., 0] ** 2 + q[..., 1] ** 2)

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.shape.form_factor(q) * self._gauss(q[..., 0] ** 2 + q[..., 1] ** 2) ** 2

    def coherent_form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return (self.shape.coherent_form_factor(q)
                * self._gauss(q[..., 0] ** 2 + q[..., 1] ** 2) ** 2)

    def amplitude_radial(self, q_abs) -> np.ndarray:
        q_abs = _radial_array(q_abs)
        return self.shape.amplitude_radial(q_abs) * self._gauss(q_abs**2)

    def form_factor_radial(self, q_abs) -> np.ndarray:
        q_abs = _radial_array(q_abs)
        return self.shape.form_factor_radial(q_abs) * self._gauss(q_abs**2) ** 2

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        q_abs = _radial_array(q_abs)
        return self.shape.coherent_form_factor_radial(q_abs) * self._gauss(q_abs**2) ** 2


class RandomOrientation(Modifier):
    """A shape in uniformly random orientation (isotropic).

        ``⟨|Â|²⟩(|q|) = (1/2π) ∫ |Â(R_φ q)|² dφ``,  ``⟨Â⟩(|q|) = (1/2π) ∫ Â(R_φ q) dφ``.

    Both are computed by the trapezoidal rule in φ, which converges
    spectrally for these periodic integrands.  Â(R_φ q) has angular harmonics
    up to order ≈ |q| R (R the circumradius) and |Â|² up to 2|q| R, so
    ``N = ⌈(2.2 |q| R + 24)/m⌉`` (rounded up to a multiple of 8) angles over one
    symmetry period ``2π/m`` are used, m the order of the shape's rotational
    symmetry (4 for a square, n for a regular n-gon, 2 for rectangles and
    ellipses, 1 otherwise).  For size distributions R is the radius of the
    1 - 1e-10 quantile of the ``s⁴``-weighted sizes.

    Parameters
    ----------
    shape : Shape
        The profile to rotate (an isotropic shape is returned unchanged in
        value).

    Notes
    -----
    ``area``, ``length_scale``, ``exclusion_diameter`` and ``self_overlap``
    are those of ``shape``.

    References
    ----------
    J. S. Pedersen, "Analysis of small-angle scattering data from colloids and
    polymer solutions: modeling and least-squares fitting",
    Adv. Colloid Interface Sci. 70, 171–210 (1997).
    """

    isotropic = True
    _symmetry = 0
    _deterministic = False
    _MAX_POINTS = _ORIENTATION_MAX_POINTS

    def __repr__(self):
        return f"RandomOrientation({self.shape!r})"

    def _average(self, q_abs):
        """(⟨|Â|²⟩, ⟨Â⟩) at ``|q|`` (any shape)."""
        return _orientation_average(self.shape, q_abs, self._MAX_POINTS)

    def _intensity_radial(self, q_abs):
        base = self.shape
        if base.isotropic:
            return base._intensity_radial(q_abs)
        return self._average(q_abs)[0]

    def _intensity(self, q):
        q = _q_array(q)
        return self._intensity_radial(np.hypot(q[..., 0], q[..., 1]))

    def _both_radial(self, q_abs):
        return self._average(q_abs)

    def _both(self, q):
        q = _q_array(q)
        return self._average(np.hypot(q[..., 0], q[..., 1]))

    def amplitude_radial(self, q_abs) -> np.ndarray:
        if self.shape.isotropic:
            return self.shape.amplitude_radial(q_abs)
        return self._average(q_abs)[1]

    def form_factor_radial(self, q_abs) -> np.ndarray:
        return self._intensity_radial(q_abs) / self.area

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        return np.abs(self.amplitude_radial(q_abs)) ** 2 / self.area

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.amplitude_radial(np.hypot(q[..., 0], q[..., 1]))

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.form_factor_radial(np.hypot(q[..., 0], q[..., 1]))

    def coherent_form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.coherent_form_factor_radial(np.hypot(q[..., 0], q[..., 1]))


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):   # pragma: no cover - not Linux
        return os.cpu_count() or 1


class SizeDistribution(Modifier):
    """A shape with a random scale factor s (number-weighted, mean 1, relative std ``spread``).

    The scaled profile ``A_s(x) = A(x/s)`` has ``Â_s(q) = s² Â(s q)`` and
    ``|A_s| = s² |A|``, so

        ``⟨|Â|²⟩ = ∫ p(s) s⁴ |Â(s q)|² ds``,  ``⟨Â⟩ = ∫ p(s) s² Â(s q) ds``,
        ``⟨|A|⟩ = |A| ⟨s²⟩``.

    Distributions of s (mean 1, std ``spread``):

    * ``"lognormal"``: ``ln s ~ N(μ, σ²)``, ``σ² = ln(1 + spread²)``, ``μ = -σ²/2``;
    * ``"schulz"`` (gamma): ``p(s) = k^k s^{k-1} e^{-ks} / Γ(k)``, ``k = 1/spread²``.

    Quadrature: the trapezoidal rule in ``y = ln s`` over the range holding
    all but 1e-16 of the number-weighted distribution below and 1e-10 of the
    ``s⁴``-weighted one above (the largest sizes set the cost), which is
    spectrally accurate for these smooth, rapidly decaying integrands (it is
    the Gauss rule's equal for Gaussian weights and, unlike a fixed Gauss
    rule, can be refined).  The step is smooth in y and resolves both the
    distribution (``≤ σ_y/2.5``, σ_y the std of ln s) and the oscillation of
    ``Â(s q)`` in s (``≤ π/(2.2 q R s)`` up to the 1 - 1e-7 quantile of ``s p(s)``,
    R = ``length_scale``), so the number of nodes grows with ``q R · spread``
    above the minimum ``n_nodes``.  Radial averages of many ``|q|`` (a lobe
    table) are computed at 16 points per σ_y of a log grid in ``|q|`` and
    interpolated by cubic splines: in ``ln|q|`` the size average is a blur of
    width σ_y, so it is smooth on that scale (``_average_radial``; agreement
    with the quadrature at every point to 1e-6, tests/robustness/test_adversarial.py).

    Parameters
    ----------
    shape : Shape
        The mean shape (s = 1).
    spread : float
        Relative standard deviation of s, in [0, 1]; 0 gives ``shape``.
    distribution : {"lognormal", "schulz"}
    n_nodes : int, default 64
        Minimum number of quadrature nodes (8 … 100000).

    Notes
    -----
    ``length_scale``, ``exclusion_diameter`` and ``self_overlap`` are those of
    the mean shape (s = 1): the tables stay in u = q R of the mean particle,
    and a hard-core process built on ``exclusion_diameter`` lets the largest
    particles overlap slightly — pass an explicit diameter to the process if
    that matters.

    References
    ----------
    M. Kotlarchyk, S.-H. Chen, "Analysis of small angle neutron scattering
    spectra from polydisperse interacting colloids", J. Chem. Phys. 79,
    2461–2469 (1983); Pedersen, Adv. Colloid Interface Sci. 70, 171 (1997).

    Examples
    --------
    Lognormal circles, spread 0.2: ``⟨|A|⟩ = π R² ⟨s²⟩ = π R² (1 + spread²)``,
    and in the forward direction the coherent part is ``C(0)/P(0) =
    ⟨s²⟩² / ⟨s⁴⟩ = (1 + spread²)⁻⁴`` (moments ``⟨sⁿ⟩ = e^{nμ + n²σ²/2}``):

    >>> import numpy as np, corona
    >>> sd = corona.SizeDistribution(corona.Circle(radius=1.0), spread=0.2)
    >>> round(sd.area / np.pi, 6)
    1.04
    >>> ratio = sd.coherent_form_factor_radial(0.0) / sd.form_factor_radial(0.0)
    >>> round(float(ratio), 6), round(1.04 ** -4, 6)
    (0.854804, 0.854804)
    """

    _deterministic = False
    _MAX_POINTS = 4_000_000
    _RES_SIGMA = 2.5   # y step <= σ_y / _RES_SIGMA
    _RES_OSC = 2.2     # y step <= π / (_RES_OSC q R s)
    _LOG_GRID_PER_SIGMA = 16   # radial: log-grid points per σ_y (see _average_radial)
    _DIRECT_U = 1.0            # radial: |q| R below this is computed directly
    _THREADED_TERMS = 1 << 24  # (points x nodes) above which the quadrature runs on every core

    def __init__(self, shape: Shape, spread: float, distribution: str = "lognormal",
                 n_nodes: int = 64):
        super().__init__(shape)
        self.spread = check_range("spread", spread, 0.0, 1.0)
        self.distribution = check_choice("distribution", distribution, ("lognormal", "schulz"))
        self.n_nodes = _check_int("n_nodes", n_nodes, 8, 100_000)
        self._nodes_cache = {}
        self._setup()

    def __repr__(self):
        return (f"SizeDistribution({self.shape!r}, spread={self.spread:g}, "
                f"distribution={self.distribution!r}, n_nodes={self.n_nodes})")

    # --- distribution ------------------------------------------------------
    def _setup(self):
        sp = self.spread
        if sp == 0.0:
            self._m2 = self._m4 = 1.0
            self._s_big = 1.0
            return
        if self.distribution == "lognormal":
            s2 = math.log1p(sp * sp)
            sig = math.sqrt(s2)
            mu = -0.5 * s2
            self._sig_y = sig
            z16 = 8.3  # Φ(-8.3) ≈ 5e-17
            self._y_lo = mu - z16 * sig
            self._y_hi = mu + 4 * s2 + 6.4 * sig               # 1 - 1e-10 of s⁴ p(s)
            self._s_top = math.exp(mu + s2 + 5.3 * sig)        # 1 - 1e-7 of s p(s)
            self._s_big = math.exp(self._y_hi)
            self._m2 = math.exp(2 * mu + 2 * s2)
            self._m4 = math.exp(4 * mu + 8 * s2)
            self._logpdf = lambda y: (-0.5 * ((y - mu) / sig) ** 2
                                      - math.log(sig * math.sqrt(_TWO_PI)))
        else:
            from scipy import stats
            k = 1.0 / (sp * sp)
            self._sig_y = math.sqrt(float(scipy.special.polygamma(1, k)))
            g = stats.gamma(k, scale=1.0 / k)
            g4 = stats.gamma(k + 4.0, scale=1.0 / k)
            g1 = stats.gamma(k + 1.0, scale=1.0 / k)
            self._y_lo = math.log(g.ppf(1e-17))
            self._s_big = float(g4.isf(1e-10))
            self._y_hi = math.log(self._s_big)
            self._s_top = float(g1.isf(1e-7))
            self._m2 = (k + 1.0) / k
            self._m4 = (k + 1.0) * (k + 2.0) * (k + 3.0) / k**3
            # log of k^k s^k e^{-ks} / Γ(k) in y = ln s, without the cancellation of
            # k ln k - lnΓ(k) + k y - k e^y at large k (tiny spreads): Stirling's
            # lnΓ(k) = (k - ½) ln k - k + ½ ln 2π + r(k) gives ½ ln(k/2π) - r(k) - k (e^y - 1 - y)
            r = (math.lgamma(k) - ((k - 0.5) * math.log(k) - k + 0.5 * math.log(_TWO_PI))
                 if k < 1e7 else 1.0 / (12.0 * k) - 1.0 / (360.0 * k**3))
            c0 = 0.5 * math.log(k / _TWO_PI) - r

            def logpdf(y):
                y = np.asarray(y, dtype=np.float64)
                small = np.abs(y) < 1e-4
                em1my = np.where(small, y * y * (0.5 + y * (1 / 6 + y * (1 / 24 + y / 120))),
                                 np.expm1(y) - y)                     # e^y - 1 - y
                return c0 - k * em1my
            self._logpdf = logpdf

    def _nodes(self, q_max: float):
        """Nodes s_j and weights (Σ = 1) resolving ``Â(s q)`` for ``|q| <= q_max``."""
        if self.spread == 0.0 or not self._y_hi > self._y_lo:   # (a spread below float resolution)
            return np.ones(1), np.ones(1)
        h1 = self._sig_y / self._RES_SIGMA
        c = self._RES_OSC * q_max * self.shape._support / np.pi
        st = self._s_top
        # smooth map t(y) with dt/dy = 1/h1 + c·e^y s_top/(e^y + s_top); nodes at unit t steps
        def t_of(y):
            return y / h1 + c * st * np.logaddexp(y, math.log(st))
        t_lo, t_hi = float(t_of(self._y_lo)), float(t_of(self._y_hi))
        n = max(self.n_nodes, int(math.ceil(t_hi - t_lo)) + 1)
        key = n
        if key in self._nodes_cache:
            return self._nodes_cache[key]
        t = np.linspace(t_lo, t_hi, n)
        dt = (t_hi - t_lo) / (n - 1)
        ygrid = np.linspace(self._y_lo, self._y_hi, 4 * n + 64)
        y = np.interp(t, t_of(ygrid), ygrid)
        for _ in range(6):   # Newton polish of t(y) = t
            es = np.exp(y)
            dty = 1.0 / h1 + c * es * st / (es + st)
            y = np.clip(y - (t_of(y) - t) / dty, self._y_lo - 1.0, self._y_hi + 1.0)
        es = np.exp(y)
        dty = 1.0 / h1 + c * es * st / (es + st)
        w = np.exp(self._logpdf(y)) * dt / dty
        w[0] *= 0.5
        w[-1] *= 0.5
        keep = w > 1e-18 * w.max()
        s, w = es[keep], w[keep]
        w = w / w.sum()
        if len(self._nodes_cache) > 64:
            self._nodes_cache.clear()
        self._nodes_cache[key] = (s, w)
        return s, w

    def _levels(self, qa: np.ndarray) -> np.ndarray:
        """Group |q| into levels of node count (geometric steps of 1.25 in q R)."""
        u = qa * self.shape.length_scale
        return np.where(u < 1.0, 0, np.ceil(np.log(np.maximum(u, 1.0)) / math.log(1.25)) + 1
                        ).astype(np.int64)

    def _level_qmax(self, level: int) -> float:
        if level == 0:
            return 1.0 / self.shape.length_scale
        return 1.25 ** (level - 1) / self.shape.length_scale

    def _average(self, q, radial: bool):
        """(⟨|Â|²⟩, ⟨Â⟩) at q (..., 2) or |q| (radial)."""
        if radial:
            qa = np.abs(_radial_array(q))
            I, A = self._average_radial(qa.ravel())
            return I.reshape(qa.shape), A.reshape(qa.shape)
        return self._average_direct(q, radial=False)

    def _average_radial(self, qa: np.ndarray):
        """(⟨|Â|²⟩, ⟨Â⟩) at ``|q|`` (flat): on a log grid and interpolated where that is cheaper.

        In ``x = ln|q|`` and ``y = ln s`` the size average is a correlation,
        ``⟨|Â|²⟩(x) = ∫ K(y) |Â|²(e^{x+y}) dy`` with ``K(y) = p(e^y) e^{5y}``
        (``e^{3y}`` for ⟨Â⟩), a kernel of width σ_y: the average is smooth in x
        on that scale whatever the shape (a Gaussian blur for the lognormal), so
        it is computed exactly at ``_LOG_GRID_PER_SIGMA`` points per σ_y and
        interpolated by cubic splines in x (error ~ (h ω)⁴/384 on components
        that the kernel damps by exp(-σ_y² ω²/2): below 1e-7 of the local
        value).  Points with ``|q| R < _DIRECT_U`` (and every point when the
        grid would be the larger set) are computed directly.
        """
        from scipy.interpolate import CubicSpline
        inten = np.empty(qa.shape)
        amp = np.empty(qa.shape, dtype=np.complex128)
        R = self.shape.length_scale
        rest = (qa * R >= self._DIRECT_U) if self.spread > 0 else np.zeros(qa.shape, bool)
        if np.any(rest):
            x = np.log(qa[rest])
            h = self._sig_y / self._LOG_GRID_PER_SIGMA
            pad = 3
            # cells of the log grid (inf for a spread so small that σ_y underflows the step)
            cells = (x.max() - x.min()) / h
            n_grid = int(math.ceil(cells)) + 1 + 2 * pad if math.isfinite(cells) else None
            if n_grid is not None and 4 * n_grid < x.size:
                xg = x.min() + h * (np.arange(n_grid) - pad)
                Ig, Ag = self._average_direct(np.exp(xg), radial=True)
                inten[rest] = CubicSpline(xg, Ig)(x)
                amp[rest] = CubicSpline(xg, Ag.real)(x) + 1j * CubicSpline(xg, Ag.imag)(x)
            else:
                rest[:] = False
        if not np.all(rest):
            inten[~rest], amp[~rest] = self._average_direct(qa[~rest], radial=True)
        return inten, amp

    def _average_direct(self, q, radial: bool):
        """(⟨|Â|²⟩, ⟨Â⟩) at q (..., 2) or |q| (radial), by the quadrature in s at each point."""
        base = self.shape
        if radial:
            qa = np.abs(_radial_array(q))
            flat = qa.ravel()
            qn = flat
            out_shape = qa.shape
        else:
            q = _q_array(q)
            out_shape = q.shape[:-1]
            flat = q.reshape(-1, 2)
            qn = np.hypot(flat[:, 0], flat[:, 1])
        inten = np.empty(qn.shape)
        amp = np.empty(qn.shape, dtype=np.complex128)
        tasks = []
        for lev, idx in _groups(self._levels(qn)):
            s, w = self._nodes(self._level_qmax(lev))
            step = max(1, self._MAX_POINTS // len(s))
            tasks += [(idx[a0:a0 + step], s, w) for a0 in range(0, len(idx), step)]

        def run(task):                    # disjoint slices of inten and amp: safe in threads
            sub, s, w = task
            if radial:
                I, A = base._both_radial(flat[sub, None] * s[None, :])
            else:
                I, A = base._both(flat[sub, None, :] * s[None, :, None])
            inten[sub] = (I * (w * s**4)[None, :]).sum(axis=1)
            amp[sub] = (A * (w * s**2)[None, :]).sum(axis=1)
        # large averages (a 2D lobe table: 1e8-1e9 terms) on every core: numpy's
        # transcendentals and sums release the GIL, so threads share the work
        threads = min(len(tasks), _cpus()) if sum(len(t[0]) * len(t[1]) for t in tasks) > self._THREADED_TERMS else 1
        if threads > 1:
            from concurrent.futures import ThreadPoolExecutor
            with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="corona-size-average") as pool:
                list(pool.map(run, tasks))
        else:
            for task in tasks:
                run(task)
        return inten.reshape(out_shape), amp.reshape(out_shape)

    # --- Shape interface -------------------------------------------------------
    @property
    def _support(self):
        return self.shape._support * self._s_big

    @property
    def area(self) -> float:
        return self.shape.area * self._m2

    def _overlap_sum(self, widths, coeffs) -> float:
        # ∫(A_s * G_w)² = s² ∫(A * G_{w/s})²
        s, p = self._nodes(1.0 / self.shape.length_scale)
        widths = np.asarray(widths, dtype=np.float64).ravel()
        coeffs = np.asarray(coeffs, dtype=np.float64).ravel()
        return self.shape._overlap_sum(np.outer(widths, 1.0 / s).ravel(),
                                       np.outer(coeffs, p * s**2).ravel())

    def _both(self, q):
        return self._average(q, radial=False)

    def _both_radial(self, q_abs):
        return self._average(q_abs, radial=True)

    def _intensity(self, q):
        return self._average(q, radial=False)[0]

    def _intensity_radial(self, q_abs):
        return self._average(q_abs, radial=True)[0]

    def kernel_terms(self):
        """The shape's kernel terms at zero spread; None for a true size average (the grid)."""
        return self.shape.kernel_terms() if self.spread == 0.0 else None

    def amplitude(self, q) -> np.ndarray:
        return self._average(q, radial=False)[1]

    def form_factor(self, q) -> np.ndarray:
        return self._average(q, radial=False)[0] / self.area

    def coherent_form_factor(self, q) -> np.ndarray:
        return np.abs(self.amplitude(q)) ** 2 / self.area

    def amplitude_radial(self, q_abs) -> np.ndarray:
        return self._average(q_abs, radial=True)[1]

    def form_factor_radial(self, q_abs) -> np.ndarray:
        return self._average(q_abs, radial=True)[0] / self.area

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        return np.abs(self.amplitude_radial(q_abs)) ** 2 / self.area


class Mixture(Shape):
    """A number-weighted mixture of scatterer types.

        ``⟨|Â|²⟩ = Σ w_i ⟨|Â_i|²⟩``,  ``⟨Â⟩ = Σ w_i ⟨Â_i⟩``,  ``⟨|A|⟩ = Σ w_i |A_i|``

    with the number weights normalised to ``Σ w_i = 1``.  With the decoupling
    approximation the layer's lobe is ``n [⟨|Â|²⟩ + |⟨Â⟩|² (S - 1)]``.

    Parameters
    ----------
    components : sequence of (Shape, float)
        Shapes and their number weights (>= 0, not all 0).

    Notes
    -----
    ``isotropic`` if all components are.  ``length_scale`` and
    ``exclusion_diameter`` are the maxima over the components (the tables
    use u = q R of the largest, and a hard-core process keeps even the
    largest apart).  ``self_overlap = Σ w_i |A_i| so_i / Σ w_i |A_i|``.

    References
    ----------
    Kotlarchyk & Chen, J. Chem. Phys. 79, 2461 (1983) (decoupling approximation).
    """

    _deterministic = False

    def __init__(self, components):
        try:
            comps = list(components)
        except TypeError:
            raise CoronaError("components must be a list of (shape, number_weight) pairs") from None
        if not comps:
            raise CoronaError("components is empty; expected at least one (shape, weight) pair")
        shapes, weights = [], []
        for i, c in enumerate(comps):
            try:
                sh, wt = c
            except (TypeError, ValueError):
                raise CoronaError(f"components[{i}]={c!r} is not a (shape, number_weight) pair") \
                    from None
            shapes.append(_check_shape(f"components[{i}] shape", sh))
            weights.append(check_range(f"components[{i}] weight", wt, 0.0, math.inf, hi_open=True))
        top = max(weights)
        if not top > 0.0:
            raise CoronaError("components: all number weights are 0; expected a positive sum")
        weights = [wt / top for wt in weights]      # relative to the largest: the sum stays finite
        total = sum(weights)
        self.components = [(sh, wt / total) for sh, wt in zip(shapes, weights)]

    def __repr__(self):
        inner = ", ".join(f"({sh!r}, {wt:g})" for sh, wt in self.components)
        return f"Mixture([{inner}])"

    @property
    def isotropic(self) -> bool:
        return all(sh.isotropic for sh, _ in self.components)

    @property
    def _symmetry(self):
        orders = [int(sh._symmetry) for sh, _ in self.components if not sh.isotropic]
        if not orders:
            return 0
        return max(1, reduce(math.gcd, orders))

    @property
    def _support(self):
        return max(sh._support for sh, _ in self.components)

    @property
    def _cost(self):
        return sum(sh._cost for sh, _ in self.components)

    @property
    def area(self) -> float:
        return float(sum(wt * sh.area for sh, wt in self.components))

    @property
    def length_scale(self) -> float:
        return max(sh.length_scale for sh, _ in self.components)

    @property
    def exclusion_diameter(self) -> float:
        return max(sh.exclusion_diameter for sh, _ in self.components)

    @property
    def self_overlap(self) -> float:
        return float(sum(wt * sh.self_overlap * sh.area for sh, wt in self.components)) / self.area

    def _overlap_sum(self, widths, coeffs) -> float:
        coeffs = np.asarray(coeffs, dtype=np.float64)
        return float(sum(sh._overlap_sum(widths, wt * coeffs) for sh, wt in self.components))

    def _intensity(self, q):
        return sum(wt * sh._intensity(q) for sh, wt in self.components)

    def _intensity_radial(self, q_abs):
        return sum(wt * sh._intensity_radial(q_abs) for sh, wt in self.components)

    def _both(self, q):
        I, A = 0.0, 0.0
        for sh, wt in self.components:
            i, a = sh._both(q)
            I, A = I + wt * i, A + wt * a
        return I, A

    def _both_radial(self, q_abs):
        I, A = 0.0, 0.0
        for sh, wt in self.components:
            i, a = sh._both_radial(q_abs)
            I, A = I + wt * i, A + wt * a
        return I, A

    def kernel_terms(self):
        """One kernel term per component outline (their number weights), or None."""
        out = []
        for sh, w in self.components:
            inner = sh.kernel_terms()
            if inner is None:
                return None
            out += [Term(t.kind, t.params, t.weight * w, t.area, t.blur, shape=t.shape) for t in inner if w > 0]
        return out

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        return sum(wt * sh.amplitude(q) for sh, wt in self.components)

    def amplitude_radial(self, q_abs) -> np.ndarray:
        q_abs = _radial_array(q_abs)
        return sum(wt * sh.amplitude_radial(q_abs) for sh, wt in self.components)

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self._intensity(q) / self.area

    def form_factor_radial(self, q_abs) -> np.ndarray:
        return self._intensity_radial(_radial_array(q_abs)) / self.area

    def coherent_form_factor(self, q) -> np.ndarray:
        return np.abs(self.amplitude(q)) ** 2 / self.area

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        return np.abs(self.amplitude_radial(q_abs)) ** 2 / self.area
