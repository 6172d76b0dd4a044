"""The ``corona`` plugin's code path for ``shape=sphere``: a layer of Mie droplets (docs/physics.md#transparent-droplets-mie-spheres).

``mi.load_dict({'type': 'corona', 'shape': 'sphere', ...})`` builds this BSDF
(:func:`corona.mitsuba.bsdf.register` dispatches on ``shape``), a family on the plugins' one shell
(:class:`corona.mitsuba.core.PluginCore`) with its components chosen at load: the lobe
(:class:`MieRowsLobe`, or the lattice's), the substrate, the rows' layout (:class:`ChordRows`), the
F_a rows (:class:`corona.mitsuba.lobes.FaTables`) and the sampler.  It evaluates
and samples the tables of :class:`corona.model.mie.material.SphereMaterial`
exactly as that numpy reference does, in Dr.Jit, with the parts every
``corona`` BSDF shares (:mod:`corona.mitsuba.common`: the guide-table CDFs and
their search, the radial Newton inversion, the wavelength mixture and pick,
the spectrum folding, the component selection), and a substrate component chosen at
load (:func:`sphere_substrate`: none, or a glass pane built on
:class:`corona.mitsuba.substrate.PaneSubstrate`, the flat layer's):

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
piecewise-linear radial density (:func:`corona.mitsuba.common.guided_search`,
:func:`corona.mitsuba.common.invert_radial_bin`), row j+1 with probability
``t T_j+1 / ((1-t) T_j + t T_j+1)``, scales it by ``x_row / x`` and draws the
azimuth uniformly, so the pdf is the rows' linear, scaled blend over the
interpolated total (both lobes' densities, since a lobe's sampler reaches a
sliver past 90°); the lane's wavelengths are mixed as for the flat layers
(one-sample balance heuristic).
In JIT variants, where no derivative flows, the lane's wavelengths run as one
symbolic Dr.Jit loop (one traced copy of the lookups, the same sums as
unrolled); with a gradient they are unrolled.

With ``substrate=glass`` the droplets sit on a thin pane, with the flat
layer's weights (:mod:`corona.mitsuba.bsdf`'s table, ``R'``, ``T'`` of the
pane, ``C`` the coherent weight at ``θi``): light meeting the layer first
sends the lobes' far-side part through the pane (``T'(θo)``), leaves their
near-side part as it is, and adds 3, the pane's specular reflection
``C² R'(θi)``, and 4, the lobe in reflection ``C [R'(θi) + R'(θo)] f(wi, wo')``
(``wo'`` the mirror image of ``wo`` in the layer's plane: scattered to the far
side and reflected back, or reflected first and scattered back); light
meeting the glass first has ``T'(θi)`` on the far side, ``T'(θi) T'(θo)`` on
its own side, specular ``R'(θi)``.  Component 4 is sampled as the lobes
(forward or backward in their selection ratio), mirrored.

``area_fraction`` takes a float or a texture and is exposed to
``mi.traverse`` (``area_fraction.value`` or the texture's keys,
differentiable): the lane's F_a enters ``F_s``, the coherent beam and the cap.
With Poisson centres nothing else depends on it.  With a hard core (hard-disk,
rsa) ``S(q)`` and the forward lobe's energies (the cap) are tabulated in rows
of F_a :data:`FA_ROW_STEP` apart over the texture's range (a uniform value:
± :data:`FA_ROW_STEP` about it, re-centred when an update leaves them) and
read as the cubic Hermite interpolation between two rows, slopes from the
rows (:func:`corona.model.rows.row_slopes`), so ``∂/∂F_a`` is continuous;
the sampler draws the Mie ``P`` and does not depend on ``S``.

``radius`` takes a float or a texture, exposed to ``mi.traverse``
(``radius.value`` or the texture's keys, differentiable): each lane reads the
rows at ``x = 2π r(uv)/λ`` (:meth:`SphereBSDFMixin._size_parameter`), the
rows covering the radii :attr:`radius_cover` (a texture's range; a uniform
value ``r``: ``[r/f, r f]``, ``f`` :data:`RADIUS_HEADROOM` or the span a
dispersive index allows, :func:`corona.model.mie.layer.radius_span`), so an
update inside them changes no table and no kernel; one outside rebuilds the
rows about the new radii (a new kernel).  ``S(q r)`` and the forward energies
are tabulated in ``u = q r`` and x, so they follow the lane's radius.  The rows
hold the index of one radius (the texture's geometric middle): exact for a
constant index; a dispersive one (water) is read at ``λ r_ref/r``, and ranges
where that is more than :data:`corona.model.mie.layer.RADIUS_INDEX_PHASE`
off are refused.
"""
from __future__ import annotations

import weakref
from concurrent.futures import ThreadPoolExecutor

import drjit as dr
import mitsuba as mi
import numpy as np

from corona.model import tabulated
from corona._validation import CoronaError
from corona.mitsuba.common import NEWTON_STEPS, fold_spectrum, logical_not as _not, pick_wavelength, picked, texture_range
from corona.mitsuba.common import guided_cdfs, guided_search, invert_radial_bin, positive as _positive
from corona.mitsuba.common import uniform as _uniform, variant_class, wavelength_mixture
from corona.mitsuba.common import array as _array, channel_response as _channel_response, gather as _gather, gather4
from corona.mitsuba.common import clip, host_buffer, read_props as _read_props
from corona.mitsuba.lobes import CentredFaTables, FixedFaTables, UniformFaTables, bilinear_corners
from corona.parameters import DEFAULTS, SPEC, material_from_parameters, warn_unused
from corona.model.mie.layer import ENERGY_MARGIN, INCIDENCE_MU, SPHERE_RADIUS_MAX, radius_span
from corona.model.mie.material import SphereMaterial
from corona.model.mie.layer import share_forward_energies
from corona.mitsuba.core import PluginCore
from corona.mitsuba.substrate import BareLayer, PaneSubstrate, pane_delta_weights, pane_smooth_factors

__all__ = ["NEWTON_STEPS", "ChordRows", "MieRowsLobe", "MieRowsSampling", "UniformSampling", "PackedChordRows", "PlainChordRows", "SphereBSDFMixin", "SpheresAlone", "SpheresOnPane", "sphere_bsdf_class",
           "sphere_substrate"]

#: A uniform radius's rows serve radii this factor below and above it (an optimiser's steps need no
#: rebuild); a radius texture's rows serve its range.
RADIUS_HEADROOM = 1.05
#: Spacing of the F_a rows of ``S(q)`` and the forward energies with a hard core (hard-disk, rsa)
#: (a uniform value: ± one step about it), read by :class:`corona.mitsuba.lobes.FaTables` as the flat
#: layer's rows are.  Why a step of its own: a sphere's F_a row is a whole Mie layer's build (S and
#: the forward energies over x and μ), a flat one a radial table the accuracy rule places
#: (``bsdf.FA_WINDOW``, :meth:`corona.Material.area_fraction_rows`).
FA_ROW_STEP = 0.05
#: The most memory [bytes] the lobes' rows take as packed Catmull–Rom intervals (four floats a node:
#: one Vector4f gather reads a row's interval; beyond it the plain rows are held instead, read by
#: four scalar gathers).  One of the two is allocated.
LOBE_PACKING_BYTES = 1 << 28
#: Chord nodes per block of rows of the lobes' CDFs and guides (:func:`_guided_rows`).
GUIDE_BLOCK = 1 << 18


