"""The pane under a layer: a glass sheet, bare or back-silvered (numpy reference).

A fogged window is droplets on glass, and glass reflects.  :class:`GlassPane`
is the sheet of glass the corona layer sits on, :class:`Mirror` a pane
silvered on its back face; :class:`corona.Material` combines them with the
layer (see ``docs/physics.md#the-layer-on-glass-substrateglass`` for which
inter-reflections the combination keeps and which it drops).

With a thickness, the light a particle scatters on its way to the back face
and the light it scatters on its way out interfere: the coherent double pass
of Stokes' "colours of thick plates", which draws Quetelet rings
(:meth:`GlassPane.reflected_lobe_factor`,
``docs/physics.md#the-coherent-double-pass-quetelet-rings``).
"""
from __future__ import annotations

import numpy as np

from corona._validation import CoronaError, check_choice, check_range

SIDES = ("front", "back")
#: Index of refraction of window (soda-lime) glass at 550 nm.
GLASS_IOR = 1.52
#: Thickness of a mirror's glass when none is given [µm] (a 4 mm mirror).
MIRROR_THICKNESS = 4000.0
#: Reflectance of the silvering seen from inside the glass at normal incidence: silver
#: (n ≈ 0.06 + 3.6i near 550 nm, P. B. Johnson, R. W. Christy, Phys. Rev. B 6, 4370 (1972))
#: behind glass of index 1.52 gives |(1.52 - N)/(1.52 + N)|² ≈ 0.975; 0.97 allows for the
#: protective layers of a household mirror.
SILVER_REFLECTANCE = 0.97
#: Named silverings: the metal's complex index (Mitsuba 3's tabulated optical constants,
#: ``mitsuba/data/ior/<X>.eta.spd`` and ``.k.spd``) behind the glass, ``|(n - N) / (n + N)|²``.
METALS = {"silver": "Ag", "aluminium": "Al", "aluminum": "Al", "gold": "Au", "copper": "Cu"}
#: Wavelengths [nm] on which a named or textual silvering spectrum is tabulated.
SPECTRUM_GRID = np.arange(360.0, 831.0, 5.0)
#: Allowed pane thickness [µm] for the coherent double pass (0.05–100 mm).
THICKNESS_RANGE = (50.0, 1.0e5)
#: Internal round trips whose interference is summed in closed form (all of them); the
#: channel-averaged (RGB) form truncates after this many, the rest below T² R_b (R_b R)^3.
RGB_ORDERS = 3
#: The channel-averaged fringe table: path differences up to this [µm], every DELTA_STEP [µm].
DELTA_MAX = 100.0
DELTA_STEP = 0.25


def metal_reflectance(metal: str, ior: float, wavelengths=SPECTRUM_GRID) -> np.ndarray:
    """Normal-incidence reflectance of a metal seen from inside glass of index ``ior``.

    ``R_m(λ) = |(n - N) / (n + N)|²`` with ``N = η + iκ`` the metal's complex index from Mitsuba 3's
    tabulated optical constants (``mitsuba/data/ior``, from the luxpop database), interpolated
    linearly in ``λ`` [nm].  The metal is one of :data:`METALS`.  Silver behind glass of 1.52:
    0.84 at 400 nm, 0.90 at 450 nm, 0.945 at 550 nm, 0.957 at 650 nm.
    """
    import importlib.util
    import os
    import sys
    name = check_choice("mirror_reflectance", metal, tuple(METALS))
    module = sys.modules.get("mitsuba")
    origin = getattr(module, "__file__", None)
    if origin is None:
        spec = importlib.util.find_spec("mitsuba")
        origin = None if spec is None else spec.origin
    base = None if origin is None else os.path.join(os.path.dirname(origin), "data", "ior", METALS[name])
    if base is None or not os.path.isfile(base + ".eta.spd"):
        raise CoronaError(f"mirror_reflectance={metal!r} needs Mitsuba 3's tabulated optical constants "
                          "(pip install mitsuba); give a number or a 'wavelength:value, ...' spectrum instead")
    eta, kappa = (np.loadtxt(base + ext, comments="#") for ext in (".eta.spd", ".k.spd"))
    lam = np.asarray(wavelengths, dtype=np.float64)
    n_c = np.interp(lam, eta[:, 0], eta[:, 1]) + 1j * np.interp(lam, kappa[:, 0], kappa[:, 1])
    return np.abs((ior - n_c) / (ior + n_c)) ** 2


