"""The renderer's rows and the checks of its lobe against the model.

What the plugin reads beyond one material's table: rows of the structure factor over the
area fraction for anisotropic shapes (:func:`structure_rows`, :func:`row_energy_changes`),
the slopes of Catmull–Rom rows (:func:`row_slopes`), and the points where the renderer's
lobe is checked against the exact one (:func:`region_points`, :func:`relative_error`).

The lobe as the renderer evaluates it (:class:`~corona.model.render_lobe.RenderLobe`, the
closed-form outlines, the B-spline grids) is :mod:`corona.model.render_lobe`; the table types
and the cache are :mod:`corona.model.tabulated`.
"""
from __future__ import annotations

import numpy as np

from corona.model.render_lobe import terms_amplitudes


def region_points(material, n: int = 100_000, frac: float = 1e-3, scan: int = 401, seed: int = 0):
    """Points where the renderer's lobe is checked against the model.

    Uniform points in the u plane over the part of the reachable disk
    (``|u| <= 2π R · 2 / 360 nm``: every ``|d| <= 2`` at every wavelength)
    where the exact lobe ``v`` (:meth:`corona.Material.lobe_dimensionless`)
    is at least ``frac`` times its peak.  The bounding box comes from a
    ``scan × scan`` grid of the exact lobe (at a fifth of the threshold, two
    cells of margin).  Returns ``u`` (m, 2) and the exact ``v`` there.
    """
    from corona.model import tabulated
    reach = 2 * np.pi * material.length_scale * tabulated.D_MAX / (tabulated.WAVELENGTH_MIN * 1e-3)
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
    through ``S`` (:mod:`corona.model.render_lobe`), so a layer whose ``F_a`` varies
    needs rows of the radial ``S - 1`` alone, on the step of
    :attr:`~corona.model.render_lobe.RenderLobe.s_du`.  The rows start at the process's tabulation nodes
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
    from corona.model import tabulated
    from corona.model.tabulated import ROW_TOLERANCE
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
        keys, worst = tabulated.bisect_rows(
            rows, lambda mids: [s_of(m) for m in mids],
            lambda lerp, e: np.max(np.abs(lerp - e) / np.maximum(e + 1.0, 1e-6)), tolerance, max_rows)
        return {"area_fraction": np.array(keys), "s_minus_one": np.stack([rows[k] for k in keys]),
                "error": np.array(worst)}

    arrays = tabulated.cached({**material.table_params(), "s_rows": [lo, hi], "tolerance": tolerance,
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
