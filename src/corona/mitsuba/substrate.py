"""What lies under a flat ``corona`` layer, in Dr.Jit: nothing, a glass pane, or a back-silvered mirror.

One object per substrate, chosen once at load by :func:`substrate_component`; the plugin
(:mod:`corona.mitsuba.bsdf`) calls it in ``eval``, ``pdf`` and ``sample`` and reads no substrate
flag there.  Every kind has the same interface:

- :meth:`~BareLayer.components`: its BSDF components after the layer's three (the pane: 3, its
  specular reflection, ``DeltaReflection``; 4, the lobe seen in reflection, ``GlossyReflection``);
- :meth:`~BareLayer.energies`: the components' energies that choose one in ``sample``;
- :meth:`~BareLayer.delta_weights`: the weights of the coherent beam and the specular reflection;
- :meth:`~BareLayer.modulation` and :meth:`~BareLayer.smooth`: the Fresnel factors on the smooth
  components (the table of :mod:`corona.mitsuba.bsdf`'s docstring), the coherent double pass
  (Quetelet rings) where the pane has a thickness;
- :meth:`~BareLayer.pick`, :meth:`~BareLayer.lobe_share`, :meth:`~BareLayer.sampled`,
  :meth:`~BareLayer.delta_sample`: its part of ``sample``.

The physics: docs/physics.md#the-layer-on-glass-substrateglass and
#the-coherent-double-pass-quetelet-rings; the numpy model: :mod:`corona.model.substrate`.
"""
from __future__ import annotations

import functools

import drjit as dr
import mitsuba as mi
import numpy as np

from corona.mitsuba.common import (N_RESPONSE, array, channel_curves, cos, fold_spectrum, gather, lambda_um,
                                   sincos, wavelength_mixture)
from corona.model.substrate import DELTA_STEP, RGB_ORDERS, Mirror, channel_envelopes

#: Wavelengths [nm] of the plugin's table of a silvering spectrum (1 nm apart).
SILVER_GRID = np.arange(360.0, 831.0, 1.0)

__all__ = ["SILVER_GRID", "BareLayer", "layer_first", "pane_delta_weights", "pane_reflectance", "pane_sample",
           "pane_smooth_factors", "PaneSubstrate", "MirrorSubstrate", "SpectralMirrorSubstrate",
           "IncoherentPasses", "DoublePass", "substrate_component"]


# --------------------------------------------------------------------------
# the thin glass pane (docs/physics.md#the-layer-on-glass-substrateglass)
# --------------------------------------------------------------------------
def pane_reflectance(cos_theta, eta):
    """``R' = 2R / (1 + R)``: a thin pane's reflectance at ``|cos θ|`` (as ``thindielectric``),
    ``R`` the polarisation-averaged Fresnel reflectance of one face at index ``eta``."""
    r = mi.fresnel(dr.abs(cos_theta), eta)[0]
    return r * 2.0 / (1.0 + r)


def layer_first(cos_i, layer_on_front):
    """True where light from ``wi`` meets the layer before the pane (layer on the front face or not)."""
    return (cos_i > 0) if layer_on_front else (cos_i < 0)


def _face_from_pane(r):
    """The one face's Fresnel ``R`` of a thin non-absorbing pane of reflectance ``R' = 2R / (1 + R)``."""
    return r / (2.0 - r)


def pane_delta_weights(coherent, r_i, first, t_i=None, behind=None, front=None):
    """Weights of the coherent transmission ``C T'`` and of the specular reflection
    (``C R + C² (R' - R)`` when light meets the layer first, else ``behind``, by default ``R'``);
    ``r_i = R'(θi)``, ``t_i = T'(θi)`` (default ``1 - R'``: a pane that does not absorb), ``front``
    the Fresnel ``R(θi)`` of the face the layer lies on (default: that of a thin glass pane of
    reflectance ``r_i``).  The front face returns the light through the same place of the layer,
    which it crosses once (docs/physics.md#the-front-face)."""
    t_i = 1.0 - r_i if t_i is None else t_i
    behind = r_i if behind is None else behind
    front = _face_from_pane(r_i) if front is None else front
    return coherent * t_i, dr.select(first, coherent * (front + coherent * (r_i - front)), behind)