def parse_spectrum(text: str, name: str = "mirror_reflectance"):
    """``'λ:value, λ:value, ...'`` (Mitsuba's spectrum syntax, λ in nm) as two arrays."""
    try:
        pairs = [item.split(":") for item in str(text).replace(";", ",").split(",") if item.strip()]
        lam, val = (np.array([float(p[i]) for p in pairs]) for i in (0, 1))
        if any(len(p) != 2 for p in pairs):
            raise ValueError
    except (ValueError, IndexError):
        raise CoronaError(f"{name}={text!r} is not a spectrum; allowed a number in [0, 1], a metal "
                          f"({', '.join(METALS)}) or 'wavelength:value, ...' (nm in [360, 830], "
                          "increasing)") from None
    return lam, val


def fresnel_dielectric(cos_theta_i, eta) -> np.ndarray:
    """Unpolarised Fresnel reflectance of one air → dielectric interface.

    Parameters
    ----------
    cos_theta_i : array
        Cosine of the angle of incidence, |cos| is used (the interface is
        entered from the air side, so there is no total internal reflection).
    eta : float
        Relative index of refraction ``n_glass / n_air`` (>= 1).

    Returns
    -------
    R = (r_s² + r_p²) / 2 with ``r_s = (cos_i - η cos_t) / (cos_i + η cos_t)``,
    ``r_p = (η cos_i - cos_t) / (η cos_i + cos_t)`` and Snell's
    ``sin_t = sin_i / η`` (M. Born, E. Wolf, *Principles of Optics*, §1.5.2).
    """
    ci = np.clip(np.abs(np.asarray(cos_theta_i, dtype=np.float64)), 0.0, 1.0)
    st2 = (1.0 - ci * ci) / (eta * eta)
    ct = np.sqrt(np.maximum(0.0, 1.0 - st2))
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = (ci - eta * ct) / (ci + eta * ct)
        rp = (eta * ci - ct) / (eta * ci + ct)
        r = 0.5 * (rs * rs + rp * rp)
    return np.where(ci > 0, r, 1.0)


