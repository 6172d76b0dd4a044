"""The ``corona`` BSDF plugin for Mitsuba 3 (Dr.Jit only inside eval/sample/pdf).

A thin layer of scatterers (pores, droplets, grains) that transmits a
coherent (delta) beam, a diffraction lobe ``F_a T_a T_s`` and optionally
reflects diffusely from its opaque part (DESIGN §3).  Register it with
:func:`corona.register` after ``mi.set_variant(...)``; then
``<bsdf type="corona">`` and ``mi.load_dict({'type': 'corona', ...})`` work.

Parameters (all optional; the one specification is :data:`corona.parameters.PARAMETERS`):

{table}

Components: 0 = coherent transmission (``DeltaTransmission``), 1 = diffraction
lobe (``GlossyTransmission``), 2 = diffuse reflection (``DiffuseReflection``,
weight 0 when ``albedo`` is 0).  The layer is two-sided and symmetric.
``mi.traverse`` exposes ``albedo``; the lobe's parameters fix its tables, so
change them by loading a new BSDF.

Spectral variants evaluate each of the lane's wavelengths.  Sampling picks
one of the lane's wavelengths at random (each with probability 1/n, reusing
the component-selection random number), draws ``d`` for it, and returns the
pdf averaged over all the lane's wavelengths (a one-sample balance-heuristic
mixture, hence unbiased).  RGB and mono variants evaluate each channel as the lobe averaged
over that channel's spectral response (CIE 1931 → linear sRGB, negative lobes
clipped; luminance ȳ for mono), using ``N_RESPONSE`` wavelengths per channel.

Wavelengths are clamped to [360, 830] nm (the range the tables cover); a zero
wavelength (as in a zero-initialised interaction) is clamped too, so no NaN.
The lobe outside the propagating disk is evanescent and dropped, so the
layer never transmits plus reflects more than it receives.
"""
from __future__ import annotations


import drjit as dr
import mitsuba as mi
import numpy as np

from . import tables
from ._validation import CoronaError
from .parameters import SPEC, material_from_parameters, rst_table

__doc__ = __doc__.replace("{table}", rst_table())

N_RESPONSE = 8
NEWTON_STEPS = 5


def _read_props(props) -> dict:
    """Named parameters from a ``mi.Properties``, checked against :data:`SPEC`
    (unknown names are an error)."""
    out = {}
    for name in props.keys():
        if name not in SPEC:
            raise CoronaError(f"corona BSDF: unknown parameter '{name}'; known: {', '.join(sorted(SPEC))}")
        value = props.get(name)
        if SPEC[name].kind in ("float", "int"):
            if isinstance(value, bool):   # <boolean name="radius" value="true"/> is no size
                raise CoronaError(f"corona BSDF: {name}={value!r} is not a number; allowed {SPEC[name].allowed}")
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise CoronaError(f"corona BSDF: {name}={value!r} is not a number; "
                                  f"allowed {SPEC[name].allowed}") from None
        else:
            value = str(value)
        out[name] = SPEC[name].check(value)
    return out


def _channel_response():
    """(wavelengths [nm], weights) of the RGB / mono channels, each (channels, N_RESPONSE).

    Each channel's response (CIE 1931 → linear sRGB, negative lobes clipped;
    ȳ for mono) is represented by ``N_RESPONSE`` wavelengths at equal-weight
    quantiles of the response, so the channel value is their mean.
    """
    from .color import XYZ_TO_SRGB, cie1931_xyz
    lam = np.linspace(tables.WAVELENGTH_MIN, tables.WAVELENGTH_MAX, 2048)
    xyz = cie1931_xyz(lam).T                                     # (3, n)
    resp = xyz[1:2] if mi.is_monochromatic else np.maximum(XYZ_TO_SRGB @ xyz, 0.0)
    chans = []
    for r in resp:
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * np.diff(lam))])
        qs = (np.arange(N_RESPONSE) + 0.5) / N_RESPONSE * cdf[-1]
        chans.append(np.interp(qs, cdf, lam))
    chans = np.array(chans)
    return chans, np.full(chans.shape, 1.0 / N_RESPONSE)


def _array(dtype, values):
    """A Dr.Jit array of ``values`` (float32 / uint32); a numpy array in scalar variants."""
    if dtype is mi.UInt32:
        a = np.asarray(values, dtype=np.uint32)
    else:
        a = np.asarray(values, dtype=np.float32)
    return a if dr.is_array_v(dtype) is False else dtype(a)


def _positive(x):
    """``x`` where it is > 0, else 1: a divisor safe in scalar variants too, where
    ``dr.select`` evaluates both branches (``value / pdf`` raised ZeroDivisionError)."""
    return dr.select(x > 0, x, 1.0)