def pane_smooth_factors(coherent, r_i, r_o, first, t_i=None, t_o=None, front_i=None, front_o=None):
    """Factors of the smooth components on the pane: (lobe in transmission, lobe in reflection, diffuse).

    Light meeting the layer first: ``T'(θo)``, ``min(R_i, R_o) + C [P_i + P_o]``, 1 (``R`` the
    front face's Fresnel reflectance, ``front_i``/``front_o``, by default that of a thin glass
    pane; ``P = R' - R`` the round trips); the glass first: ``T'(θi)``, 0, ``T'(θi) T'(θo)``
    (the module docstring of :mod:`corona.mitsuba.bsdf` tabulates them).
    """
    t_i = 1.0 - r_i if t_i is None else t_i
    t_o = 1.0 - r_o if t_o is None else t_o
    front_i = _face_from_pane(r_i) if front_i is None else front_i
    front_o = _face_from_pane(r_o) if front_o is None else front_o
    transmitted = dr.select(first, t_o, t_i)
    reflected = dr.select(first, dr.minimum(front_i, front_o) + coherent * (r_i - front_i + r_o - front_o), 0.0)
    diffuse = dr.select(first, 1.0, t_i * t_o)
    return transmitted, reflected, diffuse


def pane_sample(bs, wi, pick_spec, pick_rlobe, wo_rlobe):
    """The pane's two components over what ``bs`` (a ``mi.BSDFSample3f``) holds: 3, the specular
    reflection (``wo`` the mirror image of ``wi``, ``DeltaReflection``) where ``pick_spec``, and 4,
    the lobe in reflection (``wo_rlobe``, ``GlossyReflection``) where ``pick_rlobe``; ``bs.wo``,
    ``bs.sampled_component`` and ``bs.sampled_type`` are set in place (and ``bs`` returned)."""
    bs.wo = dr.select(pick_spec, mi.Vector3f(-wi.x, -wi.y, wi.z), dr.select(pick_rlobe, wo_rlobe, bs.wo))
    bs.sampled_component = dr.select(pick_spec, mi.UInt32(3),
                                     dr.select(pick_rlobe, mi.UInt32(4), bs.sampled_component))
    bs.sampled_type = dr.select(pick_spec, mi.UInt32(+mi.BSDFFlags.DeltaReflection),
                                dr.select(pick_rlobe, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                          bs.sampled_type))
    return bs


@functools.lru_cache(maxsize=2)
def _channel_envelopes(mono: bool):
    """The double pass's fringe tables of the active variant's channels (built once per kind)."""
    return channel_envelopes(*channel_curves(), N_RESPONSE)


def substrate_component(pane, channel_lambdas=None, channel_weights=None):
    """The Dr.Jit substrate of a layer whose numpy substrate is ``pane`` (``Material.substrate``:
    None, a :class:`corona.model.substrate.GlassPane` or a :class:`corona.model.substrate.Mirror`);
    ``channel_lambdas`` / ``channel_weights``: the RGB / mono response wavelengths
    (:func:`corona.mitsuba.common.channel_response`; None in spectral variants)."""
    if pane is None:
        return BareLayer()
    if isinstance(pane, Mirror):
        cls = SpectralMirrorSubstrate if pane.spectral else MirrorSubstrate
        return cls(pane, channel_lambdas, channel_weights)
    return PaneSubstrate(pane, channel_lambdas, channel_weights)