class GlassPane:
    """A thin, flat, non-absorbing pane (the substrate of a layer).

    Parameters
    ----------
    ior : float >= 1, default 1.52
        Index of refraction of the glass (the surroundings are air, n = 1).
    side : {"front", "back"}
        The face of the pane that carries the layer, in the layer's local
        frame: ``front`` is the +z face (the side the shading normal points
        to), ``back`` the -z face.

    Notes
    -----
    The pane is thin: a ray leaves it parallel to the way it entered (the
    two faces are parallel), so it only splits light into a specular
    reflection and an undeviated transmission.  Summing the incoherent
    bounces between its two faces (R, TRT, TR³T, ...), with the same
    single-face reflectance R on both faces (Stokes relations),

        R' = R + T² R / (1 - R²) = 2R / (1 + R),       T' = 1 - R' = (1 - R) / (1 + R),

    applied to the polarisation-averaged Fresnel reflectance R, the way
    Mitsuba 3's ``thindielectric`` plugin does.  The pane is dispersion-free
    (one index for every wavelength).
    """

    def __init__(self, ior: float = GLASS_IOR, side: str = "front", thickness: float | None = None):
        self.ior = check_range("substrate_ior", ior, 1.0, np.inf, hi_open=True)
        self.side = check_choice("substrate_side", side, SIDES)
        self.thickness = None if thickness is None else check_range("substrate_thickness", thickness,
                                                                    *THICKNESS_RANGE)

    def __repr__(self):
        t = "" if self.thickness is None else f", thickness={self.thickness:g}"
        return f"{type(self).__name__}(ior={self.ior:g}, side={self.side!r}{t})"

    def key(self) -> dict:
        return {"ior": self.ior, "side": self.side, "thickness": self.thickness}

    @property
    def coherent(self) -> bool:
        """True when the two passes through the layer interfere (a thickness is given)."""
        return self.thickness is not None

    def face_reflectance(self, cos_theta) -> np.ndarray:
        """Fresnel reflectance R of one face at incidence ``cos_theta``."""
        return fresnel_dielectric(cos_theta, self.ior)

    def reflectance(self, cos_theta, wavelength=None) -> np.ndarray:
        """Specular reflectance of the whole pane, ``R' = 2R / (1 + R)`` (no dispersion)."""
        r = self.face_reflectance(cos_theta)
        return 2.0 * r / (1.0 + r)

    def transmittance(self, cos_theta) -> np.ndarray:
        """Undeviated transmittance of the pane, ``T' = 1 - R'`` (no absorption)."""
        return 1.0 - self.reflectance(cos_theta)

    def layer_first(self, cos_theta_i) -> np.ndarray:
        """True where light arriving from the direction ``wi`` (signed ``cos θi``
        in the layer's frame) meets the layer before the glass."""
        c = np.asarray(cos_theta_i, dtype=np.float64)
        return c > 0 if self.side == "front" else c < 0

    # --- the coherent double pass --------------------------------------------------------
    def back_reflectance(self, cos_theta, wavelength) -> np.ndarray:
        """Reflectance ``R_b`` of the back face seen from inside, for light that left the
        air at ``cos_theta``: bare glass, the same Fresnel ``R`` (Stokes)."""
        return self.face_reflectance(cos_theta) + 0.0 * np.asarray(wavelength, dtype=np.float64)

    def round_trips(self, cos_theta, wavelength, orders: int) -> np.ndarray:
        """Intensities ``I_k``, k = 0 .. orders - 1, of the paths that leave the front face after
        ``k`` round trips through the glass (air at ``cos_theta``; shape ``(orders, ...)``).

        ``I_0 = R`` (the front face), ``I_k = T² R_b (R R_b)^(k-1)`` with ``T = 1 - R``;
        ``Σ_k I_k`` is the pane's :meth:`reflectance`.
        """
        r = self.face_reflectance(cos_theta)
        rb = self.back_reflectance(cos_theta, wavelength)
        k = np.arange(orders).reshape((-1,) + (1,) * np.ndim(r * rb))
        return np.where(k == 0, r, (1 - r) ** 2 * rb * (r * rb) ** np.maximum(k - 1, 0))

    def path_difference(self, cos_s, cos_o) -> np.ndarray:
        """``Δ = 2 n t (cos r_s - cos r_o)`` [µm]: the extra optical path of one round trip
        at the source's refracted angle over one at the observer's.

        ``r`` are the angles in the glass, ``sin r = sin θ / n`` (``|cos θ|`` given); written as
        ``2 t (sin²θ_o - sin²θ_s) / (n (cos r_s + cos r_o))`` (no cancellation near Δ = 0).
        """
        n, t = self.ior, float(self.thickness)
        s2s = 1.0 - np.minimum(np.asarray(cos_s, dtype=np.float64) ** 2, 1.0)
        s2o = 1.0 - np.minimum(np.asarray(cos_o, dtype=np.float64) ** 2, 1.0)
        crs = np.sqrt(1.0 - s2s / (n * n))
        cro = np.sqrt(1.0 - s2o / (n * n))
        return 2.0 * t * (s2o - s2s) / (n * (crs + cro))

    def interference(self, cos_s, cos_o, wavelength) -> np.ndarray:
        """``Q = Σ_{k≥1} √(I_k(θs) I_k(θo)) cos(2π k Δ / λ)``, summed in closed form.

        With ``a = T_s T_o R_b`` and ``x = R_b √(R_s R_o)``:
        ``Q = a (cos Φ - x) / (1 - 2 x cos Φ + x²)``, ``Φ = 2πΔ/λ`` (``wavelength`` in nm).
        ``|Q| <= (R'(θs) + R'(θo)) / 2``.
        """
        lam = np.asarray(wavelength, dtype=np.float64) * 1e-3
        rs, ro = self.face_reflectance(cos_s), self.face_reflectance(cos_o)
        rbs, rbo = self.back_reflectance(cos_s, wavelength), self.back_reflectance(cos_o, wavelength)
        rb = np.sqrt(rbs * rbo)
        a = (1 - rs) * (1 - ro) * rb
        x = rb * np.sqrt(rs * ro)
        c = np.cos(2 * np.pi * self.path_difference(cos_s, cos_o) / lam)
        return a * (c - x) / (1.0 - 2.0 * x * c + x * x)

    def inner_reflectance(self, cos_theta, wavelength=550.0) -> np.ndarray:
        """``P = R' - R = Σ_{k≥1} I_k``: the part of the pane's reflectance that has crossed the
        glass (every round trip), at ``|cos θ|``; the front face's own ``R`` is the rest."""
        c = np.abs(np.asarray(cos_theta, dtype=np.float64))
        return self.reflectance(c, wavelength) - self.face_reflectance(c)

    def specular_through_layer(self, cos_theta, wavelength, coherent) -> np.ndarray:
        """Weight of the pane's mirror image seen through a layer on its face (light meets the
        layer first): ``C R + C² P``.

        The front face reflects the light that crossed the layer back through the same place of
        the layer (a screen on the face is crossed once, ``t(x)² = t(x)`` for a binary screen:
        ``C R``); the light of the round trips crosses it a second time (``C² P``,
        :meth:`inner_reflectance`).  ``coherent`` is the layer's ``C``.
        """
        c = np.abs(np.asarray(cos_theta, dtype=np.float64))
        return coherent * self.face_reflectance(c) + coherent * coherent * self.inner_reflectance(c, wavelength)

    def reflected_lobe_factor(self, cos_s, cos_o, wavelength, coherent, visibility=1.0) -> np.ndarray:
        """The pane's factor on the lobe ``f`` seen in reflection (light meets the layer first).

            min(R_s, R_o) + C [P_s + P_o + 2 V Q(θs, θo, λ)]

        ``R`` the front face's Fresnel reflectance, ``P`` the round trips'
        (:meth:`inner_reflectance`), ``C`` = ``coherent``, the layer's coherent weight.  The front
        face reflects the lobe once (a screen on the face: ``R f``, not ``2 C R f``); the
        smaller of the two angles' ``R`` keeps it reciprocal and within each scattered
        direction's budget (equal to first order about the mirror direction).  The round trips
        add the two single-scattering paths (scattered on the way in, or on the way out), and,
        with a thickness, their interference ``Q`` (:meth:`interference`) with the energy cap's
        visibility ``V`` in [0, 1] (:func:`double_pass_visibility`); without a thickness the two
        paths add incoherently.  See ``docs/physics.md#the-front-face``.
        """
        cs, co = np.abs(np.asarray(cos_s, dtype=np.float64)), np.abs(np.asarray(cos_o, dtype=np.float64))
        front = np.minimum(self.face_reflectance(cs), self.face_reflectance(co))
        inner = self.inner_reflectance(cs, wavelength) + self.inner_reflectance(co, wavelength)
        if self.coherent:
            inner = inner + 2.0 * visibility * self.interference(cs, co, wavelength)
        return front + coherent * inner


