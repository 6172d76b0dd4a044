"""The ``corona`` plugin's code path for ``shape=sphere``: a layer of Mie droplets (docs/physics.md#transparent-droplets-mie-spheres).

``mi.load_dict({'type': 'corona', 'shape': 'sphere', ...})`` builds this BSDF
(:func:`corona.mitsuba_bsdf.register` dispatches on ``shape``).  It evaluates
and samples the tables of :class:`corona.sphere_material.SphereMaterial`
exactly as that numpy reference does, in Dr.Jit:

* component 0, coherent transmission (``DeltaTransmission``): ``|1 - F_s s₀(λ)|²``
  along ``-wi``, a spectrum (the optical theorem's mean field depends on λ);
* component 1, the **forward lobe** (Θ < 90° from ``wt = -wi``): ``F_s w [P + C (S(q) - 1)]``;
* component 2, the **backward lobe** (Θ >= 90°: glory, fogbow): ``F_s w P``;

both lobes may fall on either side of the layer at oblique incidence, so
each is flagged ``GlossyTransmission | GlossyReflection``.  A lobe is
tabulated in rows of the size parameter ``x`` (not evenly spaced: a guide of
uniform bins in x finds the row) and in the chord
``s = |wo + wi|`` (forward) or ``|wo - wi|`` (backward), with ``dΩ = s ds dφ``:
the two rows j, j+1 around a wavelength (weight t) are read at the chord
scaled by ``x / x_row`` (rings at a fixed ``x·s`` line up), with Catmull–Rom
cubics in the chord for the value.  Sampling draws the chord from one row's
piecewise-linear radial density (guide table, bisection, safeguarded Newton
on the cubic CDF, as the flat layers' radial tables), row j+1 with
probability ``t T_j+1 / ((1-t) T_j + t T_j+1)``, scales it by ``x_row / x``
and draws the azimuth uniformly, so the pdf is the rows' linear, scaled blend
over the interpolated total (both lobes' densities, since a lobe's sampler
reaches a sliver past 90°); the lane's wavelengths are mixed as for the flat
layers (one-sample balance heuristic).

Uniform parameters, except an ``area_fraction`` texture with Poisson centres
(the tables do not depend on F_a then: the lane's F_a enters ``F_s``, the
coherent beam and the cap); the isotropic processes (poisson, hard-disk,
rsa); nothing is exposed to ``mi.traverse``.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from . import tables
from ._validation import CoronaError
from .mitsuba_common import NEWTON_STEPS, fold_spectrum, logical_not as _not, pick_wavelength, texture_range
from .mitsuba_common import variant_class, wavelength_mixture
from .mitsuba_common import array as _array, channel_response as _channel_response, gather as _gather
from .mitsuba_common import read_props as _read_props
from .parameters import SPEC, material_from_parameters
from .sphere_material import ENERGY_MARGIN, INCIDENCE_MU


def _cdf_rows(values: np.ndarray, ds: float):
    """Normalised float32 CDFs of the radial densities ``2π s v(s)`` of each row, guide tables,
    the bisection depth and the guide size (see ``CoronaBSDFMixin._set_cdf``)."""
    cdfs = [tables.RadialTable(ds, row).cdf for row in values]
    n_bins = values.shape[1] - 1
    G = int(min(max(n_bins, 16), 1 << 16))
    marks = (np.arange(G + 1) / G).astype(np.float32)
    cdf_all, guide_all, width = [], [], 1
    for cdf64 in cdfs:
        total = cdf64[-1] if cdf64[-1] > 0 else 1.0
        cdf32 = (np.asarray(cdf64) / total).astype(np.float32)
        guide = np.clip(np.searchsorted(cdf32, marks, side="right") - 1, 0, n_bins - 1)
        width = max(width, int(np.max(guide[1:] - guide[:-1])) + 1)
        cdf_all.append(cdf32)
        guide_all.append(guide)
    return (np.concatenate(cdf_all), np.concatenate(guide_all),
            max(1, int(np.ceil(np.log2(width + 1)))), G)


class SphereBSDFMixin:
    """Mitsuba 3 BSDF of a layer of Mie spheres (see the module docstring)."""

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        params, textures = _read_props(props)
        self.fa_tex = None
        fa_tex = textures.pop("area_fraction", None)
        if fa_tex is not None and fa_tex.is_spatially_varying():
            # Poisson centres: the tables do not depend on F_a, only F_s, the coherent beam and the
            # cap do; the other processes' S(q) (and so the tables) change with F_a
            if params.get("process", "poisson") != "poisson":
                textures["area_fraction"] = fa_tex
            else:
                lo, hi = texture_range(fa_tex)
                if lo is None or not (0.0 < lo and hi < 1.0):
                    raise CoronaError(f"corona BSDF: area_fraction texture values {lo!r} … {hi!r} are out of "
                                      "range for shape='sphere'; allowed (0, 1)")
                self.fa_tex, self.fa_range = fa_tex, (lo, hi)
                params["area_fraction"] = hi
        elif fa_tex is not None:                  # a uniform texture is a value
            params["area_fraction"] = texture_range(fa_tex)[1]
        if textures:
            raise CoronaError(f"corona BSDF: shape='sphere' takes uniform values here; "
                              f"{', '.join(sorted(textures))} cannot be a texture (an area_fraction texture "
                              "needs process='poisson': the other processes' tables depend on F_a; a radius "
                              "texture would need a Mie table per radius)")
        self.sampling = params.pop("sampling", SPEC["sampling"].default)
        self.params = params
        self._setup()
        if not mi.is_spectral:
            self.channel_lambdas, self.channel_weights = _channel_response()
        sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        glossy = mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection | sides
        self.m_components = [mi.BSDFFlags.DeltaTransmission | sides, glossy, glossy]
        self.m_flags = self.m_components[0] | glossy

    def _setup(self):
        material = material_from_parameters(**self.params)
        self.material = material
        rows = material.rows
        der = material._derived
        self.fa = float(material.area_fraction)
        self.radius = float(material.sphere.radius)
        x = rows["x"]
        self.x0, self.n_rows = float(x[0]), int(x.size)
        self.x_rows = _array(mi.Float, x)
        # rows are not evenly spaced: a guide of bins half the smallest row step wide names the
        # row at or below each bin's start; one step up at most finds the row below x
        self.bin_dx = 0.5 * float(np.min(np.diff(x)))
        n_bins = int(np.ceil((x[-1] - x[0]) / self.bin_dx)) + 2
        edges = x[0] + np.arange(n_bins) * self.bin_dx
        self.n_bins = n_bins
        self.row_guide = _array(mi.UInt32, np.clip(np.searchsorted(x, edges, side="right") - 1, 0, x.size - 2))
        self.ds = float(rows["ds"])
        # the largest chord a lobe's sampler draws: a row's last node scaled by x_j+1 / x_j
        self.reach = min(2.0, (rows["P_f"].shape[1] - 1) * self.ds * float(np.max(x[1:] / x[:-1])) * (1 + 1e-6))
        self.K = int(rows["P_f"].shape[1])
        self.has_C = bool(rows["C_f"].size)
        if self.has_C:
            self.Cf = _array(mi.Float, rows["C_f"].ravel())
        self.Tf, self.Tb = _array(mi.Float, der["T_f"]), _array(mi.Float, der["T_b"])
        self.Ef = _array(mi.Float, der["e_f_mu"].ravel())
        # per-row scalars packed 8 to a row, gathered as two Vector4f:
        # (Re s0, Im s0, e_f, e_b), (T_f, T_b, 0, 0)
        packed = np.zeros((x.size, 8))
        packed[:, 0], packed[:, 1] = rows["s0"][:, 0], rows["s0"][:, 1]
        packed[:, 2], packed[:, 3] = der["e_f"], der["e_b"]
        packed[:, 4], packed[:, 5] = der["T_f"], der["T_b"]
        self.row_data = _array(mi.Float, packed.ravel())
        # both lobes in one array: forward rows, then backward rows
        self.P = _array(mi.Float, np.concatenate([rows["P_f"].ravel(), rows["P_b"].ravel()]))
        self.back_offset = int(rows["P_f"].size)
        st = material.structure_table
        self.has_S = st is not None
        if self.has_S:
            self.S_du, self.S = float(st[0]), _array(mi.Float, st[1])
            self.S_n = int(st[1].size)
        self.cdf_f, self.guide_f, self.steps_f, self.G = _cdf_rows(rows["P_f"], self.ds)
        self.cdf_b, self.guide_b, self.steps_b, _ = _cdf_rows(rows["P_b"], self.ds)
        self.cdf_f, self.cdf_b = _array(mi.Float, self.cdf_f), _array(mi.Float, self.cdf_b)
        self.guide_f, self.guide_b = _array(mi.UInt32, self.guide_f), _array(mi.UInt32, self.guide_b)

    # ------------------------------------------------------------------
    # per-wavelength state
    # ------------------------------------------------------------------
    def _wavelengths(self, wavelengths):
        """The lane's wavelengths [nm] and their (equal) mixture weight (:func:`wavelength_mixture`)."""
        lams, weights = wavelength_mixture(wavelengths, getattr(self, "channel_lambdas", None))
        return lams, weights[0]

    def _row(self, lam_nm):
        lam = dr.clip(lam_nm, tables.WAVELENGTH_MIN, tables.WAVELENGTH_MAX) * 1e-3
        x = (2.0 * dr.pi * self.radius) / lam
        b = mi.UInt32(dr.clip(dr.floor((x - self.x0) / self.bin_dx), 0, self.n_bins - 1))
        j = _gather(mi.UInt32, self.row_guide, b)
        for _ in range(2):        # float32 rounding of the bin: at most one row up, checked twice
            up = (j + 1 < self.n_rows - 1) & (x >= _gather(mi.Float, self.x_rows, j + 1))
            j = dr.select(up, j + 1, j)
        xj, xj1 = _gather(mi.Float, self.x_rows, j), _gather(mi.Float, self.x_rows, j + 1)
        return j, (x - xj) / (xj1 - xj), lam, x, xj, xj1

    def _state(self, lam_nm, mu_i, active, fa=None):
        """Row, energies and lobe weight of one wavelength of the lane (``fa``: the lane's F_a)."""
        j, t, lam, x, xj, xj1 = self._row(lam_nm)

        if dr.is_array_v(mi.Float):
            a0 = dr.gather(mi.Vector4f, self.row_data, 2 * j, active)
            a1 = dr.gather(mi.Vector4f, self.row_data, 2 * j + 2, active)
            b0 = dr.gather(mi.Vector4f, self.row_data, 2 * j + 1, active)
            b1 = dr.gather(mi.Vector4f, self.row_data, 2 * j + 3, active)
        else:   # scalar variants
            row = lambda k: mi.Vector4f(*[float(self.row_data[4 * k + c]) for c in range(4)])
            a0, a1, b0, b1 = row(2 * j), row(2 * j + 2), row(2 * j + 1), row(2 * j + 3)
        a = dr.lerp(a0, a1, t)
        fs = dr.minimum((self.fa if fa is None else fa) / dr.maximum(mu_i, 1e-12), 1.0)
        re = 1.0 - fs * a.x
        im = fs * a.y
        coherent = dr.minimum(dr.fma(re, re, im * im), 1.0)
        ef, eb = self._forward(j, t, mu_i, active), a.w
        scattered = fs * (ef + eb) * ENERGY_MARGIN
        w = dr.minimum(1.0, dr.maximum(1.0 - coherent, 0.0) / dr.maximum(scattered, 1e-30))
        Tf0, Tf1, Tb0, Tb1 = b0.x, b1.x, b0.y, b1.y
        return dict(j=j, t=t, lam=lam, x=x, xj=xj, xj1=xj1, fs=fs, coherent=coherent, w=w, e_f=fs * w * ef, e_b=fs * w * eb,
                    Tf=dr.lerp(Tf0, Tf1, t), Tb=dr.lerp(Tb0, Tb1, t), Tf1=Tf1, Tb1=Tb1, Tf0=Tf0, Tb0=Tb0)

    def _forward(self, st_j, t, mu_i, active):
        """The forward lobe's energy e_f at the row (j, t) and ``mu_i`` (SphereMaterial._forward)."""
        n = len(INCIDENCE_MU)
        g = (1.0 - dr.clip(mu_i, 0.0, 1.0)) * (n - 1)
        b = dr.minimum(mi.UInt32(dr.maximum(dr.floor(g), 0)), n - 2)
        f = dr.clip(g - mi.Float(b), 0.0, 1.0)
        k = st_j * n + b
        e00 = _gather(mi.Float, self.Ef, k, active)
        e01 = _gather(mi.Float, self.Ef, k + 1, active)
        e10 = _gather(mi.Float, self.Ef, k + n, active)
        e11 = _gather(mi.Float, self.Ef, k + n + 1, active)
        return dr.lerp(dr.lerp(e00, e01, f), dr.lerp(e10, e11, f), t)

    def _states(self, si, active):
        lams, m = self._wavelengths(si.wavelengths)
        mu_i = dr.abs(mi.Frame3f.cos_theta(si.wi))
        fa = None
        if self.fa_tex is not None:
            fa = dr.clip(self.fa_tex.eval_1(si, active), self.fa_range[0], self.fa_range[1])
        states = [self._state(lam, mu_i, active, fa) for lam in lams]
        return states, m

    def _selection(self, ctx, states, m):
        coh = states[0]["coherent"]
        ef = states[0]["e_f"]
        eb = states[0]["e_b"]
        for s in states[1:]:
            coh, ef, eb = coh + s["coherent"], ef + s["e_f"], eb + s["e_b"]
        en = [coh if ctx.is_enabled(mi.BSDFFlags.DeltaTransmission, 0) else mi.Float(0.0),
              ef if ctx.is_enabled(mi.BSDFFlags.GlossyTransmission, 1) else mi.Float(0.0),
              eb if ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 2) else mi.Float(0.0)]
        total = en[0] + en[1] + en[2]
        inv = dr.select(total > 0, 1.0 / dr.maximum(total, 1e-30), 0.0)
        return en[0] * inv, en[1] * inv, en[2] * inv

    def _spectrum(self, values):
        """Per-wavelength values as a Spectrum (:func:`fold_spectrum`)."""
        return fold_spectrum(values, getattr(self, "channel_lambdas", None), getattr(self, "channel_weights", None))

    # ------------------------------------------------------------------
    # tables
    # ------------------------------------------------------------------
    def _rows_at(self, arr, st, s, active, offset=0):
        """Rows j, j+1 (weight t) of a chord table, each read at its chord scaled by ``x / x_row``
        (corona.sphere_material._scaled_blend): (Catmull–Rom value, linear value, the sampler's
        density up to its total)."""
        cub, lin = mi.Float(0.0), mi.Float(0.0)
        K = self.K
        for d, wgt, x_row in ((0, 1.0 - st["t"], st["xj"]), (1, st["t"], st["xj1"])):
            row = st["j"] + d
            c = x_row / st["x"]
            g = s / (c * self.ds)
            i = dr.minimum(mi.UInt32(dr.maximum(dr.floor(g), 0)), K - 2)
            f = dr.clip(g - mi.Float(i), 0.0, 1.0)
            inside = active & (g <= K - 1)
            k = row * K + i + offset
            p1 = _gather(mi.Float, arr, k, inside)
            p2 = _gather(mi.Float, arr, k + 1, inside)
            p0 = dr.select(i > 0, _gather(mi.Float, arr, k - 1, inside & (i > 0)), p1)
            p3 = dr.select(i + 2 < K, _gather(mi.Float, arr, k + 2, inside & (i + 2 < K)), p2)
            v = p1 + 0.5 * f * (p2 - p0 + f * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3
                                               + f * (3.0 * (p1 - p2) + p3 - p0)))
            scale = wgt / (c * c)
            cub += dr.select(inside, dr.maximum(v, 0.0) * scale, 0.0)
            lin += dr.select(inside, dr.maximum(dr.lerp(p1, p2, f), 0.0) * scale, 0.0)
        return cub, lin

    def _structure(self, u, active):
        x = u / self.S_du
        i = dr.minimum(mi.UInt32(dr.maximum(dr.floor(x), 0)), self.S_n - 2)
        f = dr.clip(x - mi.Float(i), 0.0, 1.0)
        inside = active & (x <= self.S_n - 1)
        v = dr.lerp(_gather(mi.Float, self.S, i, inside), _gather(mi.Float, self.S, i + 1, inside), f)
        return dr.select(inside, v, 1.0)

    def _sample_chord(self, xi, row, forward, active):
        """Invert the normalised CDF of a row of the forward or backward table (radial density 2π s P)."""
        n_bins = self.K - 1
        G = self.G
        base_c = row * (n_bins + 1)
        base_g = row * (G + 1)
        g = mi.UInt32(dr.minimum(xi * G, G - 1))
        lo = dr.select(forward, _gather(mi.UInt32, self.guide_f, base_g + g, active),
                       _gather(mi.UInt32, self.guide_b, base_g + g, active))
        hi_f = _gather(mi.UInt32, self.guide_f, base_g + g + 1, active)
        hi_b = _gather(mi.UInt32, self.guide_b, base_g + g + 1, active)
        hi = dr.minimum(dr.select(forward, hi_f, hi_b) + 1, n_bins)
        for _ in range(max(self.steps_f, self.steps_b)):
            mid = (lo + hi) >> 1
            c = dr.select(forward, _gather(mi.Float, self.cdf_f, base_c + mid, active),
                          _gather(mi.Float, self.cdf_b, base_c + mid, active))
            right = c <= xi
            lo = dr.select(right, mid, lo)
            hi = dr.select(right, hi, mid)
        idx = dr.minimum(lo, n_bins - 1)
        c0 = dr.select(forward, _gather(mi.Float, self.cdf_f, base_c + idx, active),
                       _gather(mi.Float, self.cdf_b, base_c + idx, active))
        c1 = dr.select(forward, _gather(mi.Float, self.cdf_f, base_c + idx + 1, active),
                       _gather(mi.Float, self.cdf_b, base_c + idx + 1, active))
        ds = self.ds
        s0 = mi.Float(idx) * ds
        k = row * self.K + idx + dr.select(forward, mi.UInt32(0), mi.UInt32(self.back_offset))
        a = _gather(mi.Float, self.P, k, active)
        b = _gather(mi.Float, self.P, k + 1, active) - a
        total = dr.select(forward, _gather(mi.Float, self.Tf, row, active), _gather(mi.Float, self.Tb, row, active))
        norm = 2.0 * dr.pi * ds / dr.maximum(total, 1e-30)
        k1 = norm * s0 * a
        k2 = norm * (s0 * b + ds * a) * 0.5
        k3 = norm * ds * b * (1.0 / 3.0)
        rest = xi - c0
        t = dr.clip(rest / dr.maximum(c1 - c0, 1e-30), 0.0, 1.0)
        lo_t, hi_t = mi.Float(0.0), mi.Float(1.0)
        for _ in range(NEWTON_STEPS):
            f = dr.fma(dr.fma(k3, t, k2), t, k1) * t - rest
            lo_t = dr.select(f < 0, t, lo_t)
            hi_t = dr.select(f >= 0, t, hi_t)
            df = dr.fma(dr.fma(3.0 * k3, t, 2.0 * k2), t, k1)
            t_new = t - f / dr.maximum(df, 1e-30)
            t = dr.select((t_new <= lo_t) | (t_new >= hi_t), 0.5 * (lo_t + hi_t), t_new)
        return s0 + dr.clip(t, 0.0, 1.0) * ds

    # ------------------------------------------------------------------
    # BSDF interface
    # ------------------------------------------------------------------
    def _eval_pdf(self, ctx, si, wo, active, cached=None):
        wi = si.wi
        states, m = cached if cached is not None else self._states(si, active)
        p_coh, p_f, p_b = self._selection(ctx, states, m)
        fwd_on = ctx.is_enabled(mi.BSDFFlags.GlossyTransmission, 1)
        bwd_on = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 2)
        s_f = dr.norm(wo + wi)
        s_b = dr.norm(wo - wi)
        forward = s_f <= s_b
        a_f = active & forward
        a_b = active & _not(forward)
        dxy = dr.sqrt(dr.square(wo.x + wi.x) + dr.square(wo.y + wi.y))
        values = []
        pdf = mi.Float(0.0)
        s_any = dr.select(forward, s_f, s_b)
        offset = dr.select(forward, mi.UInt32(0), mi.UInt32(self.back_offset))
        on = dr.select(forward, fwd_on, bwd_on)
        s_other = dr.select(forward, s_b, s_f)
        offset_other = dr.select(forward, mi.UInt32(self.back_offset), mi.UInt32(0))
        near = active & (s_other < self.reach)     # the sliver past 90° that a lobe's sampler reaches
        for st in states:
            P, P_lin = self._rows_at(self.P, st, s_any, active, offset)       # P_f or P_b
            Z = P
            if self.has_S:
                S = self._structure((2.0 * dr.pi * self.radius) * dxy / st["lam"], a_f)
                C_f = self._rows_at(self.Cf, st, s_f, a_f)[0] if self.has_C else P
                Z = dr.select(forward, dr.maximum(dr.fma(C_f, S - 1.0, P), 0.0), P)
            values.append(dr.select(active & on, Z * (st["fs"] * st["w"]), 0.0))
            if self.sampling == "cosine":
                continue
            Q_lin = self._rows_at(self.P, st, s_other, near, offset_other)[1]
            dens_f = dr.select(forward, P_lin, Q_lin) / dr.maximum(st["Tf"], 1e-30)
            dens_b = dr.select(forward, Q_lin, P_lin) / dr.maximum(st["Tb"], 1e-30)
            pdf += m * (p_f * dens_f + p_b * dens_b)
        if self.sampling == "cosine":   # comparisons only: uniform sphere for both lobes
            pdf = dr.select(active, (p_f + p_b) * (0.25 * dr.inv_pi), 0.0)
        return self._spectrum(values), dr.select(active, pdf, 0.0)

    def eval(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, mi.Bool(active))[0]

    def pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, mi.Bool(active))[1]

    def eval_pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, mi.Bool(active))

    def sample(self, ctx, si, sample1, sample2, active=True):
        wi = si.wi
        active = mi.Bool(active) & (mi.Frame3f.cos_theta(wi) != 0)
        states, m = self._states(si, active)
        p_coh, p_f, p_b = self._selection(ctx, states, m)
        pick_coh = active & (sample1 < p_coh)
        pick_f = active & _not(pick_coh) & (sample1 < p_coh + p_f) & (p_f > 0)
        pick_b = active & _not(pick_coh) & _not(pick_f) & (p_b > 0)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.eta = 1.0
        if self.sampling == "cosine":
            d = mi.warp.square_to_uniform_sphere(sample2)
            wo_lobe = d
        else:
            # the lobe's share of sample1 picks the hero wavelength, what is left of it the row
            s = dr.select(pick_f, (sample1 - p_coh) / dr.maximum(p_f, 1e-30),
                          (sample1 - p_coh - p_f) / dr.maximum(p_b, 1e-30))
            n = len(states)
            pick, _, rest = pick_wavelength(s, [st["x"] for st in states])
            j, p_next, x = states[-1]["j"], mi.Float(0.0), states[-1]["x"]
            for q in range(n - 1, -1, -1):
                st = states[q]
                x = dr.select(pick == q, st["x"], x)
                T0 = dr.select(pick_f, st["Tf0"], st["Tb0"])
                T1 = dr.select(pick_f, st["Tf1"], st["Tb1"])
                pn = st["t"] * T1 / dr.maximum(dr.lerp(T0, T1, st["t"]), 1e-30)
                j = dr.select(pick == q, st["j"], j)
                p_next = dr.select(pick == q, pn, p_next)
            row = dr.select(rest < p_next, j + 1, j)
            chord = self._sample_chord(sample2.x, row, pick_f, pick_f | pick_b)
            # the row's chord scaled to the lane's x: rings at a fixed x·s
            chord = dr.minimum(chord * _gather(mi.Float, self.x_rows, row, pick_f | pick_b) / x, 2.0)
            cos_t = 1.0 - 0.5 * chord * chord
            sin_t = chord * dr.safe_sqrt(1.0 - 0.25 * chord * chord)
            sp, cp = dr.sincos(2.0 * dr.pi * sample2.y)
            axis = dr.select(pick_f, -wi, wi)
            wo_lobe = mi.Frame3f(axis).to_world(mi.Vector3f(sin_t * cp, sin_t * sp, cos_t))
            wo_lobe = dr.normalize(wo_lobe)
        bs.wo = dr.select(pick_coh, -wi, wo_lobe)
        bs.sampled_component = dr.select(pick_coh, mi.UInt32(0), dr.select(pick_f, mi.UInt32(1), mi.UInt32(2)))
        same_side = mi.Frame3f.cos_theta(wi) * mi.Frame3f.cos_theta(bs.wo) > 0
        bs.sampled_type = dr.select(pick_coh, mi.UInt32(+mi.BSDFFlags.DeltaTransmission),
                                    dr.select(same_side, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                              mi.UInt32(+mi.BSDFFlags.GlossyTransmission)))
        smooth = pick_f | pick_b
        value, pdf = self._eval_pdf(ctx, si, bs.wo, smooth, (states, m))
        bs.pdf = dr.select(pick_coh, p_coh, pdf)
        weight = value / dr.select(pdf > 0, pdf, 1.0)
        coh = self._spectrum([st["coherent"] for st in states])
        weight = dr.select(pick_coh, coh / dr.maximum(p_coh, 1e-30), weight)
        ok = pick_coh | (smooth & (bs.pdf > 0))
        return bs, dr.select(ok, mi.Spectrum(weight), 0.0)

    def traverse(self, callback):
        pass

    def parameters_changed(self, keys):
        pass

    def to_string(self):
        return f"CoronaSphereBSDF[{self.material!r}]"


def sphere_bsdf_class() -> type:
    """The sphere BSDF class of the active variant."""
    return variant_class(SphereBSDFMixin, "BSDF", "CoronaSphereBSDF")