def _catmull_rom_intervals(*lobes, out=None):
    """The Catmull–Rom intervals of chord rows (each lobe (J, K)), four floats each, as one float32
    numpy array (n, 4), node-major (interval i of row j of lobe l at ``l J K + i J + j``: rows j and j+1 at one
    chord share a cache line mostly).  Interval i of row j is ``(p1, p2 - p1, c1, c2)`` with
    ``v(f) = p1 + f (c1 + f (c2 + f c3))``, ``c1 = (p2 - p0) / 2``, ``c2 = (2 p0 - 5 p1 + 4 p2 - p3) / 2``, ``c3 = p2 - p1 - c1 - c2``
    (``p0 .. p3`` the nodes i-1 .. i+2, an end node repeated past the row's ends); the linear
    value is ``p1 + f (p2 - p1)``.  Interval K-1 (past the last node) starts at the last node.

    Built in float64 from slices of the node-major rows (the padded nodes as views), written
    straight into the float32 result (``out``, float32 of ``4 n`` values, when given: e.g. the view
    of a Dr.Jit array, :func:`corona.mitsuba.common.host_buffer`)."""
    lobes = [np.asarray(rows, dtype=np.float64) for rows in lobes]
    n = sum(rows.size for rows in lobes)
    out = np.empty((n, 4), dtype=np.float32) if out is None else out.reshape(n, 4)
    start = 0
    T = None
    for rows in lobes:
        J, K = rows.shape
        # node-major rows padded by an end node before and two after: node i-1 .. i+2 as slices
        # (one buffer for lobes of one shape: fresh memory is paid for page by page)
        T = np.empty((K + 3, J)) if T is None or T.shape != (K + 3, J) else T
        T[1:K + 1] = rows.T
        T[0], T[K + 1], T[K + 2] = T[1], T[K], T[K]
        o = out[start:start + rows.size].reshape(K, J, 4)
        step = max(1, (1 << 15) // J)                        # node blocks that stay in the caches
        for a in range(0, K, step):
            b = min(a + step, K)
            p0, p1, p2, p3 = T[a:b], T[a + 1:b + 1], T[a + 2:b + 2], T[a + 3:b + 3]
            ob = o[a:b]
            ob[..., 0] = p1
            ob[..., 1] = p2 - p1
            ob[..., 2] = 0.5 * (p2 - p0)
            ob[..., 3] = 0.5 * (2 * p0 - 5 * p1 + 4 * p2 - p3)
        start += rows.size
    return out


def _guided_rows(material, rows) -> dict:
    """:func:`corona.mitsuba.common.guided_cdfs` of the forward then the backward rows of
    ``rows["P_f"]``, ``rows["P_b"]`` (radial densities ``2π s P(s)``), kept in the table cache
    beside the rows (the rows' key plus :func:`corona.model.tabulated.code_key` of the code that makes
    them): a warm load reads them back instead of searching 2J rows."""
    ds = float(rows["ds"])

    def make():
        # block by block of rows (the CDFs and guides of a row depend on that row alone; the
        # bisection steps are those of the widest guide cell, the most over the blocks): the
        # float64 CDFs of a block stay in the caches and neither the rows nor their CDFs are
        # copied whole
        lobes = (rows["P_f"], rows["P_b"])
        n_rows, K = sum(v.shape[0] for v in lobes), lobes[0].shape[1]
        step = max(1, GUIDE_BLOCK // K)
        cdf = guide = None
        steps, r = 1, 0
        for v in lobes:
            for a in range(0, v.shape[0], step):
                part = guided_cdfs(tabulated.radial_cdfs(ds, v[a:a + step]))
                n = min(step, v.shape[0] - a)
                if cdf is None:
                    cdf = np.empty((n_rows, K), np.float32)
                    guide = np.empty((n_rows, part["G"] + 1), np.uint32)   # as the plugin holds it
                    G, n_bins = part["G"], part["n_bins"]
                cdf[r:r + n] = part["cdf"].reshape(n, K)
                guide[r:r + n] = part["guide"].reshape(n, G + 1)
                steps, r = max(steps, part["steps"]), r + n
        return {"cdf": cdf.ravel(), "guide": guide.ravel(), "G": np.array(G), "n_bins": np.array(n_bins),
                "steps": np.array(steps)}
    key = {**material.table_params(), "guided_rows": tabulated.code_key(guided_cdfs, tabulated.radial_cdfs, make)}
    g = tabulated.cached(key, make, use_cache=material.use_cache, background=True)
    return {"cdf": np.asarray(g["cdf"]), "guide": np.asarray(g["guide"]),
            **{k: int(g[k]) for k in ("G", "n_bins", "steps")}}


class SphereBSDFMixin(PluginCore):
    """Mitsuba 3 BSDF of a layer of Mie spheres (see the module docstring): the sphere family on the
    shared shell (:class:`corona.mitsuba.core.PluginCore`), its lobe component :attr:`lobe`."""

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        params, textures = _read_props(props)
        process = params.get("process", SPEC["process"].default)
        lattice = None
        from corona.model.processes.lattice import Lattice
        if isinstance(process, Lattice) or str(process).startswith("lattice"):   # the Mie rows; the lattice apart
            from corona.mitsuba.sphere_lattice import lattice_layer_params
            lattice, params = lattice_layer_params(params, textures)
        albedo_tex = textures.pop("albedo", None)
        if albedo_tex is not None:     # means nothing for a sphere: the one unused-parameter warning
            warn_unused(["albedo"], {**DEFAULTS, **params}, stacklevel=2)
        self._radius_init(textures.pop("radius", None), params)
        fa_tex = textures.pop("area_fraction", None)
        self.fa_range = (0.0, 1.0)
        if fa_tex is not None and fa_tex.is_spatially_varying():
            lo, hi = texture_range(fa_tex)
            if lo is None or not (0.0 < lo and hi < 1.0):
                raise CoronaError(f"corona BSDF: area_fraction texture values {lo!r} … {hi!r} are out of "
                                  "range for shape='sphere'; allowed (0, 1)")
            self.fa_range = (lo, hi)
            params["area_fraction"] = hi
        elif fa_tex is not None:                  # a uniform texture is a value
            params["area_fraction"] = texture_range(fa_tex)[1]
            fa_tex = None
        self.sampling = params.pop("sampling", SPEC["sampling"].default)
        #: how the lobes are sampled, chosen once here (:class:`MieRowsSampling`, :class:`UniformSampling`)
        self.sampler = UniformSampling() if self.sampling == "cosine" else MieRowsSampling()
        self.params = params
        self.fa_textured = fa_tex is not None
        #: a lane's F_a, chosen once here: a texture's clipped to its range, a uniform one as it is
        #: (the class's function, called with the plugin: a bound method would be a reference cycle)
        self._lane_fa = type(self)._textured_fa if self.fa_textured else type(self)._uniform_fa
        self._setup(*(self.fa_range if self.fa_textured else (params.get("area_fraction", SPEC["area_fraction"].default),) * 2))
        if self.radius_tex is None:
            self.radius_tex = _uniform(self.params.get("radius", SPEC["radius"].default))
        self.fa_tex = fa_tex if fa_tex is not None else _uniform(self.fa)
        if not mi.is_spectral:
            self.channel_lambdas, self.channel_weights = _channel_response()
        sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        glossy = mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection | sides
        #: the substrate component, chosen once here: none (:class:`SpheresAlone`) or a glass pane
        #: (:class:`SpheresOnPane`: 3, the pane's mirror image, 4, the lobes in reflection)
        self.substrate = sphere_substrate(self.material.substrate)
        #: the rows' eval of a fresh lane, chosen once here: its wavelengths as one symbolic loop
        #: where the substrate allows it (:meth:`_lane_eval_pdf`), else unrolled (a function, as _lane_fa)
        self._fresh_eval_pdf = (type(self)._lane_eval_pdf if self.substrate.wavelength_loop
                                else type(self)._unrolled_eval_pdf)
        self.set_components([mi.BSDFFlags.DeltaTransmission | sides, glossy, glossy]
                            + self.substrate.components(sides, False),
                            (mi.BSDFFlags.DeltaTransmission, mi.BSDFFlags.GlossyTransmission,
                             mi.BSDFFlags.GlossyReflection) + self.substrate.flags())
        #: the fixed lattice of ``process=lattice-*`` (its Bragg orders), None for a disordered layer
        self.lattice = lattice
        #: the lobe component, chosen once here: the disordered layer's Mie rows (:class:`MieRowsLobe`),
        #: or the lattice's lobe over them (:class:`corona.mitsuba.sphere_lattice.LatticeLayer`);
        #: eval, pdf and sample call its ``eval_pdf`` and ``sample``
        self.lobe = MieRowsLobe(self)
        if lattice is not None:
            from corona.mitsuba.sphere_lattice import LatticeLayer
            self.lobe = LatticeLayer(self.lobe, lattice)

    def _radius_init(self, radius_tex, params):
        """The radius texture (None: a uniform value, made after the tables) and the radii the rows serve."""
        self.radius_textured = radius_tex is not None and radius_tex.is_spatially_varying()
        if self.radius_textured:
            self.radius_tex = radius_tex
            self.radius_cover = self._radius_range()
            lo, hi = self.radius_cover
            params["radius"] = float(np.sqrt(lo * hi))     # the rows' index: that of the middle radius
            return
        if radius_tex is not None:                # a uniform texture is a value
            params["radius"] = SPEC["radius"].check(texture_range(radius_tex)[1])
        self.radius_tex = None
        self.radius_cover = None                  # set with the tables (_material)

    def _radius_range(self):
        """Checked (lo, hi) [µm] of the radius texture: a bitmap's texel values (its filter stays between
        them), else :func:`corona.mitsuba.common.texture_range`."""
        lo, hi = texture_range(self.radius_tex)
        if self.radius_tex.is_spatially_varying():
            try:
                data = np.asarray(dr.detach(mi.traverse(self.radius_tex)["data"]), dtype=np.float64).ravel()
                lo, hi = float(np.min(data)), float(np.max(data))
            except Exception:  # noqa: BLE001 - not a bitmap: the sampled range
                pass
        if lo is None or not (np.isfinite(lo) and np.isfinite(hi) and 0.0 < lo and hi <= SPHERE_RADIUS_MAX):
            raise CoronaError(f"corona BSDF: radius={lo!r} … {hi!r} is out of range for shape='sphere'; "
                              f"allowed (0, {SPHERE_RADIUS_MAX:g}] µm")
        return float(lo), float(hi)

    def _material(self, params):
        """The numpy layer of ``params`` with rows serving :attr:`radius_cover`.  A uniform radius r
        serves ``[r/f, r f]``, ``f`` :data:`RADIUS_HEADROOM` or less where a dispersive index would
        be read too far from its wavelength (:func:`corona.model.mie.layer.radius_span`) or the
        headroom would pass the tables' largest sizes."""
        material = material_from_parameters(**params)
        make = lambda cover: SphereMaterial(material.shape, material.process, substrate=material.substrate,
                                            use_cache=material.use_cache, radius_cover=cover)
        if self.radius_textured:
            try:
                return make(self.radius_cover)
            except CoronaError as err:
                raise CoronaError(f"corona BSDF: the radius texture: {err}") from None
        if self.radius_cover is None:
            r = float(material.sphere.radius)
            f = radius_span(material.sphere, RADIUS_HEADROOM)
            self.radius_cover = (r / f, r * f)
        for cover in (self.radius_cover, (self.radius_cover[0], float(material.sphere.radius))):
            try:
                out = make(cover)
                self.radius_cover = cover
                return out
            except CoronaError:
                continue
        r = float(material.sphere.radius)
        self.radius_cover = (r, r)
        return material

    def _setup(self, fa_lo, fa_hi):
        """The tables of the layer, their F_a rows covering [fa_lo, fa_hi] (a hard core) and their x rows
        the radii of :attr:`radius_cover`."""
        material = self._material(self.params)
        self.material = material
        rows = material.rows
        fa_rows = self._area_fraction_layers(material, fa_lo, fa_hi)     # before any derives its energies
        der = material.row_totals
        self.fa = float(material.area_fraction)
        x = rows["x"]
        self.x0, self.n_rows = float(x[0]), int(x.size)
        # rows are not evenly spaced: a guide of bins half the smallest row step wide names the
        # row at or below each bin's start; at most two steps up find the row below x
        self.bin_dx = 0.5 * float(np.min(np.diff(x)))
        n_bins = int(np.ceil((x[-1] - x[0]) / self.bin_dx)) + 2
        edges = x[0] + np.arange(n_bins) * self.bin_dx
        self.x_bins = n_bins
        guide = np.clip(np.searchsorted(x, edges, side="right") - 1, 0, x.size - 2)
        # the guide packed for one Vector4f gather a bin: (row as a float, x of the next two rows, 0),
        # a next row's x infinite where it is the last row (the row below x is at most the second last)
        x_up = np.concatenate([x, [np.inf, np.inf]])
        x_up[x.size - 1:] = np.inf
        self.row_guide4 = _array(mi.Float, np.stack([guide, x_up[guide + 1], x_up[guide + 2],
                                                     np.zeros(guide.size)], axis=-1).ravel())
        self.ds = float(rows["ds"])
        # the largest chord a lobe's sampler draws: a row's last node scaled by x_j+1 / x_j
        self.reach = min(2.0, (rows["P_f"].shape[1] - 1) * self.ds * float(np.max(x[1:] / x[:-1])) * (1 + 1e-6))
        self.K = int(rows["P_f"].shape[1])
        has_C = bool(rows["C_f"].size)
        # the lobes' rows: packed Catmull–Rom intervals where the memory allows, else the plain rows
        # (one of the two is allocated, the other is None)
        packing = self._lobe_packing(rows)
        # the packed intervals (numpy, about a third of a cold load) are built on a second thread
        # while this one builds (or reads) the guided CDFs below: numpy releases the GIL, so on two
        # cores the two overlap; the same values
        lobes = ([(rows["C_f"],)] if has_C else []) + [(rows["P_f"], rows["P_b"])]
        pool = ThreadPoolExecutor(max_workers=1) if packing else None
        # written in place into the plugin's arrays where the backend allows (host_buffer): no numpy
        # copy of them beside (at 8 µm 174 MB, whose fresh pages cost more than the arithmetic here)
        buffers = [host_buffer(mi.Float, 4 * sum(a.size for a in ls)) for ls in lobes] if packing else None
        splines = ([pool.submit(_catmull_rom_intervals, *ls, out=view) for ls, (_, view) in zip(lobes, buffers)]
                   if packing else None)
        self.Tf, self.Tb = _array(mi.Float, der["T_f"]), _array(mi.Float, der["T_b"])
        self._setup_area_fraction_rows(material, fa_rows, fa_hi)
        # per-row scalars of both rows of an interval j, j+1 packed 16 to the interval (one 64-byte
        # cache line), gathered as four Vector4f: (Re s0, Im s0) of j, j+1; e_b and T_f of j, j+1;
        # T_b and x of j, j+1; 1 / x of j, j+1 and 1 / (x_j+1 - x_j), 0
        ends = lambda v: np.stack([v[:-1], v[1:]], axis=-1)
        packed = np.zeros((max(x.size - 1, 1), 16))
        packed[:, 0:4:2], packed[:, 1:4:2] = ends(rows["s0"][:, 0]), ends(rows["s0"][:, 1])
        packed[:, 4:6], packed[:, 6:8] = ends(der["e_b"]), ends(der["T_f"])
        packed[:, 8:10], packed[:, 10:12] = ends(der["T_b"]), ends(x)
        packed[:, 12:14], packed[:, 14] = ends(1.0 / x), 1.0 / np.diff(x)
        self.row_data = _array(mi.Float, packed.ravel())
        # both lobes in one array: forward rows, then backward rows; as Catmull–Rom intervals, one
        # Vector4f each (where the memory allows), else plain
        self.back_offset = int(rows["P_f"].size)
        # the radial densities 2π s P(s) of both lobes' rows in one guided table: forward rows 0 .. J-1,
        # backward rows J .. 2J-1 (corona.mitsuba.common.guided_cdfs)
        try:
            g = _guided_rows(material, rows)
        finally:
            if pool is not None:
                pool.shutdown(wait=True)
        # the rows' layout, chosen here once (:class:`ChordRows`)
        if packing:
            packed = [buf if buf is not None else _array(mi.Float, job.result().ravel())
                      for job, (buf, _) in zip(splines, buffers)]
            for job in splines:
                job.result()                       # (raises what the thread raised)
            self.chords = PackedChordRows(packed[-1], packed[0] if has_C else None, self.n_rows, self.K, self.ds)
        else:
            self.chords = PlainChordRows(_array(mi.Float, np.concatenate([rows["P_f"].ravel(), rows["P_b"].ravel()])),
                                         _array(mi.Float, rows["C_f"].ravel()) if has_C else None,
                                         self.n_rows, self.K, self.ds)
        self.cdf, self.guide = _array(mi.Float, g["cdf"]), _array(mi.UInt32, g["guide"])
        self.G, self.n_bins, self.steps = g["G"], g["n_bins"], g["steps"]

    @staticmethod
    def _lobe_packing(rows):
        """Whether the lobes' rows are read as packed Catmull–Rom intervals (:func:`_catmull_rom_intervals`):
        while the packed arrays (four times the rows) stay within :data:`LOBE_PACKING_BYTES`."""
        n = rows["P_f"].size + rows["P_b"].size + rows["C_f"].size
        return 16 * n <= LOBE_PACKING_BYTES

    def _area_fraction_layers(self, material, fa_lo, fa_hi):
        """The F_a rows covering [fa_lo, fa_hi] (a hard core) and a layer at each (``material`` at its
        own F_a), sharing its Mie rows and computing their forward energies together
        (:func:`corona.model.mie.layer.share_forward_energies`); None without a hard core (Poisson)."""
        if material.structure_table is None:
            return None
        if not material.process.varying_area_fraction:
            # a point file: its S and F_a are its own (no parameter moves them): the one layer
            # as three equal rows about its F_a (the Hermite reads it whatever the lane's F_a)
            fa = float(material.area_fraction)
            return fa + FA_ROW_STEP * np.array([-1.0, 0.0, 1.0]), [material] * 3
        top = material.process.area_fraction_limit(material.shape)
        lo, hi = float(fa_lo), float(fa_hi)
        if hi - lo < FA_ROW_STEP:                   # a uniform value (or a narrow range): a row at hi, one step either side
            fas = hi + FA_ROW_STEP * np.array([-1.0, 0.0, 1.0])
            fas = fas[(fas >= 1e-3) & (fas <= top * (1 + 1e-12))]
        else:                                       # a texture's range, its ends on rows
            n = int(np.ceil((hi - lo) / FA_ROW_STEP - 1e-9)) + 1
            fas = np.linspace(lo, hi, n)
        layers = []
        import warnings
        with warnings.catch_warnings():             # the unused-parameter warning was given once
            warnings.simplefilter("ignore")
            for fa in fas:
                m = material if abs(fa - material.area_fraction) < 1e-12 else \
                    self._material({**self.params, "area_fraction": float(fa)})
                if m is not material and m.table_params() == material.table_params():
                    m.__dict__.setdefault("rows", material.rows)   # the same Mie rows: not read again
                layers.append(m)
        share_forward_energies(layers)
        return fas, layers

    def _setup_area_fraction_rows(self, material, fa_rows, fa_hi):
        """``S(u)`` and the forward energies ``e_f(x_j, μ)`` in rows of F_a (a hard core; ``fa_rows``
        from :meth:`_area_fraction_layers`, ``fa_hi`` the top of the layer's F_a) with their slopes
        in F_a, or the one F_a-independent energy table (Poisson): the representation
        (:class:`corona.mitsuba.lobes.FaTables`) chosen here, once per build."""
        st = material.structure_table
        n_rows, n_mu = self.n_rows, len(INCIDENCE_MU)
        if st is None:
            self.fa_tables = FixedFaTables(_array(mi.Float, bilinear_corners(material.row_totals["e_f_mu"]).ravel()),
                                           n_rows, n_mu)
            self.fa_cover = (0.0, 1.0)
            return
        fas, layers = fa_rows
        S = np.array([m.structure_table[1] for m in layers])
        E = np.array([m.row_totals["e_f_mu"] for m in layers])
        self.fa_cover = (float(fas[0]), float(fas[-1]))
        self.fa_rows_np = fas
        grid = UniformFaTables(fas, S, E, n_rows, n_mu, float(st[0]), int(S.shape[1]))
        # a texture: the Hermite between the rows; one F_a: the rows centred at that value
        self.fa_tables = grid if self.fa_textured else CentredFaTables(
            grid, fas, S, E, float(fa_hi) if material.process.varying_area_fraction else self.fa)

    # ------------------------------------------------------------------
    # per-wavelength state
    # ------------------------------------------------------------------
    def _wavelengths(self, wavelengths):
        """The lane's wavelengths [nm] and their (equal) mixture weight (:func:`wavelength_mixture`)."""
        lams, weights = wavelength_mixture(wavelengths, getattr(self, "channel_lambdas", None))
        return lams, weights[0]

    def _size_parameter(self, lam_nm, radius):
        """(λ [µm], ``x = 2π r/λ``) of one wavelength [nm] of the lane and its radius [µm] (within the
        rows' radii: :attr:`radius_cover`)."""
        lam = dr.clip(lam_nm, tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX) * 1e-3
        return lam, (2.0 * dr.pi) * radius / lam

    def _lane_radius(self, si, active):
        """The lane's radius [µm]: the texture's (or the uniform value's), clipped to the rows' radii."""
        r, (lo, hi) = self.radius_tex.eval_1(si, active), self.radius_cover
        # r itself on the ends (a texel at the texture's least radius: dr.clip there has lo's derivative, 0)
        return clip(r, lo, hi)

    def _row(self, lam_nm, radius, active=True):
        """Row j of the lane's x (the row at or below it), the weight t of row j+1, λ [µm], x, x_j,
        x_j+1, and two of the interval's packed Vector4f: ``(T_b j, T_b j+1, x_j, x_j+1)`` and
        ``(1/x_j, 1/x_j+1, 1/(x_j+1 - x_j), 0)``."""
        lam, x = self._size_parameter(lam_nm, radius)
        b = mi.UInt32(dr.clip(dr.floor((x - self.x0) * (1.0 / self.bin_dx)), 0, self.x_bins - 1))
        # float32 rounding of the bin: at most two rows up (the guide holds their x)
        g = gather4(self.row_guide4, b, active)
        one, zero = mi.UInt32(1), mi.UInt32(0)
        j = mi.UInt32(g.x) + dr.select(x >= g.y, one, zero) + dr.select(x >= g.z, one, zero)
        c = gather4(self.row_data, 4 * j + 2, active)
        r = gather4(self.row_data, 4 * j + 3, active)
        return j, (x - c.z) * r.z, lam, x, c.z, c.w, (c, r)

    def _state(self, lam_nm, mu_i, active, fa, hw=None, radius=None):
        """Row, energies and lobe weight of one wavelength of the lane (``fa``: the lane's F_a, ``hw`` its
        F_a rows' weights, :meth:`corona.mitsuba.lobes.FaTables.locate`; ``radius`` its radius [µm])."""
        j, t, lam, x, xj, xj1, (c, r) = self._row(lam_nm, radius, active)
        a = gather4(self.row_data, 4 * j, active)           # (Re s0, Im s0) of rows j, j+1
        e = gather4(self.row_data, 4 * j + 1, active)       # (e_b j, e_b j+1, T_f j, T_f j+1)
        fs = dr.minimum(fa / dr.maximum(mu_i, 1e-12), 1.0)
        re = 1.0 - fs * dr.lerp(a.x, a.z, t)
        im = fs * dr.lerp(a.y, a.w, t)
        coherent = dr.minimum(dr.fma(re, re, im * im), 1.0)
        ef, eb = self._forward(j, t, mu_i, active, hw), dr.lerp(e.x, e.y, t)
        scattered = fs * (ef + eb) * ENERGY_MARGIN
        w = dr.minimum(1.0, dr.maximum(1.0 - coherent, 0.0) / dr.maximum(scattered, 1e-30))
        Tf0, Tf1, Tb0, Tb1 = e.z, e.w, c.x, c.y
        return dict(hw=hw, j=j, t=t, lam=lam, x=x, xj=xj, xj1=xj1, rj=x * r.x, rj1=x * r.y,
                    fs=fs, coherent=coherent, w=w,
                    e_f=fs * w * ef, e_b=fs * w * eb,
                    Tf=dr.lerp(Tf0, Tf1, t), Tb=dr.lerp(Tb0, Tb1, t), Tf1=Tf1, Tb1=Tb1, Tf0=Tf0, Tb0=Tb0)

    def _forward(self, st_j, t, mu_i, active, hw=None):
        """The forward lobe's energy e_f at the row (j, t), ``mu_i`` (SphereMaterial._forward) and the
        lane's F_a (``hw``, its weights in the F_a rows: :attr:`fa_tables`): bilinear in (x row, μ)."""
        n = len(INCIDENCE_MU)
        g = (1.0 - dr.clip(mu_i, 0.0, 1.0)) * (n - 1)
        b = dr.minimum(mi.UInt32(dr.maximum(dr.floor(g), 0)), n - 2)
        f = dr.clip(g - mi.Float(b), 0.0, 1.0)
        return self.fa_tables.forward(hw, st_j, b, f, t, active)

    def _lane(self, si, active):
        """What a lane's wavelengths share: (wavelengths [nm], their mixture weight, μ_i, F_a, its rows'
        weights (:attr:`fa_tables`), radius [µm])."""
        lams, m = self._wavelengths(si.wavelengths)
        mu_i = dr.abs(mi.Frame3f.cos_theta(si.wi))
        fa = self._lane_fa(self, si, active)
        return lams, m, mu_i, fa, self.fa_tables.locate(fa), self._lane_radius(si, active)

    def _textured_fa(self, si, active):
        """A lane's F_a from a texture, clipped to its range (fa itself on the ends, as _lane_radius)."""
        lo, hi = self.fa_range
        return clip(self.fa_tex.eval_1(si, active), lo, hi)

    def _uniform_fa(self, si, active):
        """A lane's F_a from a uniform texture (the rows are centred at it)."""
        return self.fa_tex.eval_1(si, active)

    def _states(self, si, active, lane=None):
        lams, m, mu_i, fa, hw, radius = lane if lane is not None else self._lane(si, active)
        states = [self._state(lam, mu_i, active, fa, hw, radius) for lam in lams]
        return states, m

    def _spectrum(self, values):
        """Per-wavelength values as a Spectrum (:func:`fold_spectrum`)."""
        return fold_spectrum(values, getattr(self, "channel_lambdas", None), getattr(self, "channel_weights", None))

    # ------------------------------------------------------------------
    # tables
    # ------------------------------------------------------------------
    def _sample_chord(self, xi, row, forward, active, total=None):
        """Invert the normalised CDF of a row of the forward or backward table (radial density 2π s P):
        :func:`guided_search` for the bin, :func:`invert_radial_bin` inside it (``total``: the row's
        total of the lobe, gathered where not given)."""
        table_row = dr.select(forward, row, row + self.n_rows)
        idx, c0, c1 = guided_search(self.cdf, self.guide, self.G, self.n_bins, self.steps, table_row, xi, active)
        k = row * self.K + idx + dr.select(forward, mi.UInt32(0), mi.UInt32(self.back_offset))
        a, b = self.chords.interval(idx, row, k, active)
        if total is None:
            total = dr.select(forward, _gather(mi.Float, self.Tf, row, active),
                              _gather(mi.Float, self.Tb, row, active))
        s0 = mi.Float(idx) * self.ds
        return s0 + invert_radial_bin(xi - c0, c0, c1, s0, self.ds, a, b, total) * self.ds

    def _lobes(self, states, wi, wo, active, on_f, on_b, mix=None):
        """Per wavelength the lobes' ``Z`` at ``wo`` (the enabled lobe, 0 else) and, with ``mix = (m, p_f,
        p_b)`` (the wavelengths' mixture weight and the lobes' selection probabilities), the sampler's
        density there, ``Σ_λ m (p_f dens_f + p_b dens_b)`` (solid angle; None without ``mix`` or with
        cosine sampling).  One symbolic Dr.Jit loop over the wavelengths (:meth:`_looped_lobes`) where
        the kernel is traced and no derivative flows, else unrolled; the same sums either way."""
        geo = self._lobe_geometry(wi, wo, active, on_f, on_b)
        with_pdf = mix is not None and self.sampler.densities
        if self._loopable(len(states), wi, wo, *(mix if with_pdf else ()),
                          *(st[k] for st in states for k in self._LOBE_KEYS + ("fs",))):
            return self._looped_lobes(states, geo, mix if with_pdf else None)
        values, pdf = [], (mi.Float(0.0) if with_pdf else None)
        Q = self._other_lobe(states, geo) if with_pdf else None
        for k, st in enumerate(states):
            z, d_f, d_b = self._lobe_at(st, geo, Q[k] if with_pdf else None)
            values.append(z)
            if with_pdf:
                m, p_f, p_b = mix
                pdf += m * (p_f * d_f + p_b * d_b)
        return values, pdf

    def _lobe_geometry(self, wi, wo, active, on_f, on_b):
        """What the lobes' lookups at ``wo`` share over the lane's wavelengths: the chords, the lobe
        ``wo`` is in (``forward``), the other lobe's chord and the sliver past 90° its sampler reaches
        (``near``)."""
        s_f = dr.norm(wo + wi)
        s_b = dr.norm(wo - wi)
        forward = s_f <= s_b
        s_other = dr.select(forward, s_b, s_f)
        return dict(active=active, s_f=s_f, forward=forward, a_f=active & forward,
                    dxy=dr.sqrt(dr.square(wo.x + wi.x) + dr.square(wo.y + wi.y)),
                    s_any=dr.select(forward, s_f, s_b),
                    offset=dr.select(forward, mi.UInt32(0), mi.UInt32(self.back_offset)),
                    on=active & dr.select(forward, on_f, on_b), s_other=s_other,
                    offset_other=dr.select(forward, mi.UInt32(self.back_offset), mi.UInt32(0)),
                    near=active & (s_other < self.reach))

    def _lobe_at(self, st, geo, Q_lin=None):
        """One wavelength's ``Z`` at the lane's ``wo`` (:meth:`_lobe_geometry`) and, given the other
        lobe's linear rows ``Q_lin`` there, the sampler's density of each lobe (dens_f, dens_b)."""
        forward, active, a_f = geo["forward"], geo["active"], geo["a_f"]
        chords = self.chords
        P, P_lin = chords.rows_at(chords.P, st, geo["s_any"], active, geo["offset"])   # P_f or P_b
        # with S (a hard core) the decoupling rule, u = q r = x |wo + wi|_xy
        Z = self.fa_tables.decoupled(st["hw"], st["x"] * geo["dxy"], P,
                                     lambda: chords.forward_C(st, geo["s_f"], a_f, P), forward, a_f)
        Z = dr.select(geo["on"], Z, 0.0)
        if Q_lin is None:
            return Z, None, None
        return (Z, dr.select(forward, P_lin, Q_lin) / dr.maximum(st["Tf"], 1e-30),
                dr.select(forward, Q_lin, P_lin) / dr.maximum(st["Tb"], 1e-30))

    #: The per-wavelength state :meth:`_lobe_at` reads (with ``hw``, the lane's).
    _LOBE_KEYS = ("j", "t", "rj", "rj1", "x", "Tf", "Tb")

    @staticmethod
    def _loopable(n, *inputs):
        """Whether ``n`` wavelengths run as a symbolic loop: a JIT variant, more than one wavelength and
        no derivative through ``inputs`` (Dr.Jit's reverse mode of a symbolic loop needs a bound on its
        iterations: the wavelengths are unrolled then)."""
        return dr.is_jit_v(mi.Float) and n > 1 and not dr.grad_enabled(*inputs)

    def _looped_lobes(self, states, geo, mix):
        """:meth:`_lobes` as one symbolic Dr.Jit loop over the lane's wavelengths: one traced copy of the
        row lookups (and of the other lobe's conditional) instead of one a wavelength, so the kernel
        compiles in a fraction of the time; each wavelength's values and the density's sum in the same
        order and operations as unrolled."""
        n = len(states)
        hw = states[0]["hw"]
        zero = dr.zeros(mi.Float, dr.width(geo["s_any"]))

        def body(q, values, pdf):
            st = {k: picked(q, [s[k] for s in states]) for k in self._LOBE_KEYS}
            st["hw"] = hw
            Q_lin = self._other_lobe([st], geo)[0] if mix is not None else None
            z, d_f, d_b = self._lobe_at(st, geo, Q_lin)
            values = [dr.select(q == k, z, v) for k, v in enumerate(values)]
            if mix is not None:
                m, p_f, p_b = mix
                pdf = pdf + m * (p_f * d_f + p_b * d_b)
            return q + 1, values, pdf

        state = (dr.zeros(mi.UInt32, dr.width(zero)), [mi.Float(zero) for _ in range(n)], mi.Float(zero))
        _, values, pdf = dr.while_loop(state, lambda q, *_: q < n, body, label="corona sphere wavelengths")
        return values, (pdf if mix is not None else None)

    def _other_lobe(self, states, geo):
        """Per wavelength the other lobe's linear rows at its chord (the sampler's density of the lobe
        that ``wo`` is not in), nonzero only in the sliver past 90° its sampler reaches (``near``).  One
        conditional for the wavelengths given: a packet of lanes none of which is ``near`` (nearly all)
        skips the reads."""
        keys = ("j", "t", "rj", "rj1")
        flat = tuple(st[k] for st in states for k in keys)
        n = len(states)
        s_other, near, offset_other = geo["s_other"], geo["near"], geo["offset_other"]

        def reads(s_o, near_, off, *flat):
            out = []
            for i in range(n):
                st = dict(zip(keys, flat[4 * i:4 * i + 4]))
                out.append(self.chords.rows_at(self.chords.P, st, s_o, near_, off)[1])
            return tuple(out)

        def zeros(s_o, near_, off, *flat):
            return tuple(dr.zeros(mi.Float, dr.width(s_o)) for _ in range(n))
        if not dr.is_array_v(mi.Float):        # scalar variants: a Python branch
            return reads(s_other, near, offset_other, *flat) if near else (mi.Float(0.0),) * n
        return dr.if_stmt((s_other, near, offset_other) + flat, near, reads, zeros, label="corona other lobe")

    # ------------------------------------------------------------------
    # BSDF interface
    # ------------------------------------------------------------------
    def _eval_pdf(self, ctx, si, wo, active=True):
        """``(f |cos θo|, pdf)``: the lobe component's (:attr:`lobe`)."""
        return self.lobe.eval_pdf(ctx, si, wo, mi.Bool(active))

    def _sample(self, ctx, si, sample1, sample2, active=True):
        """``(BSDFSample3f, weight)``: the lobe component's (:attr:`lobe`)."""
        return self.lobe.sample(ctx, si, sample1, sample2, active)

    def _rows_eval_pdf(self, ctx, si, wo, active, cached=None):
        """``(f |cos θo|, pdf)`` of the disordered layer (``cached``: :meth:`_rows_sample`'s states)."""
        if cached is None:
            return self._fresh_eval_pdf(self, ctx, si, wo, active)
        return self._states_eval_pdf(ctx, si, wo, active, cached)

    def _lane_eval_pdf(self, ctx, si, wo, active):
        """:meth:`_rows_eval_pdf` of a fresh lane whose wavelengths may run as one symbolic loop."""
        lane = self._lane(si, active)
        # literal wavelengths (RGB's channels, fixed ones) fold into each unrolled copy with
        # roundings a traced loop variable does not get: unrolled there, the values bit for bit
        folded = any(getattr(lam, "state", None) == dr.VarState.Literal for lam in lane[0])
        if not folded and self._loopable(len(lane[0]), si.wi, wo, lane[3], lane[5]):
            return self._looped_eval_pdf(ctx, si, wo, active, lane)
        return self._states_eval_pdf(ctx, si, wo, active, self._states(si, active, lane))

    def _unrolled_eval_pdf(self, ctx, si, wo, active):
        """:meth:`_rows_eval_pdf` of a fresh lane, its wavelengths unrolled."""
        return self._states_eval_pdf(ctx, si, wo, active, self._states(si, active))

    def _states_eval_pdf(self, ctx, si, wo, active, cached):
        """:meth:`_rows_eval_pdf` from the lane's states ``cached`` (:meth:`_states`)."""
        wi = si.wi
        cos_i = mi.Frame3f.cos_theta(wi)
        cos_o = mi.Frame3f.cos_theta(wo)
        states, m = cached
        p_coh, p_f, p_b, *p_sub = self._selection(ctx, states, cos_i)
        on_f = ctx.is_enabled(mi.BSDFFlags.GlossyTransmission, 1)
        on_b = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 2)
        Z, pdf = self._lobes(states, wi, wo, active, on_f, on_b, (m, p_f, p_b))
        values, pdf = self.substrate.lobe_values(self, ctx, states, wi, wo, cos_i, cos_o, active, Z, pdf,
                                                 (m, p_f, p_b), p_sub)
        pdf = self.sampler.smooth_pdf(active, pdf, p_f + p_b + self.substrate.smooth_share(p_sub))
        return self._spectrum(values), dr.select(active, pdf, 0.0)

    def _looped_eval_pdf(self, ctx, si, wo, active, lane):
        """:meth:`_rows_eval_pdf` without a pane (its lane's share ``lane``, :meth:`_lane`) as one symbolic
        Dr.Jit loop over the wavelengths: each wavelength's state (:meth:`_state`) and its lobes
        (:meth:`_lobe_at`) in one traced copy; the loop hands out per wavelength the value, the two
        lobe densities and the energies, summed after it (the selection, the mixture) in the same
        order and operations as unrolled."""
        lams, m, mu_i, fa, hw, radius = lane
        wi = si.wi
        cos_i = mi.Frame3f.cos_theta(wi)
        on_f = ctx.is_enabled(mi.BSDFFlags.GlossyTransmission, 1)
        on_b = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 2)
        geo = self._lobe_geometry(wi, wo, active, on_f, on_b)
        with_pdf = self.sampler.densities
        n = len(lams)
        keys = ("value", "coherent", "e_f", "e_b") + (("dens_f", "dens_b") if with_pdf else ())

        def body(q, *outs):
            st = self._state(picked(q, list(lams)), mu_i, active, fa, hw, radius)
            z, d_f, d_b = self._lobe_at(st, geo, self._other_lobe([st], geo)[0] if with_pdf else None)
            new = dict(value=z * (st["fs"] * st["w"]), dens_f=d_f, dens_b=d_b,
                       coherent=st["coherent"], e_f=st["e_f"], e_b=st["e_b"])
            return (q + 1, *([dr.select(q == k, new[key], v) for k, v in enumerate(out)] for key, out in zip(keys, outs)))

        zero = dr.zeros(mi.Float, dr.width(geo["s_any"]))
        outs = [[mi.Float(zero) for _ in range(n)] for _ in keys]
        _, *outs = dr.while_loop((dr.zeros(mi.UInt32, dr.width(zero)), *outs), lambda q, *_: q < n, body,
                                 label="corona sphere wavelengths")
        per = [dict(zip(keys, vals)) for vals in zip(*outs)]   # per wavelength, as the states
        p_coh, p_f, p_b = self._selection(ctx, per, cos_i)
        pdf = mi.Float(0.0)
        if with_pdf:
            for d in per:
                pdf += m * (p_f * d["dens_f"] + p_b * d["dens_b"])
        pdf = self.sampler.smooth_pdf(active, pdf, p_f + p_b)
        return self._spectrum([d["value"] for d in per]), dr.select(active, pdf, 0.0)

    def _rows_sample(self, ctx, si, sample1, sample2, active=True):
        """The disordered layer's sample (:meth:`MieRowsLobe.sample`)."""
        wi = si.wi
        cos_i = mi.Frame3f.cos_theta(wi)
        active = mi.Bool(active) & (cos_i != 0)
        states, m = self._states(si, active)
        probs = self._selection(ctx, states, cos_i)
        p_coh, p_f, p_b = probs[:3]
        pick_coh = active & (sample1 < p_coh)
        pick_f = active & _not(pick_coh) & (sample1 < p_coh + p_f) & (p_f > 0)
        pick_b = active & _not(pick_coh) & _not(pick_f) & (sample1 < p_coh + p_f + p_b) & (p_b > 0)
        # what is left of sample1 inside the picked lobe's share
        s = dr.select(pick_f, (sample1 - p_coh) / dr.maximum(p_f, 1e-30),
                      (sample1 - p_coh - p_f) / dr.maximum(p_b, 1e-30))
        # the backward lobe takes what is left; the substrate's own picks after the lobes
        pick_b, lobe_f, lobe_any, s, picks = self.substrate.lobe_picks(active, sample1, probs, pick_coh, pick_f,
                                                                      pick_b, s)
        bs = self._new_sample()
        wo_lobe = self.sampler.direction(self, states, s, lobe_f, lobe_any, wi, sample2)
        bs.wo = dr.select(pick_coh, -wi, wo_lobe)
        bs.sampled_component = dr.select(pick_coh, mi.UInt32(0), dr.select(pick_f, mi.UInt32(1), mi.UInt32(2)))
        same_side = cos_i * mi.Frame3f.cos_theta(bs.wo) > 0
        bs.sampled_type = dr.select(pick_coh, mi.UInt32(+mi.BSDFFlags.DeltaTransmission),
                                    dr.select(same_side, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                              mi.UInt32(+mi.BSDFFlags.GlossyTransmission)))
        # the substrate's sampled components (the lobes mirrored: wo_lobe's mirror image)
        smooth, pick_delta = self.substrate.sampled(bs, wi, picks, mi.Vector3f(wo_lobe.x, wo_lobe.y, -wo_lobe.z),
                                                    True, pick_f | pick_b, pick_coh)
        value, pdf = self._rows_eval_pdf(ctx, si, bs.wo, smooth, (states, m))
        bs.pdf = dr.select(pick_coh, p_coh, pdf)
        weight = self._sample_weight(value, pdf)
        deltas = [self.substrate.delta_weights(st, cos_i) for st in states]
        coh = self._spectrum([d[0] for d in deltas])
        weight = dr.select(pick_coh, coh / dr.maximum(p_coh, 1e-30), weight)
        bs.pdf, weight = self.substrate.specular_sample(picks, probs, [d[1] for d in deltas], self._spectrum,
                                                        bs.pdf, weight)
        return self._accepted(bs, weight, pick_delta, smooth)

    def traverse(self, callback):
        # area_fraction and radius (a uniform texture's "….value", or the texture's own keys), differentiable
        callback.put("area_fraction", self.fa_tex, mi.ParamFlags.Differentiable)
        callback.put("radius", self.radius_tex, mi.ParamFlags.Differentiable)

    # updates (:meth:`corona.mitsuba.core.PluginCore.parameters_changed`)
    def _checked_ranges(self):
        """Checked ``((lo, hi) of F_a, (lo, hi) of the radius)``; None on a lattice (whose values are
        fixed: one error where they changed)."""
        lo, hi = texture_range(self.fa_tex)
        if self.lattice is not None:
            if abs(hi - self.fa) > 1e-7 or abs(texture_range(self.radius_tex)[1]
                                              - float(self.params.get("radius", SPEC["radius"].default))) > 1e-7:
                raise CoronaError("corona BSDF: area_fraction and radius of spheres on a lattice are out of range "
                                  "for updates; allowed the values the layer was loaded with (the lattice's "
                                  "spacing follows them)")
            return None
        if lo is None or not (0.0 < lo and hi < 1.0) or not (np.isfinite(lo) and np.isfinite(hi)):
            raise CoronaError(f"corona BSDF: area_fraction={lo!r} … {hi!r} is out of range for "
                              "shape='sphere'; allowed (0, 1)")
        if self.fa_textured:
            self.fa_range = (lo, hi)
        return (lo, hi), self._radius_range()

    def _radius_out(self, radii):
        """Whether the radii leave those the rows serve (:attr:`radius_cover`)."""
        return radii[0] < self.radius_cover[0] * (1 - 1e-6) or radii[1] > self.radius_cover[1] * (1 + 1e-6)

    def _outside(self, ranges):
        if ranges is None:
            return False
        (lo, hi), radii = ranges
        return self._radius_out(radii) or lo < self.fa_cover[0] - 1e-7 or hi > self.fa_cover[1] + 1e-7

    def _rebuild(self, ranges):
        (lo, hi), (r_lo, r_hi) = ranges
        if self._radius_out((r_lo, r_hi)):          # new rows in x about the new radii (a new kernel)
            if self.radius_textured:
                self.radius_cover = (r_lo, r_hi)
                self.params["radius"] = float(np.sqrt(r_lo * r_hi))
            else:
                self.params["radius"] = r_hi
                self.radius_cover = None
        self.params["area_fraction"] = hi
        self._setup(*(self.fa_range if self.fa_textured else (hi, hi)))

    def _recentre(self, ranges):
        if ranges is not None:
            self.fa_tables.recentre(ranges[0][1])

    def to_string(self):
        return f"CoronaSphereBSDF[{self.material!r}]"


