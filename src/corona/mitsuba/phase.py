"""``corona_mie``: a Mitsuba 3 phase function of Mie droplets (docs/volumes.md).

The phase function of a volume of spheres (:class:`corona.model.mie.volume.MieVolume`):
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
gamma_exponent      1          γ of "modified_gamma" (n(r) ∝ r^α exp(-B r^γ)), [0.1, 10]
ior                 "water"    "water" (with its dispersion) or the particles' real index [1, 10]
ior_imag            0          κ >= 0 (absorption)
volume_fraction     0          φ > 0: the Percus–Yevick structure factor (dense media)
host_ior            1          index of the host in [1, 3]: m = (ior + i ior_imag) / host_ior,
                               wavelength λ / host_ior (water 1.33, a resin 1.5)
truncation          0          forward-peak truncation angle [degrees], 0 or [0.5, 30]: the
                               phase function capped inside the cone, renormalised; the medium's
                               σ_t, albedo must be the truncated ones
                               (corona.mitsuba.volume.homogeneous_medium(..., truncation=...))
==================  =========  ==========================================================

Evaluation.  One packet gather per lane reads the table around a direction:
spectral variants the two rows around the wavelength times the two angle nodes
around the direction (four floats), RGB and mono variants every channel's two
nodes.  Spectral variants evaluate each of the lane's wavelengths
(rows linear in size parameter ``x = 2πr/λ``, nodes linear in
``v = sin²(Θ/2)``; the node is found from the chords ``|wo + wi| / 2 =
sin(Θ/2)`` (forward half) and ``|wo - wi| / 2 = cos(Θ/2)`` (backward half),
so the forward peak and the glory keep their float32 accuracy and no
trigonometry is needed); RGB and mono variants evaluate each channel's row, the phase
function averaged over the channel's spectral response weighted by ``σ_s``
(:meth:`corona.model.mie.volume.MieVolume.rgb_table`).  Wavelengths are clamped to
[360, 830] nm (a zero wavelength too).

Sampling.  ``sample1`` picks one of the lane's wavelengths (or channels)
with probability 1/n and, for spectral rows, row ``j + 1`` with probability
``t`` (both rows integrate to 1, so the mixture is the interpolated value);
``sample2.x`` inverts the row's CDF exactly (a guide table of 2 cells per angle bin and a
bisection while the cell holds more than one bin find the bin, then the quadratic of a density
linear in v), ``sample2.y`` the azimuth; the packets read at the sampled bin give both the
quadratic's two nodes and the returned value.  The
returned pdf is the mean of the lanes' (channels') values, the one-sample
balance-heuristic mixture, and the weight is value / pdf.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from corona.model import tabulated
from corona._validation import CoronaError
from corona.mitsuba.common import channel_response, variant_class  # the channels the corona BSDF uses

_KEYS = ("radius", "distribution", "variance", "gamma_exponent", "ior", "ior_imag", "volume_fraction",
         "host_ior", "truncation")
#: Largest guide table (cells over all rows) and cells per angle bin at most.
GUIDE_BUDGET, GUIDE_PER_BIN = 1 << 23, 2


def _array(dtype, values):
    """A Dr.Jit array of ``values`` on 64-byte aligned memory (Dr.Jit maps a NumPy buffer
    without copying, and packet gathers need an aligned source; else they fall back to one
    gather per element)."""
    a = np.ascontiguousarray(values, dtype=np.uint32 if dtype is mi.UInt32 else np.float32).ravel()
    if not dr.is_array_v(dtype):
        return a
    buf = np.empty(a.nbytes + 64, np.uint8)
    off = (-buf.ctypes.data) % 64
    out = buf[off:off + a.nbytes].view(a.dtype)
    out[:] = a
    return dtype(out)


def _gather(dtype, source, index, active=True):
    if dr.is_array_v(dtype):
        return dr.gather(dtype, source, index, active)
    return dtype(source[int(index)]) if active else dtype(0)


def _packet(source, size, index, active=True):
    """The ``size`` consecutive floats ``source[size·index …]`` as a list: one packet gather
    (a single vector load per lane) in the JIT variants."""
    if dr.is_array_v(mi.Float):
        import sys
        array_x = sys.modules[type(source).__module__].ArrayXf
        v = dr.gather(array_x, source, index, active, shape=(size, dr.width(index)))
        return [v[c] for c in range(size)]
    k = int(index) * size
    return [mi.Float(source[k + c]) if active else mi.Float(0.0) for c in range(size)]


def _opaque(dtype, value):
    return dr.opaque(dtype, value) if dr.is_array_v(dtype) else dtype(value)


def _volume_from_props(props):
    from corona.model.mie.volume import MieVolume
    names = [n for n in props.keys() if not n.startswith("_")] if hasattr(props, "keys") else []
    unknown = [n for n in names if n not in _KEYS and n != "id"]
    if unknown:
        raise CoronaError(f"corona_mie: unknown parameter {unknown[0]!r}; allowed: {', '.join(_KEYS)}")
    get = lambda k, d: props[k] if k in props else d

    def number(name, default):
        value = get(name, default)
        if isinstance(value, (bool, np.bool_)) or isinstance(value, str):
            raise CoronaError(f"corona_mie: {name}={value!r} is not a number")
        try:
            return float(value)
        except (TypeError, ValueError):
            raise CoronaError(f"corona_mie: {name}={value!r} is not a number") from None
    ior = get("ior", "water")
    if not isinstance(ior, str):
        ior = number("ior", "water")
    return MieVolume(number("radius", 10.0), str(get("distribution", "mono")),
                     number("variance", 0.0), number("gamma_exponent", 1.0), ior,
                     number("ior_imag", 0.0), number("volume_fraction", 0.0),
                     host_ior=number("host_ior", 1.0), truncation=number("truncation", 0.0))


class CoronaMiePhaseMixin:
    """Methods of the ``corona_mie`` phase function (copied into a subclass of the active
    variant's ``mi.PhaseFunction``, see :func:`phase_class`).

    Memory layout (one packet gather per lookup):

    * spectral: ``quad[j, i] = (p[j, i], p[j, i+1], p[j+1, i], p[j+1, i+1])``, the two rows
      around a wavelength and the two nodes around an angle;
    * RGB / mono: ``pair[i] = (p[c, i], p[c, i+1])`` for every channel c (padded to 2 or 8);
    * sampling: the CDF per row, and a guide table per row of cells uniform in ξ, each
      ``lo | hi << 16`` with ``cdf[lo] <= ξ < cdf[hi]`` for the cell's ξ; a bisection (a loop
      while ``hi - lo > 1``: 0.2–0.4 steps on average, docs/volumes.md#speed) finds the bin.
    """

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
            self.x0 = _opaque(mi.Float, float(xr[0]))
            self.inv_dx = _opaque(mi.Float, float(1.0 / (xr[1] - xr[0])))
            # x = two_pi_r / λ[nm]: 2π r n_host
            self.two_pi_r = _opaque(mi.Float, float(self.volume.k_scale * self.volume.radius * 1e3))
        else:
            lam, w = channel_response()
            rows = self.volume.rgb_table(lam, w)
        self.n_rows = int(rows.shape[0])
        from corona.model.mie.volume import node_dv
        dv = node_dv(ds, self.M)
        mass = 4 * np.pi * 0.5 * (rows[:, 1:] + rows[:, :-1]) * dv
        cdf = np.concatenate([np.zeros((rows.shape[0], 1)), np.cumsum(mass, axis=1)], axis=1)
        total = cdf[:, -1:]
        rows = rows / total
        cdf = cdf / total
        K1 = self.K - 1
        if mi.is_spectral:
            quad = np.stack([rows[:-1, :-1], rows[:-1, 1:], rows[1:, :-1], rows[1:, 1:]], axis=-1)
            self.P = 4
            self.vals = _array(mi.Float, quad.ravel())                 # ((J-1) (K-1), 4)
        else:
            C = self.n_rows
            self.P = 2 if C == 1 else 8
            pair = np.zeros((K1, self.P))
            for c in range(C):
                pair[:, 2 * c], pair[:, 2 * c + 1] = rows[c, :-1], rows[c, 1:]
            self.vals = _array(mi.Float, pair.ravel())                 # (K-1, P)
        cdf32 = cdf.astype(np.float32)
        self.cdf = _array(mi.Float, cdf32.ravel())
        # guide table: G cells uniform in ξ; cell c's bins lie in [lo, hi) (cdf[lo] <= c/G,
        # cdf[hi] >= (c+1)/G); a bisection then finds the bin
        self.G = int(min(GUIDE_PER_BIN * self.K, max(self.K, GUIDE_BUDGET // self.n_rows)))
        edges = (np.arange(self.G + 1) / self.G).astype(np.float32)
        # lo: the last node with cdf <= c/G; hi: the first with cdf >= (c+1)/G (the nodes of the
        # float32 tail at cdf = 1, never sampled, stay out of the last cell)
        lo = np.stack([np.clip(np.searchsorted(row, edges[:-1], side="right") - 1, 0, self.K - 2)
                       for row in cdf32])
        hi = np.stack([np.searchsorted(row, edges[1:], side="left") for row in cdf32])
        hi = np.clip(hi, lo + 1, self.K - 1)
        span = hi - lo
        #: bisection steps: at most (any cell), and the mean over the cells
        self.steps = (int(np.ceil(np.log2(span.max()))), float(np.mean(np.ceil(np.log2(span)))))
        self.guide = _array(mi.UInt32, lo.astype(np.uint32) | (hi.astype(np.uint32) << 16))  # K < 2^16
        self.inv_ds = _opaque(mi.Float, 1.0 / ds)
        self.ds2 = _opaque(mi.Float, ds * ds)

    # ------------------------------------------------------------------
    def _angle(self, wi, wo):
        """(bin i, fraction f in v) of the scattering angle between -wi and wo on the chord nodes
        (corona.model.mie.volume.node_bin): no trigonometry, accurate at both ends."""
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
        lam = dr.clip(lam, tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX)
        g = (self.two_pi_r / lam - self.x0) * self.inv_dx
        j = dr.minimum(mi.UInt32(dr.maximum(dr.floor(g), 0.0)), self.n_rows - 2)
        t = dr.clip(g - mi.Float(j), 0.0, 1.0)
        return j, t

    def _lookup(self, mei, i, active):
        """The table around angle bin i, one packet per lane: spectral [(j, t, (p_j,i, p_j,i+1,
        p_j+1,i, p_j+1,i+1))] per wavelength; RGB / mono [(c, None, (p_c,i, p_c,i+1))] per channel."""
        if mi.is_spectral:
            out = []
            for l in range(dr.size_v(mi.Spectrum)):
                j, t = self._row_of(mei.wavelengths[l])
                out.append((j, t, _packet(self.vals, 4, j * (self.K - 1) + i, active)))
            return out
        q = _packet(self.vals, self.P, i, active)
        return [(c, None, (q[2 * c], q[2 * c + 1])) for c in range(self.n_rows)]

    @staticmethod
    def _values(look, f):
        """Per-lane values at fraction f in v of the bin, and their mean (the pdf)."""
        vals = []
        for _, t, q in look:
            v = dr.lerp(q[0], q[1], f)
            if t is not None:
                v = dr.lerp(v, dr.lerp(q[2], q[3], f), t)
            vals.append(v)
        pdf = vals[0]
        for v in vals[1:]:
            pdf = pdf + v
        return vals, pdf * (1.0 / len(vals))

    def eval_pdf(self, ctx, mei, wo, active=True):
        i, f = self._angle(mei.wi, wo)
        vals, pdf = self._values(self._lookup(mei, i, active), f)
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
            upper = u < t
            row = dr.select(upper, j + 1, j)
        else:
            upper = False
            row = lane
        xi = dr.clip(sample2.x, 0.0, 0.99999994)
        base = row * self.K
        cell = dr.minimum(mi.UInt32(xi * self.G), self.G - 1)
        lohi = _gather(mi.UInt32, self.guide, row * self.G + cell, active)
        lo, hi = lohi & 0xFFFF, lohi >> 16                              # cdf[lo] <= ξ < cdf[hi]

        def bisect(lo, hi):
            mid = (lo + hi) >> 1
            below = _gather(mi.Float, self.cdf, base + mid) <= xi
            return dr.select(below, mid, lo), dr.select(below, hi, mid)

        lo, hi = dr.while_loop((lo, hi), lambda lo, hi: active & (hi > lo + 1), bisect,
                               labels=("lo", "hi"), label="corona_mie_bisect")
        i = dr.minimum(lo, self.K - 2)
        c_lo = _gather(mi.Float, self.cdf, base + i, active)
        # the lanes' packets at bin i: the sampled row's two nodes, and the values below
        look = self._lookup(mei, i, active)
        p0, p1 = look[0][2][0], look[0][2][1]
        if mi.is_spectral:
            p0 = dr.select(upper & (lane == 0), look[0][2][2], p0)
            p1 = dr.select(upper & (lane == 0), look[0][2][3], p1)
        for l in range(1, n):
            q = look[l][2]
            sel = lane == l
            p0 = dr.select(sel, dr.select(upper, q[2], q[0]) if mi.is_spectral else q[0], p0)
            p1 = dr.select(sel, dr.select(upper, q[3], q[1]) if mi.is_spectral else q[1], p1)
        fwd = i < self.M
        l = dr.select(fwd, i, 2 * self.M - 1 - i)          # the chord index of the bin
        lf = mi.Float(l)
        h = (2.0 * lf + 1.0) * self.ds2                     # bin width in v
        r = dr.maximum(xi - c_lo, 0.0) / (4.0 * dr.pi * h)
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
        vals, pdf = self._values(look, tt)
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
                f"volume_fraction={v.volume_fraction:g}, host_ior={v.host_ior:g}, "
                f"truncation={v.truncation:g}, rows={self.n_rows}, nodes={self.K}]")


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