class BareLayer:
    """No substrate: the layer alone, two-sided and symmetric (components 0, 1, 2 only)."""

    def components(self, sides, anisotropic):
        """BSDF flags of the components after the layer's three: none."""
        return []

    def flags(self):
        """The flags of :meth:`components` as ``_selection`` enumerates them (3, 4, ...)."""
        return ()

    def energies(self, layer, cos_i):
        """Energies of (coherent, lobe, diffuse reflection[, the substrate's components])."""
        return layer["coherent"], layer["lobe"], layer["reflect"]

    def delta_weights(self, layer, cos_i, wavelengths=None):
        """Weights of the coherent transmission and of the specular reflection (None: there is none)."""
        return layer["coherent"], None

    def lobe_sides(self, transmit, reflect):
        """Where the lobe is evaluated: in transmission only."""
        return transmit

    def modulation(self, layer, wi, wo, cos_i, cos_o, active):
        """The double pass's factor on the lobe per wavelength: none."""
        return None

    def smooth(self, layer, cos_i, cos_o, lobe, diffuse, modulated, abs_cos_o):
        """The smooth components' values on the substrate: (lobe in transmission, diffuse,
        lobe in reflection); the layer's own here (no lobe in reflection)."""
        return lobe, diffuse, None

    def add_reflected(self, ctx, value, pdf, reflect, lobe_reflected, probs, pdf_d, abs_cos_o):
        """``(value, pdf)`` plus the lobe in reflection: nothing to add."""
        return value, pdf

    def pick(self, active, sample1, probs):
        """The diffuse reflection's pick from ``sample1`` and the selection ``probs``, and the
        substrate's own picks (None: none)."""
        p_coh, p_lobe, p_refl = probs
        return active & (sample1 >= p_coh + p_lobe) & (p_refl > 0), None

    def lobe_share(self, picks, probs, sample1, s, pick_lobe):
        """``s``, the lobe's share of ``sample1``, and the lanes that sample the lobe's ``d``."""
        return s, pick_lobe

    def sampled(self, bs, wi, picks, wo_rlobe, lobe_ok, smooth, pick_delta):
        """Set the substrate's sampled components in ``bs``; returns (smooth, delta) picks."""
        return smooth, pick_delta

    def delta_sample(self, layer, cos_i, wavelengths, picks, probs, pdf, weight):
        """The coherent weight and ``(pdf, weight)`` of the sample with the substrate's delta component."""
        return layer["coherent"], pdf, weight


class IncoherentPasses:
    """The two passes of the lobe in reflection add in intensity (a pane without a thickness)."""

    def modulation(self, layer, wi, wo, cos_i, cos_o, active):
        return None

    def reflected_lobe(self, first, lobe, f_reflected, modulated, abs_cos_o):
        """The lobe in reflection: ``f [R_min + C (P_i + P_o)] |cos θo|``."""
        return lobe * f_reflected


