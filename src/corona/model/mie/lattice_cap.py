"""The energy cap of spheres on a lattice: bounds of the lobes' energy for a renderer.

A layer of spheres on a fixed :class:`corona.Lattice` has the lobe
``Z = P (1 - e^{-q²δ²}) + P Σ_G W_G g_G(q)`` (docs/physics.md#spheres-on-a-lattice) and the cap
``w = min(1, (1 - |t|²) / (ENERGY_MARGIN F_s ē))``.  The energy ``e = ∫ Z dΩ`` depends on λ and
on ``wi`` (its azimuth too), and an order at grazing exit carries ``∝ 1/|cos θ_G|`` (a Rayleigh
anomaly, finite only through the peak's width): a table of ``e`` interpolated between nodes is no
bound there.  The orders are split by a linear partition of unity ``χ`` in ``ρ_G = |G λ/2π -
wi_xy|`` (:data:`CAP_NEAR`):

* **the far orders** (``ρ_G ≤ 1 - Δ``, :func:`far_energy`) in the narrow-peak limit, at the nodes
  of a grid in λ and ``wi_xy`` (``e`` is even in ``wi_z``), read trilinearly: smooth, but an
  interpolation, not a bound;
* **the near orders** (``ρ_G ≥ 1 - 2Δ``), a proven bound per cell of λ (``n_lam`` cells) and
  ``wi_xy`` (``n_near`` × ``n_near`` cells over [-1, 1]²), or per lane
  (:func:`near_bound_at`).  In ``p = wo_xy`` the order ``G`` is the unit
  Gaussian ``ĝ`` of rms ``ε = w/k`` about ``p_G = G λ/2π - wi_xy`` (``w`` the peak's rms width in
  q, :attr:`corona.Lattice.peak_width`), and ``dΩ = d²p / c``, ``c = (1 - |p|²)^½``, so

      e_G = (W_G / k²) ∫ ĝ(p - p_G) [P(wo↑) + P(wo↓)] / c  d²p
          ≤ (W_G / k²) [ P̄_G H̄_G + P_max 2.51 e^{-R²/2} / ε ]

  with ``P̄_G`` a bound of ``P(wo↑) + P(wo↓)`` over the directions within ``R ε`` of every
  ``p_G`` of the cell (``R`` = :data:`CAP_REACH`; the chords' ranges by interval arithmetic,
  the rows' nodes there by :func:`_range_max`, times 9/8: a Catmull–Rom cubic of non-negative
  nodes stays below ``(2 + f - f²)/2 ≤ 9/8`` of its interval's larger node), and ``H̄_G`` a bound of
  ``H = ∫ ĝ / c d²p``: ``|p|`` is Rice-distributed with density
  ``A(r) = (r/ε²) e^{-(r-ρ)²/2ε²} i0e(rρ/ε²)``, so for any split ``r₁ < 1``

      H ≤ c(r₁)⁻¹ Pr(|p| < r₁) + sup_{[r₁, 1]} A · arccos r₁,

  ``Pr(|p| < r₁) ≤ e^{-(ρ - r₁)²/2ε²}`` for ``ρ > r₁``, each factor bounded over the cell's
  ``ρ = |p_G|`` range (``ρ`` moves by at most ``|G| Δλ/4π`` + the ``wi_xy`` cell's half diagonal
  from the cell's centre) and ``ε`` range; the least over a few ``r₁``.  The last term is the
  Gaussian's tail beyond ``R ε`` with the largest ``P`` of the cell's rows.  Orders whose ``ρ``
  stays beyond ``1 + 2 R ε`` are left out (their share is below ``e^{-2R²}`` of one order's).
* **the diffuse part** ``P (1 - e^{-q²δ²})`` of a jittered lattice per row of x: since
  ``|q| ≤ k s`` (``s = |wo + wi|`` the forward chord) and the lane reads rows j, j+1 at
  ``σ = s x_row/x`` with weights ``(1 - t) (x/x_j)², t (x/x_j+1)²``, its energy is at most
  ``(1 - t) D_j + t D_j+1``, ``D_j = ∫ P_f,j(σ) (1 - e^{-(σ x_j δ/r)²}) 2πσ dσ + ∫ P_b,j 2πσ dσ``
  (``k/x = 1/r``): no λ or ``wi`` left.

Cells overlap by :data:`CAP_OVERLAP` of their width, so that float32 rounding of a lane's cell
index stays covered.  Neither the numpy model (which keeps its exact cap,
:meth:`corona.model.mie.material.SphereMaterial.lattice_energy` per lane) nor the renderer uses this
table: its bound is too loose to render with (docs/physics.md#spheres-on-a-lattice has the
measured figures, from ``benchmarks/lattice_cap.py``).  The renderer sums the orders per lane in
closed form instead (:func:`rim_rules`, :func:`order_energy`,
:class:`corona.mitsuba.sphere_lattice.LatticeCap`), with :func:`diffuse_rows_mu` for the
diffuse part.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import i0e

#: Gaussian reach [rms widths] of an order's window for the bound of ``P``.
CAP_REACH = 8.0
#: Table cells in λ, per axis of ``wi_xy`` for the far orders' nodes and for the near orders' cells.
CAP_LAMBDA_CELLS = 64
CAP_WI_CELLS = 32
CAP_NEAR_CELLS = 96
#: Orders with ``ρ_G = |G λ/2π - wi_xy|`` beyond ``1 - 2Δ`` are near grazing exit (bounded per cell),
#: those below ``1 - Δ`` far (tabulated at nodes); a linear partition of unity between.
CAP_NEAR = 0.05
#: Each cell's bound covers this fraction of its width beyond its edges.
CAP_OVERLAP = 1e-3
#: The Catmull–Rom cubic's largest excess over its interval's larger node (non-negative nodes).
CUBIC_EXCESS = 1.125

__all__ = ["CAP_LAMBDA_CELLS", "CAP_NEAR", "CAP_NEAR_CELLS", "CAP_WI_CELLS", "RIM_NODES", "RIM_U", "cap_energy", "cap_parts",
           "DIFFUSE_MU_NODES", "DIFFUSE_PHI", "diffuse_rows_mu", "order_energy", "rim_rules",
           "cap_table", "diffuse_bound_rows", "far_energy", "near_bound_at"]


def _sparse_max(values):
    """Levels of a sparse table of running maxima of ``values`` (K,): level l holds the maximum of
    ``values[i : i + 2^l]``."""
    levels = [np.asarray(values, dtype=np.float64)]
    n = levels[0].size
    step = 1
    while 2 * step <= n:
        prev = levels[-1]
        levels.append(np.maximum(prev[:-step], prev[step:]))
        step *= 2
    return levels


def _range_max(levels, lo, hi):
    """``max(values[lo : hi + 1])`` (inclusive, clipped to the array) for arrays of ``lo``, ``hi``;
    0 where the range is empty."""
    n = levels[0].size
    lo = np.clip(lo, 0, n - 1)
    hi_c = np.clip(hi, 0, n - 1)
    empty = (hi < 0) | (lo > hi_c)
    length = np.maximum(hi_c - lo + 1, 1)
    lv = np.minimum(np.floor(np.log2(length)).astype(np.int64), len(levels) - 1)
    out = np.zeros(np.shape(lo))
    for l in np.unique(lv):
        sel = lv == l
        arr = levels[l]
        a = lo[sel]
        b = np.maximum(hi_c[sel] - (1 << l) + 1, a)
        out[sel] = np.maximum(arr[np.minimum(a, arr.size - 1)], arr[np.minimum(b, arr.size - 1)])
    return np.where(empty, 0.0, out)


def _hypot_range(a_lo, a_hi, b_lo, b_hi):
    """Range of ``√(a² + b²)`` for ``a ∈ [a_lo, a_hi]``, ``b ∈ [b_lo, b_hi]`` (all ≥ 0)."""
    return np.hypot(a_lo, b_lo), np.hypot(a_hi, b_hi)


def _abs_diff_range(a_lo, a_hi, b_lo, b_hi):
    """Range of ``|a - b|`` for ``a ∈ [a_lo, a_hi]``, ``b ∈ [b_lo, b_hi]``."""
    lo = np.maximum(np.maximum(a_lo - b_hi, b_lo - a_hi), 0.0)
    hi = np.maximum(a_hi - b_lo, b_hi - a_lo)
    return lo, hi


def _h_bound(rho_lo, rho_hi, eps_lo, eps_hi):
    """A proven upper bound of ``H = ∫ ĝ(p - p_G) / (1 - |p|²)^½ d²p`` (over ``|p| < 1``) for every
    ``|p_G| ∈ [rho_lo, rho_hi]`` and rms ``ε ∈ [eps_lo, eps_hi]`` (see the module docstring)."""
    best = np.full(np.shape(rho_lo), np.inf)
    root = np.sqrt(eps_hi)
    cands = [rho_hi + CAP_REACH * eps_hi, rho_hi + 3.0 * eps_hi]
    cands += [1.0 - 0.5 * (f * root) ** 2 for f in (0.25, 0.5, 1.0, 2.0, 4.0)]
    cands += [1.0 - 0.5 * (f * eps_hi) ** 2 for f in (1.0, 4.0)]
    for r1 in cands:
        r1 = np.clip(r1, 0.0, 1.0 - 1e-15)
        inv_c = 1.0 / np.sqrt(1.0 - r1 * r1)
        gap = np.maximum(rho_lo - r1, 0.0)
        inner = inv_c * np.exp(-0.5 * (gap / eps_hi) ** 2)
        # sup of the Rice density over r ∈ [r1, 1], ρ ∈ [rho_lo, rho_hi], ε ∈ [eps_lo, eps_hi]
        dist = np.maximum(np.maximum(r1 - rho_hi, rho_lo - 1.0), 0.0)
        a_sup = (1.0 / eps_lo ** 2) * np.exp(-0.5 * (dist / eps_hi) ** 2) * i0e(r1 * rho_lo / eps_hi ** 2)
        best = np.minimum(best, inner + a_sup * np.arccos(r1))
    return best


def diffuse_bound_rows(rows: dict, radius: float, jitter: float, sub: int = 8) -> np.ndarray:
    """``D_j`` (J,): per row of x a bound of the diffuse part's energy (module docstring); 0 for a
    perfect crystal.  Integrated over the rows' Catmull–Rom cubics (as the lobe is read) with
    ``sub`` Gauss–Legendre nodes per interval (a polynomial of degree ≤ 5 times a smooth factor)."""
    P_f, P_b, x, ds = rows["P_f"], rows["P_b"], rows["x"], float(rows["ds"])
    J, K = P_f.shape
    if jitter <= 0.0:
        return np.zeros(J)
    from corona.model.mie.layer import catmull_rom
    xg, wg = np.polynomial.legendre.leggauss(sub)
    g = (np.arange(K - 1)[:, None] + 0.5 * (xg[None, :] + 1.0)).ravel()     # fractional nodes
    wq = np.tile(0.5 * wg, K - 1) * ds
    sigma = g * ds
    out = np.zeros(J)
    for j in range(J):
        rr = np.full(g.shape, j)
        vf = catmull_rom(P_f, rr, g)
        vb = catmull_rom(P_b, rr, g)
        damp = -np.expm1(-(sigma * x[j] * jitter / radius) ** 2)
        out[j] = np.sum((vf * damp + vb) * 2 * np.pi * sigma * wq)
    return out


def _chi(rho):
    """The far orders' share: 1 for ``ρ ≤ 1 - 2Δ``, 0 for ``ρ ≥ 1 - Δ``, linear between
    (``Δ`` = :data:`CAP_NEAR`)."""
    return np.clip((1.0 - CAP_NEAR - np.asarray(rho)) / CAP_NEAR, 0.0, 1.0)


def far_energy(material, wi_xy, wavelength: float) -> np.ndarray:
    """The far orders' energy ``Σ_G χ(ρ_G) (W_G/k²) [P(wo↑) + P(wo↓)] / c_G`` at ``wi_xy`` (N, 2)
    and one wavelength [nm], in the narrow-peak limit (``ρ_G ≤ 1 - Δ``, where ``1/c`` is smooth on
    the scale of the peak).  Points outside the unit disk are read on its rim."""
    s = np.atleast_2d(np.asarray(wi_xy, dtype=np.float64))
    r = np.hypot(s[:, 0], s[:, 1])
    s = s * np.minimum(1.0, (1.0 - 1e-6) / np.maximum(r, 1e-300))[:, None]
    ci = np.sqrt(np.maximum(1.0 - np.sum(s * s, axis=-1), 0.0))
    lam = float(wavelength)
    k = 2 * np.pi / (lam * 1e-3)
    G, W = material.lattice.bragg_peaks(2.0 * k)
    pc = G[None, :, :] / k - s[:, None, :]
    rho = np.hypot(pc[..., 0], pc[..., 1])
    chi = _chi(rho)
    n_i, g_i = np.nonzero(chi > 0)
    p = pc[n_i, g_i]
    co = np.sqrt(1.0 - rho[n_i, g_i] ** 2)
    wi = np.concatenate([s[n_i], ci[n_i, None]], axis=-1)
    e = 0.0
    for side in (1.0, -1.0):
        wo = np.concatenate([p, side * co[:, None]], axis=-1)
        P_f, P_b, fwd = material._mie_at(wi, wo, lam)
        e = e + np.where(fwd, P_f, P_b)
    e = e * chi[n_i, g_i] * W[g_i] / (k * k * co)
    return np.bincount(n_i, weights=e, minlength=s.shape[0])


def _far_nodes(material, lam_nodes, s_nodes):
    """:func:`far_energy` on the grid ``lam_nodes`` × ``s_nodes`` × ``s_nodes`` ([λ, y, x])."""
    sx, sy = np.meshgrid(s_nodes, s_nodes, indexing="xy")
    s = np.stack([sx.ravel(), sy.ravel()], -1)
    return np.stack([far_energy(material, s, lam) for lam in lam_nodes]).reshape(
        lam_nodes.size, s_nodes.size, s_nodes.size)


def _near_bound(material, sc, hs: float, l0: float, l1: float) -> np.ndarray:
    """Per cell of ``wi_xy`` (centres ``sc`` (N, 2), half diagonal ``hs``) and wavelengths
    ``[l0, l1]`` [µm]: a proven bound of the near orders' energy ``Σ_G (1 - χ(ρ_G)) e_G``
    (module docstring)."""
    lattice, rows, radius = material.lattice, material.rows, material.length_scale
    P_f, P_b, xr, ds = rows["P_f"], rows["P_b"], rows["x"], float(rows["ds"])
    J = P_f.shape[0]
    s_abs = np.hypot(sc[:, 0], sc[:, 1])
    s_min, s_max = np.clip(s_abs - hs, 0.0, 1.0), np.clip(s_abs + hs, 0.0, 1.0)
    inside = s_abs - hs < 1.0
    ci_lo, ci_hi = np.sqrt(1.0 - s_max ** 2), np.sqrt(1.0 - s_min ** 2)
    w = lattice.peak_width
    chord_top = math.sqrt(2.0)
    out = np.zeros(sc.shape[0])
    jrow = lambda xx: int(np.clip(np.searchsorted(xr, xx, side="right") - 1, 0, J - 2))
    lc = 0.5 * (l0 + l1)
    k_lo, k_hi = 2 * np.pi / l1, 2 * np.pi / l0
    x_lo, x_hi = radius * k_lo, radius * k_hi
    j0, j1 = jrow(x_lo), jrow(x_hi) + 1
    xrow_min, xrow_max = xr[j0], xr[j1]
    scale = CUBIC_EXCESS * (x_hi / xrow_min) ** 2
    lev_f = _sparse_max(P_f[j0:j1 + 1].max(axis=0))
    lev_b = _sparse_max(P_b[j0:j1 + 1].max(axis=0))
    p_glob = scale * max(lev_f[0].max(), lev_b[0].max())

    def lobe_max(levels, s_lo, s_hi):
        """Bound of the lane's P over lane chords [s_lo, s_hi] (the lobe is used up to √2)."""
        s_hi = np.minimum(s_hi, chord_top)
        use = s_lo <= s_hi
        lo = np.floor(np.minimum(s_lo, 4.0) * x_lo / (xrow_max * ds)).astype(np.int64)
        hi = np.floor(s_hi * x_hi / (xrow_min * ds)).astype(np.int64) + 1
        return np.where(use, scale * _range_max(levels, lo, hi), 0.0)

    eps_lo, eps_hi = w * l0 / (2 * np.pi), w * l1 / (2 * np.pi)
    rwin = CAP_REACH * eps_hi
    G, W = lattice.bragg_peaks(k_hi * (2.0 + 2.0 * rwin) + CAP_REACH * w)
    Gn = np.hypot(G[:, 0], G[:, 1])
    pc_all = G[None, :, :] * (lc / (2 * np.pi)) - sc[:, None, :]          # (cells, orders, 2)
    lip_all = np.broadcast_to(Gn[None, :] * (l1 - l0) / (4 * np.pi) + hs, pc_all.shape[:2])
    rc_all = np.hypot(pc_all[..., 0], pc_all[..., 1])
    near = 1.0 - _chi(rc_all + lip_all)                     # the near share's bound over the cell
    keep = (rc_all - lip_all < 1.0 + 2.0 * rwin) & inside[:, None] & (near > 0)
    n_i, g_i = np.nonzero(keep)
    if n_i.size == 0:
        return out
    Gb, Wb, Gnb = G[g_i], W[g_i], Gn[g_i]
    rc, lip, share = rc_all[n_i, g_i], lip_all[n_i, g_i], near[n_i, g_i]
    rho_lo, rho_hi = np.maximum(rc - lip, 0.0), rc + lip
    H = _h_bound(rho_lo, rho_hi, eps_lo, eps_hi)
    # the directions of the window: |p| range, then c_o = (1 - |p|²)^½
    p_lo = np.clip(rho_lo - rwin, 0.0, 1.0)
    p_hi = np.clip(rho_hi + rwin, 0.0, 1.0)
    co_lo, co_hi = np.sqrt(1.0 - p_hi ** 2), np.sqrt(1.0 - p_lo ** 2)
    cil, cih = ci_lo[n_i], ci_hi[n_i]
    # |wo + wi|_xy = |q|/k and |wo - wi|_xy = |G λ/2π - 2 wi_xy + δ|
    qk_lo = np.maximum(Gnb * l0 / (2 * np.pi) - rwin, 0.0)
    qk_hi = Gnb * l1 / (2 * np.pi) + rwin
    pm = Gb * (lc / (2 * np.pi)) - 2.0 * sc[n_i]
    pm_c = np.hypot(pm[:, 0], pm[:, 1])
    pm_r = Gnb * (l1 - l0) / (4 * np.pi) + 2.0 * hs + rwin
    pm_lo, pm_hi = np.maximum(pm_c - pm_r, 0.0), pm_c + pm_r
    dlo, dhi = _abs_diff_range(cil, cih, co_lo, co_hi)       # |c_i - c_o|
    slo, shi = cil + co_lo, cih + co_hi                         # c_i + c_o
    # transmitted: s_f² = (q/k)² + (c_i - c_o)², s_b² = |p - s|² + (c_i + c_o)²
    # reflected:   s_f² = (q/k)² + (c_i + c_o)², s_b² = |p - s|² + (c_o - c_i)²
    P_sum = np.zeros_like(rc)
    for (fa, fb), (ba, bb) in (((dlo, dhi), (slo, shi)), ((slo, shi), (dlo, dhi))):
        f_lo, f_hi = _hypot_range(qk_lo, qk_hi, fa, fb)
        b_lo, b_hi = _hypot_range(pm_lo, pm_hi, ba, bb)
        P_sum += np.maximum(lobe_max(lev_f, f_lo, f_hi), lobe_max(lev_b, b_lo, b_hi))
    tail = p_glob * 2.0 * 2.51 * math.exp(-0.5 * CAP_REACH ** 2) / eps_lo
    e = share * (Wb / k_lo ** 2) * (P_sum * H + tail)
    return np.bincount(n_i, weights=e, minlength=sc.shape[0])