class Mirror(GlassPane):
    """A back-silvered glass pane: the layer on its front (+z) face, silver behind the glass.

    Parameters
    ----------
    ior : float >= 1, default 1.52
        Index of the glass.
    thickness : float [µm], default 4000
        Thickness of the glass (the two passes through the layer interfere; always coherent).
    reflectance : float in [0, 1], str, or (wavelengths [nm], values), default 0.97
        Reflectance ``R_m`` of the silvering seen from inside the glass, constant in angle:
        a number; a metal of :data:`METALS` (``"silver"``: its tabulated spectrum behind this
        glass, :func:`metal_reflectance`); ``'λ:value, ...'`` text or a (wavelengths, values)
        pair, interpolated linearly (clamped at its ends).

    Notes
    -----
    The air-side reflectance sums the front face and every round trip incoherently,
    ``R' = R + T² R_m / (1 - R R_m)``; nothing is transmitted (``T' = 0``), and the back of
    the mirror (light from -z) is black.
    """

    def __init__(self, ior: float = GLASS_IOR, thickness: float | None = None,
                 reflectance=SILVER_REFLECTANCE):
        super().__init__(ior, "front", MIRROR_THICKNESS if thickness is None else thickness)
        if isinstance(reflectance, str) and reflectance.strip().lower() in METALS:
            self.metal = reflectance.strip().lower()
            self._rm = (SPECTRUM_GRID, metal_reflectance(self.metal, self.ior))
            return
        self.metal = None
        if isinstance(reflectance, str):
            try:
                reflectance = float(reflectance)
            except ValueError:
                reflectance = parse_spectrum(reflectance)
        if np.ndim(reflectance) == 0:
            self._rm = (None, float(check_range("mirror_reflectance", reflectance, 0.0, 1.0)))
        else:
            lam, val = (np.asarray(a, dtype=np.float64) for a in reflectance)
            if lam.ndim != 1 or lam.shape != val.shape or lam.size < 2 or np.any(np.diff(lam) <= 0):
                raise CoronaError("mirror_reflectance spectrum must be (wavelengths, values), two 1-D arrays "
                                  "of the same length >= 2 with increasing wavelengths")
            from corona.model.tabulated import WAVELENGTH_MAX, WAVELENGTH_MIN
            bad = lam[~((lam >= WAVELENGTH_MIN) & (lam <= WAVELENGTH_MAX))]
            if bad.size:     # -5 and 99999 nm were taken (the ends are held flat beyond the data)
                raise CoronaError(f"mirror_reflectance spectrum wavelength {float(bad[0])!r} nm is out of range; "
                                  f"allowed [{WAVELENGTH_MIN:g}, {WAVELENGTH_MAX:g}] nm (Mitsuba's spectral range, "
                                  "MI_CIE_MIN..MI_CIE_MAX)")
            for v in val:
                check_range("mirror_reflectance", float(v), 0.0, 1.0)
            self._rm = (lam, val)

    def __repr__(self):
        rm = self._rm[1] if self._rm[0] is None else repr(self.metal or "spectrum")
        return f"Mirror(ior={self.ior:g}, thickness={self.thickness:g}, reflectance={rm})"

    def key(self) -> dict:
        lam, val = self._rm
        return {**super().key(), "mirror": val if lam is None else (tuple(lam), tuple(val))}

    @property
    def spectral(self) -> bool:
        """True when the silvering's reflectance depends on the wavelength."""
        return self._rm[0] is not None

    def silver(self, wavelength) -> np.ndarray:
        """``R_m(λ)`` of the silvering (``wavelength`` in nm)."""
        lam, val = self._rm
        w = np.asarray(wavelength, dtype=np.float64)
        return np.full(w.shape, val) if lam is None else np.interp(w, lam, val)

    def back_reflectance(self, cos_theta, wavelength) -> np.ndarray:
        return self.silver(wavelength) + 0.0 * np.asarray(cos_theta, dtype=np.float64)

    def reflectance(self, cos_theta, wavelength=550.0) -> np.ndarray:
        """``R' = R + T² R_m / (1 - R R_m)`` from the front (signed ``cos θ > 0``), 0 from behind."""
        c = np.asarray(cos_theta, dtype=np.float64)
        r = self.face_reflectance(c)
        rm = self.silver(wavelength)
        return np.where(c >= 0, r + (1 - r) ** 2 * rm / (1 - r * rm), 0.0)

    def transmittance(self, cos_theta) -> np.ndarray:
        return np.zeros(np.shape(cos_theta))

    def layer_first(self, cos_theta_i) -> np.ndarray:
        return np.asarray(cos_theta_i, dtype=np.float64) > 0