class MieRowsLobe:
    """The lobe component of a sphere plugin (:class:`SphereBSDFMixin`) read from its Mie rows: the
    disordered layer's coherent beam, lobes and pane (:meth:`eval_pdf`, :meth:`sample`), and the
    lookups a lobe built on the same rows reads (:meth:`states`, :meth:`pattern`,
    :meth:`spectrum`: the lattice's, :mod:`corona.mitsuba.sphere_lattice`).  It holds no table of
    its own: the plugin's, rebuilt by its ``parameters_changed``, are read at each call.  It holds
    the plugin weakly (the plugin holds it: no reference cycle keeps a dropped plugin's tables), so
    it serves while its plugin lives (a lattice piece built on it, too): after, one error says so.

    Parameters
    ----------
    bsdf : the sphere plugin
    """

    def __init__(self, bsdf):
        self._ref = weakref.ref(bsdf)

    @property
    def _bsdf(self):
        b = self._ref()
        if b is None:
            raise CoronaError("corona: the sphere plugin of this MieRowsLobe was dropped; keep the plugin "
                              "(mi.load_dict's result) alive while its lobe is used")
        return b

    @property
    def material(self):
        """The numpy layer the rows are of (:class:`corona.model.mie.material.SphereMaterial`)."""
        return self._bsdf.material

    def eval_pdf(self, ctx, si, wo, active=True):
        """``(f |cos θo|, pdf)`` at ``wo`` (Mitsuba's ``eval_pdf``)."""
        return self._bsdf._rows_eval_pdf(ctx, si, wo, mi.Bool(active))

    def sample(self, ctx, si, sample1, sample2, active=True):
        """``(BSDFSample3f, weight)`` (Mitsuba's ``sample``)."""
        return self._bsdf._rows_sample(ctx, si, sample1, sample2, active)

    def states(self, si, active=True):
        """``(states, m)``: per wavelength of the lane its row, energies, coherent weight and cap (a
        dict), and the wavelengths' mixture weight."""
        return self._bsdf._states(si, active)

    def pattern(self, st, wi, wo, active=True):
        """``(P, forward)``: the Mie pattern at ``wo`` for one state ``st`` (wavelength) of
        :meth:`states`, the forward rows for ``Θ < 90°`` from ``-wi`` (``forward``), the backward
        rows beyond; ``P`` alone, whatever the layer's process."""
        b = self._bsdf
        s_f, s_b = dr.norm(wo + wi), dr.norm(wo - wi)
        forward = s_f <= s_b
        offset = dr.select(forward, mi.UInt32(0), mi.UInt32(b.back_offset))
        return b.chords.rows_at(b.chords.P, st, dr.select(forward, s_f, s_b), active, offset)[0], forward

    def spectrum(self, values):
        """Per-wavelength values of :meth:`states`' order as a Spectrum."""
        return self._bsdf._spectrum(values)