def cap_table(material, lam_range=(360.0, 830.0), n_lam: int = CAP_LAMBDA_CELLS,
              n_s: int = CAP_WI_CELLS, n_near: int = CAP_NEAR_CELLS) -> dict:
    """The cap's table of the orders' energy (module docstring): ``far`` at the nodes of a grid in
    (λ, ``wi_xy``), read trilinearly, and ``near``, per cell, a proven bound of the orders near
    grazing exit.

    Parameters
    ----------
    material : corona.model.mie.material.SphereMaterial
        On a fixed lattice (its ``lattice``, ``rows`` and radius ``length_scale``).
    lam_range : (float, float)
        Wavelengths [nm] the table covers.

    Returns
    -------
    dict: ``far`` (n_lam + 1, n_s + 1, n_s + 1), ``near`` (n_lam, n_s, n_s) [the energy per unit
    ``F_s w``], ``lam0``, ``dlam`` [nm], ``s0`` (= -1), ``ds_wi`` (the cells' width in ``wi_xy``).
    """
    lattice, rows, radius = material.lattice, material.rows, material.length_scale
    P_f, P_b, xr, ds = rows["P_f"], rows["P_b"], rows["x"], float(rows["ds"])
    J, K = P_f.shape
    lam_edges = np.linspace(lam_range[0], lam_range[1], n_lam + 1)
    dlam = lam_edges[1] - lam_edges[0]
    s_edges = np.linspace(-1.0, 1.0, n_s + 1)
    dsw = s_edges[1] - s_edges[0]
    far = _far_nodes(material, lam_edges, s_edges)
    n_s = n_near                                               # the near orders' finer cells
    s_edges = np.linspace(-1.0, 1.0, n_s + 1)
    dsw_near = s_edges[1] - s_edges[0]
    dsw, dsw_far = dsw_near, dsw
    sc1 = 0.5 * (s_edges[:-1] + s_edges[1:])
    scx, scy = np.meshgrid(sc1, sc1, indexing="xy")          # [iy, ix]
    sc = np.stack([scx.ravel(), scy.ravel()], -1)
    hs = (0.5 + CAP_OVERLAP) * dsw * math.sqrt(2.0)             # half diagonal of a cell (with overlap)
    out = np.zeros((n_lam, n_s * n_s))
    for c in range(n_lam):
        l0 = (lam_edges[c] - CAP_OVERLAP * dlam) * 1e-3
        l1 = (lam_edges[c + 1] + CAP_OVERLAP * dlam) * 1e-3
        out[c] = _near_bound(material, sc, hs, l0, l1)
    return {"far": far, "near": out.reshape(n_lam, n_s, n_s), "lam0": float(lam_edges[0]),
            "dlam": float(dlam), "s0": -1.0, "ds_wi": float(dsw_far), "ds_near": float(dsw_near)}


