"""The flat layer's diffraction lobe in Dr.Jit, one object per representation, chosen once per table build.

The plugin (:mod:`corona.mitsuba.bsdf`) builds its tables at load (and when a parameter leaves
them) and picks one of these; ``eval``, ``pdf`` and ``sample`` then call it and read no
representation flag:

- :class:`RadialRow`: one radial row ``v(u)`` (linear in ``|u|``), sampled exactly ``∝ v``
  (the area fraction fixed, or ``S = 1``);
- :class:`CentredRadialRow`: one row at the layer's own ``F_a`` plus its slope in ``F_a`` (a
  uniform area fraction: derivatives in ``F_a`` through the slope);
- :class:`RadialRows` / :class:`RadialRowPairs`: rows over a texture's ``F_a`` range, the cubic
  Hermite in ``F_a`` between two rows, sampled from row ``j`` or ``j + 1`` (the pairs: rows ``j``
  and ``j + 1`` side by side, one 8-float packet a lookup, in vectorised variants);
- :class:`ChannelTables` / :class:`CentredChannelTables`: RGB / mono, one table per channel in
  ``s = L |d|`` holding the channel's mean lobe, sampled from their sum;
- :class:`KernelLobe` / :class:`CentredKernelLobe`: anisotropic lobes, the analytic or gridded
  kernel of :mod:`corona.mitsuba.kernels`.

Where the layer's ``F_a`` falls among the rows is one object too (:class:`OneRow`,
:class:`CentredRow`, :class:`RowGrid`, :class:`PackedRowGrid`: ``locate(fa, active)``).

Each lobe has ``lobe_and_pdf(layer, dx, dy, wavelengths, active, modulation)`` (the lobe ``f`` without
the cosine as a Spectrum and the ``d``-space pdf averaged over the wavelengths, with a
modulation also the modulated lobe) and ``sample_d(sample2, layer, s, wavelengths, active)``
(``d = (wo + wi).xy`` for one wavelength picked by ``s``).  ``layer`` is the plugin's per-lane
state at the shading point (``fa``, the row ``j`` and weight ``t``, the Hermite weights, the
rows' energies, ``L``, the lobe weight).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from corona.mitsuba.common import (array, centre_rows, channel_response, clip, fold_spectrum, gather, gather4,
                                   guided_search, hermite_weights, invert_radial_bin, lambda_um, pick_wavelength,
                                   wavelength_mixture)

__all__ = ["Wavelengths", "SampledTable", "Lobe", "RadialRow", "CentredRadialRow", "RadialRows",
           "RadialRowPairs", "ChannelTables", "CentredChannelTables", "KernelLobe", "CentredKernelLobe",
           "OneRow", "CentredRow", "RowGrid", "PackedRowGrid", "differentiated",
           "FaTables", "FixedFaTables", "UniformFaTables", "CentredFaTables", "bilinear_corners"]


def differentiated(layer, dx, dy):
    """True where a derivative flows through the lobe (Dr.Jit's reverse mode of a symbolic loop
    needs a bound on its iterations: the wavelengths are unrolled then)."""
    return any(dr.grad_enabled(x) for x in (dx, dy, *(v for v in layer.values() if v is not None
                                                       and not isinstance(v, tuple))))


class Wavelengths:
    """The wavelengths a lane evaluates: spectral variants the lane's own, RGB and mono the
    channels' response wavelengths (:func:`corona.mitsuba.common.channel_response`)."""

    def __init__(self):
        self.lambdas = self.weights = None
        if not mi.is_spectral:
            self.lambdas, self.weights = channel_response()     # (channels, N) nm
        self._loop = None

    def mixture(self, wavelengths):
        """The wavelengths [nm] evaluated per lane and their pdf mixture weights (equal)."""
        return wavelength_mixture(wavelengths, self.lambdas)

    def fold(self, values):
        """The Spectrum of per-wavelength values: spectral as is, RGB / mono each channel's mean."""
        return fold_spectrum(values, self.lambdas, self.weights)

    def loop_arrays(self):
        """The response wavelengths and weights as Dr.Jit arrays (uploaded once)."""
        if self._loop is None:
            self._loop = (array(mi.Float, np.asarray(self.lambdas, dtype=np.float64).ravel()),
                          array(mi.Float, np.asarray(self.weights, dtype=np.float64).ravel()))
        return self._loop