class PaneSubstrate(BareLayer):
    """A thin non-absorbing glass pane under the layer (``substrate=glass``): components 3 and 4,
    Fresnel factors ``R' = 2R/(1 + R)``, ``T' = 1 - R'`` (:func:`pane_reflectance`)."""

    def __init__(self, pane, channel_lambdas=None, channel_weights=None):
        self.eta = float(pane.ior)
        self.layer_on_front = pane.side == "front"
        self.channel_lambdas = channel_lambdas
        self.channel_weights = channel_weights
        self.passes = DoublePass(self, pane) if pane.coherent else IncoherentPasses()

    # --- Fresnel factors -----------------------------------------------------------------
    def reflectance(self, cos_theta, lam_nm=None):
        """``R'``: the thin pane's reflectance at ``|cos θ|``."""
        return pane_reflectance(cos_theta, self.eta)

    def face_reflectance(self, cos_theta):
        """``R``: the Fresnel reflectance of the face the layer lies on, at ``|cos θ|``."""
        return mi.fresnel(dr.abs(cos_theta), self.eta)[0]

    def transmittance(self, cos_theta):
        """``T' = 1 - R'`` of the pane at ``|cos θ|``."""
        return 1.0 - self.reflectance(cos_theta)

    def behind(self, r_i):
        """What the pane reflects of light that meets the glass first: ``R'``."""
        return r_i

    def back_reflectance(self, ri, ro):
        """The reflectance behind the glass that returns the second pass: the back face's."""
        return dr.sqrt(ri * ro)

    def at_wavelength(self, lam_nm, front, c2, cos_i, cos_o, ri, ro, base, a, x):
        """The double pass's terms ``(base, a, x)`` at one wavelength: the same at every one."""
        return base, a, x

    def layer_first(self, cos_i):
        """True where light from ``wi`` meets the layer before the pane."""
        return layer_first(cos_i, self.layer_on_front)

    def reflected_lobe_energy(self, coherent, cos_i):
        """The reflected lobe's energy over ``D`` at ``θi``, the two angles taken equal:
        ``R + 2 C P`` (its selection weight)."""
        r = self.face_reflectance(cos_i)
        return r + 2.0 * coherent * (self.reflectance(cos_i) - r)

    # --- the interface ------------------------------------------------------------------
    def components(self, sides, anisotropic):
        glossy = mi.BSDFFlags.GlossyReflection | sides
        if anisotropic:
            glossy = glossy | mi.BSDFFlags.Anisotropic
        return [mi.BSDFFlags.DeltaReflection | sides,   # 3: the pane's mirror image
                glossy]                                 # 4: the lobe seen in reflection

    def flags(self):
        return (mi.BSDFFlags.DeltaReflection, mi.BSDFFlags.GlossyReflection)

    def energies(self, layer, cos_i):
        first = self.layer_first(cos_i)
        t_i = self.transmittance(cos_i)
        w_coh, w_spec = self.delta_weights(layer, cos_i)
        return (w_coh, layer["lobe"] * t_i,
                dr.select(first, layer["reflect"], layer["reflect"] * t_i), w_spec,
                dr.select(first, layer["lobe"] * self.reflected_lobe_energy(layer["coherent"], cos_i), 0.0))

    def _weights(self, layer, cos_i, lam_nm=None):
        r_i = self.reflectance(cos_i, lam_nm)
        return pane_delta_weights(layer["coherent"], r_i, self.layer_first(cos_i),
                                  t_i=self.transmittance(cos_i), behind=self.behind(r_i),
                                  front=self.face_reflectance(cos_i))

    def delta_weights(self, layer, cos_i, wavelengths=None):
        """Weights of the coherent transmission and of the specular reflection."""
        return self._weights(layer, cos_i)

    def lobe_sides(self, transmit, reflect):
        """The lobe in transmission and in reflection."""
        return transmit | reflect

    def modulation(self, layer, wi, wo, cos_i, cos_o, active):
        return self.passes.modulation(layer, wi, wo, cos_i, cos_o, active)

    def smooth(self, layer, cos_i, cos_o, lobe, diffuse, modulated, abs_cos_o):
        """Fresnel factors of the pane (:mod:`corona.mitsuba.bsdf`'s docstring table)."""
        first = self.layer_first(cos_i)
        r_i, r_o = self.reflectance(cos_i), self.reflectance(cos_o)
        t_i, t_o = self.transmittance(cos_i), self.transmittance(cos_o)
        f_through, f_reflected, f_diffuse = pane_smooth_factors(
            layer["coherent"], r_i, r_o, first, t_i=t_i, t_o=t_o,
            front_i=self.face_reflectance(cos_i), front_o=self.face_reflectance(cos_o))
        lobe_reflected = self.passes.reflected_lobe(first, lobe, f_reflected, modulated, abs_cos_o)
        return lobe * f_through, diffuse * f_diffuse, lobe_reflected

    def add_reflected(self, ctx, value, pdf, reflect, lobe_reflected, probs, pdf_d, abs_cos_o):
        rlobe_on = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 4)
        value += dr.select(reflect & rlobe_on, lobe_reflected, 0.0)
        pdf += dr.select(reflect, probs[4] * pdf_d * abs_cos_o, 0.0)
        return value, pdf

    def pick(self, active, sample1, probs):
        """After the diffuse reflection: 3 specular, 4 the lobe in reflection."""
        p_coh, p_lobe, p_refl, p_spec, p_rlobe = probs
        c3 = p_coh + p_lobe + p_refl
        c4 = c3 + p_spec
        pick_rlobe = active & (sample1 >= c4) & (p_rlobe > 0)
        pick_spec = active & (sample1 >= c3) & ((sample1 < c4) | (p_rlobe <= 0)) & (p_spec > 0)
        pick_refl = (active & (sample1 >= p_coh + p_lobe) & (p_refl > 0)
                     & ((sample1 < c3) | ((p_spec <= 0) & (p_rlobe <= 0))))
        return pick_refl, (pick_spec, pick_rlobe, c4)

    def lobe_share(self, picks, probs, sample1, s, pick_lobe):
        """The lobe in reflection has the same ``d`` (on the side of ``wi``): its share of ``sample1``."""
        _, pick_rlobe, c4 = picks
        s = dr.select(pick_rlobe, (sample1 - c4) / dr.maximum(probs[4], 1e-30), s)
        return s, pick_lobe | pick_rlobe

    def sampled(self, bs, wi, picks, wo_rlobe, lobe_ok, smooth, pick_delta):
        pick_spec, pick_rlobe, _ = picks
        pane_sample(bs, wi, pick_spec, pick_rlobe, wo_rlobe)
        return smooth | (pick_rlobe & lobe_ok), pick_delta | pick_spec

    def delta_sample(self, layer, cos_i, wavelengths, picks, probs, pdf, weight):
        pick_spec = picks[0]
        p_spec = probs[3]
        w_coh, w_spec = self.delta_weights(layer, cos_i, wavelengths)
        pdf = dr.select(pick_spec, p_spec, pdf)
        weight = dr.select(pick_spec, w_spec / dr.maximum(p_spec, 1e-30), weight)
        return w_coh, pdf, weight