def near_bound_at(material, wi_xy, wavelength: float) -> np.ndarray:
    """The near orders' bound at the lanes ``wi_xy`` (N, 2) themselves (cells of no width) and one
    wavelength [nm]: what a per-lane evaluation of the near orders would count."""
    lam = float(wavelength) * 1e-3
    return _near_bound(material, np.atleast_2d(np.asarray(wi_xy, dtype=np.float64)), 1e-9, lam, lam)


def cap_energy(table: dict, diffuse_rows, wi, wavelength, j, t):
    """``ē`` at (λ [nm], ``wi``) (:func:`cap_parts` summed)."""
    return sum(cap_parts(table, diffuse_rows, wi, wavelength, j, t))


def cap_parts(table: dict, diffuse_rows, wi, wavelength, j, t):
    """(far, near, diffuse) parts of ``ē`` at (λ [nm], ``wi``): the far orders trilinear between
    the nodes, the cell's bound of the near orders, the rows' bound of the diffuse part (the lane's
    row j, weight t: :meth:`SphereMaterial._row`)."""
    near = table["near"]
    n_lam, n_near, _ = near.shape
    n_s = table["far"].shape[1] - 1
    lam = np.asarray(wavelength, dtype=np.float64)
    wi = np.asarray(wi, dtype=np.float64)
    gl = np.clip((lam - table["lam0"]) / table["dlam"], 0.0, n_lam)
    gx = np.clip((wi[..., 0] - table["s0"]) / table["ds_wi"], 0.0, n_s)
    gy = np.clip((wi[..., 1] - table["s0"]) / table["ds_wi"], 0.0, n_s)
    c = np.minimum(np.floor(gl).astype(np.int64), n_lam - 1)
    ix = np.minimum(np.floor(gx).astype(np.int64), n_s - 1)
    iy = np.minimum(np.floor(gy).astype(np.int64), n_s - 1)
    fl, fx, fy = gl - c, gx - ix, gy - iy
    far = table["far"]
    v = 0.0
    for dl, wl in ((0, 1 - fl), (1, fl)):
        for dy, wy in ((0, 1 - fy), (1, fy)):
            for dx, wx in ((0, 1 - fx), (1, fx)):
                v = v + wl * wy * wx * far[c + dl, iy + dy, ix + dx]
    jx = np.clip(np.floor((wi[..., 0] - table["s0"]) / table["ds_near"]).astype(np.int64), 0, n_near - 1)
    jy = np.clip(np.floor((wi[..., 1] - table["s0"]) / table["ds_near"]).astype(np.int64), 0, n_near - 1)
    d = np.asarray(diffuse_rows)
    return v, near[c, jy, jx], d[j] * (1 - t) + d[j + 1] * t


