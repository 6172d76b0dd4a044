"""The ``corona`` BSDF plugin for Mitsuba 3 (Dr.Jit only inside eval/sample/pdf).

A thin layer of scatterers (pores, droplets, grains) that transmits a
coherent (delta) beam, a diffraction lobe ``F_a T_a T_s`` and optionally
reflects diffusely from its opaque part (docs/physics.md#the-model).  Register it with
:func:`corona.register` after ``mi.set_variant(...)``; then
``<bsdf type="corona">`` and ``mi.load_dict({'type': 'corona', ...})`` work.

Parameters (all optional; the one specification is :data:`corona.parameters.PARAMETERS`):

{table}

Components: 0 = coherent transmission (``DeltaTransmission``), 1 = diffraction
lobe (``GlossyTransmission``), 2 = diffuse reflection (``DiffuseReflection``,
weight 0 when ``albedo`` is 0).  Without a substrate the layer is two-sided
and symmetric.

With ``substrate=glass`` the layer sits on a thin non-absorbing pane (index
``substrate_ior``, default 1.52) on its ``substrate_side`` face, and two
components are added: 3 = the pane's specular reflection
(``DeltaReflection``) and 4 = the lobe seen in reflection
(``GlossyReflection``: light that crosses the layer once coherently and once
scattered, with a reflection off the pane in between).  The pane reflects
``R' = 2R/(1 + R)`` of what reaches it (``R`` the polarisation-averaged
Fresnel reflectance of one face, the internal bounces summed, as Mitsuba's
``thindielectric``) and transmits ``T' = 1 - R'`` undeviated.  With ``C`` the
coherent weight, ``f`` the lobe, ``ρ`` the opaque part's reflectance, ``P = R' - R`` the
round trips through the glass (the face under the layer returns its ``R`` through the layer
once, ``docs/physics.md#the-front-face``):

=====================  =================================  =========================
component              light meets the layer first        light meets the glass first
=====================  =================================  =========================
coherent transmission  ``C T'(θi)``                       ``T'(θi) C``
lobe                   ``f T'(θo)``                       ``T'(θi) f``
diffuse reflection     ``ρ/π``                            ``T'(θi) ρ/π T'(θo)``
specular reflection    ``C R(θi) + C² P(θi)``             ``R'(θi)``
lobe in reflection     ``f [R_min + C (P_i + P_o)]``      0
=====================  =================================  =========================

With ``substrate=mirror`` the pane is silvered behind (``mirror_reflectance``, default 0.97,
or a spectrum: a metal's name, ``'nm:value, ...'`` or a ``<spectrum>``, taken per wavelength):
it reflects ``R' = R + T² R_m / (1 - R R_m)``, transmits nothing, and its back is black.
With a ``substrate_thickness`` [µm] (a mirror's default 4000) the two single-scattering
paths of the lobe in reflection interfere: ``f [R_min + C (P_i + P_o + 2 V Q)]``, Quetelet
rings (``docs/physics.md#the-coherent-double-pass-quetelet-rings``); RGB and mono variants
average the fringes over each response wavelength's bin (:func:`corona.model.substrate.channel_envelopes`).

Paths that meet the layer a second time after a reflection off the pane are
dropped unless they are one of the above (the scattered-twice paths, and
light the pane returns onto the layer's opaque part), so the layer on glass
reflects plus transmits at most what the layer alone would: the white
furnace stays <= 1.  ``docs/physics.md#the-layer-on-glass-substrateglass`` lists the approximations.

Textures: ``area_fraction``, ``radius`` and ``albedo`` take a float or any
Mitsuba texture, evaluated at the shading point.  ``mi.traverse`` exposes
``area_fraction.value``, ``radius.value`` and ``albedo.value`` of a uniform
layer (a texture: its own keys), all differentiable; ``params.update()``
re-renders without recompiling.  ``radius`` scales the whole layer (the
scatterer, the exclusion diameter, edge width and jitter together, σ/R
fixed: lengths given in µm belong to the largest radius at load), so the
dimensionless table is unchanged and the lobe stays exact; for a mixture a
``radius`` texture is the radius of its largest component, every size scaling
with it.  The lobe is tabulated in rows of ``F_a`` (the texture's range; a
uniform value ± 0.1) close enough that interpolating linearly between two rows
changes it by at most 0.1 % (:meth:`corona.Material.area_fraction_rows`;
anisotropic lobes: rows of the radial ``S - 1``,
:func:`corona.model.rows.structure_rows`), evaluated as the cubic Hermite
interpolation between the two rows (slopes from the rows:
:func:`corona.model.rows.row_slopes`; so ``∂/∂F_a`` is continuous) and sampled
as the mixture of the two rows with the linear weights, which is also the pdf.
A uniform ``F_a`` is evaluated on one row at the value itself instead (that
Hermite interpolation and its slope in ``F_a``, re-centred by each
``params.update()``; a radial lobe is sampled exactly from that row, so
``pdf ∝ eval``; an anisotropic one from its table at the loaded value): one
row's cost, and derivatives in ``F_a`` through the slope.
``lattice-*`` and ``points`` (whose geometry F_a sets) take no F_a texture;
``mask`` and ``points`` (absolute sizes) no radius texture.
``breath_time`` or ``dry_time`` (``process=breath-figure``, one of them) takes a texture too (a
breath spot, a wiped streak fogging up again, a pane drying from its edges): rows over the coverage
(which grows with the breath time and falls with the dry time), each the material at one time
with its table resampled to a length ``L ∝ R(t)``, Hermite in F_a between rows; each lane's F_a
and ``R`` linear in log t (breath) or t (dry) as the table's own
(docs/physics.md#breath-figures-processbreath-figure).

Spectral variants evaluate each of the lane's wavelengths.  Sampling picks
one of the lane's wavelengths at random (each with probability 1/n, reusing
the component-selection random number), draws ``d`` for it, and returns the
pdf averaged over all the lane's wavelengths (a one-sample balance-heuristic
mixture, hence unbiased).  RGB and mono variants evaluate each channel as the lobe averaged
over that channel's spectral response (CIE 1931 → linear sRGB, negative lobes
clipped; luminance ȳ for mono), using ``N_RESPONSE`` wavelengths per channel: a uniform
radial layer (no coherent pane) from one table per channel in ``s = L |d|`` holding that mean
(:func:`_channel_tables`), sampled from their sum; the others as one symbolic Dr.Jit loop over
the wavelengths (unrolled where a derivative flows through the lobe).

Wavelengths are clamped to [360, 830] nm (the range the tables cover); a zero
wavelength (as in a zero-initialised interaction) is clamped too, so no NaN.
The lobe outside the propagating disk is evanescent and dropped, so the
layer never transmits plus reflects more than it receives.
"""
from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi
import numpy as np

from corona.model import tabulated
from corona._validation import CoronaError, CoronaWarning
from corona.mitsuba.common import (N_RESPONSE, NEWTON_STEPS, TEXTURED, array as _array, channel_response,
                                   guided_cdfs,
                                   read_props as _read_props, texture_range, uniform as _uniform,
                                   variant_class)
from corona.mitsuba.common import PROCESS_TEXTURED, centre_rows, clip as _clip, gather as _gather
from corona.mitsuba.lobes import (CentredChannelTables, CentredKernelLobe, CentredRadialRow, CentredRow,
                                  ChannelTables, KernelLobe, OneRow, PackedRowGrid, PairedTable, RadialRow,
                                  RadialRowPairs, RadialRows, RowGrid, SampledTable, Wavelengths)