def double_pass_visibility(coherent: float, lobe: float, reflectance: float) -> float:
    """The energy cap's visibility ``V`` in [0, 1] of the double pass's interference.

    With the layer's ``C`` (``coherent``), ``D`` (``lobe``, its plane integral, evanescent part
    included: an upper bound) and ``ρ`` (``reflectance``), the light reflected plus transmitted
    exceeds the layer's own ``ρ + C + D`` by an amount linear in the round trips' ``P_s`` in
    [0, 1], zero at ``P_s = 0`` unless ``C V > 1 - C``.  Two bounds on it
    (``docs/physics.md#energy``), each sufficient, give

        V₁ = min((1 - ρ - C² - 2CD) / 2CD, (1 - ρ - C - CD) / CD, E),   E = (1 - ρ - C² - D - CD) / CD
        V₂ = √(E (1 - C) / C)

    (``|Q| <= (P_s + P_o) / 2`` and ``|Q| <= √(P_s P_o)`` with the best ``P_o``), and
    ``V = min(1, max(V₁, V₂, 0))``: 1 for every layer with some slack, 0 where the layer
    itself returns all the light (``E = 0``).
    """
    c, d, rho = float(coherent), float(lobe), float(reflectance)
    cd = c * d
    if cd <= 0:
        return 1.0
    e = (1.0 - rho - c * c - d - cd) / cd
    v1 = min((1.0 - rho - c * c - 2.0 * cd) / (2.0 * cd), (1.0 - rho - c - cd) / cd, e)
    v2 = np.sqrt(max(e, 0.0) * (1.0 - c) / c)
    return float(np.clip(max(v1, v2), 0.0, 1.0))