# ----------------------------------------------------------------------
# the cap's energy per lane in closed form (what the renderer evaluates)
# ----------------------------------------------------------------------
#: Orders with ``u = (ρ_G - 1)/ε`` below ``-RIM_U`` are read at the peak's centre (``1/c`` and ``P``
#: smooth on its scale), those above by :func:`rim_rules`' Gauss rule in the radial direction.
RIM_U = 40.0
#: Orders past the horizon by more than ``RIM_REACH`` rms widths carry nothing (``< e^{-32}``).
RIM_REACH = 8.0
#: Nodes of the rim rule and the step in ``u`` of its table.
RIM_NODES = 4
RIM_DU = 0.05


def _rim_rule(u: float, n: int, m: int = 4000):
    """The ``n``-point Gauss rule of the weight ``ω_u(t) = 2 φ(t² + u)`` on ``t ≥ 0`` (``φ`` the
    standard normal density), by the Stieltjes procedure on a fine midpoint discretisation."""
    t0 = math.sqrt(max(-u, 0.0))
    hi = t0 + 10.0 / max(1.0, 2.0 * t0) + 3.0
    t = (np.arange(m) + 0.5) * (hi / m)
    wv = 2.0 * np.exp(-0.5 * (t * t + u) ** 2) / math.sqrt(2.0 * np.pi) * (hi / m)
    a, b = np.zeros(n), np.zeros(n)
    p_prev, p, nrm_prev = np.zeros_like(t), np.ones_like(t), 1.0
    for j in range(n):
        nrm = float(np.sum(wv * p * p))
        a[j] = float(np.sum(wv * t * p * p)) / nrm
        if j:
            b[j] = nrm / nrm_prev
        p, p_prev, nrm_prev = (t - a[j]) * p - (b[j] * p_prev if j else 0.0), p, nrm
    x, v = np.linalg.eigh(np.diag(a) + np.diag(np.sqrt(b[1:]), 1) + np.diag(np.sqrt(b[1:]), -1))
    return x, float(np.sum(wv)) * v[0] ** 2