from corona.mitsuba.core import PluginCore
from corona.mitsuba.substrate import substrate_component
from corona.model.registry import process_family, shape_family
from corona.parameters import DEFAULTS, SPEC, material_from_parameters, parse_mixture, rst_table
from corona.model.rows import row_slopes

__doc__ = __doc__.replace("{table}", rst_table())

#: Area-fraction rows around a uniform value: ± this much (a texture gets its own range).
FA_WINDOW = 0.1
#: Rows of a ``breath_time`` texture per interval of the breath-figure table's times (uniform in log t;
#: the error this leaves, over the table's whole span: benchmarks/results/breath_time_texture.json).
TIME_SUBDIVIDE = 4
#: Nodes of a ``breath_time`` texture's lane table (F_a and log R, uniform in log t).
TIME_GRID = 257
#: Nodes of an RGB / mono channel table (in ``s = L |d|``) per node of the lobe's table in ``u``
#: at the shortest response wavelength (:func:`_channel_tables`).
CHANNEL_OVERSAMPLE = 2
__all__ = ["N_RESPONSE", "NEWTON_STEPS", "TEXTURED", "FA_WINDOW", "texture_range", "bsdf_class", "register"]


def _identity(x):
    return x


def _aperture_shares(fa):
    """(coherent beam, opaque fraction) of apertures covering F_a of an opaque screen."""
    return dr.square(fa), 1.0 - fa


def _particle_shares(fa):
    """(coherent beam, opaque fraction) of particles covering F_a of a clear layer."""
    return dr.square(1.0 - fa), fa


def _pack_rows(rows, slopes=None):
    """Radial rows ``(n_rows, n)`` and their slopes in F_a as one float32 array of packets, bin by bin:
    ``(v(i), v(i + 1), ∂v(i), ∂v(i + 1))`` for ``i < n - 1`` (slopes 0 without ``slopes``), so that one
    packet gather (:func:`corona.mitsuba.common.gather4`) reads what linear interpolation in ``|u|``
    and the Hermite in F_a need of a row."""
    rows = np.asarray(rows, dtype=np.float64)
    slopes = np.zeros_like(rows) if slopes is None else np.asarray(slopes, dtype=np.float64)
    packed = np.stack([rows[:, :-1], rows[:, 1:], slopes[:, :-1], slopes[:, 1:]], axis=-1)
    return _array(mi.Float, packed.ravel())


def _pack_row_pairs(rows, slopes):
    """Radial rows ``(n_rows, n)`` (``n_rows >= 2``) and their slopes in F_a as one float32 array of
    8-float packets, row pair by row pair and bin by bin: packet ``(j, i)`` holds row ``j``'s packet of
    :func:`_pack_rows` for bin ``i`` and then row ``j + 1``'s (``j < n_rows - 1``), so that the Hermite
    in F_a between rows ``j`` and ``j + 1`` reads one 32-byte packet (one cache line) a lookup, and
    row ``r``'s own packet is the 4-float packet ``2 (p (n - 1) + i) + r - p``, ``p = min(r, n_rows - 2)``."""
    rows = np.asarray(rows, dtype=np.float64)
    slopes = np.asarray(slopes, dtype=np.float64)
    single = np.stack([rows[:, :-1], rows[:, 1:], slopes[:, :-1], slopes[:, 1:]], axis=-1)   # (n_rows, n - 1, 4)
    return _array(mi.Float, np.concatenate([single[:-1], single[1:]], axis=-1).ravel())


def _channel_tables(v, dv, du, lams_nm, weights):
    """A radial row ``v(u)`` (linear in ``u``, nodes ``du`` apart, 0 beyond) and its slope ``dv`` in
    F_a as one table per RGB / mono channel in ``s = L |d|`` [µm]:
    ``g_c(s) = Σ_q w_cq λ_q⁻² v(2π s / λ_q)`` over the channel's response wavelengths ``λ_q``
    [µm] (``lams_nm`` (channels, N) [nm], weights ``w_cq``: :func:`corona.mitsuba.common.channel_response`),
    so that a channel's lobe is ``F_a L² g_c(L |d|)`` (the mean of ``F_a (L/λ)² v(2π L |d| / λ)``
    over its wavelengths) at the cost of one lookup.  Nodes ``ds = du λ_min / (2π CHANNEL_OVERSAMPLE)``
    apart (a finer step in ``u`` than the row's at every wavelength) up to the row's reach at
    ``λ_max``.  Returns ``(ds, g, dg)``, ``g`` and ``dg`` (channels, n_s), float64."""
    lam = np.clip(np.asarray(lams_nm, dtype=np.float64), tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX) * 1e-3
    w = np.asarray(weights, dtype=np.float64)
    ds = du * float(lam.min()) / (2.0 * np.pi * CHANNEL_OVERSAMPLE)
    u_grid = np.arange(v.size) * du
    n_s = int(np.ceil(u_grid[-1] * float(lam.max()) / (2.0 * np.pi * ds))) + 2
    s = np.arange(n_s) * ds
    g, dg = np.zeros((lam.shape[0], n_s)), np.zeros((lam.shape[0], n_s))
    for c in range(lam.shape[0]):
        for lq, wq in zip(lam[c], w[c]):
            u = (2.0 * np.pi / lq) * s
            g[c] += wq / lq**2 * np.interp(u, u_grid, v, right=0.0)
            dg[c] += wq / lq**2 * np.interp(u, u_grid, dv, right=0.0)
    return ds, g, dg


class LobeSampling:
    """``sampling='lobe'`` (the default) of a flat plugin: the lobe's ``d`` drawn from its representation
    (:mod:`corona.mitsuba.lobes`: ``sample_d``), the pdf its density."""

    def pdf_d(self, pdf_d):
        """The lobe's d-space pdf: its density (``pdf_d``)."""
        return pdf_d

    def directions(self, bsdf, si, layer, sample1, sample2, probs, picks, pick_lobe, wo_cos, wo_refl):
        """``(wo_lobe, wo_rlobe, lobe_ok)``: the lobe's direction in transmission and, with a pane, in
        reflection, and where they are valid (``wo_cos``, ``wo_refl``: the cosine warp and its
        reflection on the side of ``wi``)."""
        wi = si.wi
        cos_i = mi.Frame3f.cos_theta(wi)
        p_coh, p_lobe = probs[0], probs[1]
        # lobe: sample u for one wavelength and one F_a row, d = u λ / (2π L), wo.xy = d - wi.xy.
        # sample1's position inside the lobe's share picks the wavelength (equal weights)
        # and what is left of it the row (j with probability 1 - t, j + 1 with t)
        s = (sample1 - p_coh) / dr.maximum(p_lobe, 1e-30)
        s, pick_any_lobe = bsdf.substrate.lobe_share(picks, probs, sample1, s, pick_lobe)
        d = bsdf.lobe.sample_d(sample2, layer, s, si.wavelengths, pick_any_lobe)
        ox = d.x - wi.x
        oy = d.y - wi.y
        r2 = dr.fma(ox, ox, oy * oy)
        oz = -dr.mulsign(dr.safe_sqrt(1.0 - r2), cos_i)
        wo_lobe = mi.Vector3f(ox, oy, oz)
        wo_rlobe = mi.Vector3f(ox, oy, -oz)   # the lobe in reflection (a pane): the same d
        lobe_ok = (r2 < 1.0) & (oz != 0)
        return wo_lobe, wo_rlobe, lobe_ok


