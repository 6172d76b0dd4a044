"""``corona_mie``: a Mitsuba 3 phase function of Mie droplets (docs/volumes.md).

The phase function of a volume of spheres (:class:`corona.volume.MieVolume`):
a radius and index (water with its dispersion by default, ``ior_imag`` for
absorbing particles), one size or a size distribution, and optionally the
hard-sphere structure factor of a dense medium.

Parameters (``mi.load_dict({"type": "corona_mie", ...})``)

==================  =========  ==========================================================
name                default    meaning
==================  =========  ==========================================================
radius              10         droplet radius, or effective radius ⟨r³⟩/⟨r²⟩ [µm]
distribution        "mono"     "mono", "lognormal", "gamma", "modified_gamma"
variance            0          effective variance v_eff (0 for "mono")
gamma_exponent      1          γ of "modified_gamma" (n(r) ∝ r^α exp(-B r^γ))
ior                 "water"    "water" (dispersion, in air) or the real index relative to the host
ior_imag            0          κ >= 0 (absorption)
volume_fraction     0          φ > 0: the Percus–Yevick structure factor (dense media)
==================  =========  ==========================================================

Evaluation.  Spectral variants evaluate each of the lane's wavelengths
(rows linear in size parameter ``x = 2πr/λ``, nodes linear in
``v = sin²(Θ/2)``; the node is found from the chords ``|wo + wi| / 2 =
sin(Θ/2)`` (forward half) and ``|wo - wi| / 2 = cos(Θ/2)`` (backward half),
so the forward peak and the glory keep their float32 accuracy and no
trigonometry is needed); RGB and mono variants evaluate each channel's row, the phase
function averaged over the channel's spectral response weighted by ``σ_s``
(:meth:`corona.volume.MieVolume.rgb_table`).  Wavelengths are clamped to
[360, 830] nm (a zero wavelength too).

Sampling.  ``sample1`` picks one of the lane's wavelengths (or channels)
with probability 1/n and, for spectral rows, row ``j + 1`` with probability
``t`` (both rows integrate to 1, so the mixture is the interpolated value);
``sample2.x`` inverts the row's CDF exactly (a guide table and a bisection find the bin, then
the quadratic of a density linear in v), ``sample2.y`` the azimuth.  The
returned pdf is the mean of the lanes' (channels') values, the one-sample
balance-heuristic mixture, and the weight is value / pdf.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from . import tables
from ._validation import CoronaError
from .mitsuba_common import channel_response, variant_class  # the channels the corona BSDF uses

_KEYS = ("radius", "distribution", "variance", "gamma_exponent", "ior", "ior_imag", "volume_fraction")


def _array(dtype, values):
    a = np.asarray(values, dtype=np.uint32 if dtype is mi.UInt32 else np.float32)
    return dtype(a) if dr.is_array_v(dtype) else a


def _gather(dtype, source, index, active=True):
    if dr.is_array_v(dtype):
        return dr.gather(dtype, source, index, active)
    return dtype(source[int(index)]) if active else dtype(0)


def _opaque(dtype, value):
    return dr.opaque(dtype, value) if dr.is_array_v(dtype) else dtype(value)


def _volume_from_props(props):
    from .volume import MieVolume
    names = [n for n in props.keys() if not n.startswith("_")] if hasattr(props, "keys") else []
    unknown = [n for n in names if n not in _KEYS and n != "id"]
    if unknown:
        raise CoronaError(f"corona_mie: unknown parameter {unknown[0]!r}; allowed: {', '.join(_KEYS)}")
    get = lambda k, d: props[k] if k in props else d
    ior = get("ior", "water")
    if not isinstance(ior, str):
        ior = float(ior)
    return MieVolume(float(get("radius", 10.0)), str(get("distribution", "mono")),
                     float(get("variance", 0.0)), float(get("gamma_exponent", 1.0)), ior,
                     float(get("ior_imag", 0.0)), float(get("volume_fraction", 0.0)))


class CoronaMiePhaseMixin:
    """Methods of the ``corona_mie`` phase function (copied into a subclass of the active
    variant's ``mi.PhaseFunction``, see :func:`phase_class`)."""

    def __init__(self, props):
        mi.PhaseFunction.__init__(self, props)
        self.volume = _volume_from_props(props)
        self.m_flags = mi.PhaseFunctionFlags.Anisotropic
        T = self.volume.table
        self.M = int(T["M"])
        self.K = 2 * self.M + 1
        ds = float(T["ds"])
        if mi.is_spectral:
            rows = T["p"]
            xr = T["x"]
            self.n_rows = int(rows.shape[0])
            self.x0 = _opaque(mi.Float, float(xr[0]))
            self.inv_dx = _opaque(mi.Float, float(1.0 / (xr[1] - xr[0])))
            self.two_pi_r = _opaque(mi.Float, float(2 * np.pi * self.volume.radius * 1e3))  # x = this / λ[nm]
        else:
            lam, w = channel_response()
            rows = self.volume.rgb_table(lam, w)
            self.n_rows = int(rows.shape[0])
        from .volume import node_dv
        dv = node_dv(ds, self.M)
        mass = 4 * np.pi * 0.5 * (rows[:, 1:] + rows[:, :-1]) * dv
        cdf = np.concatenate([np.zeros((rows.shape[0], 1)), np.cumsum(mass, axis=1)], axis=1)
        total = cdf[:, -1:]
        rows = rows / total
        cdf = cdf / total
        self.p = _array(mi.Float, rows.ravel())
        cdf32 = cdf.astype(np.float32)
        self.cdf = _array(mi.Float, cdf32.ravel())
        # guide table: G cells uniform in ξ; cell c's bins lie in [guide[c], guide[c + 1]]
        # (cdf[guide[c]] <= c/G); a bisection of `steps` steps then finds the bin
        self.G = int(2 * self.K)
        edges = (np.arange(self.G + 1) / self.G).astype(np.float32)
        guide = np.stack([np.clip(np.searchsorted(row, edges, side="right") - 1, 0, self.K - 2)
                          for row in cdf32])
        span = int(np.max(guide[:, 1:] - guide[:, :-1])) + 1
        self.steps = max(1, int(np.ceil(np.log2(span + 1))))
        self.guide = _array(mi.UInt32, guide.ravel())
        self.inv_ds = _opaque(mi.Float, 1.0 / ds)
        self.ds2 = _opaque(mi.Float, ds * ds)

    # ------------------------------------------------------------------
    def _angle(self, wi, wo):
        """(bin i, fraction f in v) of the scattering angle between -wi and wo on the chord nodes
        (corona.volume.node_bin): no trigonometry, accurate at both ends."""
        a = dr.squared_norm(wo + wi) * 0.25          # sin²(Θ/2)
        b = dr.squared_norm(wo - wi) * 0.25          # cos²(Θ/2)
        fwd = a <= b
        g = dr.sqrt(dr.select(fwd, a, b)) * self.inv_ds
        l = dr.minimum(mi.UInt32(dr.maximum(dr.floor(g), 0.0)), self.M - 1)
        lf = mi.Float(l)
        inv = dr.rcp(2.0 * lf + 1.0)
        f = dr.select(fwd, (g * g - lf * lf) * inv, (dr.square(lf + 1.0) - g * g) * inv)
        i = dr.select(fwd, l, 2 * self.M - 1 - l)
        return i, dr.clip(f, 0.0, 1.0)

    def _row_of(self, lam):
        """Row j and weight t of a wavelength [nm] (spectral)."""
        lam = dr.clip(lam, tables.WAVELENGTH_MIN, tables.WAVELENGTH_MAX)
        g = (self.two_pi_r / lam - self.x0) * self.inv_dx
        j = dr.minimum(mi.UInt32(dr.maximum(dr.floor(g), 0.0)), self.n_rows - 2)
        t = dr.clip(g - mi.Float(j), 0.0, 1.0)
        return j, t

    def _row_value(self, row, i, f, active):
        k = row * self.K + i
        v0 = _gather(mi.Float, self.p, k, active)
        v1 = _gather(mi.Float, self.p, k + 1, active)
        return dr.lerp(v0, v1, f)

    def _lane_value(self, lam, i, f, active):
        j, t = self._row_of(lam)
        return dr.lerp(self._row_value(j, i, f, active), self._row_value(j + 1, i, f, active), t)

    def _values(self, mei, i, f, active):
        """(per-lane/channel values at angle bin i, fraction f, as a list; their mean = pdf)."""
        if mi.is_spectral:
            n = dr.size_v(mi.Spectrum)
            vals = [self._lane_value(mei.wavelengths[l], i, f, active) for l in range(n)]
        else:
            vals = [self._row_value(mi.UInt32(c), i, f, active) for c in range(self.n_rows)]
        pdf = vals[0]
        for v in vals[1:]:
            pdf = pdf + v
        return vals, pdf * (1.0 / len(vals))

    def eval_pdf(self, ctx, mei, wo, active=True):
        i, f = self._angle(mei.wi, wo)
        vals, pdf = self._values(mei, i, f, active)
        value = mi.Spectrum(*vals) if len(vals) > 1 else mi.Spectrum(vals[0])
        return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    def sample(self, ctx, mei, sample1, sample2, active=True):
        n = dr.size_v(mi.Spectrum) if mi.is_spectral else self.n_rows
        u = dr.clip(sample1, 0.0, 0.99999994) * n
        lane = dr.minimum(mi.UInt32(dr.floor(u)), n - 1)
        u = u - mi.Float(lane)
        if mi.is_spectral:
            lam = mei.wavelengths[0]
            for l in range(1, n):
                lam = dr.select(lane == l, mei.wavelengths[l], lam)
            j, t = self._row_of(lam)
            row = dr.select(u < t, j + 1, j)
        else:
            row = lane
        xi = dr.clip(sample2.x, 0.0, 0.99999994)
        base = row * self.K
        cell = dr.minimum(mi.UInt32(xi * self.G), self.G - 1)
        gb = row * (self.G + 1) + cell
        lo = _gather(mi.UInt32, self.guide, gb, active)
        hi = _gather(mi.UInt32, self.guide, gb + 1, active) + 1      # cdf[lo] <= ξ < cdf[hi]
        for _ in range(self.steps):
            mid = (lo + hi) >> 1
            below = _gather(mi.Float, self.cdf, base + mid, active) <= xi
            lo = dr.select(below, mid, lo)
            hi = dr.select(below, hi, mid)
        i = dr.minimum(lo, self.K - 2)
        c0 = _gather(mi.Float, self.cdf, base + i, active)
        p0 = _gather(mi.Float, self.p, base + i, active)
        p1 = _gather(mi.Float, self.p, base + i + 1, active)
        fwd = i < self.M
        l = dr.select(fwd, i, 2 * self.M - 1 - i)          # the chord index of the bin
        lf = mi.Float(l)
        h = (2.0 * lf + 1.0) * self.ds2                     # bin width in v
        r = dr.maximum(xi - c0, 0.0) / (4.0 * dr.pi * h)
        disc = dr.sqrt(dr.maximum(p0 * p0 + 2.0 * (p1 - p0) * r, 0.0))
        den = p0 + disc
        tt = dr.clip(2.0 * r / dr.select(den > 0, den, 1.0), 0.0, 1.0)
        a = dr.select(fwd, lf * lf * self.ds2 + tt * h, 1.0 - (dr.square(lf + 1.0) * self.ds2 - tt * h))
        b = dr.select(fwd, 1.0 - a, dr.square(lf + 1.0) * self.ds2 - tt * h)   # accurate where small
        cos_t = b - a
        sin_t = 2.0 * dr.sqrt(dr.maximum(a * b, 0.0))
        sp, cp = dr.sincos(2.0 * dr.pi * sample2.y)
        frame = mi.Frame3f(-mei.wi)
        wo = frame.to_world(mi.Vector3f(sin_t * cp, sin_t * sp, cos_t))
        # the value and pdf at the sampled direction: the same bin and fraction in v
        vals, pdf = self._values(mei, i, tt, active)
        value = mi.Spectrum(*vals) if len(vals) > 1 else mi.Spectrum(vals[0])
        ok = active & (pdf > 0)
        weight = dr.select(ok, value / dr.select(pdf > 0, pdf, 1.0), 0.0)
        return wo, weight, dr.select(ok, pdf, 0.0)

    def projected_area(self, mei, active=True):
        return mi.Float(1.0)

    def max_projected_area(self):
        return 1.0

    def to_string(self):
        v = self.volume
        return (f"CoronaMiePhase[radius={v.radius:g} µm, distribution={v.distribution!r}, "
                f"variance={v.variance:g}, ior={v.ior!r}, ior_imag={v.ior_imag:g}, "
                f"volume_fraction={v.volume_fraction:g}, rows={self.n_rows}, nodes={self.K}]")


_REGISTERED: set[str] = set()


def phase_class() -> type:
    """The ``CoronaMiePhase`` class of the active variant."""
    return variant_class(CoronaMiePhaseMixin, "PhaseFunction", "CoronaMiePhase")


def register() -> None:
    """Register the ``corona_mie`` phase function for the active Mitsuba variant (idempotent)."""
    variant = mi.variant()
    if variant is None:
        raise CoronaError("corona_mie: call mi.set_variant(...) first")
    if "polarized" in variant:
        raise CoronaError(f"variant={variant!r} is not supported; use a spectral, rgb or mono variant")
    if variant in _REGISTERED:
        return
    cls = phase_class()
    mi.register_phase("corona_mie", lambda props: cls(props))
    _REGISTERED.add(variant)