class SampledTable:
    """Radial rows in packets ``(v(i), v(i + 1), ∂v(i), ∂v(i + 1))`` (``n`` nodes ``du`` apart a row),
    their energies ``totals`` and the guide-table CDFs that sample them
    (:func:`corona.mitsuba.common.guided_cdfs`: ``cdf``, ``guide``, ``guide_size``, ``n_bins``, ``steps``)."""

    def __init__(self, du, n, packed, totals, cdf, guide, guide_size, n_bins, steps):
        self.du, self.n, self.packed, self.totals = du, n, packed, totals
        self.cdf, self.guide, self.guide_size, self.n_bins, self.steps = cdf, guide, guide_size, n_bins, steps

    def packet(self, row, idx):
        """The 4-float packet of row ``row``, bin ``idx``."""
        return row * (self.n - 1) + idx

    def sample(self, s, row, active):
        """Invert the CDF of row ``row``: s (Vector2f) -> x (Vector2f, radius in the table's units).

        Radial: density ``2π x v_lin(x)`` in the bin; its CDF a cubic, solved by safeguarded Newton."""
        target = s.x
        idx, c0, c1 = guided_search(self.cdf, self.guide, self.guide_size, self.n_bins,
                                    self.steps, row, target, active)
        du = self.du
        u0 = mi.Float(idx) * du
        q = gather4(self.packed, self.packet(row, idx), active)    # (bins of the CDF = of the rows)
        a = q.x
        b = q.y - a
        t = invert_radial_bin(target - c0, c0, c1, u0, du, a, b, gather(mi.Float, self.totals, row, active))
        r = u0 + t * du
        sin_phi, cos_phi = dr.sincos(2.0 * dr.pi * s.y)
        return mi.Vector2f(r * cos_phi, r * sin_phi)


class PairedTable(SampledTable):
    """:class:`SampledTable` whose packets are row pairs (8 floats: row ``j``'s packet, then row
    ``j + 1``'s; ``n_rows`` rows): row ``r``'s own packet is the 4-float packet
    ``2 (p (n - 1) + i) + r - p``, ``p = min(r, n_rows - 2)``."""

    def __init__(self, n_rows, *args):
        super().__init__(*args)
        self.n_rows = n_rows

    def packet(self, row, idx):
        pair = dr.minimum(row, self.n_rows - 2)
        return 2 * (pair * (self.n - 1) + idx) + (row - pair)