def rim_rules(n: int = RIM_NODES, du: float = RIM_DU):
    """The table of the orders' radial rule near the horizon: ``(u, nodes, weights)``, ``u`` from
    ``-RIM_U`` to ``RIM_REACH`` step ``du``, nodes and weights (len(u), n).

    An order ``G`` of the lattice lobe (rms ``ε = w/k`` in ``p = wo_xy``, centre ``p_G``,
    ``ρ = |p_G|``) carries ``(W_G/k²) ∫ ĝ(p - p_G) [P(wo↑) + P(wo↓)] / c d²p`` (``c = (1 -
    |p|²)^½``).  With the Gaussian's tangential part integrated out (``ε`` ≪ 1), ``r = |p| = 1 -
    ε t²`` and ``u = (ρ - 1)/ε``, ``dr / c = ε^½ 2 dt / (1 + r)^½``, so

        e_G = W_G / (k² ε^½) ∫_0^∞ ω_u(t) [P(wo↑) + P(wo↓)](r(t)) / (1 + r(t))^½ dt,

    ``ω_u(t) = 2 φ(t² + u)``, a smooth weight (the ``1/c`` singularity is gone: ``P`` is smooth in
    ``t``, ``t ∝ θ`` at grazing exit) whose integral is ``F(u) = e^{-u²/4} D_{-1/2}(u)/√2``
    (``D`` the parabolic cylinder function; ``F → |u|^{-1/2}``, ``e_G → P/c``, far from the
    horizon).  Its Gauss rule is tabulated in ``u`` (read linearly)."""
    us = np.arange(-RIM_U, RIM_REACH + 0.5 * du, du)
    rules = [_rim_rule(float(u), n) for u in us]
    return us, np.array([r[0] for r in rules]), np.array([r[1] for r in rules])


