"""Brute-force wave reference for the coherent double pass (Quetelet rings), in one dimension.

A random binary screen (opaque segments, particle mode) lies on the front face of a glass
pane of thickness ``t`` and index ``n``, silvered (or bare) at the back.  A plane wave falls
on it at ``θs``.  The field is followed without the model's assumptions: through the screen
(multiplied by ``t(x)``), into the pane and back as an angular spectrum (every plane-wave
component ``k_x`` gets the pane's exact coherent reflection amplitude, every internal round
trip summed), through the screen again, and into the far field (an FFT).  Its ensemble average
gives the diffuse reflected intensity with every path: single scattering on the way in or on
the way out (what :meth:`corona.GlassPane.reflected_lobe_factor` models), and the scattering
twice that the model drops.

The comparison is per plane-wave component: the ratio of the double-pass diffuse intensity
to ``C`` times the single-pass diffuse intensity of the same screens (``C = |<t>|²``) is the
pane's factor on ``C f`` in the model, measured.  Everything is scalar (each of the two
polarisations, TE and TM, with its own Fresnel amplitudes; their intensities are averaged),
periodic over the screen's length, and evanescent components are dropped after each pass
through the screen (as the model drops the lobe's evanescent part).

References
----------
G. G. Stokes, "On the colours of thick plates", Trans. Camb. Phil. Soc. 9, 147 (1851).
J. W. Goodman, *Introduction to Fourier Optics*, 3rd ed., §3.10 (the angular spectrum).
"""
from __future__ import annotations

import numpy as np

from corona._validation import check_range


def _fresnel_r(kz1, kz2, n1, n2, polarisation):
    """Amplitude reflection coefficient of a plane interface, from medium 1 (k_z in each)."""
    if polarisation == "TE":
        return (kz1 - kz2) / (kz1 + kz2)
    return (n2 * n2 * kz1 - n1 * n1 * kz2) / (n2 * n2 * kz1 + n1 * n1 * kz2)


def pane_reflection(kx, k, ior, thickness, back, polarisation, front_reflection=True):
    """Coherent reflection amplitude of the pane for the air-side plane wave of transverse ``kx``.

    ``r = r01 + t01 t10 r_b e^{2iφ} / (1 - r10 r_b e^{2iφ})``, ``φ = k_z,glass t``, with the
    Stokes relations ``t01 t10 = 1 - r01²``, ``r10 = -r01``; ``back`` is ``"glass"`` (the
    back face's own Fresnel amplitude) or a silvering's intensity reflectance (amplitude
    ``-√R_m``).  ``front_reflection=False`` leaves out the front face's own reflection ``r01``
    (the paths that do not enter the glass).
    """
    kz0 = np.sqrt(np.maximum(k * k - kx * kx, 0.0)).astype(complex)
    kz1 = np.sqrt((ior * k) ** 2 - kx * kx + 0j)
    r01 = _fresnel_r(kz0, kz1, 1.0, ior, polarisation)
    rb = _fresnel_r(kz1, kz0, ior, 1.0, polarisation) if isinstance(back, str) else -np.sqrt(back)
    e = np.exp(2j * kz1 * thickness)
    inside = (1 - r01 * r01) * rb * e / (1 + r01 * rb * e)
    return (r01 if front_reflection else 0.0) + inside


def screens(rng, n_screens, n_samples, length, radius, area_fraction):
    """Binary particle screens ``t(x)`` (1 clear, 0 blocked): Poisson centres of segments of
    half-width ``radius`` [µm] on a periodic line of ``length`` [µm], covering ``area_fraction``
    on average (``1 - exp(-ρ 2R)``)."""
    dx = length / n_samples
    rho = -np.log(1.0 - area_fraction) / (2 * radius)            # centres per µm
    for _ in range(n_screens):
        centres = rng.uniform(0, length, rng.poisson(rho * length))
        # samples x_i = i dx with |x_i - c| < R (periodic): +1 at the first, -1 after the last
        lo = np.floor((centres - radius) / dx).astype(np.int64) + 1
        hi = np.ceil((centres + radius) / dx).astype(np.int64)       # exclusive
        cover = np.zeros(n_samples + 1)
        wraps = np.floor_divide(lo, n_samples) != np.floor_divide(hi - 1, n_samples)
        np.add.at(cover, np.mod(lo, n_samples), 1.0)
        np.add.at(cover, np.mod(hi - 1, n_samples) + 1, -1.0)
        cover[0] += wraps.sum()                                       # a wrapped segment restarts at 0
        t = (np.cumsum(cover[:-1]) < 0.5).astype(np.float64)
        yield t