def channel_envelopes(wavelengths, responses, n_per_channel: int, delta_max: float = DELTA_MAX,
                      step: float = DELTA_STEP, n_fine: int = 8000):
    """Bin-averaged ``cos(2π Δ σ)`` of each channel's equal-weight bins, as a table in ``Δ``.

    The renderer's RGB / mono channels are each the mean of the lobe at ``n_per_channel``
    wavelengths, the midpoints of equal-weight quantile bins of the channel's response.  The
    double pass's ``cos(2π Δ / λ)`` is averaged over each bin with the response as weight,

        G_q(Δ) = ∫_bin r(λ) λ⁻² cos(2π Δ / λ) dλ / ∫_bin r(λ) λ⁻² dλ = Re[e^{2πiΔσ_q} E_q(Δ)],

    weighted by the response and by the lobe's own ``λ⁻²`` (the height ``F_a (L/λ)² v(0)`` of
    its forward peak, where the rings are), so that the bin's one lobe value times ``G_q`` is
    the bin's average of lobe times fringes (a wide bin, like the one across the gap between
    the red channel's two lobes, would otherwise mix a bright blue end with a dim red one),
    with ``σ_q`` the bin's mean wavenumber [1/µm] and the envelope
    ``E_q(Δ) = <e^{2πiΔ(σ - σ_q)}>_bin``, which varies slowly (on the bin's coherence length
    ``1/δσ``) and is tabulated every ``step`` µm up to ``delta_max`` (0 beyond: there every
    channel's average is below 10⁻³).  The bins together average over the whole channel, so
    fringes wash out as they do in white light instead of aliasing
    between the sample wavelengths.

    Parameters
    ----------
    wavelengths : array (n,)
        Grid [nm] of the responses.
    responses : array (channels, n)
        Non-negative spectral responses.

    Returns
    -------
    sigma : array (channels, n_per_channel) [1/µm]
    envelope : complex array (channels, n_per_channel, n_delta), ``Δ = 0, step, ...``
    """
    lam0 = np.asarray(wavelengths, dtype=np.float64)
    lam = np.linspace(lam0[0], lam0[-1], n_fine)
    delta = np.arange(int(np.ceil(delta_max / step)) + 1) * step
    sig_all, env_all = [], []
    for r0 in np.asarray(responses, dtype=np.float64):
        r = np.interp(lam, lam0, r0)
        w = r * np.gradient(lam)
        cdf = np.cumsum(w) - 0.5 * w
        q = np.minimum((cdf / w.sum() * n_per_channel).astype(int), n_per_channel - 1)
        sig_c, env_c = [], []
        for b in range(n_per_channel):
            m = q == b
            sg = 1e3 / lam[m]
            wb = w[m] * sg * sg                 # the lobe's own λ⁻² (its forward peak F_a (L/λ)² v(0))
            wb = wb / wb.sum()
            sc = float(np.sum(wb * sg))
            sig_c.append(sc)
            env_c.append(np.exp(2j * np.pi * delta[:, None] * (sg - sc)[None]) @ wb)
        sig_all.append(sig_c)
        env_all.append(env_c)
    return np.array(sig_all), np.array(env_all)


def channel_average_cos(sigma, envelope, delta, step: float = DELTA_STEP) -> np.ndarray:
    """``G_q(|Δ|)`` from :func:`channel_envelopes` (linear in the envelope; 0 beyond the table)."""
    d = np.abs(np.asarray(delta, dtype=np.float64))
    x = d / step
    n = envelope.shape[-1]
    i = np.minimum(np.floor(x).astype(int), n - 2)
    t = x - i
    e = envelope[..., np.clip(i, 0, n - 2)] * (1 - t) + envelope[..., np.clip(i + 1, 0, n - 1)] * t
    e = np.where(x <= n - 1, e, 0.0)
    return np.real(np.exp(2j * np.pi * sigma[..., None] * d) * e)


def interference_integral(material, cos_theta_i: float, wavelength: float, phi_i: float = 0.0,
                          n_rings: int = 1500, n_phi: int = 256, per_fringe: int = 16) -> float:
    """``∫ f(d) Q(θi, θo, λ) d²d`` over the reflected hemisphere, the fringes resolved.

    ``Q`` (:meth:`GlassPane.interference`) depends on ``wo`` only through ``sin θo = s``, so
    the integral is ``∫₀¹ Q(s) h(s) s ds`` with ``h(s) = ∫ f(s e_φ + wi.xy) dφ`` the lobe
    (:meth:`corona.Material.lobe_tabulated`) on rings around the normal, taken on
    ``n_rings`` rings × ``n_phi`` azimuths and interpolated (cubic) onto a grid in ``s`` with
    ``per_fringe`` points per fringe at the fastest (``s → 1``).
    """
    pane = material.substrate
    ci = abs(float(cos_theta_i))
    si = np.sqrt(max(0.0, 1.0 - ci * ci))
    wx, wy = si * np.cos(phi_i), si * np.sin(phi_i)
    # rings: denser near the light's image (s = sin θi), where the lobe peaks
    x = np.linspace(-1.0, 1.0, n_rings)
    s = np.unique(np.clip(si + np.sign(x) * np.abs(x) ** 2 * max(si, 1.0 - si) * 1.0001, 0.0, 1.0))
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    d = np.stack([s[:, None] * np.cos(phi) + wx, s[:, None] * np.sin(phi) + wy], -1)
    h = material.lobe_tabulated(d, wavelength).sum(-1) * (2 * np.pi / n_phi)
    from scipy.interpolate import CubicSpline    # (0.4 s of import: loaded where used)
    spline = CubicSpline(s, h)
    n = pane.ior
    slope = 2.0 * pane.thickness / (n * np.sqrt(1.0 - 1.0 / (n * n))) / (wavelength * 1e-3)   # fringes per unit s
    fine = np.linspace(0.0, 1.0, int(per_fringe * slope) + 2)
    co = np.sqrt(np.maximum(0.0, 1.0 - fine * fine))
    g = pane.interference(ci, co, wavelength) * np.maximum(spline(fine), 0.0) * fine
    return float(np.trapezoid(g, fine))