def order_energy(material, wi, wavelength: float, rules=None) -> float:
    """The orders' energy ``Σ_G e_G`` (per unit ``F_s w``) at one ``wi`` (3,) and wavelength [nm]
    by :func:`rim_rules` (orders with ``u ≥ -RIM_U``) and the peak's centre (the rest, ``P/c``
    times ``1 + 3/(8u²)``, the Gaussian's second moment of ``1/c``): the closed form the renderer
    evaluates per lane, for checks against the model's quadrature
    (:meth:`SphereMaterial.lattice_energy`)."""
    us, tn, tw = rules if rules is not None else rim_rules()
    wi = np.asarray(wi, dtype=np.float64)
    lam = float(wavelength)
    k = 2 * np.pi / (lam * 1e-3)
    lat = material.lattice
    eps = lat.peak_width / k
    G, W = lat.bragg_peaks(2 * k + RIM_REACH * lat.peak_width)
    p = G / k - wi[:2]
    rho = np.hypot(p[:, 0], p[:, 1])
    keep = rho < 1 + RIM_REACH * eps
    p, rho, W = p[keep], rho[keep], W[keep]
    u = (rho - 1) / eps

    def psum(pp):
        cz = np.sqrt(np.maximum(1 - np.sum(pp * pp, axis=1), 0.0))
        e = 0.0
        for side in (1.0, -1.0):
            P_f, P_b, fwd = material._mie_at(wi, np.c_[pp, side * cz], lam)
            e = e + np.where(fwd, P_f, P_b)
        return e

    far = u < -RIM_U
    e = float(np.sum(W[far] / k ** 2 * psum(p[far]) * (1 + 0.375 / u[far] ** 2) / np.sqrt(1 - rho[far] ** 2)))
    if np.any(~far):
        g = np.clip((u[~far] - us[0]) / (us[1] - us[0]), 0, us.size - 1 - 1e-9)
        i = np.floor(g).astype(np.int64)
        f = (g - i)[:, None]
        nodes, wts = tn[i] * (1 - f) + tn[i + 1] * f, tw[i] * (1 - f) + tw[i + 1] * f
        pn, rn = p[~far], rho[~far]
        for q in range(nodes.shape[1]):
            r = 1 - eps * nodes[:, q] ** 2
            e += float(np.sum(W[~far] / (k * k * math.sqrt(eps)) * wts[:, q] * psum(pn / rn[:, None] * r[:, None])
                              / np.sqrt(1 + r)))
    return e