class MieRowsSampling:
    """``sampling='lobe'`` (the default) of a sphere plugin: a lobe's direction drawn from its Mie rows
    (:meth:`SphereBSDFMixin._sample_chord`), the pdf the lobes' samplers' mixture (their densities)."""

    #: the lobes' densities are summed for the pdf
    densities = True

    def smooth_pdf(self, active, pdf, p_smooth):
        """The smooth components' pdf: the densities summed (``pdf``)."""
        return pdf

    def direction(self, bsdf, states, s, lobe_f, lobe_any, wi, sample2):
        """The lobe's direction (``lobe_f``: the forward one) for the lane's ``states``, ``s`` what is left
        of ``sample1`` inside the lobe's share."""
        # the lobe's share of sample1 picks the hero wavelength, what is left of it the row
        pick, x, rest = pick_wavelength(s, [st["x"] for st in states])
        # the picked wavelength's row interval, its lobe's totals at both rows, their x
        j, t, xj, xj1, Tf0, Tf1, Tb0, Tb1 = (picked(pick, [st[k] for st in states])
                                             for k in ("j", "t", "xj", "xj1", "Tf0", "Tf1", "Tb0", "Tb1"))
        T0, T1 = dr.select(lobe_f, Tf0, Tb0), dr.select(lobe_f, Tf1, Tb1)
        p_next = t * T1 / dr.maximum(dr.lerp(T0, T1, t), 1e-30)
        up = rest < p_next
        row = dr.select(up, j + 1, j)
        chord = bsdf._sample_chord(sample2.x, row, lobe_f, lobe_any, dr.select(up, T1, T0))
        # the row's chord scaled to the lane's x: rings at a fixed x·s
        chord = dr.minimum(chord * dr.select(up, xj1, xj) / x, 2.0)
        cos_t = 1.0 - 0.5 * chord * chord
        sin_t = chord * dr.safe_sqrt(1.0 - 0.25 * chord * chord)
        sp, cp = dr.sincos(2.0 * dr.pi * sample2.y)
        axis = dr.select(lobe_f, -wi, wi)
        wo_lobe = mi.Frame3f(axis).to_world(mi.Vector3f(sin_t * cp, sin_t * sp, cos_t))
        wo_lobe = dr.normalize(wo_lobe)
        return wo_lobe


