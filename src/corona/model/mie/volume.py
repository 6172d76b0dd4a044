"""A volume of Mie droplets: size distributions, size-averaged Mie intensities and the phase
function's tables (docs/volumes.md); numpy and scipy only.

The Mitsuba side reads these: the ``corona_mie`` phase function (:mod:`corona.mitsuba.phase`)
and the media dicts around it (:mod:`corona.mitsuba.volume`).

A cloud, a fog or a suspension is a volume of spheres (radius ``r``, complex
index ``m = n + iκ`` relative to the host, number density ``N``).  In the
radiative-transfer picture each unit volume scatters ``σ_s = N ⟨C_sca⟩`` and
extinguishes ``σ_t = N ⟨C_ext⟩`` (per unit length), with the phase function

    p(Θ, λ) = ⟨dσ/dΩ⟩ / ⟨C_sca⟩ = ⟨|S1|² + |S2|²⟩ / (2 k² ⟨C_sca⟩)       [1/sr],

``∫ p dΩ = 1``, Θ the scattering angle (0 forward), ``k = 2π/λ``, ``⟨·⟩`` the
number-weighted mean over the size distribution (:mod:`corona.model.mie.theory`).

Size distributions (all by number; ``r_eff = ⟨r³⟩/⟨r²⟩``, ``v_eff = ⟨r⁴⟩⟨r²⟩/⟨r³⟩² - 1``,
Hansen & Travis 1974):

* ``"mono"``: one radius ``r`` (``variance`` 0);
* ``"lognormal"``: ``ln r ~ N(ln r_g, s²)`` with ``s² = ln(1 + v_eff)``,
  ``r_g = r_eff / (1 + v_eff)^{5/2}``;
* ``"gamma"``: ``n(r) ∝ r^{(1-3b)/b} e^{-r/(ab)}``, ``a = r_eff``, ``b = v_eff``
  (Hansen 1971; needs ``v_eff < 1/2``);
* ``"modified_gamma"``: ``n(r) ∝ r^α exp(-B r^γ)`` (Deirmendjian 1969) with the
  exponent ``γ`` given and ``α``, ``B`` solved from ``r_eff``, ``v_eff``
  (``γ = 1`` is the gamma distribution).

These are the families of a layer's size spread (:class:`corona.model.shapes.SizeDistribution`,
by the relative standard deviation ``σ`` of the number distribution): ``"lognormal"`` with
``σ² = v_eff``, ``"gamma"`` the Schulz distribution with ``σ² = v_eff / (1 - 2 v_eff)``.  A volume
keeps the radiative-transfer convention (``r_eff``, ``v_eff``, Hansen & Travis) and its own
quadrature (Gauss–Legendre over the area-weighted central range): the layer's nodes would change
its tables.

Dense media (docs/volumes.md#dense-media): where the spheres occupy a volume
fraction ``φ = N ⟨4π r³/3⟩`` beyond a few per cent their positions correlate.
In the decoupling approximation (Kerker 1969; Pedersen 1994) the mean
intensity per particle becomes

    ⟨dσ/dΩ⟩ S_eff = [P(Θ) + C(Θ) (S(q) - 1)] / (2k²),
    P = ⟨|S1|² + |S2|²⟩,  C = |⟨S1⟩|² + |⟨S2⟩|²,  q = 2k sin(Θ/2),

with ``S`` the Percus–Yevick structure factor of hard spheres of diameter
``2⟨r⟩`` (:func:`corona.model.processes.percus_yevick_3d`); ``σ_s`` is scaled by the
angular mean of that factor (``σ_a`` is not), and the phase function is the
bracket normalised.

Tables
------
Rows at size parameters ``x_j = 2π r / λ_j`` uniform from 830 to 360 nm, at
most ``ROW_DX`` apart (``r`` the effective radius); per row the phase function
at the chord nodes ``sin(Θ/2) = k ds`` over the forward half and
``cos(Θ/2) = k ds`` over the backward half (``ds ≈ THETA_DX / (2 x_max)``:
``dΘ ≈ THETA_DX / x_max`` at both ends, about ``4π / THETA_DX`` nodes per
diffraction ring at the shortest wavelength, as the surface lobe's chord
grid), linear in ``v = sin²(Θ/2)`` between nodes, normalised so that each row
integrates to 1 with that interpolation (``dΩ = 4π dv`` over the azimuth).
A direction's node needs no trigonometry: ``|wo ± wi|² / 4`` are ``sin²``
and ``cos²(Θ/2)``.

References
----------
1. J. E. Hansen, L. D. Travis, "Light scattering in planetary atmospheres",
   Space Sci. Rev. 16, 527–610 (1974).
2. D. Deirmendjian, *Electromagnetic Scattering on Spherical Polydispersions*,
   Elsevier, 1969.
3. J. S. Pedersen, "Determination of size distributions from small-angle
   scattering data for systems with effective hard-sphere interactions",
   J. Appl. Cryst. 27, 595–608 (1994).
"""
from __future__ import annotations

import functools
import math

import numpy as np
import scipy   # scipy.optimize, scipy.special: loaded on first use (a volume's size spread)