class MirrorSubstrate(PaneSubstrate):
    """A back-silvered pane (``substrate=mirror``, silvering ``R_m`` constant in wavelength): it reflects
    ``R' = R + T² R_m / (1 - R R_m)``, transmits nothing, and its back is black."""

    def __init__(self, pane, channel_lambdas=None, channel_weights=None):
        self.silver = float(pane.silver(550.0))
        super().__init__(pane, channel_lambdas, channel_weights)

    def silver_at(self, lam_nm):
        """``R_m`` at ``lam_nm`` [nm] (None: at 550 nm): the constant silvering."""
        return self.silver

    def reflectance(self, cos_theta, lam_nm=None):
        """``R' = R + T² R_m / (1 - R R_m)``, ``R_m`` at ``lam_nm`` when given (else at 550 nm)."""
        r = mi.fresnel(dr.abs(cos_theta), self.eta)[0]
        rm = self.silver_at(lam_nm)
        return r + dr.square(1.0 - r) * rm / (1.0 - r * rm)

    def transmittance(self, cos_theta):
        """Nothing goes through a mirror: 0."""
        return 0.0 * cos_theta

    def behind(self, r_i):
        """A mirror's back is black."""
        return 0.0

    def back_reflectance(self, ri, ro):
        return self.silver


class SpectralMirrorSubstrate(MirrorSubstrate):
    """A mirror whose silvering ``R_m(λ)`` depends on the wavelength (a metal, a spectrum): taken at
    each evaluated wavelength, linear between the entries of a 1 nm table."""

    def __init__(self, pane, channel_lambdas=None, channel_weights=None):
        super().__init__(pane, channel_lambdas, channel_weights)
        self.silver_table = array(mi.Float, pane.silver(SILVER_GRID))

    def silver_at(self, lam_nm):
        """``R_m(λ)`` of the silvering spectrum (clamped to the table; None: the value at 550 nm)."""
        if lam_nm is None:
            return self.silver
        x = dr.clip(mi.Float(lam_nm) - SILVER_GRID[0], 0.0, float(SILVER_GRID.size - 1))
        i = mi.UInt32(dr.minimum(dr.floor(x), float(SILVER_GRID.size - 2)))
        t = x - mi.Float(i)
        return dr.lerp(gather(mi.Float, self.silver_table, i), gather(mi.Float, self.silver_table, i + 1), t)

    def at_wavelength(self, lam_nm, front, c2, cos_i, cos_o, ri, ro, base, a, x):
        """The double pass's terms with the silvering's ``R_m`` at this wavelength."""
        rm = self.silver_at(lam_nm)
        b = front + c2 * (self.reflectance(cos_i, lam_nm) - ri + self.reflectance(cos_o, lam_nm) - ro)
        return b, (1.0 - ri) * (1.0 - ro) * rm, rm * dr.sqrt(ri * ro)

    def delta_weights(self, layer, cos_i, wavelengths=None):
        """With ``wavelengths``, the specular weight per wavelength (a Spectrum)."""
        w_coh, w_spec = self._weights(layer, cos_i)
        if wavelengths is not None:
            lams, _ = wavelength_mixture(wavelengths, self.channel_lambdas)
            w_spec = fold_spectrum([self._weights(layer, cos_i, lam)[1] for lam in lams],
                                   self.channel_lambdas, self.channel_weights)
        return w_coh, w_spec