class UniformSampling:
    """``sampling='cosine'`` of a sphere plugin (comparisons only): the lobes drawn uniformly over the sphere."""

    densities = False

    def smooth_pdf(self, active, pdf, p_smooth):
        """The smooth components' pdf: their share ``p_smooth`` over the sphere."""
        return dr.select(active, p_smooth * (0.25 * dr.inv_pi), 0.0)

    def direction(self, bsdf, states, s, lobe_f, lobe_any, wi, sample2):
        return mi.warp.square_to_uniform_sphere(sample2)


class ChordRows:
    """The Mie rows in the chord ``s``: both lobes' ``P`` (``P``: the forward rows, then the backward
    ones from ``offset``) and the forward ``C`` (``Cf``; None for one size, where ``C = P``), ``n_rows``
    rows of x, ``K`` nodes ``ds`` apart, in one layout chosen at load: :class:`PackedChordRows` (one
    Vector4f an interval) or :class:`PlainChordRows` (the nodes)."""

    def __init__(self, P, Cf, n_rows, K, ds):
        self.P, self.Cf, self.n_rows, self.K, self.ds = P, Cf, n_rows, K, ds

    def rows_at(self, table, st, s, active, offset=0):
        """Rows j, j+1 (weight t) of ``table`` (:attr:`P` or :attr:`Cf`), each read at its chord scaled by
        ``x / x_row`` (corona.model.mie.layer's scaled blend): (Catmull–Rom value, linear value: the
        sampler's density up to its total)."""
        cub, lin = mi.Float(0.0), mi.Float(0.0)
        K = self.K
        for d, wgt, r in ((0, 1.0 - st["t"], st["rj"]), (1, st["t"], st["rj1"])):
            row = st["j"] + d              # read at the chord s x / x_row (r = x / x_row)
            g = s * (r * (1.0 / self.ds))
            i = dr.minimum(mi.UInt32(dr.maximum(dr.floor(g), 0)), K - 2)
            f = dr.minimum(g - mi.Float(i), 1.0)   # >= 0; no clip at 0: its derivative there (a node) is 0
            inside = active & (g <= K - 1)
            scale = wgt * (r * r)
            v, v_lin = self.node(table, row, i, offset, f, inside)
            cub += dr.select(inside, dr.maximum(v, 0.0) * scale, 0.0)
            lin += dr.select(inside, dr.maximum(v_lin, 0.0) * scale, 0.0)
        return cub, lin

    def forward_C(self, st, s, active, P):
        """The forward ``C`` at chord ``s`` (:meth:`rows_at`); ``P`` itself for one size (``C = P``)."""
        return P if self.Cf is None else self.rows_at(self.Cf, st, s, active)[0]