from corona.model import tabulated
from corona.model.mie import theory as mie
from corona.model.layer import decoupled_lobe
from corona._validation import CoronaError, check_choice, check_positive, check_range

__all__ = ["DISTRIBUTIONS", "size_nodes", "droplet_index", "MieVolume", "droplet_density",
           "medium_coefficients", "WATER_DENSITY"]

#: Table format (bump on any change of the layout or the grids).
VOLUME_FORMAT = 2
DISTRIBUTIONS = ("mono", "lognormal", "gamma", "modified_gamma")
#: Range of ``γ`` of the modified gamma distribution: Deirmendjian's cloud and haze models use
#: 0.5-2; beyond [0.1, 10] the moments overflow (γ -> 0) or the quantiles do (γ -> ∞).
GAMMA_EXPONENT_RANGE = (0.1, 10.0)
#: Row step in size parameter (monodisperse); a distribution of relative spread s allows s x / 4, at most 2.
ROW_DX = 0.05
MIN_ROWS, MAX_ROWS = 16, 1024
#: Angle step ``dΘ = THETA_DX / x_max`` [rad].
THETA_DX = 0.25
MIN_NODES, MAX_NODES = 1024, 8192
#: Radii of a size distribution per table (Gauss–Legendre in the light-weighted central 1 - 2e-4):
#: one per unit of size parameter at 360 nm across that range, within these bounds.
SIZE_NODES = (48, 160)
#: Density of liquid water [g/m³].
WATER_DENSITY = 0.998e6
#: Largest relative size parameter one table may hold (Mie series length ~ x).
X_MAX = 4000.0


def _moments_check(r_eff, v_eff, distribution):
    r = check_positive("radius", r_eff, "µm")
    if r > 500.0:
        raise CoronaError(f"radius={r_eff!r} is out of range; allowed (0, 500] µm")
    if distribution == "mono":
        if v_eff not in (0, 0.0, None):
            raise CoronaError(f"variance={v_eff!r} is out of range for distribution='mono'; allowed 0")
        return r, 0.0
    hi = 0.5 if distribution == "gamma" else 2.0
    v = check_range("variance", v_eff, 0.0, hi, lo_open=True, hi_open=True)
    return r, v


def size_nodes(radius: float, distribution: str = "mono", variance: float = 0.0,
               gamma_exponent: float = 1.0, n: int | None = None, host_ior: float = 1.0):
    """Quadrature radii [µm] and number weights (sum 1) of a droplet size distribution.

    Parameters
    ----------
    radius : float
        Effective radius ``r_eff = ⟨r³⟩/⟨r²⟩`` [µm] (the radius for "mono").
    distribution : {"mono", "lognormal", "gamma", "modified_gamma"}
    variance : float
        Effective variance ``v_eff`` (0 for "mono"; (0, 0.5) for "gamma"; (0, 2) otherwise).
    gamma_exponent : float
        ``γ`` of the modified gamma distribution, in [0.1, 10].
    n : int, optional
        Number of nodes (default: one per unit of size parameter at 360 nm in the host across
        the range, within :data:`SIZE_NODES`).
    host_ior : float
        Index of the host (the wavelength in it is ``λ / host_ior``); only sets the default ``n``.

    Returns
    -------
    r, w : ndarray
        Radii and number weights.  The nodes are Gauss–Legendre in ``r`` over
        the central range that holds all but 2e-4 of the area-weighted
        (``r² n(r)``) distribution; the weights are the number density there,
        normalised.

    Examples
    --------
    The effective radius and variance are reproduced:

    >>> r, w = size_nodes(10.0, "gamma", 0.1)
    >>> reff = (w * r**3).sum() / (w * r**2).sum()
    >>> veff = (w * r**4).sum() * (w * r**2).sum() / (w * r**3).sum() ** 2 - 1
    >>> round(float(reff), 2), round(float(veff), 3)
    (10.0, 0.1)
    """
    check_choice("distribution", distribution, DISTRIBUTIONS)
    r_eff, v_eff = _moments_check(radius, variance, distribution)
    if distribution == "mono":
        return np.array([r_eff]), np.ones(1)
    if distribution == "lognormal":
        s2 = math.log1p(v_eff)
        rg = r_eff / (1 + v_eff) ** 2.5
        # area-weighted: ln r ~ N(ln rg + 2 s², s²)
        # (scipy.stats.lognorm's ppf, without importing scipy.stats, the largest import of a volume scene)
        s_ln, scale_ln = math.sqrt(s2), rg * math.exp(2 * s2)
        def area_ppf(p):
            return np.exp(s_ln * scipy.special.ndtri(p)) * scale_ln
        logpdf = lambda r: -np.log(r) - (np.log(r / rg)) ** 2 / (2 * s2)
    else:
        g = 1.0 if distribution == "gamma" else check_range("gamma_exponent", gamma_exponent,
                                                              *GAMMA_EXPONENT_RANGE)
        if distribution == "gamma" and gamma_exponent != 1.0:
            raise CoronaError(f"gamma_exponent={gamma_exponent!r} is out of range for "
                              "distribution='gamma'; allowed 1 (use 'modified_gamma')")
        # moments of r^α exp(-B r^γ): <r^k> ∝ Γ((α+1+k)/γ) B^{-k/γ}; v_eff depends on α only
        def veff_of(alpha):
            lg = lambda k: scipy.special.gammaln((alpha + 1 + k) / g)
            return math.exp(lg(4) + lg(2) - 2 * lg(3)) - 1
        lo, hi = -2.999 + 1e-9, 1e5
        if not (veff_of(hi) < v_eff < veff_of(lo)):
            raise CoronaError(f"variance={variance!r} is out of range for gamma_exponent={g:g}; "
                              f"allowed ({veff_of(hi):.3g}, {veff_of(lo):.3g})")
        alpha = scipy.optimize.brentq(lambda a: veff_of(a) - v_eff, lo, hi, xtol=1e-12)
        # r_eff = B^{-1/γ} Γ((α+4)/γ)/Γ((α+3)/γ)
        scale = r_eff / math.exp(scipy.special.gammaln((alpha + 4) / g) - scipy.special.gammaln((alpha + 3) / g))
        B = scale ** (-g)
        # area-weighted: r^{α+2} exp(-B r^γ): u = B r^γ ~ Gamma((α+3)/γ)
        a_ga = (alpha + 3) / g           # (scipy.stats.gamma(a_ga).ppf is gammaincinv(a_ga, p))
        def area_ppf(p):
            return (scipy.special.gammaincinv(a_ga, p) / B) ** (1 / g)
        logpdf = lambda r: alpha * np.log(r) - B * r**g
    lo_r, hi_r = float(area_ppf(1e-4)), float(area_ppf(1 - 1e-4))
    if n is None:
        n = int(np.clip(math.ceil(2 * np.pi * float(host_ior) * (hi_r - lo_r) / (tabulated.WAVELENGTH_MIN * 1e-3)),
                        *SIZE_NODES))
    t, wt = np.polynomial.legendre.leggauss(int(n))
    r = lo_r + (hi_r - lo_r) * 0.5 * (t + 1)
    lw = logpdf(r)
    w = wt * np.exp(lw - lw.max())
    return r, w / w.sum()