# --- what the numpy layer holds: one object per substrate, chosen once ----------------------------
class BareLayer:
    """No substrate: the layer alone.  Every pane factor is the identity (``R' = 0``, ``T' = 1``),
    light always meets the layer first, nothing is reflected specularly.

    :class:`corona.Material` and the Mie layer hold one of :class:`BareLayer`, :class:`OnPane` or
    :class:`DoublePass` (:func:`layer_substrate`), chosen once when they are built, and ask it for
    every pane term of ``eval``, ``specular_reflection`` and ``directional_albedo``.
    """

    pane = None

    def __repr__(self):
        return "BareLayer()"

    def fresnel(self, cos_theta, wavelength=550.0):
        """``(R', T')`` of the pane at ``cos θ``: (0, 1)."""
        c = np.asarray(cos_theta, dtype=np.float64)
        return np.zeros_like(c), np.ones_like(c)

    def layer_first(self, cos_theta_i) -> np.ndarray:
        """True where light from ``wi`` meets the layer before the pane: everywhere."""
        return np.ones(np.shape(cos_theta_i), bool)

    def specular_reflection(self, layer, cos_theta_i, wavelength) -> np.ndarray:
        """The delta reflection's weight: 0 (``layer``'s coherent weight is not read)."""
        return np.zeros_like(np.asarray(cos_theta_i, dtype=np.float64))

    def reflected_lobe_factor(self, layer, cos_i, cos_o, wavelength) -> np.ndarray:
        """The factor on ``layer``'s lobe seen in reflection: 0."""
        return np.zeros(np.broadcast(cos_i, cos_o).shape)

    def lobe_factors(self, cos_i, cos_o, coherent, wavelength=550.0):
        """(far side, own side, mirrored) factors of a layer's own lobes: (1, 1, 0)."""
        shape = np.broadcast(cos_i, cos_o).shape
        return np.ones(shape), np.ones(shape), np.zeros(shape)

    def front_and_round_trips(self, cos_i, cos_o, wavelength, coherent) -> np.ndarray:
        """``min(R_i, R_o) + C (P_i + P_o)`` over the reflected directions: 0."""
        return np.zeros_like(cos_o)

    def reflected_lobe_energy(self, layer, incoherent, cos_theta_i, wavelength, phi_i) -> float:
        """The reflected lobe's energy, the double pass's interference added: ``incoherent``."""
        return incoherent

    def lobes_on_pane(self, value, mirrored_value, wi, wo, coherent):
        """A layer's lobes ``value`` at ``wo`` as the pane passes them on: unchanged."""
        return value