class PackedChordRows(ChordRows):
    """:class:`ChordRows` as Catmull–Rom intervals, node-major (:func:`_catmull_rom_intervals`)."""

    def node(self, table, row, i, offset, f, inside):
        """(Catmull–Rom, linear) value of row ``row`` in interval ``i`` at ``f``."""
        q = gather4(table, i * self.n_rows + row + offset, inside)     # (p1, p2 - p1, c1, c2)
        return dr.fma(f, dr.fma(f, dr.fma(f, q.y - q.z - q.w, q.w), q.z), q.x), dr.fma(f, q.y, q.x)

    def interval(self, idx, row, k, active):
        """``(P(i), P(i + 1) - P(i))`` of the :attr:`P` interval ``idx`` of row ``row`` (node ``k``, row-major)."""
        q = gather4(self.P, idx * self.n_rows + row + (k - row * self.K - idx), active)
        return q.x, q.y


class PlainChordRows(ChordRows):
    """:class:`ChordRows` as the nodes, row-major (four scalar gathers a Catmull–Rom value)."""

    def node(self, table, row, i, offset, f, inside):
        K = self.K
        k = row * K + i + offset
        p1 = _gather(mi.Float, table, k, inside)
        p2 = _gather(mi.Float, table, k + 1, inside)
        p0 = dr.select(i > 0, _gather(mi.Float, table, k - 1, inside & (i > 0)), p1)
        p3 = dr.select(i + 2 < K, _gather(mi.Float, table, k + 2, inside & (i + 2 < K)), p2)
        v = p1 + 0.5 * f * (p2 - p0 + f * (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3
                                           + f * (3.0 * (p1 - p2) + p3 - p0)))
        return v, dr.lerp(p1, p2, f)

    def interval(self, idx, row, k, active):
        a = _gather(mi.Float, self.P, k, active)
        return a, _gather(mi.Float, self.P, k + 1, active) - a