def double_pass(theta_s_deg=0.0, wavelength=550.0, thickness=4000.0, ior=1.52, back=0.97,
                radius=5.0, area_fraction=0.03, n_screens=64, n_samples=2**15, length=4000.0,
                front_reflection=False, bandwidth=2.0, seed=0):
    """Ensemble of screens on a pane: the measured factor on ``C f`` per outgoing direction.

    Parameters
    ----------
    theta_s_deg : float
        Incidence [deg] (rounded to the nearest plane wave of the periodic domain).
    wavelength : float [nm];  thickness : float [µm];  ior : float
    back : "glass" or float
        The back face: bare glass, or a silvering of this reflectance.
    radius, area_fraction : float
        Half-width [µm] of the opaque segments and the covered fraction.
    n_screens, n_samples, length
        Ensemble size, samples per screen and the period [µm].
    front_reflection : bool
        Keep the front face's own reflection (the paths that never enter the glass).
    bandwidth : float [nm]
        Each screen is lit at a wavelength drawn uniformly from ``wavelength ± bandwidth/2``:
        the light of any source but a laser, over which the interference of paths with
        different numbers of round trips (phase ``2 k n t cos r`` per trip) averages out.

    Returns
    -------
    dict with ``sin_o`` (sin θo of the outgoing components, same side as the light),
    ``sin_s``, ``ratio`` (the double-pass diffuse intensity over ``C`` times the single-pass
    one), ``sigma`` (its standard error from 8 batches of screens), ``single`` (the
    single-pass diffuse intensity per component, normalised so that its sum is the diffuse
    energy fraction), ``coherent`` (``C``), ``specular`` (the intensity of the reflected
    component along the mirror direction: the pane's coherent image seen through the screen,
    band-averaged; its diffuse share, one component of the speckle, is of order 1/n_samples).
    """
    check_range("area_fraction", area_fraction, 0.0, 1.0, lo_open=True, hi_open=True)
    k = 2 * np.pi / (wavelength * 1e-3)
    kx = 2 * np.pi * np.fft.fftfreq(n_samples, d=length / n_samples)
    m0 = int(round(np.sin(np.radians(theta_s_deg)) * k * length / (2 * np.pi)))
    kx0 = 2 * np.pi * m0 / length
    x = np.arange(n_samples) * (length / n_samples)
    incident = np.exp(1j * kx0 * x)
    prop = np.abs(kx) < k * (1 - 0.5 * bandwidth / wavelength)     # propagating at every wavelength
    rng = np.random.default_rng(seed)
    n_batch = 8
    sums = np.zeros((n_batch, 4, n_samples))      # single |A|², single A (for the mean), double |B|², B
    tmean = np.zeros(n_batch, complex)
    specular = 0.0
    for i, t in enumerate(screens(rng, n_screens, n_samples, length, radius, area_fraction)):
        b = i % n_batch
        k_i = 2 * np.pi / (1e-3 * (wavelength + bandwidth * (rng.uniform() - 0.5)))
        refl = {p: pane_reflection(kx, k_i, ior, thickness, back, p, front_reflection) for p in ("TE", "TM")}
        a_k = np.fft.fft(t * incident) / n_samples
        a_k = np.where(prop, a_k, 0.0)
        sums[b, 0] += np.abs(a_k) ** 2
        tmean[b] += t.mean()
        for p in ("TE", "TM"):
            up = np.fft.ifft(refl[p] * a_k) * n_samples           # upgoing field below the screen
            c_k = np.fft.fft(t * up) / n_samples
            c_k = np.where(prop, c_k, 0.0)
            sums[b, 2] += 0.5 * np.abs(c_k) ** 2
            specular += 0.5 * abs(c_k[m0 % n_samples]) ** 2 / n_screens
    counts = np.bincount(np.arange(n_screens) % n_batch, minlength=n_batch)[:, None]
    # diffuse parts: the coherent beams are single components (kx0 and the mirror image kx0)
    tm = tmean.sum() / n_screens
    coherent = abs(tm) ** 2
    single_b = sums[:, 0] / counts
    double_b = sums[:, 2] / counts
    keep = prop & (np.arange(n_samples) != (m0 % n_samples))
    ratio_b = double_b[:, keep] / np.maximum(coherent * single_b[:, keep], 1e-300)
    ratio = double_b[:, keep].sum(0) / np.maximum(coherent * single_b[:, keep].sum(0), 1e-300)
    sigma = ratio_b.std(0, ddof=1) / np.sqrt(n_batch)
    sin_o = kx[keep] / k
    return {"sin_o": sin_o, "sin_s": kx0 / k, "ratio": ratio, "sigma": sigma,
            "single": single_b[:, keep].mean(0), "coherent": coherent, "specular": float(specular)}