class Lobe:
    """A representation evaluated one wavelength at a time (:meth:`at`): its wavelengths summed
    unrolled or in one symbolic Dr.Jit loop, sampled for a wavelength picked from the lane's."""

    #: True where one wavelength costs many operations (a loop in spectral variants too).
    costly = False

    def __init__(self, spectrum: Wavelengths):
        self.spectrum = spectrum

    # --- one wavelength ---------------------------------------------------------------------
    def value_pdf(self, layer, dx, dy, ux, uy, k, active):
        """``v(u)`` and the pdf ``p_u`` of sampling ``u`` at ``u = k d`` (``k = 2π L / λ``)."""
        raise NotImplementedError

    def at(self, layer, dx, dy, lam_nm, active):
        """One wavelength's lobe ``F_a (L/λ)² v(u)`` at ``d = (dx, dy)`` and its d-space pdf ``p_u k²``."""
        L_lam = layer["L"] * dr.rcp(lambda_um(lam_nm))      # L/λ (one division a wavelength)
        k = 2.0 * dr.pi * L_lam                             # u = 2π L d / λ
        v, p_u = self.value_pdf(layer, dx, dy, dx * k, dy * k, k, active)
        return layer["weight"] * dr.square(L_lam) * v, p_u * dr.square(k)

    # --- all the lane's wavelengths ---------------------------------------------------------
    def lobe_and_pdf(self, layer, dx, dy, wavelengths, active, modulation=None):
        """Lobe value f (Spectrum, no cosine) and the d-space pdf averaged over wavelengths;
        with ``modulation(q, λ)`` also the lobe with each wavelength's value times that factor."""
        lams, mix = self.spectrum.mixture(wavelengths)
        # a loop where the wavelengths are many (RGB / mono) or each costs many operations (the
        # anisotropic kernels): compile time; the spectral radial rows stay unrolled (a few operations)
        if (dr.is_array_v(mi.Float) and (not mi.is_spectral or self.costly)
                and not differentiated(layer, dx, dy)):
            return self._looped(layer, dx, dy, active, modulation, lams)
        values = []
        pdf = mi.Float(0.0)
        for lam_nm, m in zip(lams, mix):
            value, p_d = self.at(layer, dx, dy, lam_nm, active)
            values.append(value)
            pdf += m * p_d
        fold = self.spectrum.fold
        if modulation is None:
            return fold(values), pdf
        return fold(values), pdf, fold([v * modulation(q, lam_nm) for q, (v, lam_nm) in enumerate(zip(values, lams))])

    def _looped(self, layer, dx, dy, active, modulation=None, lams=None):
        """:meth:`lobe_and_pdf` as one symbolic Dr.Jit loop over the wavelengths (``lams``, the
        lane's in spectral variants; the channels' response wavelengths in RGB / mono): a traced
        body instead of one unrolled copy per wavelength, so the kernel compiles in a fraction of
        the time; the same sums."""
        if mi.is_spectral:
            nc, per = len(lams), 1

            def wavelength(q):
                lam = lams[-1]
                for k in range(nc - 2, -1, -1):
                    lam = dr.select(q == k, lams[k], lam)
                return lam, 1.0
        else:
            nc, per = np.shape(self.spectrum.lambdas)
            lam_arr, w_arr = self.spectrum.loop_arrays()

            def wavelength(q):
                return gather(mi.Float, lam_arr, q), gather(mi.Float, w_arr, q)
        n = nc * per
        zero = dr.zeros(mi.Float, dr.width(dx))
        with_mod = modulation is not None

        def body(q, chans, mods, pdf):
            lam_nm, w = wavelength(q)
            value, p_d = self.at(layer, dx, dy, lam_nm, active)
            pdf = dr.fma(1.0 / n, p_d, pdf)
            c = q // per
            factor = modulation(q, lam_nm) if with_mod else None
            chans = [dr.select(c == i, dr.fma(w, value, a), a) for i, a in enumerate(chans)]
            if with_mod:
                mods = [dr.select(c == i, dr.fma(w, value * factor, a), a) for i, a in enumerate(mods)]
            return q + 1, chans, mods, pdf

        q0 = dr.zeros(mi.UInt32, dr.width(dx))
        state = (q0, [mi.Float(zero) for _ in range(nc)], [mi.Float(zero) for _ in range(nc if with_mod else 0)],
                 mi.Float(zero))
        _, chans, mods, pdf = dr.while_loop(state, lambda q, *_: q < n, body, label="corona wavelengths")
        spec = (lambda xs: mi.Spectrum(xs[0]) if nc == 1 else mi.Spectrum(xs))
        if not with_mod:
            return spec(chans), pdf
        return spec(chans), pdf, spec(mods)

    # --- sampling --------------------------------------------------------------------------
    def sampled_row(self, layer, rest):
        """The row sampled (``rest`` in [0, 1) what is left of the wavelength's pick): the layer's."""
        return layer["j"]

    def sample_u(self, s, row, active):
        """``u`` (Vector2f) of row ``row`` from ``s`` (Vector2f)."""
        raise NotImplementedError

    def sample_d(self, sample2, layer, s, wavelengths, active):
        """``d`` for one wavelength (picked by ``s`` with equal weights) and one row: ``u λ / (2π L)``."""
        lams, _ = self.spectrum.mixture(wavelengths)
        pick, hero, rest = pick_wavelength(s, lams)
        lam = lambda_um(hero)
        u = self.sample_u(sample2, self.sampled_row(layer, rest), active)
        return u * (lam / (2.0 * dr.pi * layer["L"]))


class RadialRow(Lobe):
    """One radial row ``v(u)`` (linear in ``|u|``), sampled exactly ``∝ v``."""

    def __init__(self, spectrum, table: SampledTable):
        super().__init__(spectrum)
        self.table = table

    def _bin(self, ux, uy, row, active):
        """The packet index of ``|u|``'s bin in row ``row``, the position ``t`` inside it and where it is inside the table."""
        table = self.table
        x = dr.sqrt(dr.fma(ux, ux, dr.fma(uy, uy, 1e-20))) / table.du   # (no NaN gradient at u = 0)
        i = dr.minimum(mi.UInt32(dr.maximum(dr.floor(x), 0)), table.n - 2)
        t = x - mi.Float(i)
        inside = active & (x <= table.n - 1)
        return row * (table.n - 1) + i, t, inside     # the packet of bin i: v(i), v(i + 1), ∂v(i), ∂v(i + 1)

    def value_pdf(self, layer, dx, dy, ux, uy, k, active):
        idx, t, inside = self._bin(ux, uy, layer["j"], active)
        q = gather4(self.table.packed, idx, inside)
        v = dr.select(inside, dr.maximum(dr.lerp(q.x, q.y, t), 0.0), 0.0)
        return v, v / dr.maximum(layer["total"], 1e-30)

    def sample_u(self, s, row, active):
        return self.table.sample(s, row, active)