def sphere_substrate(pane):
    """The substrate component of a sphere layer whose numpy substrate is ``pane``
    (``SphereMaterial.substrate``: None or an incoherent :class:`corona.model.substrate.GlassPane`)."""
    return SpheresAlone() if pane is None else SpheresOnPane(pane)


class SpheresAlone(BareLayer):
    """No substrate under the spheres: components 0, 1, 2 (the flat layer's :class:`BareLayer`,
    with the sphere plugin's per-wavelength parts: :meth:`energies`, :meth:`lobe_values`,
    :meth:`lobe_picks`, :meth:`specular_sample`)."""

    #: the lane's wavelengths may run as one symbolic loop (:meth:`SphereBSDFMixin._looped_eval_pdf`)
    wavelength_loop = True

    def energies(self, states, cos_i):
        """Energies of (coherent, forward, backward) summed over the lane's wavelengths (``states``)."""
        en = [mi.Float(0.0) for _ in range(3)]
        for st in states:
            en[0] = en[0] + self.delta_weights(st, cos_i)[0]
            en[1] = en[1] + st["e_f"]
            en[2] = en[2] + st["e_b"]
        return en

    def lobe_values(self, bsdf, ctx, states, wi, wo, cos_i, cos_o, active, Z, pdf, mix, probs):
        """Per wavelength ``f |cos θo|`` of the lobes (``Z`` from :meth:`SphereBSDFMixin._lobes`) and the
        density ``pdf`` plus the substrate's (``mix = (m, p_f, p_b)``, ``probs`` its selection probabilities)."""
        return [z * (st["fs"] * st["w"]) for st, z in zip(states, Z)], pdf

    def smooth_share(self, probs):
        """The substrate's glossy share of the selection (cosine sampling): none."""
        return 0.0

    def lobe_picks(self, active, sample1, probs, pick_coh, pick_f, pick_b, s):
        """``(pick_b, lobe_f, lobe_any, s, picks)``: the backward lobe takes what is left of ``sample1``;
        the lobe drawn (forward: ``lobe_f``), the lanes drawing one, the lobe's share of ``sample1``,
        and the substrate's picks (None: none)."""
        p_coh, p_f, p_b = probs
        pick_b = pick_b | (active & _not(pick_coh | pick_f) & (p_b > 0))
        return pick_b, pick_f, pick_f | pick_b, s, None

    def specular_sample(self, picks, probs, spec, spectrum, pdf, weight):
        """``(pdf, weight)`` of the sample with the specular reflection (``spec`` per wavelength): none."""
        return pdf, weight