def disc_screens(rng, n_screens, n_samples, length, radius, area_fraction):
    """Binary 2-D particle screens ``t(x, y)`` (1 clear, 0 blocked): Poisson centres of opaque discs
    of ``radius`` [µm] on a periodic square of side ``length`` [µm] sampled ``n_samples``² times
    (a pixel is blocked when its centre lies in a disc), covering ``area_fraction`` on average
    (``1 - exp(-ρ π R²)``)."""
    dx = length / n_samples
    rho = -np.log(1.0 - area_fraction) / (np.pi * radius * radius)     # centres per µm²
    reach = int(np.ceil(radius / dx)) + 1
    off = np.arange(-reach, reach + 1)
    for _ in range(n_screens):
        centres = rng.uniform(0, length, (rng.poisson(rho * length * length), 2))
        i0 = np.floor(centres / dx).astype(np.int64)
        # pixel centres (i + 1/2) dx within the disc of each centre
        px = (i0[:, 0, None] + off[None, :] + 0.5) * dx - centres[:, 0, None]
        py = (i0[:, 1, None] + off[None, :] + 0.5) * dx - centres[:, 1, None]
        inside = px[:, :, None] ** 2 + py[:, None, :] ** 2 < radius * radius
        k, a, b = np.nonzero(inside)
        ix = np.mod(i0[k, 0] + off[a], n_samples)
        iy = np.mod(i0[k, 1] + off[b], n_samples)
        blocked = np.zeros((n_samples, n_samples), bool)
        blocked[ix, iy] = True
        yield (~blocked).astype(np.float64)


def round_trip_orders(kt, k, ior, thickness, back, polarisation, orders):
    """Amplitudes of the paths that leave the front face after ``1 .. orders`` round trips through
    the pane, for the air-side plane wave of transverse wave number ``kt`` (shape
    ``(orders, ...)``): ``t01 t10 r_b e^{2iφ} (-r10 r_b e^{2iφ})^(j-1)`` (Airy's series of
    :func:`pane_reflection`, term by term)."""
    kz0 = np.sqrt(np.maximum(k * k - kt * kt, 0.0)).astype(complex)
    kz1 = np.sqrt((ior * k) ** 2 - kt * kt + 0j)
    r01 = _fresnel_r(kz0, kz1, 1.0, ior, polarisation)
    rb = _fresnel_r(kz1, kz0, ior, 1.0, polarisation) if isinstance(back, str) else -np.sqrt(back)
    e = np.exp(2j * kz1 * thickness)
    first = (1 - r01 * r01) * rb * e
    return np.stack([first * (r01 * rb * e) ** j for j in range(orders)])