class CentredRadialRow(RadialRow):
    """One radial row at the layer's uniform ``F_a`` (``fa_centre``), plus ``(F_a - fa_centre)`` times
    its slope in ``F_a`` (0 in value, the derivative in ``F_a``); ``pdf ∝ eval``."""

    def __init__(self, spectrum, table, fa_centre):
        super().__init__(spectrum, table)
        self.fa_centre = fa_centre

    def value_pdf(self, layer, dx, dy, ux, uy, k, active):
        idx, t, inside = self._bin(ux, uy, layer["j"], active)
        q = gather4(self.table.packed, idx, inside)
        v0 = dr.lerp(q.x, q.y, t)
        v = dr.select(inside, dr.maximum(dr.fma(layer["fa"] - self.fa_centre, dr.lerp(q.z, q.w, t), v0), 0.0), 0.0)
        return v, v / dr.maximum(layer["energy"], 1e-30)


class RadialRows(RadialRow):
    """Radial rows over an ``F_a`` range: evaluated as the cubic Hermite in ``F_a`` between rows ``j``
    and ``j + 1``, sampled from row ``j`` or ``j + 1`` (weights ``1 - t``, ``t``), which is the pdf."""

    def _rows(self, idx, inside):
        """Packets of rows ``j`` and ``j + 1`` at bin packet ``idx`` of row ``j``."""
        return gather4(self.table.packed, idx, inside), gather4(self.table.packed, idx + (self.table.n - 1), inside)

    def value_pdf(self, layer, dx, dy, ux, uy, k, active):
        idx, t, inside = self._bin(ux, uy, layer["j"], active)
        q, q1 = self._rows(idx, inside)
        v0 = dr.lerp(q.x, q.y, t)
        v1 = dr.lerp(q1.x, q1.y, t)
        h00, h10, h01, h11 = layer["hermite"]
        v = h00 * v0 + h01 * v1 + h10 * dr.lerp(q.z, q.w, t) + h11 * dr.lerp(q1.z, q1.w, t)
        v0 = dr.select(inside, dr.maximum(v0, 0.0), 0.0)
        v1 = dr.select(inside, dr.maximum(v1, 0.0), 0.0)
        p_u = dr.lerp(v0 / dr.maximum(layer["total"], 1e-30), v1 / dr.maximum(layer["total_next"], 1e-30), layer["t"])
        return dr.select(inside, dr.maximum(v, 0.0), 0.0), p_u

    def sampled_row(self, layer, rest):
        """Row ``j`` with probability ``1 - t``, ``j + 1`` with ``t``."""
        return dr.select(rest >= 1.0 - layer["t"], layer["j"] + 1, layer["j"])


class RadialRowPairs(RadialRows):
    """:class:`RadialRows` with rows ``j`` and ``j + 1`` side by side (:class:`PairedTable`): one
    8-float packet gather a lookup (vectorised variants)."""

    def _rows(self, idx, inside):
        r8 = dr.gather(mi.ArrayXf, self.table.packed, idx, inside, shape=(8, dr.width(idx)))
        return mi.Vector4f(r8[0], r8[1], r8[2], r8[3]), mi.Vector4f(r8[4], r8[5], r8[6], r8[7])