#: Range of the host's index (a gas, a liquid, a resin or a glass).
HOST_IOR_RANGE = (1.0, 3.0)


def check_host_ior(host_ior) -> float:
    """The host's refractive index, in [1, 3] (one clear error otherwise)."""
    return check_range("host_ior", host_ior, *HOST_IOR_RANGE)


def droplet_index(ior, ior_imag: float = 0.0, host_ior: float = 1.0):
    """A function ``λ [nm] → m`` for the particles' index relative to the host.

    ``m = (n + iκ) / n_host``: ``ior="water"`` is water with its dispersion
    (:func:`corona.model.mie.theory.water_ior`, relative to air), a number a constant real
    part ``n`` in [1, 10]; ``ior_imag`` (κ >= 0) adds absorption; ``host_ior``
    (``n_host`` in [1, 3], constant over wavelength; 1: air) is the medium the
    particles are suspended in (water droplets in air, latex spheres in water,
    pigments in a resin).  ``m`` may be below 1 (air bubbles in water, water in
    oil), not equal to 1 (no scattering): ``|m - 1| >= 1e-4`` at 550 nm.

    ``λ`` is the wavelength in air (the renderer's); in the host it is ``λ / n_host``.
    """
    k = check_range("ior_imag", ior_imag, 0.0, 10.0)
    nh = check_host_ior(host_ior)
    if isinstance(ior, str):
        check_choice("ior", ior, ("water",))
        f = lambda lam: (mie.water_ior(lam) + 1j * k) / nh
    else:
        n = check_range("ior", ior, 1.0, 10.0)
        f = lambda lam: (np.full(np.shape(lam), n) + 1j * k) / nh
    m = complex(np.asarray(f(np.array(550.0))))
    if abs(m - 1) < 1e-4:
        raise CoronaError(f"ior={ior!r} is out of range for host_ior={nh:g}: the particles' relative "
                          f"index {m.real:.5g} would equal the host's (no scattering); allowed "
                          "|ior / host_ior - 1| >= 1e-4")
    return f


def _structure(phi: float, diameter: float):
    from corona.model.processes.hard_sphere import PY_FLUID_LIMIT, percus_yevick_3d
    if not (0.0 <= phi < PY_FLUID_LIMIT):
        raise CoronaError(f"volume_fraction={phi!r} is out of range; allowed [0, {PY_FLUID_LIMIT}) "
                          "(the hard-sphere fluid)")
    return lambda q: percus_yevick_3d(q, diameter, phi)


def node_v(ds: float, M: int) -> np.ndarray:
    """``v = sin²(Θ/2)`` at the 2M + 1 angle nodes (:meth:`MieVolume.grid`)."""
    k = np.arange(M + 1)
    l = np.arange(M - 1, -1, -1)                     # backward nodes k = 2M - l: cos(Θ/2) = l ds
    return np.concatenate([(k * ds) ** 2, 1.0 - (l * ds) ** 2])


def node_dv(ds: float, M: int) -> np.ndarray:
    """Widths in v of the 2M bins, exact: ``(2k+1) ds²`` (forward), mirrored (backward)."""
    k = np.arange(M)
    w = (2 * k + 1) * ds * ds
    return np.concatenate([w, w[::-1]])