class OnPane(BareLayer):
    """The layer on a thin pane without a thickness (:class:`GlassPane`): its Fresnel terms,
    the front face's reflection of the lobe and the round trips, summed incoherently."""

    def __init__(self, pane: GlassPane):
        self.pane = pane

    def __repr__(self):
        return f"{type(self).__name__}({self.pane!r})"

    def fresnel(self, cos_theta, wavelength=550.0):
        c = np.asarray(cos_theta, dtype=np.float64)
        return self.pane.reflectance(c, wavelength), self.pane.transmittance(c)

    def layer_first(self, cos_theta_i) -> np.ndarray:
        return self.pane.layer_first(np.asarray(cos_theta_i, dtype=np.float64))

    def specular_reflection(self, layer, cos_theta_i, wavelength) -> np.ndarray:
        """``C R + C² P`` where light meets the layer first (:meth:`GlassPane.specular_through_layer`;
        ``C`` is ``layer.coherent_weight``), ``R'`` where it meets the glass first."""
        r = self.pane.reflectance(np.asarray(cos_theta_i, dtype=np.float64), wavelength)
        through = self.pane.specular_through_layer(cos_theta_i, wavelength, layer.coherent_weight(cos_theta_i,
                                                                                                   wavelength))
        return np.where(self.layer_first(cos_theta_i), through, r)

    def reflected_lobe_factor(self, layer, cos_i, cos_o, wavelength) -> np.ndarray:
        """:meth:`GlassPane.reflected_lobe_factor` at ``|cos θ|`` with ``layer``'s coherent weight
        ``C`` (:attr:`corona.Material.coherent_transmittance`; the paths add incoherently)."""
        return self.pane.reflected_lobe_factor(np.abs(cos_i), np.abs(cos_o), wavelength,
                                               layer.coherent_transmittance, 1.0)

    def lobe_factors(self, cos_i, cos_o, coherent, wavelength=550.0):
        """(far side ``T'``, own side ``1`` or ``T'(θi) T'(θo)``, mirrored
        :meth:`GlassPane.reflected_lobe_factor`) where light meets the layer first / the glass."""
        first = self.layer_first(cos_i)
        ri, ti = self.fresnel(cos_i)
        ro, to = self.fresnel(cos_o)
        through = np.where(first, to, ti)
        own = np.where(first, 1.0, ti * to)
        # the front face reflects the lobe once, the round trips cross the layer again
        mirrored = np.where(first, self.pane.reflected_lobe_factor(cos_i, cos_o, wavelength, coherent), 0.0)
        return through, own, mirrored

    def front_and_round_trips(self, cos_i, cos_o, wavelength, coherent) -> np.ndarray:
        pane = self.pane
        front = np.minimum(pane.face_reflectance(cos_i), pane.face_reflectance(cos_o))
        return front + coherent * (pane.inner_reflectance(cos_i, wavelength) + pane.inner_reflectance(cos_o, wavelength))

    def lobes_on_pane(self, value, mirrored_value, wi, wo, coherent):
        """``f + F f(wo')`` on the side of ``wi``, ``f T'`` on the far side (light meets the layer
        first; ``T'(θi) f (T'(θo))`` when it meets the glass first); ``mirrored_value(wo')`` is the
        layer's lobe at ``wo``'s mirror image in the layer's plane."""
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        ci, co = np.broadcast_arrays(wi[..., 2], wo[..., 2])
        through, own, mirrored = self.lobe_factors(ci, co, coherent)
        same = ci * co > 0
        val_m = mirrored_value(wo * np.array([1.0, 1.0, -1.0]))
        return np.where(same, value * own + mirrored * val_m, value * through)


class DoublePass(OnPane):
    """The layer on a pane with a thickness: a :class:`GlassPane` given one, or a :class:`Mirror`
    (always; its silvering's reflectance, constant or a spectrum, is the pane's own).  The two
    passes through the layer interfere (Quetelet rings), with the visibility ``V`` of the energy
    cap (:func:`double_pass_visibility`: the layer's ``double_pass_visibility``)."""

    def reflected_lobe_factor(self, layer, cos_i, cos_o, wavelength) -> np.ndarray:
        """``min(R_i, R_o) + C [P_i + P_o + 2 V Q]`` (:meth:`GlassPane.reflected_lobe_factor`)."""
        return self.pane.reflected_lobe_factor(np.abs(cos_i), np.abs(cos_o), wavelength,
                                               layer.coherent_transmittance, layer.double_pass_visibility)

    def reflected_lobe_energy(self, layer, incoherent, cos_theta_i, wavelength, phi_i) -> float:
        """``incoherent + 2 V C ∫ f Q`` (:func:`interference_integral`)."""
        return incoherent + 2.0 * layer.double_pass_visibility * layer.coherent_transmittance * \
            interference_integral(layer, cos_theta_i, wavelength, phi_i)


def layer_substrate(pane: GlassPane | None) -> BareLayer:
    """The substrate component of a layer on ``pane`` (None: :class:`BareLayer`; a pane with a
    thickness, a mirror included: :class:`DoublePass`; else :class:`OnPane`)."""
    if pane is None:
        return BareLayer()
    return DoublePass(pane) if pane.coherent else OnPane(pane)


def make_substrate(kind: str, ior=None, side: str = "front", thickness=None,
                   mirror_reflectance=None) -> GlassPane | None:
    """The substrate of ``substrate=kind`` (None for ``none``), with one clear error."""
    kind = check_choice("substrate", kind, ("none", "glass", "mirror"))
    if kind == "none":
        for name, v in (("substrate_ior", ior), ("substrate_thickness", thickness),
                        ("mirror_reflectance", mirror_reflectance)):
            if v is not None:
                raise CoronaError(f"{name}={v!r} needs substrate='glass' or 'mirror' (got substrate='none')")
        return None
    ior = GLASS_IOR if ior is None else ior
    if kind == "mirror":
        return Mirror(ior, thickness, SILVER_REFLECTANCE if mirror_reflectance is None else mirror_reflectance)
    if mirror_reflectance is not None:
        raise CoronaError(f"mirror_reflectance={mirror_reflectance!r} needs substrate='mirror' (got 'glass')")
    return GlassPane(ior, side, thickness)