class ChannelTables(Lobe):
    """RGB / mono, one radial row: one table per channel in ``s = L |d|`` [µm] (``packed``: bin-major,
    one packet per bin and channel), channel ``c``'s lobe ``F_a L² g_c(s)``, sampled from their sum
    ``G = Σ_c g_c`` (``table``: its CDF, packets and ``(∫G d²s, ∫∂G d²s)``), pdf ``L² G(s) / ∫G d²s``."""

    def __init__(self, spectrum, table: SampledTable, packed, count):
        super().__init__(spectrum)
        self.table, self.packed, self.count = table, packed, count

    def dfa(self, layer):
        """``F_a`` minus the table's (None: the table is at the layer's F_a)."""
        return None

    def lobe_and_pdf(self, layer, dx, dy, wavelengths, active, modulation=None):
        L = layer["L"]
        table = self.table
        # (the 1e-24 keeps the gradient of |d| finite at d = 0)
        x = dr.sqrt(dr.fma(dx, dx, dr.fma(dy, dy, 1e-24))) * L * (1.0 / table.du)
        i = dr.minimum(mi.UInt32(dr.maximum(dr.floor(x), 0)), table.n - 2)
        t = x - mi.Float(i)
        inside = active & (x <= table.n - 1)
        dfa = self.dfa(layer)
        nc = self.count
        scale = layer["weight"] * dr.square(L)
        chans, g_sum = [], mi.Float(0.0)
        for c in range(nc):
            q = gather4(self.packed, i * nc + c, inside)
            g = dr.lerp(q.x, q.y, t)
            if dfa is not None:
                g = dr.fma(dfa, dr.lerp(q.z, q.w, t), g)
            g = dr.select(inside, dr.maximum(g, 0.0), 0.0)
            g_sum += g
            chans.append(scale * g)
        energy = gather(mi.Float, table.totals, mi.UInt32(0), active)
        if dfa is not None:
            energy = dr.fma(dfa, gather(mi.Float, table.totals, mi.UInt32(1), active), energy)
        pdf = dr.square(L) * g_sum / dr.maximum(energy, 1e-30)
        return (mi.Spectrum(chans[0]) if nc == 1 else mi.Spectrum(chans)), pdf

    def sample_d(self, sample2, layer, s, wavelengths, active):
        """``s = L |d|`` from the channels' sum (one row): ``d = s / L``."""
        return self.table.sample(sample2, layer["j"], active) / layer["L"]


class CentredChannelTables(ChannelTables):
    """:class:`ChannelTables` of the row at the layer's uniform ``F_a`` (``fa_centre``), plus
    ``(F_a - fa_centre)`` times the tables' slopes in ``F_a``."""

    def __init__(self, spectrum, table, packed, count, fa_centre):
        super().__init__(spectrum, table, packed, count)
        self.fa_centre = fa_centre

    def dfa(self, layer):
        return layer["fa"] - self.fa_centre


class KernelLobe(Lobe):
    """An anisotropic lobe: the kernel of :mod:`corona.mitsuba.kernels` (analytic form factors or
    cubic form-factor grids × radial S; bilinear for lattices), sampled exactly from its bilinear
    table, the pdf that table's density."""

    costly = True

    def __init__(self, spectrum, kernel):
        super().__init__(spectrum)
        self.kernel = kernel

    def dfa(self, layer):
        """``F_a`` minus the kernel's centred row's (None: no centred row)."""
        return None

    def value_pdf(self, layer, dx, dy, ux, uy, k, active):
        srow = None if layer["hermite"] is None else (layer["j"], *layer["hermite"])
        v = self.kernel.value(dx, dy, active, srow, self.dfa(layer), scale=k)      # (d and k: see value)
        return v, self.kernel.pdf(ux, uy, active)

    def sample_u(self, s, row, active):
        """(Mitsuba's distribution samples the F_a-interpolated mixture itself.)"""
        return self.kernel.sample(s, active)


class CentredKernelLobe(KernelLobe):
    """:class:`KernelLobe` whose structure factor is one row at the layer's uniform ``F_a``
    (``fa_centre``) plus its slope in ``F_a``."""

    def __init__(self, spectrum, kernel, fa_centre):
        super().__init__(spectrum, kernel)
        self.fa_centre = fa_centre

    def dfa(self, layer):
        return layer["fa"] - self.fa_centre


# --------------------------------------------------------------------------
# where the layer's F_a falls among the rows (the plugin's per-lane state)
# --------------------------------------------------------------------------
class OneRow:
    """One row at a fixed area fraction (``F_a`` does not move the lobe, or cannot vary): row 0,
    its energy ``totals[0]``."""

    def __init__(self, totals):
        self.totals = totals

    def locate(self, fa, active):
        """The row ``j`` of ``fa``, the weight ``t`` of row ``j + 1``, the rows' energies, the cubic
        Hermite weights in ``F_a`` (None: no second row) and the energy at ``fa``."""
        j, t = mi.UInt32(0), mi.Float(0.0)
        total = gather(mi.Float, self.totals, j, active)
        return dict(j=j, t=t, total=total, total_next=total, hermite=None, energy=total)