def node_bin(a, b, ds: float, M: int):
    """Bin i and fraction f (linear in v) of ``a = sin²(Θ/2)``, ``b = cos²(Θ/2)`` on the chord
    nodes: forward from ``sqrt(a)/ds``, backward from ``sqrt(b)/ds`` (accurate at both ends)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    fwd = a <= b
    g = np.sqrt(np.where(fwd, a, b)) / ds
    l = np.clip(np.floor(g).astype(np.int64), 0, M - 1)
    f_fwd = (g * g - l * l) / (2 * l + 1)
    f_bwd = ((l + 1) ** 2 - g * g) / (2 * l + 1)
    i = np.where(fwd, l, 2 * M - 1 - l)
    return i, np.clip(np.where(fwd, f_fwd, f_bwd), 0.0, 1.0)


#: Allowed forward-peak truncation angles [degrees] (besides 0: none).
TRUNCATION_RANGE = (0.5, 30.0)


def check_truncation(truncation) -> float:
    """0 (no truncation) or an angle [degrees] in :data:`TRUNCATION_RANGE`."""
    if isinstance(truncation, (int, float)) and not isinstance(truncation, bool) and truncation == 0:
        return 0.0
    return check_range("truncation", truncation, *TRUNCATION_RANGE, unit="degrees (or 0: none)")


def truncate_table(table: dict, truncation: float) -> dict:
    """Forward-peak truncation of phase rows (Potter 1970; the delta-M idea of Wiscombe 1977).

    Each row ``p`` is capped inside the cone ``Θ < Θ_c`` at its value at the first node
    at or beyond ``Θ_c`` (``p_c = min(p, p(Θ_c))``); the removed fraction
    ``f = 1 - ∫ p_c dΩ`` is treated as a delta function forward, i.e. as no scattering:

        p* = p_c / (1 - f),   C_sca* = (1 - f) C_sca,   C_ext* = C_ext - f C_sca,

    so ``σ_s* p*(Θ) = σ_s p(Θ)`` exactly outside the cone (the glory, the bows and all
    wide angles keep their single scattering), ``σ_a`` is unchanged and the
    transport coefficient ``σ_s (1 - g)`` changes by at most ``f (1 - cos Θ_c) σ_s``
    (the removed light's deflection).  Inside the cone the aureole is lost: use it
    where the camera does not look near the light through the medium.

    Parameters
    ----------
    table : dict
        A :attr:`MieVolume.table` (``p``, ``theta``, ``v``, ``ds``, ``M``, ``c_ext``, ``c_sca``).
    truncation : float
        ``Θ_c`` [degrees].

    Returns
    -------
    dict
        The table with ``p``, ``c_sca``, ``c_ext``, ``g`` replaced, ``truncated_fraction`` =
        ``f`` per row, ``truncation_node`` the first node kept (its angle ``theta[node]`` >= Θ_c),
        and the untruncated ``c_sca_full``, ``c_ext_full``, ``g_full``.

    References
    ----------
    J. F. Potter, "The delta function approximation in radiative transfer theory",
    J. Atmos. Sci. 27, 943–949 (1970).  W. J. Wiscombe, "The delta-M method", J. Atmos. Sci.
    34, 1408–1422 (1977).
    """
    out = dict(table)
    theta = np.asarray(table["theta"])
    ic = int(np.searchsorted(theta, math.radians(float(truncation)) * (1 - 1e-12)))
    p = np.asarray(table["p"], dtype=np.float64)
    cap = p[:, ic:ic + 1]
    pc = p.copy()
    pc[:, :ic] = np.minimum(p[:, :ic], cap)
    dv = node_dv(float(table["ds"]), int(table["M"]))
    keep = 4 * np.pi * np.sum(0.5 * (pc[:, 1:] + pc[:, :-1]) * dv, axis=1)
    f = 1.0 - keep
    ps = pc / keep[:, None]
    v = np.asarray(table["v"])
    g = 4 * np.pi * np.sum(0.5 * (ps[:, 1:] + ps[:, :-1]) * (1 - (v[1:] + v[:-1])) * dv, axis=1)
    c_sca, c_ext = np.asarray(table["c_sca"]), np.asarray(table["c_ext"])
    out.update(p=ps, c_sca=c_sca * keep, c_ext=c_ext - f * c_sca, g=g, truncated_fraction=f,
               truncation_node=np.array(ic), c_sca_full=c_sca, c_ext_full=c_ext,
               g_full=np.asarray(table["g"]))
    return out


#: (row, size) pairs per block of :func:`size_averaged_scattering` (its products' height; fewer
#: where the angle grid is long, the products at most 2^22 values).
PAIR_BLOCK = 1024


def size_averaged_scattering(m, k, radii, weights, mu, coherent=False):
    """Size-averaged Mie intensities per wavelength: ``P = ⟨|S1|² + |S2|²⟩``, ``C = |⟨S1⟩|² + |⟨S2⟩|²``.

    Parameters
    ----------
    m : complex ndarray (J,)
        Relative index per row (wavelength).
    k : ndarray (J,)
        Wavenumber in the host [rad/µm] per row.
    radii, weights : ndarray (S,)
        The size distribution's nodes [µm] and number weights (sum 1; :func:`size_nodes`).
    mu : ndarray (K,)
        ``cos Θ`` of the angle nodes.
    coherent : bool
        Also return ``C`` (the decoupling approximation's coherent term); else ``C`` is None.

    Returns
    -------
    P : ndarray (J, K)
        ``Σ_s w_s (|S1|² + |S2|²)`` (dimensionless; ``dσ/dΩ = P / (2k²)``).
    C : ndarray (J, K) or None
        ``|Σ_s w_s S1|² + |Σ_s w_s S2|²``.
    c_ext, c_sca : ndarray (J,)
        ``Σ_s w_s C_ext``, ``Σ_s w_s C_sca`` [µm²].

    Notes
    -----
    The amplitudes are summed as ``S± = S1 ± S2 = Σ_n (2n+1)/(n(n+1)) (a_n ± b_n)(π_n ± τ_n)``,
    so that ``|S1|² + |S2|² = (|S+|² + |S-|²) / 2`` (and the same for the averaged amplitudes
    in ``C``): two products of real matrices (the coefficients' real and imaginary parts stacked)
    with ``π_n ± τ_n`` per (row, size) pair instead of four complex ones.  The pairs are taken in
    blocks of at most :data:`PAIR_BLOCK` ordered by their series length (Wiscombe's
    :func:`corona.model.mie.theory.n_terms`), each block's products only as long as its longest
    series (the coefficients past a sphere's own length are 0 in
    :func:`corona.model.mie.theory.coefficients`): the same sums in a different order.
    """
    m = np.asarray(m, dtype=np.complex128)
    k = np.asarray(k, dtype=np.float64)
    radii = np.asarray(radii, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    J, S, K = k.size, radii.size, np.size(mu)
    x = (k[:, None] * radii[None, :]).ravel()                       # pair = row * S + size
    own = mie.n_terms(x)
    order = np.argsort(own, kind="stable")
    n_all = int(own.max())
    pi_all, tau_all = mie.angular_functions(mu, n_all)
    plus, minus = pi_all + tau_all, pi_all - tau_all                # (N, K)
    del pi_all, tau_all
    n = np.arange(1, n_all + 1)
    c = (2 * n + 1) / (n * (n + 1.0))
    row = np.repeat(np.arange(J), S)
    w = np.tile(weights, J)
    m_pair = np.repeat(m, S)
    P = np.zeros((J, K))
    A = [np.zeros((J, K), complex), np.zeros((J, K), complex)] if coherent else None
    c_ext, c_sca = np.zeros(J), np.zeros(J)
    block = min(PAIR_BLOCK, max(64, (1 << 22) // max(K, 1)))      # (2 block, K) products <= 64 MB
    for b0 in range(0, x.size, block):
        idx = order[b0:b0 + block]
        idx = idx[np.argsort(row[idx], kind="stable")]            # the block's pairs grouped by row
        B = idx.size
        nb = int(own[idx].max())
        a, b = mie.coefficients(m_pair[idx], x[idx], n_max=nb)       # (B, nb)
        rb, wb = row[idx], w[idx]
        kb2 = k[rb] ** 2
        nn = 2 * n[:nb] + 1
        c_ext += np.bincount(rb, wb * 2 * np.pi / kb2 * ((a + b).real @ nn), minlength=J)
        c_sca += np.bincount(rb, wb * 2 * np.pi / kb2 * ((np.abs(a) ** 2 + np.abs(b) ** 2) @ nn),
                             minlength=J)
        rows_b, starts = np.unique(rb, return_index=True)            # the block's rows and their runs
        sw = np.sqrt(wb)
        for sign, basis in ((1.0, plus), (-1.0, minus)):
            cs = (a + sign * b) * (c[:nb] * sw[:, None])
            amp = np.concatenate([cs.real, cs.imag]) @ basis[:nb]      # (2B, K): √w Re S±, √w Im S±
            re, im = amp[:B], amp[B:]
            P[rows_b] += 0.5 * np.add.reduceat(re * re + im * im, starts, axis=0)
            if coherent:
                A[0 if sign > 0 else 1][rows_b] += (np.add.reduceat(re * sw[:, None], starts, axis=0)
                                                    + 1j * np.add.reduceat(im * sw[:, None], starts, axis=0))
    C = None
    if coherent:
        C = 0.5 * (np.abs(A[0]) ** 2 + np.abs(A[1]) ** 2)
    return P, C, c_ext, c_sca


class MieVolume:
    """The spheres of a volume: cross-sections and the tabulated phase function per wavelength.

    Parameters
    ----------
    radius : float
        Radius (``"mono"``) or effective radius [µm].
    distribution, variance, gamma_exponent
        The size distribution (:func:`size_nodes`).
    ior : "water" or float
        Real part of the particles' index (water: with dispersion), relative to air.
    ior_imag : float
        Imaginary part κ (absorption), >= 0.
    volume_fraction : float
        ``φ`` of the spheres; > 0 applies the Percus–Yevick structure factor
        (decoupling approximation, module docstring).  0: dilute (S = 1).
    use_cache : bool
        Keep the tables in corona's on-disk cache.
    host_ior : float
        Index ``n_host`` of the medium around the particles, in [1, 3] (1: air): the
        relative index is ``m = (ior + i ior_imag) / n_host`` and the wavelength in the host
        ``λ / n_host``, so ``x = 2π r n_host / λ`` and ``k = 2π n_host / λ`` (``λ`` the
        renderer's wavelength in air).
    truncation : float
        Forward-peak truncation angle ``Θ_c`` [degrees], 0 (default: none) or in [0.5, 30]:
        the phase function is capped at its value at ``Θ_c`` inside the cone,
        the removed fraction ``f`` of the scattered light counts as unscattered and
        ``C_sca``, ``C_ext`` drop by ``f C_sca`` (:func:`truncate_table`; docs/volumes.md#forward-peak-truncation).

    Examples
    --------
    A 10 µm droplet: ``⟨C_ext⟩ ≈ 2 π r²`` and the table's phase function integrates to 1:

    >>> v = MieVolume(10.0)
    >>> round(float(v.cross_sections(550.0)["c_ext"] / (3.14159 * 100)), 1)
    2.0
    >>> round(float(v.integral(550.0)), 6)
    1.0
    """

    def __init__(self, radius, distribution="mono", variance=0.0, gamma_exponent=1.0,
                 ior="water", ior_imag=0.0, volume_fraction=0.0, use_cache=True, host_ior=1.0,
                 truncation=0.0):
        self.host_ior = check_host_ior(host_ior)
        self.radii, self.weights = size_nodes(radius, distribution, variance, gamma_exponent,
                                              host_ior=self.host_ior)
        self.radius = float(radius)
        self.distribution, self.variance = distribution, float(variance or 0.0)
        self.gamma_exponent = float(gamma_exponent)
        self.index = droplet_index(ior, ior_imag, self.host_ior)
        self.ior, self.ior_imag = ior, float(ior_imag)
        self.volume_fraction = check_range("volume_fraction", volume_fraction, 0.0, 0.494, hi_open=True)
        self.truncation = check_truncation(truncation)
        self.use_cache = bool(use_cache)
        x_top = 2 * np.pi * self.host_ior * float(self.radii.max()) / (tabulated.WAVELENGTH_MIN * 1e-3)
        if x_top > X_MAX:
            raise CoronaError(f"radius={radius!r} is out of range with this distribution: the largest "
                              f"droplets reach x = {x_top:.0f} > {X_MAX:g} at 360 nm")

    @property
    def k_scale(self) -> float:
        """``2π n_host`` [rad]: ``k = k_scale / λ`` and ``x = k_scale r / λ``."""
        return 2 * np.pi * self.host_ior

    def key(self) -> dict:
        """The cache key of the untruncated table (truncation is applied on reading)."""
        key = {"volume_format": VOLUME_FORMAT, "radius": self.radius, "distribution": self.distribution,
                "variance": self.variance, "gamma_exponent": self.gamma_exponent, "ior": str(self.ior),
                "ior_imag": self.ior_imag, "volume_fraction": self.volume_fraction,
                "grid": [ROW_DX, MIN_ROWS, MAX_ROWS, THETA_DX, MIN_NODES, MAX_NODES, SIZE_NODES],
                "wavelengths": [tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX]}
        if self.host_ior != 1.0:                   # (air keeps the keys of tables cached before)
            key["host_ior"] = self.host_ior
        return key

    @property
    def mean_radius(self) -> float:
        return float(np.sum(self.weights * self.radii))

    @property
    def mean_volume(self) -> float:
        """``⟨4π r³/3⟩`` [µm³]."""
        return float(np.sum(self.weights * 4 / 3 * np.pi * self.radii**3))

    def grid(self):
        """(x rows of the effective radius, chord step ds, M): the angle nodes are the chords
        ``sin(Θ/2) = k ds`` (k = 0 … M, forward half) then ``cos(Θ/2) = (2M - k) ds``
        (k = M … 2M, backward half), ``M ds = 1/√2``; K = 2M + 1 nodes."""
        r = self.radius
        x_lo = self.k_scale * r / (tabulated.WAVELENGTH_MAX * 1e-3)
        x_hi = self.k_scale * r / (tabulated.WAVELENGTH_MIN * 1e-3)
        spread = math.sqrt(self.variance)
        row_dx = max(ROW_DX, min(2.0, 0.25 * spread * x_lo))
        J = int(np.clip(math.ceil((x_hi - x_lo) / row_dx) + 1, MIN_ROWS, MAX_ROWS))
        # angular resolution for the radii that carry the light (r_eff (1 + 2 sqrt(v_eff))):
        # dΘ ≈ 2 ds <= THETA_DX / x_top
        x_top = x_hi * min(float(self.radii.max()) / r, 1 + 2 * spread)
        M = int(np.clip(math.ceil(math.sqrt(0.5) * 2 * x_top / THETA_DX), (MIN_NODES - 1) // 2,
                        (MAX_NODES - 1) // 2))
        return np.linspace(x_lo, x_hi, J), math.sqrt(0.5) / M, M

    @functools.cached_property
    def table(self) -> dict:
        """The rows (cached on disk): ``wavelength`` (J,) [nm, in air], ``theta`` (K,), ``p`` (J, K)
        [1/sr] normalised, ``c_ext``, ``c_sca`` (J,) [µm²] per droplet (``c_sca`` with S and
        truncation), ``s_gain`` (J,) the factor S brought to ``c_sca``, ``g`` (J,) the asymmetry of
        ``p``, ``truncated_fraction`` (J,) the fraction ``f`` of the scattering folded into the
        unscattered beam (0 without truncation)."""
        arrays = tabulated.cached(self.key(), self._build, use_cache=self.use_cache)
        out = {k: np.asarray(v) for k, v in arrays.items()}
        out["truncated_fraction"] = np.zeros(out["p"].shape[0])
        return truncate_table(out, self.truncation) if self.truncation > 0 else out

    def _build(self) -> dict:
        x_rows, ds, M = self.grid()
        lam = self.k_scale * self.radius / x_rows * 1e3        # in air [nm]
        v = node_v(ds, M)
        K = v.size
        mu = 1.0 - 2.0 * v
        theta = 2.0 * np.arcsin(np.sqrt(v))
        J = x_rows.size
        m = self.index(lam)
        k = self.k_scale / (lam * 1e-3)                # in the host [rad/µm]
        P, C, c_ext, c_sca = size_averaged_scattering(m, k, self.radii, self.weights, mu,
                                                     coherent=self.volume_fraction > 0)
        if self.volume_fraction > 0:
            S = _structure(self.volume_fraction, 2 * self.mean_radius)
            q = 2 * k[:, None] * np.sin(theta[None, :] / 2)
            Z = decoupled_lobe(P, C, S(q))              # the one decoupling rule
        else:
            Z = P
        # the rows normalised under linear interpolation in v = sin²(Θ/2) (dΩ = 4π dv)
        dv = node_dv(ds, M)
        total_P = 4 * np.pi * np.sum(0.5 * (P[:, 1:] + P[:, :-1]) * dv, axis=1)
        total_Z = 4 * np.pi * np.sum(0.5 * (Z[:, 1:] + Z[:, :-1]) * dv, axis=1)
        p = Z / total_Z[:, None]
        gain = total_Z / total_P
        mid = 0.5 * (p[:, 1:] + p[:, :-1])
        g = 4 * np.pi * np.sum(mid * (1 - 2 * 0.5 * (v[1:] + v[:-1])) * dv, axis=1)
        c_sca_s = c_sca * gain
        return {"wavelength": lam, "x": x_rows, "theta": theta, "v": v, "ds": np.array(ds),
                "M": np.array(M), "p": p, "c_ext": c_ext - c_sca + c_sca_s,
                "c_sca": c_sca_s, "s_gain": gain, "g": g, "c_sca_dilute": c_sca}

    # ------------------------------------------------------------------
    def _row(self, wavelength):
        lam = np.clip(np.asarray(wavelength, dtype=np.float64), tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX)
        xr = self.table["x"]
        f = (self.k_scale * self.radius / (lam * 1e-3) - xr[0]) / (xr[1] - xr[0])
        j = np.clip(np.floor(f).astype(np.int64), 0, xr.size - 2)
        return j, np.clip(f - j, 0.0, 1.0)

    def cross_sections(self, wavelength) -> dict:
        """``c_ext``, ``c_sca`` [µm²] per droplet (dense media: with S), ``albedo``, ``g``, at
        ``wavelength`` [nm] (linear in x between rows)."""
        j, t = self._row(wavelength)
        T = self.table
        out = {k: T[k][j] * (1 - t) + T[k][j + 1] * t for k in ("c_ext", "c_sca", "g", "s_gain")}
        out["albedo"] = out["c_sca"] / out["c_ext"]
        return out

    def phase(self, cos_theta, wavelength) -> np.ndarray:
        """The tabulated phase function [1/sr] at ``cos Θ`` (0 forward) and ``wavelength`` [nm],
        as the Mitsuba plugin evaluates it (linear in v between angle nodes, in x between rows)."""
        mu = np.clip(np.asarray(cos_theta, dtype=np.float64), -1.0, 1.0)
        i, f = node_bin((1 - mu) / 2, (1 + mu) / 2, float(self.table["ds"]), int(self.table["M"]))
        T = self.table
        j, t = self._row(wavelength)
        p = T["p"]
        a = p[j, i] * (1 - f) + p[j, i + 1] * f
        b = p[j + 1, i] * (1 - f) + p[j + 1, i + 1] * f
        return a * (1 - t) + b * t

    def integral(self, wavelength) -> float:
        """``∫ p dΩ`` of the tabulated row(s) at ``wavelength`` (1 by construction)."""
        T = self.table
        j, t = self._row(wavelength)
        row = T["p"][j] * (1 - t) + T["p"][j + 1] * t
        dv = node_dv(float(T["ds"]), int(T["M"]))
        return float(4 * np.pi * np.sum(0.5 * (row[1:] + row[:-1]) * dv))

    def exact_phase(self, cos_theta, wavelength) -> np.ndarray:
        """Mie theory directly at ``cos Θ`` and ``wavelength`` [nm] (float64, no tables; dilute)."""
        mu = np.atleast_1d(np.asarray(cos_theta, dtype=np.float64))
        lam = float(wavelength)
        k = self.k_scale / (lam * 1e-3)
        m = complex(self.index(np.array(lam)))
        num = np.zeros(mu.shape)
        csca = 0.0
        for r, w in zip(self.radii, self.weights):
            num += w * mie.differential_cross_section(m, r, lam * 1e-3 / self.host_ior, mu)
            csca += w * float(mie.efficiencies(m, k * r)["q_sca"]) * np.pi * r * r
        return num / csca

    def rgb_table(self, wavelengths, weights) -> np.ndarray:
        """Phase rows of channels: ``Σ_i w_i σ_s(λ_i) p(λ_i) / Σ_i w_i σ_s(λ_i)`` per channel
        (``wavelengths``, ``weights`` (C, n)), shape (C, K)."""
        lam = np.asarray(wavelengths, dtype=np.float64)
        wts = np.asarray(weights, dtype=np.float64)
        T = self.table
        out = []
        for lc, wc in zip(lam, wts):
            j, t = self._row(lc)
            p = T["p"][j] * (1 - t)[:, None] + T["p"][j + 1] * t[:, None]
            cs = self.cross_sections(lc)["c_sca"] * wc
            out.append(np.sum(cs[:, None] * p, axis=0) / np.sum(cs))
        return np.array(out)


# ----------------------------------------------------------------------
# a medium of droplets: number density and coefficients
# ----------------------------------------------------------------------
def droplet_density(volume: MieVolume, lwc=None, number_density=None, number_density_cm3=None) -> float:
    """Droplets per m³ from exactly one of ``lwc`` [g/m³] (water), ``number_density`` [1/m³] or
    ``number_density_cm3`` [1/cm³]; one clear error where they would fill a volume fraction >= 0.494."""
    given = [(k, v) for k, v in (("lwc", lwc), ("number_density", number_density),
                                 ("number_density_cm3", number_density_cm3)) if v is not None]
    if len(given) != 1:
        raise CoronaError("give exactly one of lwc [g/m³], number_density [1/m³] or "
                          f"number_density_cm3 [1/cm³]; got {', '.join(k for k, _ in given) or 'none'}")
    name, value = given[0]
    if name == "lwc":
        if volume.ior != "water":
            raise CoronaError(f"lwc={value!r} needs ior='water' (liquid water content); give "
                              "number_density for other particles")
        v = check_positive("lwc", value, "g/m³")
        N = v / (WATER_DENSITY * volume.mean_volume * 1e-18)
    elif name == "number_density":
        N = check_positive("number_density", value, "1/m³")
    else:
        N = check_positive("number_density_cm3", value, "1/cm³") * 1e6
    phi = N * volume.mean_volume * 1e-18
    if phi >= 0.494:
        raise CoronaError(f"{name}={value!r} is out of range: the droplets would fill a volume fraction "
                          f"{phi:.3g} >= 0.494 (the densest hard-sphere fluid)")
    return N


#: Metres per scene unit: a nanometre to a million kilometres (σ_t per scene unit stays far
#: inside float32, which Mitsuba's media use; 1e300 gave an infinite σ_t and NaN renders).
SCENE_UNIT_RANGE = (1e-9, 1e9)


def medium_coefficients(radius, lwc, number_density, number_density_cm3, distribution, variance,
                        gamma_exponent, ior, ior_imag, scene_unit, correlated, use_cache, host_ior=1.0,
                        truncation=0.0) -> dict:
    """The droplets' number density, volume fraction and, per table row, ``σ_t`` [1/scene unit]
    and the albedo (parameters of :func:`corona.mitsuba.volume.homogeneous_medium`).

    Returns
    -------
    dict
        ``number_density`` [1/m³], ``volume_fraction`` ``φ``, ``wavelength`` [nm] of the rows,
        ``sigma_t`` [1/scene unit], ``albedo``, ``volume`` (the :class:`MieVolume` of the phase
        function: its ``volume_fraction`` is ``φ`` where ``correlated``, else 0) and
        ``truncated_fraction`` per row.
    """
    unit = check_range("scene_unit", scene_unit, *SCENE_UNIT_RANGE, unit="m per scene unit")
    dilute = MieVolume(radius, distribution, variance, gamma_exponent, ior, ior_imag, 0.0, use_cache,
                       host_ior=host_ior, truncation=truncation)
    N = droplet_density(dilute, lwc, number_density, number_density_cm3)
    phi = N * dilute.mean_volume * 1e-18
    use = phi if correlated else 0.0
    vol = MieVolume(radius, distribution, variance, gamma_exponent, ior, ior_imag, use, use_cache,
                    host_ior=host_ior, truncation=truncation) if use > 0 else dilute
    per_unit = N * 1e-12 * unit                        # droplets per m³ × µm² → 1/m, × m per unit
    sigma_t = vol.table["c_ext"] * per_unit
    albedo = vol.table["c_sca"] / vol.table["c_ext"]
    return {"number_density": N, "volume_fraction": phi, "wavelength": vol.table["wavelength"],
            "sigma_t": sigma_t, "albedo": albedo, "volume": vol,
            "truncated_fraction": vol.table["truncated_fraction"]}