#: Nodes in μ_i = |cos θi| of the diffuse part's table (uniform on [0, 1]) and its azimuths.
DIFFUSE_MU_NODES = 17
DIFFUSE_PHI = 32


def diffuse_rows_mu(rows: dict, radius: float, jitter: float, n_mu: int = DIFFUSE_MU_NODES,
                    n_phi: int = DIFFUSE_PHI) -> np.ndarray:
    """``D[j, m]`` (J, n_mu): the jittered lattice's diffuse energy ``∫ P (1 - e^{-q²δ²}) dΩ`` of
    both lobes per row of x (``k = x_j / r``) at ``μ_i = m/(n_mu - 1)`` (``wi`` in the xz plane:
    the integral does not depend on its azimuth), on the rows' own chord nodes (``dΩ = s ds dφ``,
    trapezoid in ``s``, ``n_phi`` azimuths about ``∓wi``), ``q = k (wo + wi)_xy``; 0 for a
    perfect crystal.  Read bilinearly in (row, μ) it is the lane's diffuse part (not a bound)."""
    from corona.model.mie.layer import frame
    P_f, P_b, x, ds = rows["P_f"], rows["P_b"], rows["x"], float(rows["ds"])
    J, K = P_f.shape
    out = np.zeros((J, n_mu))
    if jitter <= 0.0:
        return out
    s = np.arange(K) * ds
    ws = np.full(K, ds)
    ws[0] = ws[-1] = 0.5 * ds
    ws = ws * s * (s <= math.sqrt(2.0)) * (2 * np.pi / n_phi)
    cos_t, sin_t = 1 - 0.5 * s * s, s * np.sqrt(np.maximum(1 - 0.25 * s * s, 0.0))
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    k2d2 = (x / radius * jitter) ** 2
    for m, mu in enumerate(np.linspace(0.0, 1.0, n_mu)):
        wi = np.array([math.sqrt(max(1.0 - mu * mu, 0.0)), 0.0, mu])
        for P, axis in ((P_f, -wi), (P_b, wi)):
            e1, e2 = frame(axis)
            wo = (cos_t[:, None, None] * axis + sin_t[:, None, None]
                  * (np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2))
            q2 = np.sum((wo + wi)[..., :2] ** 2, axis=-1)                  # (K, n_phi), per k²
            damp = -np.expm1(-k2d2[:, None, None] * q2[None, :, :]).sum(axis=-1)   # (J, K)
            out[:, m] += np.sum(P * damp * ws[None, :], axis=1)
    return out