class CentredRow(OneRow):
    """One row at the layer's uniform ``F_a`` (``fa_centre``): the energy is ``totals[0]`` in value
    and its derivative in ``F_a`` the row's slope's energy ``total_slopes[0]``."""

    def __init__(self, totals, total_slopes, fa_centre):
        super().__init__(totals)
        self.total_slopes, self.fa_centre = total_slopes, fa_centre

    def locate(self, fa, active):
        out = super().locate(fa, active)
        out["energy"] = dr.fma(fa - self.fa_centre, gather(mi.Float, self.total_slopes, out["j"], active),
                               out["total"])
        return out


class RowGrid:
    """Rows at area fractions ``fa_rows`` (``n_rows >= 2``), found through a uniform guide grid
    (``guide``: each cell's first row; ``cells`` cells from ``fa_lo``, ``scale`` cells per unit
    ``F_a``; ``steps`` comparisons find the row); the energy cubic Hermite in ``F_a`` between
    rows ``j`` and ``j + 1`` (``totals`` and their slopes ``total_slopes``)."""

    def __init__(self, fa_rows, n_rows, guide, cells, scale, steps, fa_lo, totals, total_slopes):
        self.fa_rows, self.n_rows, self.guide = fa_rows, n_rows, guide
        self.cells, self.scale, self.steps, self.fa_lo = cells, scale, steps, fa_lo
        self.totals, self.total_slopes = totals, total_slopes

    def _last_step(self, j, fa, active):
        """The last comparison: (up, F_a of rows j, j + 1, j + 2, the energies of the row found)."""
        f0 = gather(mi.Float, self.fa_rows, j, active)
        f1 = gather(mi.Float, self.fa_rows, j + 1, active)
        f2 = gather(mi.Float, self.fa_rows, dr.minimum(j + 2, self.n_rows - 1), active)
        up = (f1 <= fa) & (j < self.n_rows - 2)

        def energies(jj):
            return (gather(mi.Float, self.totals, jj, active), gather(mi.Float, self.totals, jj + 1, active),
                    gather(mi.Float, self.total_slopes, jj, active),
                    gather(mi.Float, self.total_slopes, jj + 1, active))
        return up, f0, f1, f2, energies

    def locate(self, fa, active):
        # the row j with fa_rows[j] <= fa < fa_rows[j + 1] (j <= n_rows - 2): the guide cell's
        # first row, or the next one where that lies inside the cell below fa (float32
        # rounding at a cell's edge may leave fa an ulp below fa_rows[j]: t ~ -1e-6, harmless)
        cell = dr.clip(dr.floor((fa - self.fa_lo) * self.scale), 0, self.cells - 1)
        j = gather(mi.UInt32, self.guide, mi.UInt32(cell), active)
        for _ in range(self.steps - 1):
            up = (gather(mi.Float, self.fa_rows, j + 1, active) <= fa) & (j < self.n_rows - 2)
            j = dr.select(up, j + 1, j)
        # the last step reads the three rows at once (no gather waits for another)
        up, f0, f1, f2, energies = self._last_step(j, fa, active)
        j = dr.select(up, j + 1, j)
        f0, f1 = dr.select(up, f1, f0), dr.select(up, f2, f1)
        total, total_next, slope, slope_next = energies(j)
        # linear in F_a between rows; no clip (fa is clamped to the rows already), so that
        # the derivative at a row is the next interval's slope, not zero
        h = dr.maximum(f1 - f0, 1e-12)
        t = (fa - f0) / h
        # cubic Hermite weights between the rows (the slopes' two scaled by the spacing h)
        h00, h10, h01, h11 = hermite_weights(t)
        hermite = (h00, h10 * h, h01, h11 * h)
        energy = (hermite[0] * total + hermite[2] * total_next
                  + hermite[1] * slope + hermite[3] * slope_next)
        return dict(j=j, t=t, total=total, total_next=total_next, hermite=hermite, energy=energy)


class PackedRowGrid(RowGrid):
    """:class:`RowGrid` reading what it needs of rows ``j .. j + 2`` (F_a, energies, slopes) in one
    16-float packet a lane (``scalars``; vectorised variants)."""

    def __init__(self, scalars, *args):
        super().__init__(*args)
        self.scalars = scalars

    def _last_step(self, j, fa, active):
        r = dr.gather(mi.ArrayXf, self.scalars, j, active, shape=(16, dr.width(j)))
        up = (r[1] <= fa) & (j < self.n_rows - 2)
        found = (dr.select(up, r[4], r[3]), dr.select(up, r[5], r[4]),
                 dr.select(up, r[7], r[6]), dr.select(up, r[8], r[7]))
        return up, r[0], r[1], r[2], lambda jj: found