class DoublePass:
    """The coherent double pass of a pane with a thickness (docs/physics.md#the-coherent-double-pass-quetelet-rings):
    the two single-scattering paths of the lobe in reflection interfere, ``f [R_min + C (P_i + P_o + 2 V Q)]``;
    exact per wavelength (spectral), averaged over each response bin (RGB / mono:
    :func:`corona.model.substrate.channel_envelopes`)."""

    def __init__(self, substrate, pane):
        self.substrate = substrate
        self.thickness = float(pane.thickness)
        if not mi.is_spectral:   # each response wavelength stands for its quantile bin: its fringe table
            sigma, env = _channel_envelopes(bool(mi.is_monochromatic))
            self.bin_sigma = sigma.ravel()
            self.bin_sigma_table = array(mi.Float, self.bin_sigma)
            env = env.reshape(-1, env.shape[-1])
            self.env_n = env.shape[-1]
            self.env_re = array(mi.Float, env.real.ravel())
            self.env_im = array(mi.Float, env.imag.ravel())

    def reflected_lobe(self, first, lobe, f_reflected, modulated, abs_cos_o):
        """The lobe in reflection: the modulated lobe ``f [R_min + C (P_i + P_o + 2 V Q)] |cos θo|``."""
        return dr.select(first, modulated[0] * abs_cos_o, 0.0)

    def _envelope_index(self, delta, active):
        """Where ``Δ`` falls in the fringe tables (shared by every bin): (entry, weight, inside)."""
        x = delta * (1.0 / DELTA_STEP)
        inside = active & (x < self.env_n - 1)
        i = mi.UInt32(dr.clip(dr.floor(x), 0, self.env_n - 2))
        return i, x - mi.Float(i), inside

    def _bin_average_cos(self, q, index, sin_cos):
        """``G_q(Δ) = Re[e^{2πiΔσ_q} E_q(Δ)]``, the envelope linear between table entries, 0 beyond;
        ``index`` from :meth:`_envelope_index`, ``sin_cos`` = sincos(2π σ_q Δ)."""
        i, t, inside = index
        k = i + q * self.env_n
        re = dr.lerp(gather(mi.Float, self.env_re, k, inside), gather(mi.Float, self.env_re, k + 1, inside), t)
        im = dr.lerp(gather(mi.Float, self.env_im, k, inside), gather(mi.Float, self.env_im, k + 1, inside), t)
        s, c = sin_cos
        return dr.select(inside, c * re - s * im, 0.0)

    def modulation(self, layer, wi, wo, cos_i, cos_o, active=True):
        """Per evaluated wavelength, the factor ``min(R_i, R_o) + C (P_i + P_o + 2 V Q)`` on ``f`` (a callable
        ``(q, λ [nm]) -> Float`` for the plugin's lobe), ``Q`` the interference of the round trips."""
        pane = self.substrate
        n = pane.eta
        ri = pane.face_reflectance(cos_i)
        ro = pane.face_reflectance(cos_o)
        c2 = layer["coherent"]
        base = dr.minimum(ri, ro) + c2 * (pane.reflectance(cos_i) - ri + pane.reflectance(cos_o) - ro)
        s2i = dr.fma(wi.x, wi.x, wi.y * wi.y)
        s2o = dr.fma(wo.x, wo.x, wo.y * wo.y)
        cri = dr.safe_sqrt(1.0 - s2i / (n * n))
        cro = dr.safe_sqrt(1.0 - s2o / (n * n))
        delta = (2.0 * self.thickness / n) * (s2o - s2i) / (cri + cro)        # 2 n t (cos r_s - cos r_o), µm
        rb = pane.back_reflectance(ri, ro)
        a = (1.0 - ri) * (1.0 - ro) * rb
        x = rb * dr.sqrt(ri * ro)
        front = dr.minimum(ri, ro)
        lobe = layer["plane"] * layer["weight"] / dr.maximum(layer["fa"], 1e-30)
        cd = c2 * lobe                         # the visibility cap (substrate.double_pass_visibility)
        slack = 1.0 - layer["reflect"]
        inv = 1.0 / dr.maximum(cd, 1e-30)
        e = (slack - c2 * c2 - lobe - cd) * inv
        vis = dr.minimum(dr.minimum((slack - c2 * c2 - 2.0 * cd) * 0.5 * inv, (slack - c2 - cd) * inv), e)
        vis = dr.maximum(vis, dr.safe_sqrt(e * (1.0 - c2) / dr.maximum(c2, 1e-30)))
        vis = dr.select(cd > 0, dr.clip(vis, 0.0, 1.0), 1.0)
        if not mi.is_spectral:   # the table position of each order's k |Δ|, the same for every bin
            index = [self._envelope_index(k * dr.abs(delta), active) for k in range(1, RGB_ORDERS + 1)]

        def factor(q, lam_nm):
            b, aq, xq = pane.at_wavelength(lam_nm, front, c2, cos_i, cos_o, ri, ro, base, a, x)
            if mi.is_spectral:
                c = cos(2.0 * dr.pi * delta / lambda_um(lam_nm))    # (not dr.cos: CUDA's cos.approx)
                qv = aq * (c - xq) / (1.0 - 2.0 * xq * c + xq * xq)
            else:   # Σ_k x^(k-1) G_q(k Δ): the bin-averaged cosine (substrate.channel_envelopes), truncated
                qv = mi.Float(0.0)
                xk = mi.Float(1.0)
                sigma = (float(self.bin_sigma[q]) if isinstance(q, int)       # (q traced: a symbolic loop's)
                         else gather(mi.Float, self.bin_sigma_table, q))
                s1, c1 = sincos(2.0 * dr.pi * sigma * dr.abs(delta))
                sk, ck = s1, c1
                for k in range(1, RGB_ORDERS + 1):   # e^{ikφ} by recurrence: one sincos a bin
                    qv += xk * self._bin_average_cos(q, index[k - 1], (sk, ck))
                    sk, ck = sk * c1 + ck * s1, ck * c1 - sk * s1
                    xk = xk * xq
                qv = aq * qv
            return b + 2.0 * c2 * vis * qv
        return factor