def _gather(dtype, source, index, active=True):
    """``dr.gather`` that also works in scalar variants (Python scalars there)."""
    if dr.is_array_v(dtype):
        return dr.gather(dtype, source, index, active)
    return dtype(source[int(index)]) if active else dtype(0)


class CoronaBSDFMixin:
    """Mitsuba 3 BSDF of a layer of correlated scatterers (see the module docstring).

    The methods live in this plain class; :func:`bsdf_class` copies them into a
    subclass of the active variant's ``mi.BSDF`` (each variant has its own
    base class, and nanobind types take a single base).
    """

    def __init__(self, props):
        mi.BSDF.__init__(self, props)  # the active variant's base class
        params = _read_props(props)
        self.sampling = params.pop("sampling", SPEC["sampling"].default)
        material = material_from_parameters(**params)
        self.material = material
        table = material.table
        self.isotropic = material.isotropic
        self.R = float(material.length_scale)

        # --- component energies (wavelength-independent) ---------------------
        self.w_coherent = float(material.coherent_transmittance)
        self.w_lobe = float(material.diffuse_transmittance())      # F_a ∫v d²u / 4π²
        self.lobe_scale = float(material.lobe_weight)                # f = F_a (R/λ)² v(u), capped
        self.w_reflect = float(material.reflectance)                 # ρ · opaque fraction, capped
        self.albedo = mi.Float(material.albedo)                      # exposed through mi.traverse
        self.table_total = float(table.total)

        # --- table in Dr.Jit arrays ------------------------------------------
        if self.isotropic:
            self.du = float(table.du)
            self.n = int(table.values.size)
            self.values = _array(mi.Float, table.values)
            self._set_cdf(table.cdf)
        else:
            self.n = int(table.n)
            self.lo = float(table.lo)                 # first vertex [u]
            self.cell = float(table.cell)
            self.span = float(table.cell * (table.n - 1))
            self.values = _array(mi.Float, table.values.ravel())
            # exact sampling of the bilinear density (marginal y, conditional x)
            self.distr = mi.MarginalContinuous2D0(np.ascontiguousarray(table.values, dtype=np.float32))

        # --- wavelengths of RGB / mono channels -------------------------------
        if not mi.is_spectral:
            lam, w = _channel_response()
            self.channel_lambdas = lam           # (channels, N) nm
            self.channel_weights = w

        # --- components and flags ----------------------------------------------
        sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        comps = [mi.BSDFFlags.DeltaTransmission | sides,
                 mi.BSDFFlags.GlossyTransmission | sides]
        comps.append(mi.BSDFFlags.DiffuseReflection | sides)   # weight 0 when albedo = 0
        if not self.isotropic:
            comps[1] = comps[1] | mi.BSDFFlags.Anisotropic
        self.m_components = [c for c in comps]
        flags = mi.BSDFFlags.Empty
        for c in comps:
            flags = flags | c
        self.m_flags = flags

    def _set_cdf(self, cdf64):
        """Normalised CDF (float32) plus a guide table that narrows each search.

        ``guide[j]`` is the last bin whose CDF is <= j/G, so a target in
        [j/G, (j+1)/G) lies in bins ``guide[j] .. guide[j+1]``; a fixed number
        of bisection steps (the widest such range) then finds the bin.
        """
        cdf = np.asarray(cdf64, dtype=np.float64) / cdf64[-1]
        cdf32 = cdf.astype(np.float32)
        n_bins = cdf.size - 1
        G = int(min(max(n_bins, 16), 1 << 16))
        marks = np.arange(G + 1) / G
        guide = np.clip(np.searchsorted(cdf32, marks.astype(np.float32), side="right") - 1, 0, n_bins - 1)
        width = int(np.max(guide[1:] - guide[:-1])) + 1
        self.guide_size = G
        self.search_steps = max(1, int(np.ceil(np.log2(width + 1))))
        self.n_bins = n_bins
        self.cdf = _array(mi.Float, cdf32)
        self.guide = _array(mi.UInt32, guide)

    # ------------------------------------------------------------------
    # helpers (traced Dr.Jit code)
    # ------------------------------------------------------------------
    @staticmethod
    def _lambda_um(lam):
        # wavelength [nm] clamped to the table range, in µm
        return dr.clip(lam, tables.WAVELENGTH_MIN, tables.WAVELENGTH_MAX) * 1e-3

    def _table_value(self, ux, uy, active):
        """v(u): linear in |u| (radial) or bilinear in (u_x, u_y) (grid)."""
        if self.isotropic:
            x = dr.sqrt(dr.fma(ux, ux, uy * uy)) / self.du
            i = dr.minimum(mi.UInt32(dr.maximum(dr.floor(x), 0)), self.n - 2)
            t = x - mi.Float(i)
            inside = active & (x <= self.n - 1)
            v0 = _gather(mi.Float, self.values, i, inside)
            v1 = _gather(mi.Float, self.values, i + 1, inside)
            return dr.select(inside, dr.maximum(dr.lerp(v0, v1, t), 0.0), 0.0)
        fx = (ux - self.lo) / self.cell
        fy = (uy - self.lo) / self.cell
        inside = active & (fx >= 0) & (fx <= self.n - 1) & (fy >= 0) & (fy <= self.n - 1)
        x0 = dr.clip(dr.floor(fx), 0, self.n - 2)
        y0 = dr.clip(dr.floor(fy), 0, self.n - 2)
        tx = dr.clip(fx - x0, 0.0, 1.0)
        ty = dr.clip(fy - y0, 0.0, 1.0)
        k = mi.UInt32(y0) * self.n + mi.UInt32(x0)
        v00 = _gather(mi.Float, self.values, k, inside)
        v01 = _gather(mi.Float, self.values, k + 1, inside)
        v10 = _gather(mi.Float, self.values, k + self.n, inside)
        v11 = _gather(mi.Float, self.values, k + self.n + 1, inside)
        v = dr.lerp(dr.lerp(v00, v01, tx), dr.lerp(v10, v11, tx), ty)
        return dr.select(inside, dr.maximum(v, 0.0), 0.0)

    def _sample_u(self, s, active):
        """Invert the table's CDF: s (Vector2f) -> u (Vector2f)."""
        if not self.isotropic:
            p01, _ = self.distr.sample(s, active=active)
            return mi.Vector2f(self.lo + p01.x * self.span, self.lo + p01.y * self.span)
        target = s.x
        # guide table, then bisection with cdf[lo] <= target < cdf[hi]
        j = mi.UInt32(dr.minimum(target * self.guide_size, self.guide_size - 1))
        lo = _gather(mi.UInt32, self.guide, j, active)
        hi = dr.minimum(_gather(mi.UInt32, self.guide, j + 1, active) + 1, self.n_bins)
        for _ in range(self.search_steps):
            mid = (lo + hi) >> 1
            go_right = _gather(mi.Float, self.cdf, mid, active) <= target
            lo = dr.select(go_right, mid, lo)
            hi = dr.select(go_right, hi, mid)
        idx = dr.minimum(lo, self.n_bins - 1)
        c0 = _gather(mi.Float, self.cdf, idx, active)
        c1 = _gather(mi.Float, self.cdf, idx + 1, active)
        # radial: density 2π u v_lin(u) in the bin; its CDF is the cubic
        # C(t) = c1 t + c2 t² + c3 t³ (normalised), solved by safeguarded Newton
        du = self.du
        u0 = mi.Float(idx) * du
        a = _gather(mi.Float, self.values, idx, active)
        b = _gather(mi.Float, self.values, idx + 1, active) - a
        norm = 2.0 * dr.pi * du / self.table_total
        k1 = norm * u0 * a
        k2 = norm * (u0 * b + du * a) * 0.5
        k3 = norm * du * b * (1.0 / 3.0)
        rest = target - c0
        t = dr.clip(rest / dr.maximum(c1 - c0, 1e-30), 0.0, 1.0)
        lo = mi.Float(0.0)
        hi = mi.Float(1.0)
        for _ in range(NEWTON_STEPS):
            f = dr.fma(dr.fma(k3, t, k2), t, k1) * t - rest
            lo = dr.select(f < 0, t, lo)
            hi = dr.select(f >= 0, t, hi)
            df = dr.fma(dr.fma(3.0 * k3, t, 2.0 * k2), t, k1)
            t_new = t - f / dr.maximum(df, 1e-30)            # df = density >= 0
            bad = (t_new <= lo) | (t_new >= hi)
            t = dr.select(bad, 0.5 * (lo + hi), t_new)
        r = u0 + dr.clip(t, 0.0, 1.0) * du
        sin_phi, cos_phi = dr.sincos(2.0 * dr.pi * s.y)
        return mi.Vector2f(r * cos_phi, r * sin_phi)

    def _lobe_and_pdf(self, wi, wo, wavelengths, active):
        """Lobe value f (Spectrum, no cosine) and the d-space pdf averaged over wavelengths."""
        dx = wo.x + wi.x
        dy = wo.y + wi.y
        lams, mix = self._wavelength_mixture(wavelengths)
        values = []
        pdf = mi.Float(0.0)
        for lam_nm, m in zip(lams, mix):
            lam = self._lambda_um(lam_nm)
            k = 2.0 * dr.pi * self.R / lam                 # u = 2π R d / λ
            ux, uy = dx * k, dy * k
            v = self._table_value(ux, uy, active)
            values.append(self.lobe_scale * dr.square(self.R / lam) * v)   # F_a (R/λ)² v
            # p_d = p_u k²; the tables are sampled exactly ∝ v, so p_u = v / ∫v d²u
            pdf += m * (v * (1.0 / self.table_total)) * dr.square(k)
        if mi.is_spectral:
            f = mi.Spectrum(values)
        else:
            nc = self.channel_lambdas.shape[0]
            per = self.channel_lambdas.shape[1]
            chans = []
            for c in range(nc):
                acc = mi.Float(0.0)
                for j in range(per):
                    acc += float(self.channel_weights[c, j]) * values[c * per + j]
                chans.append(acc)
            f = mi.Spectrum(chans[0]) if nc == 1 else mi.Spectrum(chans)
        return f, pdf

    def _wavelength_mixture(self, wavelengths):
        """The wavelengths [nm] evaluated per lane and their pdf mixture weights."""
        if mi.is_spectral:
            lams = [wavelengths[k] for k in range(dr.size_v(mi.Spectrum))]
            return lams, [1.0 / len(lams)] * len(lams)
        lams = [mi.Float(float(l)) for l in self.channel_lambdas.ravel()]
        mix = (self.channel_weights / self.channel_weights.shape[0]).ravel()
        return lams, [float(m) for m in mix]

    def _pick_hero(self, wavelengths, s):
        """One wavelength of the mixture, chosen with its mixture weight by ``s`` in [0, 1)."""
        lams, mix = self._wavelength_mixture(wavelengths)
        cum = np.cumsum(mix)
        hero = mi.Float(lams[-1])
        for k in range(len(lams) - 2, -1, -1):
            hero = dr.select(s < float(cum[k]), lams[k], hero)
        return hero

    def _selection(self, ctx):
        """Probabilities of (coherent, lobe, reflection) honouring the context."""
        flags = (mi.BSDFFlags.DeltaTransmission, mi.BSDFFlags.GlossyTransmission,
                 mi.BSDFFlags.DiffuseReflection)
        energies = (self.w_coherent, self.w_lobe, self.w_reflect)
        en = [w if ctx.is_enabled(fl, i) else 0.0
              for i, (w, fl) in enumerate(zip(energies, flags))]
        total = sum(en)
        return tuple(e / total if total > 0 else 0.0 for e in en)

    # ------------------------------------------------------------------
    # BSDF interface
    # ------------------------------------------------------------------
    def _eval_pdf(self, ctx, si, wo, active):
        wi = si.wi
        cos_i = mi.Frame3f.cos_theta(wi)
        cos_o = mi.Frame3f.cos_theta(wo)
        transmit = active & (cos_i * cos_o < 0)
        reflect = active & (cos_i * cos_o > 0)
        p_coh, p_lobe, p_refl = self._selection(ctx)
        lobe_on = ctx.is_enabled(mi.BSDFFlags.GlossyTransmission, 1)
        refl_on = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 2)

        f, pdf_d = self._lobe_and_pdf(wi, wo, si.wavelengths, transmit)
        abs_cos_o = dr.abs(cos_o)
        value = dr.select(transmit & lobe_on, f * abs_cos_o, 0.0)        # eval = f |cos θo|
        if self.sampling == "cosine":
            pdf_d = mi.Float(dr.inv_pi)                                   # p_ω = |cos θo| / π
        pdf = dr.select(transmit, p_lobe * pdf_d * abs_cos_o, 0.0)        # p_ω = p_d |cos θo|
        if self.w_reflect > 0:
            value += dr.select(reflect & refl_on, self.w_reflect * dr.inv_pi * abs_cos_o, 0.0)
            pdf += dr.select(reflect, p_refl * dr.inv_pi * abs_cos_o, 0.0)
        return value, pdf

    def eval(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)[1]

    def eval_pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        wi = si.wi
        cos_i = mi.Frame3f.cos_theta(wi)
        active = mi.Bool(active) & (cos_i != 0)
        p_coh, p_lobe, p_refl = self._selection(ctx)
        pick_coh = active & (sample1 < p_coh)
        pick_lobe = active & (sample1 >= p_coh) & (sample1 < p_coh + p_lobe)
        pick_refl = active & (sample1 >= p_coh + p_lobe) & (p_refl > 0)

        bs = dr.zeros(mi.BSDFSample3f)
        bs.eta = 1.0

        # reflection: cosine-weighted on the side of wi
        wo_cos = mi.warp.square_to_cosine_hemisphere(sample2)
        wo_refl = mi.Vector3f(wo_cos.x, wo_cos.y, dr.mulsign(wo_cos.z, cos_i))

        if self.sampling == "cosine":   # lobe: the same warp, mirrored to the far side
            wo_lobe = mi.Vector3f(wo_refl.x, wo_refl.y, -wo_refl.z)
            lobe_valid = pick_lobe & (wo_cos.z > 0)
        else:
            # lobe: sample u for the hero wavelength, d = u λ / (2π R), wo.xy = d - wi.xy;
            # the hero wavelength is picked with its mixture weight, reusing sample1
            s_hero = dr.clip((sample1 - p_coh) / max(p_lobe, 1e-30), 0.0, 0.99999994)
            lam = self._lambda_um(self._pick_hero(si.wavelengths, s_hero))
            u = self._sample_u(sample2, pick_lobe)
            d = u * (lam / (2.0 * dr.pi * self.R))
            ox = d.x - wi.x
            oy = d.y - wi.y
            r2 = dr.fma(ox, ox, oy * oy)
            oz = -dr.mulsign(dr.safe_sqrt(1.0 - r2), cos_i)
            wo_lobe = mi.Vector3f(ox, oy, oz)
            lobe_valid = pick_lobe & (r2 < 1.0) & (oz != 0)

        bs.wo = dr.select(pick_coh, -wi, dr.select(pick_lobe, wo_lobe, wo_refl))
        bs.sampled_component = dr.select(pick_coh, mi.UInt32(0),
                                         dr.select(pick_lobe, mi.UInt32(1), mi.UInt32(2)))
        bs.sampled_type = dr.select(
            pick_coh, mi.UInt32(+mi.BSDFFlags.DeltaTransmission),
            dr.select(pick_lobe, mi.UInt32(+mi.BSDFFlags.GlossyTransmission),
                      mi.UInt32(+mi.BSDFFlags.DiffuseReflection)))

        value, pdf = self._eval_pdf(ctx, si, bs.wo, (lobe_valid | pick_refl))
        bs.pdf = dr.select(pick_coh, p_coh, pdf)
        weight = dr.select(pdf > 0, value / _positive(pdf), 0.0)
        weight = dr.select(pick_coh, self.w_coherent / dr.maximum(p_coh, 1e-30), weight)
        ok = pick_coh | ((lobe_valid | pick_refl) & (bs.pdf > 0))
        return bs, dr.select(ok, mi.Spectrum(weight), 0.0)

    def traverse(self, callback):
        # the albedo can change after loading; the lobe's parameters fix its tables
        callback.put("albedo", self.albedo, mi.ParamFlags.NonDifferentiable)

    def parameters_changed(self, keys):
        if "albedo" in keys or not keys:
            a = float(self.albedo[0]) if dr.is_array_v(self.albedo) else float(self.albedo)
            if not (0.0 <= a <= 1.0):
                raise CoronaError(f"corona BSDF: albedo={a!r} is out of range; allowed [0, 1]")
            self.material.albedo = a
            self.w_reflect = float(self.material.reflectance)

    def to_string(self):
        return f"CoronaBSDF[{self.material!r}]"


_CLASSES: dict[str, type] = {}
_REGISTERED: set[str] = set()


def bsdf_class() -> type:
    """The ``CoronaBSDF`` class of the active variant."""
    variant = mi.variant()
    if variant not in _CLASSES:
        methods = {k: v for k, v in vars(CoronaBSDFMixin).items()
                   if k not in ("__dict__", "__weakref__")}
        _CLASSES[variant] = type("CoronaBSDF", (mi.BSDF,), methods)
    return _CLASSES[variant]


def register() -> None:
    """Register the ``corona`` BSDF for the active Mitsuba variant (idempotent).

    Call after ``mi.set_variant(...)``.  Polarized variants are not supported.
    """
    variant = mi.variant()
    if variant is None:
        raise CoronaError("corona.register(): call mi.set_variant(...) first "
                          "(e.g. corona.set_default_variant())")
    if "polarized" in variant:
        raise CoronaError(f"variant={variant!r} is not supported; use a spectral, rgb or mono variant")
    if variant in _REGISTERED:
        return
    cls = bsdf_class()
    mi.register_bsdf("corona", lambda props: cls(props))
    _REGISTERED.add(variant)