class SpheresOnPane(PaneSubstrate):
    """Spheres on a thin glass pane (docs/physics.md#the-layer-on-glass-substrateglass, incoherent only):
    the flat layer's :class:`PaneSubstrate` (its Fresnel factors, components 3 and 4, their picks and
    samples) with the spheres' own lobe in reflection, component 4: the forward and backward lobes at
    ``wo``'s mirror image, ``C [R'(θi) + R'(θo)] f(wi, wo')``, sampled as the lobes (forward or backward
    in their selection ratio), mirrored."""

    wavelength_loop = False

    def delta_weights(self, layer, cos_i, wavelengths=None):
        """Per wavelength (``layer``: a state) the weights of the coherent transmission and of the
        specular reflection (:func:`pane_delta_weights`, the face's ``R`` from the pane's ``R'``)."""
        return pane_delta_weights(layer["coherent"], self.reflectance(cos_i), self.layer_first(cos_i))

    def energies(self, states, cos_i):
        """Energies of (coherent, forward, backward, specular, lobe in reflection) summed over the lane's
        wavelengths: the lobes through the pane where the glass comes first (``T'(θi)``), the lobe in
        reflection ``2 C R'(θi) (e_f + e_b)`` where the layer does (roughly: its selection weight)."""
        en = [mi.Float(0.0) for _ in range(5)]
        first, r_i = self.layer_first(cos_i), self.reflectance(cos_i)
        t_i = 1.0 - r_i
        for st in states:
            w_coh, w_spec = self.delta_weights(st, cos_i)
            en[0] = en[0] + w_coh
            through = dr.select(first, 1.0, t_i)
            en[1] = en[1] + st["e_f"] * through
            en[2] = en[2] + st["e_b"] * through
            en[3] = en[3] + w_spec
            en[4] = en[4] + dr.select(first, 2.0 * st["coherent"] * r_i * (st["e_f"] + st["e_b"]), 0.0)
        return en

    def lobe_values(self, bsdf, ctx, states, wi, wo, cos_i, cos_o, active, Z, pdf, mix, probs):
        """The lobes on the pane: ``T'(θo)`` on the far side (the layer first) or ``T'(θi)`` (the glass
        first), their own side as the table of :mod:`corona.mitsuba.bsdf`, plus component 4 and its density."""
        same_side = cos_i * cos_o > 0
        first, r_i, r_o = self.layer_first(cos_i), self.reflectance(cos_i), self.reflectance(cos_o)
        wo_m = mi.Vector3f(wo.x, wo.y, -wo.z)          # the mirror image: the far side's lobe
        mirrored = active & same_side & first
        on_r = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 4)
        # component 4's sampler mirrors the lobes' samples wherever they fall: those in the
        # lobes' own reflection (the backward lobe, the forward lobe at grazing incidence) land
        # on the far side, where component 4 has no value but its density counts all the same
        Z_m, pdf_m = bsdf._lobes(states, wi, wo_m, active & first, True, True, mix)
        values = []
        for st, z, zm in zip(states, Z, Z_m):
            through, reflected, own_side = pane_smooth_factors(st["coherent"], r_i, r_o, first)
            v = z * dr.select(same_side, own_side, through)
            if on_r:
                v += dr.select(mirrored, zm * reflected, 0.0)
            values.append(v * (st["fs"] * st["w"]))
        if pdf is not None:   # component 4: the lobes' sampler, mirrored (none with cosine sampling)
            _, p_f, p_b = mix
            pdf += dr.select(active & first, probs[1] * pdf_m / _positive(p_f + p_b), 0.0)
        return values, pdf

    def smooth_share(self, probs):
        """The lobe in reflection's share of the selection (cosine sampling)."""
        return probs[1]

    def lobe_picks(self, active, sample1, probs, pick_coh, pick_f, pick_b, s):
        """After the lobes: 3 the pane's mirror image, 4 the lobes mirrored (forward or backward in the
        ratio ``p_f : p_b``, then as the lobe)."""
        p_coh, p_f, p_b, p_spec, p_r = probs
        c3 = p_coh + p_f + p_b
        c4 = c3 + p_spec
        pick_r = active & (sample1 >= c4) & (p_r > 0)
        pick_spec = active & (sample1 >= c3) & ((sample1 < c4) | (p_r <= 0)) & (p_spec > 0)
        pick_b = pick_b | (active & _not(pick_coh | pick_f | pick_spec | pick_r) & (p_b > 0))
        q_f = p_f / _positive(p_f + p_b)
        s_r = (sample1 - c4) / dr.maximum(p_r, 1e-30)
        r_f = pick_r & (s_r < q_f)
        s = dr.select(pick_r, dr.select(r_f, s_r / dr.maximum(q_f, 1e-30),
                                        (s_r - q_f) / dr.maximum(1.0 - q_f, 1e-30)), s)
        return pick_b, pick_f | r_f, pick_f | pick_b | pick_r, s, (pick_spec, pick_r, c4)

    def specular_sample(self, picks, probs, spec, spectrum, pdf, weight):
        """The pane's mirror image (component 3): its pdf and weight, ``spec`` folded by ``spectrum``."""
        pick_spec, p_spec = picks[0], probs[3]
        spec = spectrum(spec)
        pdf = dr.select(pick_spec, p_spec, pdf)
        return pdf, dr.select(pick_spec, spec / dr.maximum(p_spec, 1e-30), weight)


def sphere_bsdf_class() -> type:
    """The sphere BSDF class of the active variant."""
    return variant_class(SphereBSDFMixin, "BSDF", "CoronaSphereBSDF")