# --------------------------------------------------------------------------
# tables read node by node in rows of F_a (the sphere plugin's S(u) and forward energies e_f(x, μ))
# --------------------------------------------------------------------------
class FaTables:
    """The sphere plugin's F_a-dependent tables, ``S(u)`` (``S_n`` nodes ``S_du`` apart) and the
    forward energies ``e_f`` (``n_rows`` rows of x, ``n_mu`` nodes of μ), in one representation
    chosen at load (:class:`FixedFaTables`, :class:`UniformFaTables`, :class:`CentredFaTables`): the
    flat layer's row lookups (:class:`OneRow`, :class:`CentredRow`, :class:`RowGrid`) for tables read
    at several nodes a lane.  ``locate(fa)`` gives the lane's weights ``w`` once; ``structure`` and
    ``forward`` read with them.  ``recentre(fa)`` re-centres a centred layer (others: nothing)."""

    def __init__(self, n_rows, n_mu, S_du=None, S_n=None):
        self.n_rows, self.n_mu, self.S_du, self.S_n = n_rows, n_mu, S_du, S_n

    def recentre(self, fa):
        """Put a uniform layer's rows at ``fa`` (only :class:`CentredFaTables` has one)."""

    def decoupled(self, w, u, P, C_f, forward, active):
        """The lobe per steradian at ``u = q r`` by the decoupling rule (corona.model.layer.decoupled_lobe):
        ``max(P + C (S - 1), 0)`` on the forward lobe (``forward``), ``P`` on the backward one; ``C_f()``
        reads the forward ``C``."""
        S = self.structure(w, u, active)
        return dr.select(forward, dr.maximum(dr.fma(C_f(), S - 1.0, P), 0.0), P)

    def _node(self, u, active):
        """``S``'s node ``i`` at ``u``, the position ``f`` after it and where ``u`` is inside the table."""
        x = u * (1.0 / self.S_du)
        i = dr.minimum(mi.UInt32(dr.maximum(dr.floor(x), 0)), self.S_n - 2)
        f = dr.minimum(x - mi.Float(i), 1.0)       # >= 0; no clip at 0 (a node): its derivative there is 0
        return i, f, active & (x <= self.S_n - 1)


class FixedFaTables(FaTables):
    """One F_a that nothing moves (Poisson centres: no ``S``): the forward energies' bilinear cells
    (``corners``: one Vector4f a cell)."""

    def __init__(self, corners, n_rows, n_mu):
        super().__init__(n_rows, n_mu)
        self.corners = corners

    def locate(self, fa):
        """The lane's weights in F_a: none."""
        return None

    def decoupled(self, w, u, P, C_f, forward, active):
        """No ``S`` (Poisson centres): the lobe is ``P``."""
        return P

    def forward(self, w, j, b, f, t, active):
        """``e_f`` at x row ``j`` (weight ``t`` of ``j + 1``) and μ node ``b`` (weight ``f`` of ``b + 1``)."""
        e = gather4(self.corners, j * (self.n_mu - 1) + b, active)
        return dr.lerp(dr.lerp(e.x, e.y, f), dr.lerp(e.z, e.w, f), t)