def double_pass_2d(wavelength=550.0, thickness=1000.0, ior=1.52, back=0.97, radius=1.5,
                   area_fraction=0.03, n_screens=4, n_samples=1024, length=512.0, orders=3,
                   n_rings=None, seed=0):
    """2-D screens of discs on a pane lit on the normal: the measured factor on ``C f`` per ring.

    The field through a binary screen of opaque discs (:func:`disc_screens`), into the pane and
    back as an angular spectrum (each plane-wave component of transverse wave number ``κ``
    meets the pane's exact round-trip amplitudes at ``|κ|``, :func:`round_trip_orders`), through
    the screen again and into the far field (2-D FFTs).  Each round-trip order ``j`` is followed
    on its own and the intensities of the orders are added: the band average of a source a
    few nm wide, over which the phase ``2 j n k t cos r`` of order ``j`` against another turns
    many times (``δλ = λ² / (2 n t)`` = 0.1 nm at t = 1 mm), while the interference of the two
    paths of one order, ``Δ``, stays (as in :func:`double_pass`, which draws the wavelengths
    instead).  The front face's own reflection is left out.  Scalar, each polarisation (TE,
    TM) with its Fresnel amplitudes at ``|κ|``, intensities averaged; evanescent components are
    dropped after each pass.

    Parameters
    ----------
    wavelength : float [nm];  thickness : float [µm];  ior : float
    back : "glass" or float
        The back face: bare glass, or a silvering of this reflectance.
    radius, area_fraction : float
        Disc radius [µm] and covered fraction.
    n_screens, n_samples, length
        Ensemble size, samples per side and the period [µm] (``length / n_samples`` the pixel).
    orders : int
        Round trips followed (the next carries ``(R R_b)^orders`` of the first).
    n_rings : int, optional
        Rings in ``sin θo`` (default: one per ``λ / length``, the grid's spacing).

    Returns
    -------
    dict with ``sin_o`` (ring centres), ``ratio`` (the double-pass diffuse intensity in the
    ring over ``C`` times the single-pass one of the same screens), ``sigma`` (the standard
    error over the screens), ``count`` (grid components per ring), ``coherent`` (``C``), and,
    to average a model over each ring as the measurement does, ``ring_of`` (each grid
    component's ring index into ``ratio``, -1 outside), ``sin_grid`` (its sin θo) and
    ``single_grid`` (its single-pass diffuse intensity, the ensemble mean).
    """
    from scipy import fft as sfft
    check_range("area_fraction", area_fraction, 0.0, 1.0, lo_open=True, hi_open=True)
    k = 2 * np.pi / (wavelength * 1e-3)
    kx = 2 * np.pi * np.fft.fftfreq(n_samples, d=length / n_samples)
    kt = np.hypot(kx[:, None], kx[None, :])
    prop = kt < k
    sin_o = kt / k
    step = wavelength * 1e-3 / length
    n_rings = int(0.99 / step) if n_rings is None else n_rings
    ring = np.minimum((sin_o / step + 0.5).astype(np.int64), n_rings)     # ring 0: the coherent beam
    ring[~prop] = n_rings
    amps = {p: round_trip_orders(kt, k, ior, thickness, back, p, orders) for p in ("TE", "TM")}
    rng = np.random.default_rng(seed)
    single = np.zeros((n_screens, n_rings + 1))
    single_grid = np.zeros(kt.shape)
    double = np.zeros((n_screens, n_rings + 1))
    tm = []
    for i, t in enumerate(disc_screens(rng, n_screens, n_samples, length, radius, area_fraction)):
        a = sfft.fft2(t) / t.size
        a = np.where(prop, a, 0.0)
        single[i] = np.bincount(ring.ravel(), (np.abs(a) ** 2).ravel(), n_rings + 1)
        single_grid += np.abs(a) ** 2 / n_screens
        tm.append(t.mean())
        inten = np.zeros(t.shape)
        for p in ("TE", "TM"):
            for r_j in amps[p]:
                c = sfft.fft2(t * sfft.ifft2(r_j * a, workers=2), workers=2)
                inten += 0.5 * np.abs(np.where(prop, c, 0.0)) ** 2
        double[i] = np.bincount(ring.ravel(), inten.ravel(), n_rings + 1)
    coherent = float(np.mean(tm)) ** 2
    keep = slice(1, n_rings)
    ratio = double[:, keep].sum(0) / np.maximum(coherent * single[:, keep].sum(0), 1e-300)
    per = double[:, keep] / np.maximum(coherent * single[:, keep], 1e-300)
    sigma = per.std(0, ddof=1) / np.sqrt(n_screens) if n_screens > 1 else np.full(ratio.shape, np.nan)
    count = np.bincount(ring.ravel(), minlength=n_rings + 1)[keep]
    ring_of = np.where((ring >= 1) & (ring < n_rings), ring - 1, -1)
    return {"sin_o": np.arange(1, n_rings) * step, "ratio": ratio, "sigma": sigma, "count": count,
            "coherent": coherent, "ring_of": ring_of, "sin_grid": sin_o, "single_grid": single_grid}