class CosineSampling(LobeSampling):
    """``sampling='cosine'`` of a flat plugin (comparisons only): the lobe drawn as the cosine warp,
    mirrored to the far side, ``p_ω = |cos θo| / π``."""

    def pdf_d(self, pdf_d):
        return mi.Float(dr.inv_pi)                                    # p_ω = |cos θo| / π

    def directions(self, bsdf, si, layer, sample1, sample2, probs, picks, pick_lobe, wo_cos, wo_refl):
        wo_lobe = mi.Vector3f(wo_refl.x, wo_refl.y, -wo_refl.z)
        return wo_lobe, wo_refl, wo_cos.z > 0        # (the lobe in reflection, a pane: the warp itself)


class CoronaBSDFMixin(PluginCore):
    """Mitsuba 3 BSDF of a layer of correlated scatterers (see the module docstring): the flat family
    on the shared shell (:class:`corona.mitsuba.core.PluginCore`).

    The methods live in this plain class; :func:`bsdf_class` copies them into a
    subclass of the active variant's ``mi.BSDF`` (each variant has its own
    base class, and nanobind types take a single base).
    """

    def __init__(self, props):
        mi.BSDF.__init__(self, props)  # the active variant's base class
        params, textures = _read_props(props)
        self.sampling = params.pop("sampling", SPEC["sampling"].default)
        #: how the lobe is sampled, chosen once here (:class:`LobeSampling`, :class:`CosineSampling`)
        self.sampler = CosineSampling() if self.sampling == "cosine" else LobeSampling()
        self.params = params
        # textured parameters: a float is a uniform texture (traverse: "<name>.value")
        for name in TEXTURED:
            if name not in textures:
                value = params.get(name, SPEC[name].default)
                textures[name] = _uniform(SPEC[name].default if value is None else value)
        self.fa_tex = textures["area_fraction"]
        self.radius_tex = textures["radius"]
        self.albedo_tex = textures["albedo"]
        # breath_time or dry_time as a texture: rows over the coverage, L ∝ R(t) per lane (_time_rows)
        timed = [k for k in PROCESS_TEXTURED if k in textures]
        self.time_name = timed[0] if timed else None
        self.time_tex = textures.get(self.time_name)
        #: the traced time coordinate, chosen once: log t for breath_time, t for dry_time (:meth:`_time_axis`)
        self._time_coordinate = dr.log if self.time_name == "breath_time" else _identity
        if self.time_tex is not None and params.get("process", SPEC["process"].default) != "breath-figure":
            raise CoronaError(f"corona BSDF: {self.time_name} can be a texture only with process='breath-figure'")
        if len(timed) > 1 or (self.time_name == "breath_time" and params.get("dry_time", 0.0) != 0.0):
            raise CoronaError("corona BSDF: breath_time and dry_time cannot both vary: a breath_time texture "
                              "needs dry_time=0, a dry_time texture a float breath_time")
        self._textured = {k for k in textures if textures[k].is_spatially_varying()}
        # a mixture's radius texture is the radius of its largest component: every size scales with it
        self.mixture_scaled = params.get("shape") == "mixture" and "radius" in self._textured
        if self.mixture_scaled:
            self.mixture_items = parse_mixture(params["mixture"])
            self.mixture_largest = max(r for _, r, w in self.mixture_items if w > 0)
        # sizes that do not follow `radius`: a mask's pixels, a point file's positions, a mixture's
        # radii (unless the radius is a texture)
        # (the families that do not read `radius`, or whose positions are absolute: corona.model.registry;
        # a process instance, complete as given: corona.scatterer)
        full = {**DEFAULTS, **params}
        self.fixed_radius = (not isinstance(full["process"], str)
                             or (not SPEC["radius"].applies_to(full) or process_family(full["process"]).absolute)
                             and not self.mixture_scaled)
        if self.fixed_radius and "radius" in self._textured:
            raise CoronaError("corona BSDF: radius cannot be a texture with shape='mask', process='points' "
                              "or a process instance (their sizes and positions are absolute); give a float")
        #: where a lane's F_a and its length L come from, chosen once here: the breath figure's age
        #: (a time texture), the F_a texture with a fixed L, or with L from the radius texture
        #: (the class's function, called with the plugin: a bound method would be a reference cycle)
        cls = type(self)
        self._coverage = (cls._coverage_from_time if self.time_tex is not None
                          else cls._coverage_fixed_radius if self.fixed_radius
                          else cls._coverage_from_radius)
        ranges = self._ranges()
        # the wavelengths a lane evaluates (RGB / mono: the channels' response wavelengths)
        self.wavelengths = Wavelengths()
        self.channel_lambdas = self.wavelengths.lambdas        # (channels, N) nm; None when spectral
        self.channel_weights = self.wavelengths.weights
        # absolute lengths (edge_width, exclusion_diameter, jitter) belong to the largest radius at
        # load; `radius` scales the whole layer with them (σ/R fixed), so the table in u is unchanged
        self.radius_ref = ranges[1][1]
        self._setup(*ranges)

        # --- what lies under the layer (docs/physics.md#the-layer-on-glass-substrateglass): chosen once
        self.substrate = substrate_component(self.material.substrate, self.channel_lambdas, self.channel_weights)

        # --- components and flags ----------------------------------------------
        sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        comps = [mi.BSDFFlags.DeltaTransmission | sides,
                 mi.BSDFFlags.GlossyTransmission | sides,
                 mi.BSDFFlags.DiffuseReflection | sides]   # weight 0 where albedo = 0
        if not self.isotropic:
            comps[1] = comps[1] | mi.BSDFFlags.Anisotropic
        comps += self.substrate.components(sides, not self.isotropic)   # the pane: 3 and 4
        if self._textured:
            comps = [c | mi.BSDFFlags.SpatiallyVarying for c in comps]
        self.set_components(comps, (mi.BSDFFlags.DeltaTransmission, mi.BSDFFlags.GlossyTransmission,
                                    mi.BSDFFlags.DiffuseReflection) + self.substrate.flags())

    # ------------------------------------------------------------------
    # textures -> tables
    # ------------------------------------------------------------------
    def _ranges(self):
        """Checked (lo, hi) of the area fraction, radius and albedo textures."""
        out = []
        for name, tex in (("area_fraction", self.fa_tex), ("radius", self.radius_tex),
                          ("albedo", self.albedo_tex)):
            lo, hi = texture_range(tex)
            given = self.params.get(name)
            if given is not None and not tex.is_spatially_varying() and np.float32(given) == np.float32(hi):
                lo = hi = given                  # the float64 value given, not its float32 copy
            spec = SPEC[name]
            what = "texture" if tex.is_spatially_varying() else "value"
            # a texture may reach F_a = 0 (clear glass) but nothing below
            low_ok = (lo is None) or (lo > 0 if name == "radius" else lo >= 0)
            if not low_ok or not np.isfinite(hi) or hi > spec.high or (name == "area_fraction" and hi >= 1):
                raise CoronaError(f"corona BSDF: {name} {what} spans [{lo if lo is not None else '?'}, {hi:g}]; "
                                  f"allowed {spec.allowed}" + (" (0 allowed in a texture)"
                                                               if name == "area_fraction" else ""))
            out.append((0.0 if lo is None else lo, hi))
        return out

    def _time_span(self, params=None):
        """(lo, hi) [s] the table covers for the textured time (:attr:`time_name`) and why."""
        from corona.model.processes.breath_figure import dry_time_range, time_range
        params = self.params if params is None else params
        theta = float(params.get("contact_angle", SPEC["contact_angle"].default))
        if self.time_name == "breath_time":
            return time_range(theta), f"the breath-figure table's times at contact_angle={theta:g}"
        t = float(params.get("breath_time", SPEC["breath_time"].default))
        rate = float(params.get("evaporation_rate", SPEC["evaporation_rate"].default))
        return (dry_time_range(t, theta, rate),
                f"90 % of the water gone after breath_time={t:g} s at evaporation_rate={rate:g} µm/s")

    def _time_range(self):
        """Checked (lo, hi) of the ``breath_time`` or ``dry_time`` texture [s]: inside the table's times
        (the rows' error over that whole span: benchmarks/results/breath_time_texture.json)."""
        lo, hi = texture_range(self.time_tex)
        (t0, t1), why = self._time_span()
        low_ok = lo is not None and np.isfinite(lo) and (lo >= -1e-7 if t0 == 0 else lo >= t0 * (1 - 1e-6))
        if not low_ok or not np.isfinite(hi) or hi > t1 * (1 + 1e-6):
            raise CoronaError(f"corona BSDF: {self.time_name} texture spans [{'?' if lo is None else format(lo, 'g')}, "
                              f"{hi:g}] s; allowed within [{t0:g}, {t1:g}] s ({why})")
        return max(lo, t0), min(hi, t1)

    def _time_axis(self, t):
        """The lane table's axis: log t for ``breath_time`` (the table's own), t for ``dry_time``."""
        return np.log(t) if self.time_name == "breath_time" else np.asarray(t, dtype=np.float64)

    def _time_rows(self, params, t_lo, t_hi):
        """The breath figure's rows over its coverage for the times ``[t_lo, t_hi]`` [s].

        Rows at the table's times inside the range, its ends and :data:`TIME_SUBDIVIDE` - 1 times
        between each two (uniform in log t), each the material at that time with its radial table
        resampled to the common length ``L = c R(t)`` (``R`` the area-weighted mean radius, ``c`` that
        of the latest row): ``v'(u') = v(u' L_i / L'_i) (L_i / L'_i)²`` keeps the lobe
        ``F_a v(u) (L/λ)²``.  The coverage grows with the breath time and falls with the dry
        time, so the rows (ordered by coverage) are the F_a rows of an F_a texture (Hermite in F_a
        between them); each lane's F_a and ``log R`` are linear in ``log t`` for ``breath_time``,
        in ``t`` for ``dry_time`` (the table's own interpolations) from a table uniform in that axis."""
        from corona.model.processes.breath_figure import load_table
        from corona.model.tabulated import RadialTable
        name = self.time_name
        (t0, t1), _ = self._time_span(params)
        table = load_table()
        if name == "breath_time":
            if t_hi < t_lo * (1 + 2e-3):      # a uniform time: two rows around it
                t_lo, t_hi = max(t_lo * (1 - 1e-3), t0), min(t_hi * (1 + 1e-3), t1)
            nodes = table["times"] * (t0 / table["times"][0])
        else:
            if t_hi - t_lo < 2e-3 * t1:       # a uniform dry time: two rows around it
                t_lo, t_hi = max(t_lo - 1e-3 * t1, t0), min(t_hi + 1e-3 * t1, t1)
            nodes = np.concatenate([[0.0], table["dry_fractions"]]) * (t1 / table["dry_fractions"][-1])
        knots = np.unique(np.concatenate([[t_lo, t_hi], nodes[(nodes > t_lo) & (nodes < t_hi)]]))
        lk = self._time_axis(knots)
        grid_rows = np.unique(np.concatenate(
            [lk[:-1, None] + (lk[1:] - lk[:-1])[:, None] * np.arange(TIME_SUBDIVIDE)[None] / TIME_SUBDIVIDE,
             lk[-1:, None]], axis=None))
        times = np.exp(grid_rows) if name == "breath_time" else grid_rows
        mats = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CoronaWarning)
            for t in times:
                mats.append(material_from_parameters(**{**params, name: float(t)}))
        fas = np.array([m.area_fraction for m in mats])
        if name == "dry_time":                # the coverage falls: rows in order of coverage
            mats, fas, times = mats[::-1], fas[::-1], times[::-1]
        R = np.array([m.process.mean_radius for m in mats])
        if np.any(np.diff(fas) <= 0):
            raise CoronaError(f"corona BSDF: the breath figure's coverage does not change monotonically over "
                              f"the {name} texture's range [{t_lo:g}, {t_hi:g}] s; use a uniform {name}")
        last = mats[-1]
        c = float(last.length_scale) / float(R[-1])
        du, n = float(last.table.du), int(last.table.values.size)
        u = np.arange(n) * du
        tabs = []
        for m, r in zip(mats, R):
            k = float(m.length_scale) / (c * r)                  # L_i / L'_i
            own = np.arange(m.table.values.size) * m.table.du
            tabs.append(RadialTable(du, np.interp(u * k, own, m.table.values, right=0.0) * k * k))
        # lanes: F_a and log R over a grid uniform in the axis (exact at the rows, linear in between)
        grid = np.linspace(*self._time_axis([t_lo, t_hi]), TIME_GRID)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CoronaWarning)
            procs = [material_from_parameters(**{**params, name: float(np.exp(x) if name == "breath_time" else x)}
                                              ).process for x in grid]
        fa_grid = np.array([p.area_fraction(None) for p in procs])
        self.time_cover = (float(t_lo), float(t_hi))
        self.time_log0, self.time_scale = float(grid[0]), (TIME_GRID - 1) / float(grid[-1] - grid[0])
        self.time_fa = _array(mi.Float, np.clip(fa_grid, fas[0], fas[-1]))
        self.time_logR = _array(mi.Float, np.log([p.mean_radius for p in procs]))
        self.L_per_R = c
        self.time_rows = times
        return mats[int(np.argmin(np.abs(times - np.sqrt(t_lo * t_hi))))], fas, tabs

    def _time_lookup(self, t):
        """(F_a, L) of a lane at time ``t`` [s]: gathers from the table uniform in :meth:`_time_axis`."""
        x = (self._time_coordinate(t) - self.time_log0) * self.time_scale
        j = mi.UInt32(dr.clip(dr.floor(x), 0, TIME_GRID - 2))
        w = x - mi.Float(j)
        f0, f1 = _gather(mi.Float, self.time_fa, j), _gather(mi.Float, self.time_fa, j + 1)
        r0, r1 = _gather(mi.Float, self.time_logR, j), _gather(mi.Float, self.time_logR, j + 1)
        return f0 + w * (f1 - f0), dr.exp(r0 + w * (r1 - r0)) * self.L_per_R

    def _setup(self, fa_range, radius_range, albedo_range):
        """Build the material at the largest radius and its area-fraction rows, as Dr.Jit arrays."""
        fa_lo, fa_hi = fa_range
        params = dict(self.params)
        if self.time_tex is not None:
            t_lo, t_hi = self._time_range()
            params[self.time_name] = t_hi if self.time_name == "breath_time" else t_lo   # the densest
        # tables in u = 2π L |d| / λ cover the largest radius (uniform: 25 % headroom, so that
        # an optimiser can grow it without a rebuild); a smaller one scales L down
        cover = radius_range[1] * (1.0 if "radius" in self._textured else 1.25)
        if SPEC["area_fraction"].applies_to({**DEFAULTS, **params}):   # (a point file sets its own)
            params["area_fraction"] = min(max(fa_hi, 1e-6), 1.0 - 1e-6)
        params["albedo"] = albedo_range[1]
        lengths = ("edge_width", "exclusion_diameter", "jitter")

        def at(radius):      # the parameters with the layer scaled to `radius` (σ/R fixed)
            if self.fixed_radius:
                return params
            scaled = {k: params[k] * radius / self.radius_ref for k in lengths if params.get(k) is not None}
            if self.mixture_scaled:      # every component's radius, the largest one at `radius`
                return {**params, **scaled, "mixture": self._mixture_at(radius)}
            return {**params, "radius": radius, **scaled}
        try:
            # checked at the values given (their messages name those), built at the table's cover
            material = material_from_parameters(**at(radius_range[1]))
            if not self.fixed_radius and cover != radius_range[1]:
                try:
                    with warnings.catch_warnings():      # (the check above warned already)
                        warnings.simplefilter("ignore", CoronaWarning)
                        material = material_from_parameters(**at(cover))
                except CoronaError:      # the headroom would pass the largest size: none
                    cover = radius_range[1]
            params = at(cover)
        except CoronaError as err:
            if "area_fraction" in str(err) and fa_hi > 0 and self.fa_tex.is_spatially_varying():
                raise CoronaError(f"corona BSDF: the area_fraction texture reaches {fa_hi:g}: {err}") from None
            raise
        process = material.process
        if not process.varying_area_fraction and (fa_lo != fa_hi or "area_fraction" in self._textured):
            raise CoronaError(f"corona BSDF: area_fraction cannot be a texture with process="
                              f"{self.params.get('process', SPEC['process'].default)!r} (the area fraction "
                              "sets its geometry); use poisson, hard-disk or rsa")
        if self.time_tex is not None:
            material, fas, tabs = self._time_rows(params, t_lo, t_hi)
        self.material = material
        self.isotropic = material.isotropic
        self.radius_cover = (cover if self.mixture_scaled
                             else float(params.get("radius", SPEC["radius"].default)))
        self.L_per_radius = float(material.length_scale) / self.radius_cover   # L = radius · this
        #: the coherent beam's share and the opaque fraction of F_a, chosen once by the layer's mode
        self._shares = _aperture_shares if material.mode == "aperture" else _particle_shares
        if self.time_tex is None:
            fas, tabs, s_rows, totals = self._area_fraction_rows(material, fa_lo, fa_hi)
        else:
            # (their error against the model: benchmarks/breath_time_texture.py, not a row midpoint figure)
            s_rows, totals, self.row_error = None, np.array([t.total for t in tabs]), None
        # a uniform F_a: one row at the value itself, Hermite-interpolated from the rows (and
        # re-centred by parameters_changed), plus its slope in F_a (module docstring)
        self.centred = (process.varying_area_fraction and len(fas) > 1
                        and not self.fa_tex.is_spatially_varying())
        # RGB / mono, one radial row, no fringes of a coherent pane: a table per channel in s = L |d|
        # (_channel_tables) instead of the row at each of the channels' wavelengths
        pane = material.substrate
        self.channel_tables_on = (not mi.is_spectral and material.isotropic and (self.centred or len(fas) == 1)
                                  and not (pane is not None and pane.coherent))
        if self.centred:
            if material.isotropic:
                self._window = (fas, np.stack([t.values for t in tabs]).astype(np.float64), float(tabs[0].du))
            else:
                from corona.mitsuba.kernels import LobeKernel
                self.kernel = LobeKernel(material)
                self._window = (fas, s_rows, np.asarray(totals, dtype=np.float64))
            self.fa_cover = (float(fas[0]), float(fas[-1]))
            self.fa_rows_np = fas
            self.n_rows = 1
            self._centre(float(np.float32(material.area_fraction)))     # (chooses the lobe's representation)
            self.tail = float(material.plane_integral - material.table.total)
            return
        self.fa_rows_np = fas
        self.n_rows = len(fas)
        self.fa_rows = _array(mi.Float, fas)
        self._set_row_grid(fas, totals)
        if self.isotropic:
            self._set_radial_rows(fas, tabs)
        else:
            # the lobe as exact as the model (analytic form factors or cubic form-factor
            # grids × radial S; bilinear for lattices), sampled exactly from its bilinear
            # table: corona.mitsuba.kernels
            from corona.mitsuba.kernels import LobeKernel
            self.kernel = LobeKernel(material)
            if s_rows is not None and self.n_rows > 1:
                self.kernel.set_structure_rows(s_rows, row_slopes(fas, s_rows))
                if self.fa_tex.is_spatially_varying() and fas[0] < material.area_fraction:
                    # sampled from the table at the lowest F_a (its S closest to 1), so that
                    # eval / pdf ~ S(F_a) / S(lowest) stays bounded over the texture
                    self._sample_table_at(params, fas[0])         # (params: the layer at `cover`)
        if not (process.varying_area_fraction and s_rows is None and not material.isotropic):
            self.fa_cover = (float(fas[0]), float(fas[-1]))
        # the form factor's tail beyond the tables (S -> 1 there: the same for every row)
        self.tail = float(material.plane_integral - material.table.total)
        self._choose_lobe()

    def _area_fraction_rows(self, material, fa_lo, fa_hi):
        """The material's rows over the area fractions ``[fa_lo, fa_hi]`` (a uniform value: ± FA_WINDOW):
        ``(fas, tabs, s_rows, totals)``, the rows' F_a, their radial tables, the anisotropic lobe's
        rows of ``S - 1`` (else None) and the rows' energies; sets ``row_error`` (and ``fa_cover``
        where one row serves the whole range)."""
        process = material.process
        include = ()
        if process.varying_area_fraction and not self.fa_tex.is_spatially_varying():
            # a uniform value gets rows ± FA_WINDOW around it (exact at the value itself), so that an
            # optimiser's steps need no rebuild (leaving the rows rebuilds them: parameters_changed)
            include, fa_lo, fa_hi = (fa_hi,), fa_lo - FA_WINDOW, fa_hi + FA_WINDOW
        fa_lo, fa_hi = max(fa_lo, 0.0), max(fa_hi, 0.0)
        s_rows = None
        if process.varying_area_fraction and material.isotropic:
            # rows of the radial table over the texture's range
            fas, tabs, self.row_error = material.area_fraction_rows(fa_lo, fa_hi, include=include)
            totals = np.array([t.total for t in tabs])
        elif process.varying_area_fraction and material.render_lobe.s_minus_one is not None:
            # anisotropic lobes: F_a only moves S, so rows of the radial S - 1 (Hermite in F_a), and
            # the energy of each row (the material's table's, changed by ∫ C ΔS)
            from corona.model.rows import row_energy_changes, structure_rows
            fas, s_rows, s_du, self.row_error = structure_rows(material, fa_lo, fa_hi, include=include)
            totals = material.table.total + row_energy_changes(material, s_rows, s_du)
            tabs = [material.table]
        elif process.varying_area_fraction:
            # S = 1 (poisson): the lobe does not change with F_a, one row over the whole range
            limit = float(process.area_fraction_limit(material.shape))
            fas, tabs, self.row_error = np.array([material.area_fraction]), [material.table], 0.0
            totals = np.array([material.table.total])
            self.fa_cover = (min(fa_lo, limit), min(fa_hi, limit))
        else:
            fas, tabs, self.row_error = np.array([material.area_fraction]), [material.table], 0.0
            totals = np.array([material.table.total])
        return fas, tabs, s_rows, totals

    def _set_row_grid(self, fas, totals):
        """The rows' energies and their slopes in F_a as Dr.Jit arrays, and with two rows or more
        the guide grid that finds F_a's row (and its 16-float packets: vectorised variants)."""
        if self.n_rows > 1:
            # a uniform grid over the rows, its cells (at most 4096) narrower than the closest two
            # rows where possible: a cell's first row and `row_steps` (usually 1) comparisons find
            # F_a's row (a bisection's dependent gathers cost a sixth of the sample + eval)
            span = float(fas[-1] - fas[0])
            cells = int(min(np.ceil(span / np.min(np.diff(fas))) + 1, 4096))
            edges = fas[0] + span * np.arange(cells + 1) / cells
            guide = np.clip(np.searchsorted(fas, edges, side="right") - 1, 0, self.n_rows - 2)
            self.row_guide = _array(mi.UInt32, guide[:-1])
            self.row_cells, self.row_cell_scale = cells, cells / span
            self.row_steps = max(1, int(np.max(guide[1:] - guide[:-1])))   # rows inside one cell
        # the rows' energies and their slopes in F_a (cubic Hermite between rows: the lobe and its
        # derivative in F_a continuous, the derivative second-order accurate in the rows' spacing)
        self.totals = _array(mi.Float, totals)
        self.total_slopes = _array(mi.Float, row_slopes(fas, totals))
        self.row_scalars = None
        if self.n_rows > 1 and dr.is_array_v(mi.Float):
            # what _layer reads of rows j, j + 1, j + 2 (F_a, energy, its slope) in one wide packet
            # gather a lane: 16 floats a row j <= n_rows - 2
            jj = np.arange(self.n_rows - 1)[:, None] + np.arange(3)[None, :]
            jj = np.minimum(jj, self.n_rows - 1)
            block = np.zeros((self.n_rows - 1, 16))
            for c, x in enumerate((fas, np.asarray(totals, dtype=np.float64), row_slopes(fas, totals))):
                block[:, 3 * c:3 * c + 3] = np.asarray(x, dtype=np.float64)[jj]
            self.row_scalars = _array(mi.Float, block.ravel())

    def _set_radial_rows(self, fas, tabs):
        """The radial rows (and their slopes in F_a) in packets, their CDFs, and the channel
        tables where they are on."""
        self.du = float(tabs[0].du)
        self.n = int(tabs[0].values.size)
        rows = np.stack([t.values for t in tabs])
        # ∂v/∂F_a of each row (Hermite in F_a between rows); vectorised variants with rows to
        # interpolate keep row pairs side by side (one wide packet gather a lookup)
        self.row_pairs = self.n_rows > 1 and dr.is_array_v(mi.Float)
        self.packed = (_pack_row_pairs(rows, row_slopes(fas, rows)) if self.row_pairs else
                       _pack_rows(rows, row_slopes(fas, rows) if self.n_rows > 1 else None))
        self._set_cdf([t.cdf for t in tabs])
        if self.channel_tables_on:
            self._set_channel_tables(rows[0], np.zeros_like(rows[0]), self.du)

    def _choose_lobe(self):
        """The lobe's representation (:mod:`corona.mitsuba.lobes`) over the tables just built:
        chosen here, once per build (and re-centring), never in eval / pdf / sample."""
        def table(du, n, packed, totals, cls=SampledTable, *first):
            return cls(*first, du, n, packed, totals, self.cdf, self.guide, self.guide_size, self.n_bins,
                       self.search_steps)
        # where F_a falls among the rows
        if self.centred:
            self.rows = CentredRow(self.totals, self.total_slopes, self.fa_centre)
        elif self.n_rows == 1:
            self.rows = OneRow(self.totals)
        else:
            grid = (self.fa_rows, self.n_rows, self.row_guide, self.row_cells, self.row_cell_scale, self.row_steps,
                    self.fa_cover[0], self.totals, self.total_slopes)
            self.rows = RowGrid(*grid) if self.row_scalars is None else PackedRowGrid(self.row_scalars, *grid)
        # the lobe
        spectrum = self.wavelengths
        if self.channel_tables_on:
            sums = table(self.channel_ds, self.channel_n, self.channel_sample_packed, self.channel_totals)
            if self.centred:
                self.lobe = CentredChannelTables(spectrum, sums, self.channel_packed, self.channel_count,
                                                 self.fa_centre)
            else:
                self.lobe = ChannelTables(spectrum, sums, self.channel_packed, self.channel_count)
        elif not self.isotropic:
            self.lobe = (CentredKernelLobe(spectrum, self.kernel, self.fa_centre) if self.centred
                         else KernelLobe(spectrum, self.kernel))
        elif self.centred:
            self.lobe = CentredRadialRow(spectrum, table(self.du, self.n, self.packed, self.totals), self.fa_centre)
        elif self.n_rows == 1:
            self.lobe = RadialRow(spectrum, table(self.du, self.n, self.packed, self.totals))
        elif self.row_pairs:
            self.lobe = RadialRowPairs(spectrum, table(self.du, self.n, self.packed, self.totals, PairedTable,
                                                       self.n_rows))
        else:
            self.lobe = RadialRows(spectrum, table(self.du, self.n, self.packed, self.totals))

    def _centre(self, fa):
        """Put the uniform layer's one row at area fraction ``fa``: the cubic Hermite of the rows
        around it, its slope in F_a, their energies, and the sampling CDF of that row."""
        from corona.model.tabulated import RadialTable
        if not self.isotropic:    # rows of S - 1 and of the energy
            fas, s_rows, totals = self._window
            self.fa_centre, ((s1, ds1), (tot, dtot)) = centre_rows(fas, fa, s_rows, totals[:, None])
            self.kernel.set_structure_centre(s1, ds1)
            self.totals = _array(mi.Float, tot)
            self.total_slopes = _array(mi.Float, dtot)
            self._choose_lobe()
            return
        fas, rows, du = self._window
        self.fa_centre, ((v, dv),) = centre_rows(fas, fa, rows)
        v = np.maximum(v, 0.0)
        row = RadialTable(du, v)
        # ∫ dv/dF_a d²u of the linear-in-u slope (RadialTable clamps its values at 0: not for a slope)
        u0 = np.arange(dv.size - 1) * du
        lo, step = dv[:-1], dv[1:] - dv[:-1]
        slope_total = float(np.sum(2 * np.pi * du * (u0 * lo + (u0 * step + du * lo) / 2 + du * step / 3)))
        self.du, self.n = du, int(v.size)
        self.row_pairs = False
        self.packed = _pack_rows(v[None], dv[None])
        self.totals = _array(mi.Float, [row.total])
        self.total_slopes = _array(mi.Float, [slope_total])
        if self.channel_tables_on:
            self._set_channel_tables(v, dv, du)
        else:
            self._set_cdf([row.cdf])
        self._choose_lobe()

    def _set_channel_tables(self, v, dv, du):
        """The RGB / mono channel tables of the one radial row ``v`` (slope ``dv`` in F_a):
        :func:`_channel_tables`, one packet per bin and channel, ``(g(i), g(i + 1), ∂g(i), ∂g(i + 1))``;
        sampled (and its pdf) from their sum over channels ``G(s)``: its CDF, its packets and
        ``(∫G d²s, ∫∂G d²s)``."""
        from corona.model.tabulated import RadialTable
        lam, w = channel_response()
        ds, g, dg = _channel_tables(v, dv, du, lam, w)
        nc, n_s = g.shape
        self.channel_ds, self.channel_n, self.channel_count = float(ds), int(n_s), int(nc)
        packets = np.stack([g[:, :-1], g[:, 1:], dg[:, :-1], dg[:, 1:]], axis=-1)     # (nc, n_s - 1, 4)
        self.channel_packed = _array(mi.Float, packets.transpose(1, 0, 2).ravel())     # bin-major
        total_g = g.sum(axis=0)
        row = RadialTable(ds, np.maximum(total_g, 0.0))
        slope_g = dg.sum(axis=0)
        s0 = np.arange(n_s - 1) * ds
        lo, step = slope_g[:-1], slope_g[1:] - slope_g[:-1]
        slope_total = float(np.sum(2 * np.pi * ds * (s0 * lo + (s0 * step + ds * lo) / 2 + ds * step / 3)))
        self.channel_sample_packed = _pack_rows(total_g[None])
        self.channel_totals = _array(mi.Float, [row.total, slope_total])
        self._set_cdf([row.cdf])

    def _mixture_at(self, radius):
        """The ``mixture`` string with every radius scaled so that the largest is ``radius`` [µm]."""
        k = radius / self.mixture_largest
        return ", ".join(f"{kind}:{r * k!r}:{w!r}" for kind, r, w in self.mixture_items)

    def _sample_table_at(self, params, fa):
        """Sample the anisotropic lobe from the material's table at area fraction ``fa`` instead."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CoronaWarning)
            low = material_from_parameters(**{**params, "area_fraction": max(float(fa), 1e-6)})
        table = low.table
        own = self.kernel.sampling_source
        if not (table.n == own.n and abs(float(table.lo) - float(own.lo)) <= 1e-9 * abs(float(own.lo))
                and float(table.warp) == self.kernel.warp):
            return                                   # another grid: keep the material's own
        self.kernel.use_sampling_table(table)

    def _set_cdf(self, cdfs):
        """Normalised float32 CDFs of the rows and their guide tables (:func:`corona.mitsuba.common.guided_cdfs`)."""
        g = guided_cdfs(cdfs)
        self.guide_size = g["G"]
        self.search_steps = g["steps"]
        self.n_bins = g["n_bins"]
        self.cdf = _array(mi.Float, g["cdf"])
        self.guide = _array(mi.UInt32, g["guide"])

    # ------------------------------------------------------------------
    # helpers (traced Dr.Jit code)
    # ------------------------------------------------------------------
    def _layer(self, si, active):
        """Per-lane state at the shading point: F_a, its row j and weight t, the length L [µm],
        and the energies of the coherent beam, the lobe and the reflection."""
        fa, L = self._coverage(self, si, active)
        rows = self.rows.locate(fa, active)      # the row j, its weight t, the energies, the Hermite weights
        energy = rows["energy"]
        held = fa * energy * (1.0 / (4.0 * dr.pi**2))   # F_a ∫v d²u / 4π², tables
        plane = held + fa * (self.tail / (4.0 * dr.pi**2))     # + the evanescent tail beyond them
        coherent, opaque = self._shares(fa)
        budget = dr.maximum(1.0 - coherent, 0.0)
        # lobe weight F_a, lowered where coherent + lobe would exceed 1 (Poisson, see Material.lobe_weight)
        scale = dr.select(plane > budget, budget / dr.maximum(plane, 1e-30), 1.0)
        weight = fa * scale
        lobe = held * scale                  # the energy the tables hold: chooses the component
        albedo = _clip(self.albedo_tex.eval_1(si, active), 0.0, 1.0)
        reflect = dr.minimum(albedo * opaque, dr.maximum(1.0 - coherent - plane * scale, 0.0))
        return dict(fa=fa, **rows, weight=weight, L=L, coherent=coherent, lobe=lobe, reflect=reflect, plane=plane)

    def _coverage_from_time(self, si, active):
        """(F_a, L [µm]) of a lane from the breath figure's age (:attr:`time_tex`)."""
        fa, L = self._time_lookup(_clip(self.time_tex.eval_1(si, active), *self.time_cover))
        return _clip(fa, self.fa_cover[0], self.fa_cover[1]), L

    def _coverage_fixed_radius(self, si, active):
        """(F_a, L [µm]) of a lane: F_a from its texture, L the layer's own (absolute sizes)."""
        fa = _clip(self.fa_tex.eval_1(si, active), self.fa_cover[0], self.fa_cover[1])
        return fa, mi.Float(self.L_per_radius * self.radius_cover)

    def _coverage_from_radius(self, si, active):
        """(F_a, L [µm]) of a lane: F_a from its texture, L from the radius texture."""
        fa = _clip(self.fa_tex.eval_1(si, active), self.fa_cover[0], self.fa_cover[1])
        return fa, self.radius_tex.eval_1(si, active) * self.L_per_radius

    def _lobe_and_pdf(self, layer, wi, wo, wavelengths, active, modulation=None):
        """Lobe value f (Spectrum, no cosine) and the d-space pdf averaged over wavelengths;
        with ``modulation(q, λ)`` also the lobe with each wavelength's value times that factor
        (the representation's: :mod:`corona.mitsuba.lobes`)."""
        return self.lobe.lobe_and_pdf(layer, wo.x + wi.x, wo.y + wi.y, wavelengths, active, modulation)

    # ------------------------------------------------------------------
    # BSDF interface
    # ------------------------------------------------------------------
    def _eval_pdf(self, ctx, si, wo, active, layer=None):
        wi = si.wi
        cos_i = mi.Frame3f.cos_theta(wi)
        cos_o = mi.Frame3f.cos_theta(wo)
        # the delta components' own directions (d = (wo + wi).xy = 0: the coherent beam, the pane's
        # mirror image), where the smooth ones are a set of measure zero: 0 there, so that an
        # integrator re-evaluating `eval` along a sampled delta path (Mitsuba's prb) does not
        # differentiate the lobe or the diffuse value as if they carried that path.  1e-6 is 4x
        # the float32 round trip of -wi through a shading frame.
        off_delta = dr.fma(wo.x + wi.x, wo.x + wi.x, dr.square(wo.y + wi.y)) >= 1e-12
        transmit = active & (cos_i * cos_o < 0) & off_delta
        reflect = active & (cos_i * cos_o > 0) & off_delta
        if layer is None:
            layer = self._layer(si, active)
        probs = self._selection(ctx, layer, cos_i)
        p_lobe, p_refl = probs[1], probs[2]
        lobe_on = ctx.is_enabled(mi.BSDFFlags.GlossyTransmission, 1)
        refl_on = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 2)

        substrate = self.substrate
        lobe_sides = substrate.lobe_sides(transmit, reflect)              # a pane: the lobe in reflection
        modulation = substrate.modulation(layer, wi, wo, cos_i, cos_o, reflect)   # a thick pane's double pass
        f, pdf_d, *f_mod = self._lobe_and_pdf(layer, wi, wo, si.wavelengths, lobe_sides, modulation)
        abs_cos_o = dr.abs(cos_o)
        lobe = f * abs_cos_o                                              # eval = f |cos θo|
        diffuse = layer["reflect"] * dr.inv_pi * abs_cos_o
        # Fresnel factors of a pane (module docstring's table), its lobe in reflection
        lobe, diffuse, lobe_reflected = substrate.smooth(layer, cos_i, cos_o, lobe, diffuse, f_mod, abs_cos_o)
        value = dr.select(transmit & lobe_on, lobe, 0.0)
        pdf_d = self.sampler.pdf_d(pdf_d)
        pdf = dr.select(transmit, p_lobe * pdf_d * abs_cos_o, 0.0)        # p_ω = p_d |cos θo|
        value += dr.select(reflect & refl_on, diffuse, 0.0)
        pdf += dr.select(reflect, p_refl * dr.inv_pi * abs_cos_o, 0.0)
        return substrate.add_reflected(ctx, value, pdf, reflect, lobe_reflected, probs, pdf_d, abs_cos_o)

    def _sample(self, ctx, si, sample1, sample2, active=True):
        wi = si.wi
        cos_i = mi.Frame3f.cos_theta(wi)
        active = mi.Bool(active) & (cos_i != 0)
        layer = self._layer(si, active)
        substrate = self.substrate
        probs = self._selection(ctx, layer, cos_i)
        p_coh, p_lobe = probs[0], probs[1]
        pick_coh = active & (sample1 < p_coh)
        pick_lobe = active & (sample1 >= p_coh) & (sample1 < p_coh + p_lobe)
        pick_refl, picks = substrate.pick(active, sample1, probs)   # (a pane: 3 specular, 4 the lobe reflected)

        bs = self._new_sample()

        # reflection: cosine-weighted on the side of wi
        wo_cos = mi.warp.square_to_cosine_hemisphere(sample2)
        wo_refl = mi.Vector3f(wo_cos.x, wo_cos.y, dr.mulsign(wo_cos.z, cos_i))

        wo_lobe, wo_rlobe, lobe_ok = self.sampler.directions(self, si, layer, sample1, sample2, probs, picks,
                                                             pick_lobe, wo_cos, wo_refl)
        lobe_valid = pick_lobe & lobe_ok

        bs.wo = dr.select(pick_coh, -wi, dr.select(pick_lobe, wo_lobe, wo_refl))
        bs.sampled_component = dr.select(pick_coh, mi.UInt32(0),
                                         dr.select(pick_lobe, mi.UInt32(1), mi.UInt32(2)))
        bs.sampled_type = dr.select(
            pick_coh, mi.UInt32(+mi.BSDFFlags.DeltaTransmission),
            dr.select(pick_lobe, mi.UInt32(+mi.BSDFFlags.GlossyTransmission),
                      mi.UInt32(+mi.BSDFFlags.DiffuseReflection)))

        smooth, pick_delta = substrate.sampled(bs, wi, picks, wo_rlobe, lobe_ok, lobe_valid | pick_refl, pick_coh)

        value, pdf = self._eval_pdf(ctx, si, bs.wo, smooth, layer)
        weight = self._sample_weight(value, pdf)
        w_coh, bs.pdf, weight = substrate.delta_sample(layer, cos_i, si.wavelengths, picks, probs,
                                                       dr.select(pick_coh, p_coh, pdf), weight)
        weight = dr.select(pick_coh, w_coh / dr.maximum(p_coh, 1e-30), weight)
        return self._accepted(bs, weight, pick_delta, smooth)

    def traverse(self, callback):
        # float parameters are uniform textures: keys "area_fraction.value", "radius.value",
        # "albedo.value" (a texture exposes its own keys); all differentiable
        flag = mi.ParamFlags.Differentiable
        if self.material.process.varying_area_fraction:
            callback.put("area_fraction", self.fa_tex, flag)
        if not self.fixed_radius:
            callback.put("radius", self.radius_tex, flag)
        callback.put("albedo", self.albedo_tex, flag)
        if self.time_tex is not None:
            callback.put(self.time_name, self.time_tex, flag)

    # updates (:meth:`corona.mitsuba.core.PluginCore.parameters_changed`)
    def _checked_ranges(self):
        """Checked (lo, hi) of the area fraction, radius and albedo textures (:meth:`_ranges`) and of
        the breath time (None without a ``breath_time`` texture)."""
        return self._ranges(), (self._time_range() if self.time_tex is not None else None)

    def _outside(self, ranges):
        ((fa_lo, fa_hi), radius, albedo), times = ranges
        outside = (fa_lo < self.fa_cover[0] - 1e-7 or fa_hi > self.fa_cover[1] + 1e-7
                   or (not self.fixed_radius and radius[1] > self.radius_cover * (1 + 1e-6)))
        if times is not None:
            t_lo, t_hi = times
            outside = outside or t_lo < self.time_cover[0] * (1 - 1e-6) or t_hi > self.time_cover[1] * (1 + 1e-6)
        return outside

    def _rebuild(self, ranges):
        self._setup(*ranges[0])

    def _recentre(self, ranges):
        if self.centred:
            self._centre(float(np.float32(ranges[0][0][1])))

    def to_string(self):
        # the material at the current (largest) values, not at the table's headroom
        (_, fa), (_, radius), (_, albedo) = self._ranges()
        now = {**self.params, "area_fraction": min(max(fa, 1e-6), 1 - 1e-6), "albedo": albedo}
        if not SPEC["area_fraction"].applies_to({**DEFAULTS, **now}):   # a point file's, an instance's own
            del now["area_fraction"]
        if self.mixture_scaled:
            now["mixture"] = self._mixture_at(radius)
        elif not self.fixed_radius:
            now["radius"] = radius
        if not self.fixed_radius:
            for name in ("edge_width", "exclusion_diameter", "jitter"):
                if now.get(name) is not None:
                    now[name] = now[name] * radius / self.radius_ref
        textured = f", textured: {', '.join(sorted(self._textured))}" if self._textured else ""
        return f"CoronaBSDF[{material_from_parameters(**now)!r}{textured}]"


_REGISTERED: set[str] = set()


def bsdf_class() -> type:
    """The ``CoronaBSDF`` class of the active variant."""
    return variant_class(CoronaBSDFMixin, "BSDF", "CoronaBSDF")


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

    def make(props):
        # a family with a plugin of its own (shape=sphere: the Mie layer's code path, corona.mitsuba.sphere,
        # docs/physics.md#transparent-droplets-mie-spheres); a Shape instance is a flat layer
        value = props["shape"] if "shape" in props else None
        if isinstance(value, str) and value in SPEC["shape"].choices and shape_family(value).bsdf:
            import importlib
            module, function = shape_family(value).bsdf.split(":")
            return getattr(importlib.import_module(module), function)()(props)
        return cls(props)
    mi.register_bsdf("corona", make)
    _REGISTERED.add(variant)