class UniformFaTables(FaTables):
    """Rows at ``F_a = fa0 + k dfa`` (``n_fa >= 2``; a texture's range), the cubic Hermite in F_a between
    rows ``k`` and ``k + 1`` (:func:`corona.mitsuba.common.hermite_weights`) from packets
    ``(y_k, dfa y'_k, y_k+1, dfa y'_k+1)`` (:meth:`pack`)."""

    def __init__(self, fas, S, E, n_rows, n_mu, S_du, S_n):
        super().__init__(n_rows, n_mu, S_du, S_n)
        fas = np.asarray(fas, dtype=np.float64)
        self.n_fa, self.fa0, self.dfa = int(fas.size), float(fas[0]), float(fas[1] - fas[0])
        self.S, self.Ef = self.pack(fas, S), self.pack(fas, E)

    def pack(self, fas, rows):
        """Rows in F_a packed for one Vector4f gather per node: (y_k, Δ y'_k, y_k+1, Δ y'_k+1) of each
        interval k (Δ the row step, ``y'`` from :func:`corona.model.rows.row_slopes`)."""
        from corona.model.rows import row_slopes
        y = rows.reshape(rows.shape[0], -1)
        m = row_slopes(fas, y) * self.dfa
        return array(mi.Float, np.stack([y[:-1], m[:-1], y[1:], m[1:]], axis=-1).ravel())

    def locate(self, fa):
        """Row k and the cubic Hermite weights (value k, slope k, value k+1, slope k+1) of the lane's F_a."""
        g = (fa - self.fa0) / self.dfa                # itself on the end rows
        g = clip(g, 0.0, self.n_fa - 1.0)
        k = dr.minimum(mi.UInt32(dr.floor(g)), self.n_fa - 2)
        return k, hermite_weights(g - mi.Float(k))

    def read(self, values, stride, index, w, active):
        """Node ``index`` of rows ``stride`` long, interpolated in F_a with the weights ``w``."""
        k, (a, b, c, d) = w
        v = gather4(values, k * stride + index, active)
        return a * v.x + b * v.y + c * v.z + d * v.w

    def structure(self, w, u, active):
        """``S`` at ``u = q r``: linear in u, the cubic Hermite in F_a between its rows; 1 beyond."""
        i, f, inside = self._node(u, active)
        v = dr.lerp(self.read(self.S, self.S_n, i, w, inside), self.read(self.S, self.S_n, i + 1, w, inside), f)
        return dr.select(inside, v, 1.0)

    def forward(self, w, j, b, f, t, active):
        n = self.n_mu
        k = j * n + b
        stride = self.n_rows * n
        e00 = self.read(self.Ef, stride, k, w, active)
        e01 = self.read(self.Ef, stride, k + 1, w, active)
        e10 = self.read(self.Ef, stride, k + n, w, active)
        e11 = self.read(self.Ef, stride, k + n + 1, w, active)
        return dr.lerp(dr.lerp(e00, e01, f), dr.lerp(e10, e11, f), t)


class CentredFaTables(FixedFaTables):
    """A uniform layer's one F_a: ``S`` and the forward energies there and their slopes in F_a (the cubic
    Hermite between the rows ``fas``, :func:`corona.mitsuba.common.centre_rows`, as the flat layer's
    :class:`CentredRow`), read as value + slope × (F_a - ``fa_centre``) so that ``∂/∂F_a`` is the rows'
    and :meth:`recentre` moves them without recompiling.  ``grid``: the same rows as
    :class:`UniformFaTables` (what a texture of F_a reads)."""

    def __init__(self, grid: UniformFaTables, fas, S, E, fa):
        FaTables.__init__(self, grid.n_rows, grid.n_mu, grid.S_du, grid.S_n)
        self.grid, self.window = grid, (fas, S, E)
        self.recentre(fa)

    def recentre(self, fa):
        fas, S, E = self.window
        self.fa_centre, ((s_at, ds_at), (e_at, de_at)) = centre_rows(fas, fa, S, E)
        self.S_centre = array(mi.Float, np.stack([s_at[:-1], s_at[1:], ds_at[:-1], ds_at[1:]], axis=-1).ravel())
        # the slopes apart: a render without derivatives reads only the values
        self.corners = array(mi.Float, bilinear_corners(e_at).ravel())
        self.slopes = array(mi.Float, bilinear_corners(de_at).ravel())

    decoupled = FaTables.decoupled

    def locate(self, fa):
        """``F_a - F_a,centre`` where F_a has a gradient, else None (the values alone)."""
        return fa - self.fa_centre if dr.grad_enabled(fa) else None

    def structure(self, w, u, active):
        i, f, inside = self._node(u, active)
        v4 = gather4(self.S_centre, i, inside)     # (S_i, S_i+1, their slopes in F_a)
        v = dr.lerp(v4.x, v4.y, f)
        if w is not None:
            v = dr.fma(dr.lerp(v4.z, v4.w, f), w, v)
        return dr.select(inside, v, 1.0)

    def forward(self, w, j, b, f, t, active):
        k = j * (self.n_mu - 1) + b
        e = gather4(self.corners, k, active)
        if w is not None:                           # the slope in F_a, where it has a gradient
            e = dr.fma(gather4(self.slopes, k, active), w, e)
        return dr.lerp(dr.lerp(e.x, e.y, f), dr.lerp(e.z, e.w, f), t)


def bilinear_corners(e):
    """The four corners ``(e[j, b], e[j, b+1], e[j+1, b], e[j+1, b+1])`` of each cell of a table
    ``e`` (rows j of x, columns b of μ), cell by cell: one Vector4f gather reads a bilinear cell."""
    e = np.asarray(e, dtype=np.float64)
    return np.stack([e[:-1, :-1], e[:-1, 1:], e[1:, :-1], e[1:, 1:]], axis=-1)
