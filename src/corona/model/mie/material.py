"""A layer of transparent spheres (Mie scatterers): the numpy reference BSDF (docs/physics.md#transparent-droplets-mie-spheres).

:class:`corona.Material` builds a :class:`SphereMaterial` (the layer the sphere family registers,
:mod:`corona.model.registry`) when its shape is a
:class:`corona.Sphere` (or a size distribution of one).  The layer is a single
plane of spheres whose centres follow a 2D point process; every sphere
scatters by Mie theory (:mod:`corona.model.mie.theory`).

Model (per unit layer area; ``μ_i = |cos θi|``; λ the wavelength in air)
------------------------------------------------------------------------

* number density ``n = F_a / ⟨π r²⟩``;
* every direction ``wo`` on the sphere of directions is reached; its
  scattering angle Θ from the undeviated direction ``wt = -wi`` splits the
  pattern into a **forward lobe** (Θ < 90°, component 1) and a **backward
  lobe** (Θ >= 90°, component 2, the glory and the fogbow), each of which can
  fall on either side of the layer at oblique incidence;
* the smooth BSDF times the cosine is

      f |cos θo| = F_s · w · Z(Θ, λ),      Z = [P + C (S(q) - 1)]   (forward)
                                           Z = P                    (backward)

  with ``P = ⟨|S1|² + |S2|²⟩ / (2π ⟨x²⟩)`` and ``C = (|⟨S1⟩|² + |⟨S2⟩|²) / (2π ⟨x²⟩)``
  per steradian (``x = 2π r/λ``; ``C = P`` for one size), so that ``F_a P``
  is ``n dσ/dΩ`` and ``∫ P dΩ = Q_sca``; ``S(q)`` is the structure factor of
  the centres at the in-plane momentum transfer ``q = 2π |(wo + wi).xy| / λ``
  (decoupling rule, docs/physics.md#mixtures-and-size-distributions);
* on a fixed :class:`corona.Lattice` (a colloidal crystal, one size) ``S`` is the lattice's
  at the in-plane ``q = k (wo + wi)_xy`` (Bragg orders and the Debye–Waller background) and
  multiplies both lobes, ``Z = P S(q)``: transmitted and reflected orders
  (:meth:`SphereMaterial.lattice_nodes`, docs/physics.md#spheres-on-a-lattice);
* ``F_s = min(F_a / μ_i, 1)``: the spheres' shadow area per unit layer area
  along the beam (their cross-section does not shrink with the angle as a
  flat disk's does), saturated at full cover;
* the coherent beam is the mean transmitted field (optical theorem,
  van de Hulst §4.3): ``t = 1 - F_s s₀``, ``s₀ = 2⟨S(0)⟩/⟨x²⟩``, weight ``|t|²``
  (``(1 - F_a)²`` for large spheres at normal incidence, as opaque disks);
* ``w = min(1, (1 - |t|²) / (F_s (e_f + e_b)))`` caps the scattered energy
  (``e_f``, ``e_b``: the forward lobe with S and the backward lobe integrated
  at normal incidence) so that coherent + scattered never exceeds 1 (Poisson
  centres overlap, as for the flat shapes: docs/physics.md#lobe-weight-cap).

The rows it reads (and the plugin with it) are built by :mod:`corona.model.mie.layer`.
"""
from __future__ import annotations

import copy
import functools
import math
import os

import numpy as np

from corona._validation import CoronaError, check_choice, check_finite_array, check_range
from corona.model import registry, tabulated
from corona.model.layer import decoupled_lobe
from corona.model.material import Layer
from corona.model.mie import theory as mie
from corona.model.mie.layer import (CHORD_MAX, ENERGY_MARGIN, INCIDENCE_MU, LATTICE_DIFFUSE_PHI,
    LATTICE_PEAK_NODES, LATTICE_PEAK_REACH, LATTICE_STEEP, RADIUS_INDEX_PHASE, SIZE_TAIL,
    SPHERE_LATTICE_ONE_SIZE, SPHERE_RADIUS_MAX, SPHERE_SIZES_MAX, build_mie_rows, build_preview_rows, frame,
    index_phase_error, largest_sphere, largest_spread, radius_span, rows_key, scaled_blend)
from corona.model.mie.sphere import Sphere, sphere_parts
from corona.model.processes import Lattice, Poisson, Process
from corona.model.substrate import BareLayer, GlassPane, Mirror, layer_substrate


def _bragg_nodes(G, W, pc, k: float, w: float, reach: float, wi):
    """Quadrature nodes of the Bragg orders ``G`` (weights ``W``, ``pc = G/k - wi_xy``) for
    :meth:`SphereMaterial.lattice_nodes`: (``p`` (M, 2) the nodes' ``wo_xy``, ``cz`` (M,) their
    ``|cos θo|``, ``wq`` (M,) their weights ``W_G g_G d²q / (k² |cos θo|)``)."""
    xg, wg = np.polynomial.legendre.leggauss(LATTICE_PEAK_NODES)
    # orders well inside the unit disk of wo_xy: a tensor grid in q, weights d²q / (k² |cos θo|)
    rho0 = np.hypot(pc[:, 0], pc[:, 1])
    r_w = reach / k
    flat = rho0 + r_w < LATTICE_STEEP
    d = reach * xg
    g1 = reach * wg * np.exp(-0.5 * (d / w) ** 2) / (math.sqrt(2 * np.pi) * w)
    Gf, Wf = G[flat], W[flat]
    q = np.stack(np.broadcast_arrays(Gf[:, None, None, 0] + d[None, :, None],
                                     Gf[:, None, None, 1] + d[None, None, :]), -1).reshape(-1, 2)
    wq = (Wf[:, None, None] * g1[None, :, None] * g1[None, None, :]).reshape(-1)
    p = q / k - wi[:2]
    r2 = p[:, 0] ** 2 + p[:, 1] ** 2
    ok = (r2 < 1.0) & (wq > 0)
    p, r2 = p[ok], r2[ok]
    cz = np.sqrt(1.0 - r2)
    wq = wq[ok] / (k * k * cz)
    if np.any(~flat):
        pg, czg, wg_ = _grazing_nodes(G[~flat], W[~flat], pc[~flat], k, w, r_w, wi, xg, wg)
        p, cz, wq = np.concatenate([p, pg]), np.concatenate([cz, czg]), np.concatenate([wq, wg_])
    return p, cz, wq


def _grazing_nodes(Gs, Ws, ps, k: float, w: float, r_w: float, wi, xg, wg):
    """Orders near grazing exit for :func:`_bragg_nodes`: ``wo_xy = sin θ (cos φ, sin φ)``,
    ``d²q / (k² |cos θo|) = sin θ dθ dφ`` (no ``1/|cos θo|`` singularity), a Gauss–Legendre grid in
    θ and φ over each peak's window."""
    r0 = np.hypot(ps[:, 0], ps[:, 1])
    ph0 = np.arctan2(ps[:, 1], ps[:, 0])
    th_lo = np.arcsin(np.clip(r0 - r_w, 0.0, 1.0))
    th_hi = np.arcsin(np.clip(r0 + r_w, 0.0, 1.0))
    dph = np.arcsin(np.clip(r_w / np.maximum(r0, 1e-12), 0.0, 1.0))
    xt, wt = np.polynomial.legendre.leggauss(2 * LATTICE_PEAK_NODES)
    th = 0.5 * (th_lo + th_hi)[:, None] + 0.5 * (th_hi - th_lo)[:, None] * xt[None, :]
    wth = 0.5 * (th_hi - th_lo)[:, None] * wt[None, :]
    ph = ph0[:, None] + dph[:, None] * xg[None, :]
    wph = dph[:, None] * wg[None, :]
    st = np.sin(th)[:, :, None]
    pp = np.stack(np.broadcast_arrays(st * np.cos(ph)[:, None, :], st * np.sin(ph)[:, None, :]), -1)
    dq = k * (pp + wi[:2]) - Gs[:, None, None, :]
    gauss = np.exp(-0.5 * np.sum(dq * dq, axis=-1) / (w * w)) / (2 * np.pi * w * w)
    ws = (Ws[:, None, None] * gauss * st * wth[:, :, None] * wph[:, None, :]).reshape(-1)
    pp = pp.reshape(-1, 2)
    r2s = np.sum(pp * pp, axis=-1)
    ok = (r2s < 1.0) & (ws > 0)
    return pp[ok], np.sqrt(1.0 - r2s[ok]), ws[ok]


class SphereMaterial(Layer):
    """A layer of Mie spheres: coherent beam, forward and backward lobes (see the module docstring).

    A :class:`corona.model.material.Layer` (``corona.Material(corona.Sphere(r), ...)`` returns
    one) with the flat layer's methods, signatures and result keys; the members built on a flat
    layer's one table of ``v(u)`` it does not have (its lobes are rows over the size parameter:
    :attr:`rows`; sampled about ``wi`` and its mirror: :meth:`sample_lobe`).

    Parameters
    ----------
    shape : corona.Sphere or corona.SizeDistribution of a Sphere
    process : corona.Process, default Poisson()
        An isotropic process of the centres (poisson, hard-disk, rsa, a powder lattice, a
        point set), or a fixed :class:`corona.Lattice` (one sphere size): a colloidal
        crystal, whose lobes are the Mie lobes times the lattice's Bragg peaks and
        Debye–Waller background, in transmission and in reflection
        (docs/physics.md#spheres-on-a-lattice).
    mode : "particle"
        Spheres are particles in clear air; ``"aperture"`` is refused.
    albedo : 0
        Spheres reflect by Mie theory (the backward lobe), not diffusely.
    use_cache : bool
        Keep the tables in the on-disk cache.
    substrate : corona.GlassPane, optional
        The droplets sit on a thin pane (incoherent: no thickness), with the
        flat layer's weights (:meth:`eval`; docs/physics.md#the-layer-on-glass-substrateglass).
    radius_cover : (float, float), optional
        Radii [µm] ``(r_lo, r_hi)`` around the sphere's the rows serve (a radius texture or an
        optimiser's steps in the plugin): rows from ``2π r_lo/830 nm`` to ``2π r_hi/360 nm``, the
        chord grid fine enough for ``r_hi``; :meth:`at_radius` reads them at another radius.  Row x
        holds the index at ``λ = 2π r/x`` of the sphere's own radius r, so at radius ``r'`` a
        dispersive index is read at ``λ r/r'`` instead of λ: a cover whose phase error
        (:func:`index_phase_error`) passes ``RADIUS_INDEX_PHASE`` is refused
        (docs/layer.md#sphere-radius-textures).  None: the sphere's radius alone.

    Examples
    --------
    Water droplets of 5 µm radius at ``F_a = 0.05``, centres uncorrelated.
    At normal incidence the coherent beam is ``|1 - F_a s₀|² ≈ (1 - F_a Q_ext/2)²``
    (Q_ext = 2.19 here), the lobes carry ``F_a Q_sca``, 96 % of it forward, and the cap
    ``w`` trims their sum by the ``O(F_a²)`` that overlapping Poisson droplets would add:

    >>> import corona
    >>> m = corona.Material(corona.Sphere(5.0), corona.Poisson(0.05))
    >>> m
    SphereMaterial(Sphere(radius=5, ior='water'), Poisson(area_fraction=0.05))
    >>> e = m.directional_albedo(1.0, 550.0)
    >>> round(e["coherent"], 3), round(e["forward"], 3), round(e["backward"], 4)
    (0.898, 0.097, 0.0047)
    """

    mode = "particle"
    albedo = 0.0
    isotropic = True
    #: How the renderer evaluates the lobe: the Mie rows (:mod:`corona.mitsuba.sphere`).
    render_kind = "mie"

    @property
    def opaque_fraction(self) -> float:
        """0: the spheres are transparent (what they absorb is their ``ior``'s imaginary part)."""
        return 0.0

    def __init__(self, shape, process: Process | None = None, mode: str = "particle",
                 albedo: float = 0.0, use_cache: bool = True, substrate=None, radius_cover=None):
        parts = sphere_parts(shape)
        if parts is None:
            raise CoronaError(f"shape={shape!r} is not a sphere (corona.Sphere)")
        self.sphere, self.sizes = parts
        if process is None:
            process = Poisson()
        if not isinstance(process, Process):
            raise CoronaError(f"process={process!r} is not a corona point process (e.g. corona.Poisson())")
        #: the fixed lattice of the centres (None: an isotropic process)
        self.lattice = process if isinstance(process, Lattice) and not process.isotropic else None
        if not process.isotropic and self.lattice is None:
            raise CoronaError(f"process={process!r} is out of range for shape='sphere'; allowed an isotropic "
                              "process or a fixed lattice (the Mie lobes of an anisotropic point set's S(q) "
                              "are not built)")
        if self.lattice is not None and self.sizes is not None and self.sizes.spread > 0:
            raise CoronaError(f"size_spread={self.sizes.spread:g} is out of range for shape='sphere' on a "
                              f"lattice; allowed 0 ({SPHERE_LATTICE_ONE_SIZE})")
        self.isotropic = self.lattice is None
        self._lattice_cache = {}
        if check_choice("mode", mode, ("aperture", "particle")) != "particle":
            raise CoronaError("mode='aperture' is out of range for shape='sphere'; allowed: particle "
                              "(droplets in clear air)")
        if check_range("albedo", albedo, 0.0, 1.0) != 0.0:
            raise CoronaError(f"albedo={albedo!r} is out of range for shape='sphere'; allowed 0 (a sphere "
                              "reflects by Mie theory: the backward lobe)")
        if substrate is not None and (not isinstance(substrate, GlassPane) or isinstance(substrate, Mirror)
                                      or substrate.coherent):
            raise CoronaError(f"substrate={substrate!r} is out of range for shape='sphere'; allowed none or "
                              "an incoherent glass pane (corona.GlassPane without a thickness: the double "
                              "pass's fringes are built for the flat layer)")
        self.substrate = substrate
        #: the substrate's part (corona.model.substrate.layer_substrate), chosen once
        self.substrate_part = layer_substrate(substrate)
        self.shape = shape
        self.process = process
        self.use_cache = bool(use_cache)
        self.area_fraction = process.layer_area_fraction(shape)
        r = float(self.sphere.radius)
        if radius_cover is not None:
            lo, hi = (float(v) for v in radius_cover)
            if not (0.0 < lo <= r * (1 + 1e-9) and r <= hi * (1 + 1e-9) and math.isfinite(hi)):
                raise CoronaError(f"radius_cover={radius_cover!r} is out of range for shape='sphere' with "
                                  f"radius={r:g}; allowed (r_lo, r_hi) with 0 < r_lo <= {r:g} <= r_hi")
            radius_cover = (min(lo, r), max(hi, r))
            phase = index_phase_error(self.sphere, *radius_cover)
            if phase > RADIUS_INDEX_PHASE:
                f = radius_span(self.sphere, max(r / radius_cover[0], radius_cover[1] / r))
                raise CoronaError(
                    f"radius={radius_cover[0]:.4g} … {radius_cover[1]:.4g} is out of range for shape='sphere' "
                    f"with a dispersive ior (water): one table of rows holds the index of one radius, "
                    f"{phase:.2f} rad off at the ends (allowed {RADIUS_INDEX_PHASE:g}); allowed radii within "
                    f"a factor {f:.4g} of {r:.4g} µm, or a constant ior for any range")
        self.radius_cover = radius_cover
        top_r = r if radius_cover is None else radius_cover[1]
        if top_r > SPHERE_RADIUS_MAX:
            raise CoronaError(f"radius={top_r:g} is out of range for shape='sphere'; allowed "
                              f"(0, {SPHERE_RADIUS_MAX:g}] µm (larger droplets: use shape='circle', "
                              "whose Fraunhofer corona theirs approaches)")
        if self.sizes is not None and self.sizes.spread > 0:
            top = largest_sphere(top_r, self.sizes.spread, self.sizes.distribution)
            if top > SPHERE_SIZES_MAX:
                allowed = largest_spread(top_r, self.sizes.distribution)
                raise CoronaError(
                    f"size_spread={self.sizes.spread:g} is out of range for shape='sphere' with radius="
                    f"{top_r:g} µm: its largest droplets ({top:.3g} µm; {SIZE_TAIL:g} of the "
                    f"scattered power beyond) pass {SPHERE_SIZES_MAX:g} µm, the Mie tables' range; allowed "
                    f"size_spread <= {allowed:.3g} ({self.sizes.distribution}) at this radius")

    def __repr__(self):
        pane = "" if self.substrate is None else f", substrate={self.substrate!r}"
        tag = ", preview" if self.is_preview else ""
        return f"SphereMaterial({self.shape!r}, {self.process!r}{pane}{tag})"

    @property
    def length_scale(self) -> float:
        return float(self.sphere.radius)

    # ------------------------------------------------------------------
    # tables
    # ------------------------------------------------------------------
    def table_params(self) -> dict:
        """The table-cache key of the rows (:func:`corona.model.mie.layer.rows_key`)."""
        return rows_key(self.shape, self.radius_cover, self.is_preview)

    #: True for the coarse copy of :meth:`preview`.
    is_preview = False

    @functools.cached_property
    def rows(self) -> dict:
        """The Mie rows (:func:`build_mie_rows`, cached on disk), float64; a preview's:
        :func:`build_preview_rows` (not cached)."""
        if self.is_preview:
            return build_preview_rows(self.sphere, self.radius_cover)
        arrays = tabulated.cached(self.table_params(),
                               lambda: build_mie_rows(self.sphere, self.sizes, self.radius_cover),
                               use_cache=self.use_cache, background=True)
        return {k: np.asarray(v) for k, v in arrays.items()}

    def rows_cached(self) -> bool:
        """Whether the exact Mie rows are ready at once (built in this process or in the
        on-disk cache): when False, :attr:`rows` builds them (seconds to a minute, a progress
        bar on stderr) and :meth:`preview` gives a coarse look meanwhile."""
        if "rows" in self.__dict__ and not self.is_preview:
            return True
        if not self.use_cache:
            return False
        try:
            path = os.path.join(tabulated.cache_dir(), tabulated.cache_key(
                {k: v for k, v in self.table_params().items() if k != "preview"}) + ".npz")
        except CoronaError:
            return False
        return os.path.isfile(path)

    def preview(self) -> "SphereMaterial":
        """A coarse copy of this layer for a first look while the exact rows build: one-size Mie
        rows of the mean sphere (the size spread left out), :data:`PREVIEW_ROWS` of them, not
        refined, on a coarser chord grid (:func:`build_preview_rows`): about a second where the
        exact table of a new radius takes 10-60 s.  Its energies, lobes and renders are those
        of the coarse rows; ``repr`` says ``preview``.  The designer shows it while
        :attr:`rows` builds on another thread (``corona.model.mie.layer``; docs/mie.md)."""
        other = copy.copy(self)
        other.__dict__ = {k: v for k, v in self.__dict__.items()
                          if k not in ("rows", "_derived", "_energy_peers", "_forward_energy_handed")}
        other._lattice_cache = {}
        other.is_preview = True
        return other

    def at_radius(self, radius: float) -> "SphereMaterial":
        """The layer with spheres of ``radius`` [µm] (within :attr:`radius_cover`) read from these rows,
        as a radius texture's texel is: ``x = 2π radius/λ`` on the same rows, the same ``S(q r)`` table
        in ``u = q r`` and the same forward energies in x (what the plugin evaluates there).

        The Mie lobe of the new radius itself (:meth:`eval` with ``exact=True``) is Mie theory at
        that radius and the index at λ."""
        r = float(radius)
        lo, hi = self.radius_cover if self.radius_cover is not None else (self.sphere.radius,) * 2
        if not (lo * (1 - 1e-9) <= r <= hi * (1 + 1e-9)):
            raise CoronaError(f"radius={r!r} is out of range for these sphere rows; allowed "
                              f"[{lo:g}, {hi:g}] µm (radius_cover)")
        _ = self.rows, self.structure_table, self._derived        # shared, computed once
        other = copy.copy(self)
        other.sphere = Sphere(r, ior=self.sphere.ior)
        return other

    @functools.cached_property
    def structure_table(self):
        """``S`` on a radial grid of ``u = q r`` (RADIAL_DU), or None for Poisson (S = 1) and for a
        fixed lattice (its ``S`` is evaluated at the in-plane ``q`` itself: :meth:`_lobes`)."""
        if isinstance(self.process, Poisson) or self.lattice is not None:
            return None
        # in u = q r, radius-free for a hard core of the spheres' diameter; long enough for the cover's top
        top = self.length_scale if self.radius_cover is None else self.radius_cover[1]
        u_max = tabulated.u_max_for(top)
        n = min(int(np.ceil(u_max / tabulated.RADIAL_DU)) + 1, tabulated.RADIAL_MAX_SAMPLES)
        du = u_max / (n - 1)
        u = np.arange(n) * du
        S = self.process.structure_factor_radial(u / self.length_scale, self.shape)
        return du, np.maximum(np.asarray(S, dtype=np.float64), 0.0)

    def structure_factor(self, u) -> np.ndarray:
        """Tabulated ``S`` at ``u = q r`` (linear; 1 beyond the table and for Poisson)."""
        st = self.structure_table
        u = np.asarray(u, dtype=np.float64)
        if st is None:
            return np.ones_like(u)
        du, S = st
        return np.interp(u, np.arange(S.size) * du, S, right=1.0)

    @functools.cached_property
    def _derived(self) -> dict:
        """Totals per row: T_f, T_b (∫ P dΩ of the tabulated rows) and e_f (the forward lobe with S
        at normal incidence)."""
        r = self.rows
        ds = float(r["ds"])
        s = np.arange(r["P_f"].shape[1]) * ds
        C = r["C_f"] if r["C_f"].size else r["P_f"]
        T_f = tabulated.radial_totals(ds, r["P_f"])          # RadialTable(ds, row).total per row
        T_b = tabulated.radial_totals(ds, r["P_b"])
        if self.structure_table is None:
            e_mu = np.repeat(T_f[:, None], len(INCIDENCE_MU), axis=1)
        else:   # seconds for a hard core: kept in the table cache, per process
            key = {**self.table_params(), "forward_energy": 1, "process": tabulated.identity(self.process),
                   "incidence_mu": len(INCIDENCE_MU)}
            e_mu = np.asarray(tabulated.cached(key, lambda: {"e_f_mu": self._forward_energy_of_peers(s, C, T_f)},
                                            use_cache=self.use_cache)["e_f_mu"])
        return {"T_f": T_f, "T_b": T_b, "e_f": e_mu[:, 0], "e_f_mu": e_mu, "e_b": T_b, "s": s}

    @property
    def row_totals(self) -> dict:
        """Per row of x (numpy, read-only by convention): ``T_f``, ``T_b`` (``∫ P dΩ`` of the
        forward and backward rows), ``e_f_mu`` (the forward lobe's energy with ``S`` per row and
        ``μ_i`` of ``INCIDENCE_MU``), ``e_f`` (its normal-incidence column), ``e_b`` and the chords
        ``s``: what the plugin tabulates beside the rows (:mod:`corona.mitsuba.sphere`)."""
        return self._derived

    def _forward_energy_of_peers(self, s, C, T_f) -> np.ndarray:
        """:meth:`_forward_energy`, computed in one pass with the peers :func:`share_forward_energies`
        named that share this layer's rows and have not derived theirs yet (handed to them for when
        they do); or the one a peer handed to this layer."""
        handed = self.__dict__.pop("_forward_energy_handed", None)
        if handed is not None:
            return handed
        peers = [m for m in self.__dict__.get("_energy_peers", ()) if m is not self
                 and m.__dict__.get("rows") is self.rows and "_derived" not in m.__dict__]
        out = self._forward_energy(s, C, T_f, peers)
        for m, e in zip(peers, out[1:]):
            m.__dict__["_forward_energy_handed"] = e
        return out[0]

    def _forward_energy(self, s, C, T_f, peers=()) -> list[np.ndarray]:
        """``e_f(x_j, μ_i)`` (J, len(INCIDENCE_MU)): the forward lobe with ``S(q)`` integrated over
        the sphere of directions for light from ``μ_i = |cos θi|`` (``T_f`` for Poisson), of this
        layer and of ``peers`` (layers of the same rows with other hard-core processes), a list.

        Since ``⟨C⟩ <= ⟨P⟩`` and ``S >= 0``, ``P + C (S - 1) >= 0`` and the lobe's energy is
        ``T_f + ∫ C (⟨S⟩_φ - 1) dΩ``, where ``⟨S⟩_φ(s, u)``, the mean over the azimuth about
        ``wt = -wi`` of ``S(u h)`` with ``h = |(wo - wt)_xy| / |wo - wt|`` (a function of the
        chord s, the azimuth and μ_i only), is tabulated once on a coarse grid of s and a grid of
        ``u = x s`` and read at each row's ``x_j s``.  At oblique incidence q is smaller for a
        given Θ and the lobe meets another part of S: for dense hard disks its energy grows
        (14 % at F_a = 0.7 and 60°); the lobe weight's cap uses this energy (:meth:`energies`)."""
        mus = np.asarray(INCIDENCE_MU)
        J = T_f.size
        layers = [self, *peers]
        if self.structure_table is None:
            return [np.repeat(T_f[:, None], mus.size, axis=1)]
        r = self.rows
        xs = r["x"]
        keep = s <= CHORD_MAX + 1e-12
        sk = s[keep]
        w = 2 * np.pi * sk * (s[1] - s[0])        # trapezoid weights of dΩ = s ds dφ
        w[0] = 0.0
        w[-1] *= 0.5
        Ck = C[:, keep]
        n_c, n_phi = (16, 16) if self.is_preview else (48, 64)    # a preview: a coarser S grid
        s_c = np.linspace(1e-4, CHORD_MAX, n_c)
        # u nodes: 0.125 apart up to 40, then geometric (S - 1 fades; its φ-mean fades faster)
        u_top = max(41.0, 1.5 * CHORD_MAX * float(xs[-1]))
        n_geo = 160
        ratio = math.log(u_top / 40.0) / (n_geo - 1)
        u_c = np.concatenate([np.arange(320) * 0.125, 40.0 * np.exp(np.arange(n_geo) * ratio)])
        # the azimuths of the half circle φ in (0, π): wi lies in the xz plane, so h(-φ) = h(φ) and the
        # mean over the half is the mean over the whole circle's n_phi
        phi = (np.arange(n_phi // 2) + 0.5) * (2 * np.pi / n_phi)
        cos_c, sin_c = 1 - 0.5 * s_c * s_c, s_c * np.sqrt(1 - 0.25 * s_c * s_c)
        # ⟨S⟩_φ - 1 on the coarse (s_c, u_c) grid, one table per layer and incidence
        n_u = u_c.size
        Kc = np.empty((n_c * n_u, len(layers), mus.size))
        for k, mu in enumerate(mus):
            wi = np.array([math.sqrt(max(0.0, 1 - mu * mu)), 0.0, max(mu, 1e-9)])
            wi /= np.linalg.norm(wi)
            wt = -wi
            e1, e2 = frame(wt)
            wo = (cos_c[:, None, None] * wt + sin_c[:, None, None]
                  * (np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2))
            h = np.linalg.norm((wo - wt)[..., :2], axis=-1) / s_c[:, None]          # (n_c, n_phi)
            for n, layer in enumerate(layers):
                Kc[:, n, k] = (np.mean(layer.structure_factor(u_c[None, :, None] * h[:, None, :]), axis=-1)
                               - 1.0).ravel()
        Kc = Kc.reshape(n_c * n_u, -1)
        # ∑_s C w (⟨S⟩_φ - 1) at each row's (s, u = x s), bilinear on the grid (linear in s between
        # the coarse cells, in u on u_c), is linear in the grid's values: per row, the weights its
        # chord nodes put on the grid's nodes (np.bincount over a block of rows), times the tables
        # of all layers and incidences at once; the same sums as interpolating at every node, reordered
        cell = np.clip(np.searchsorted(s_c, sk) - 1, 0, n_c - 2)
        frac = np.clip((sk - s_c[cell]) / (s_c[cell + 1] - s_c[cell]), 0.0, 1.0)
        out = np.empty((J, len(layers) * mus.size))
        block = max(1, (1 << 22) // (n_c * n_u))             # rows a block: 4 M grid weights
        for j0 in range(0, J, block):
            j1 = min(J, j0 + block)
            U = xs[j0:j1, None] * sk[None, :]                   # the rows' u = x s
            g = np.where(U < 40.0, U / 0.125, 320 + np.log(np.maximum(U, 40.0) / 40.0) / ratio)
            i = np.clip(np.floor(g).astype(np.int64), 0, n_u - 2)
            fr = np.clip((U - u_c[i]) / (u_c[i + 1] - u_c[i]), 0.0, 1.0)
            a = Ck[j0:j1] * w
            a_lo, a_hi = a * (1 - frac), a * frac                 # the two s cells' shares
            node = (cell * n_u)[None, :] + i + (np.arange(j1 - j0) * (n_c * n_u))[:, None]
            weights = np.bincount(np.concatenate([node.ravel(), (node + 1).ravel(),
                                                  (node + n_u).ravel(), (node + n_u + 1).ravel()]),
                                  np.concatenate([(a_lo * (1 - fr)).ravel(), (a_lo * fr).ravel(),
                                                  (a_hi * (1 - fr)).ravel(), (a_hi * fr).ravel()]),
                                  minlength=(j1 - j0) * n_c * n_u)
            out[j0:j1] = T_f[j0:j1, None] + weights.reshape(j1 - j0, n_c * n_u) @ Kc
        return [np.maximum(e, 0.0) for e in np.split(out, len(layers), axis=1)]

    def _forward(self, j, t, cos_theta_i):
        """``e_f`` at the row (j, t) and ``|cos θi|``: linear in both."""
        e = self._derived["e_f_mu"]
        nodes = np.asarray(INCIDENCE_MU)
        mu = np.clip(np.abs(np.asarray(cos_theta_i, dtype=np.float64)), 0.0, 1.0)
        g = (1.0 - mu) / (nodes[0] - nodes[1])
        b = np.clip(np.floor(g).astype(np.int64), 0, nodes.size - 2)
        f = np.clip(g - b, 0.0, 1.0)
        at = lambda jj: e[jj, b] * (1 - f) + e[jj, b + 1] * f
        return at(j) * (1 - t) + at(j + 1) * t

    def _row(self, wavelength):
        """Row index j and weight t of the wavelength(s) [nm] between rows (linear in x)."""
        lam = np.clip(np.asarray(wavelength, dtype=np.float64), tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX)
        xr = self.rows["x"]
        x = 2 * np.pi * self.length_scale / (lam * 1e-3)
        j = np.clip(np.searchsorted(xr, x, side="right") - 1, 0, xr.size - 2)
        return j, (x - xr[j]) / (xr[j + 1] - xr[j])

    def _x(self, wavelength):
        """Size parameter ``2π r / λ`` of the mean sphere at ``wavelength`` [nm] (clipped to the range)."""
        lam = np.clip(np.asarray(wavelength, dtype=np.float64), tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX)
        return 2 * np.pi * self.length_scale / (lam * 1e-3)

    def _blend(self, key, j, t, x, s, cubic=True):
        r = self.rows
        return scaled_blend(r[key], float(r["ds"]), r["x"], j, t, x, s, cubic)

    def _node(self, s):
        ds = float(self.rows["ds"])
        K = self.rows["P_f"].shape[1]
        g = np.asarray(s, dtype=np.float64) / ds
        i = np.clip(np.floor(g).astype(np.int64), 0, K - 2)
        return i, np.clip(g - i, 0.0, 1.0), g <= K - 1

    # ------------------------------------------------------------------
    # energies
    # ------------------------------------------------------------------
    def _slant(self, cos_theta_i):
        mu = np.abs(np.asarray(cos_theta_i, dtype=np.float64))
        return np.minimum(self.area_fraction / np.maximum(mu, 1e-12), 1.0)

    def energies(self, cos_theta_i, wavelength) -> dict:
        """``coherent`` ``|t|²``, the lobe weight ``w``, and the energies of the forward and backward
        lobes ``F_s w e_f``, ``F_s w e_b`` (at normal-incidence S) for light from ``cos_theta_i``."""
        j, t = self._row(wavelength)
        d = self._derived
        r = self.rows
        lerp = lambda a: a[j] * (1 - t) + a[j + 1] * t
        fs = self._slant(cos_theta_i)
        s0 = lerp(r["s0"][:, 0]) + 1j * lerp(r["s0"][:, 1])
        coherent = np.minimum(np.abs(1.0 - fs * s0) ** 2, 1.0)
        e_f, e_b = self._forward(j, t, cos_theta_i), lerp(d["e_b"])
        scattered = fs * (e_f + e_b) * ENERGY_MARGIN
        w = np.minimum(1.0, np.maximum(1.0 - coherent, 0.0) / np.maximum(scattered, 1e-300))
        return {"coherent": coherent, "weight": w, "forward": fs * w * e_f, "backward": fs * w * e_b,
                "slant": fs}

    # ------------------------------------------------------------------
    # a fixed lattice (docs/physics.md#spheres-on-a-lattice)
    # ------------------------------------------------------------------
    def _mie_at(self, wi, wo, lam):
        """(P_f, P_b, forward mask) of the tables at directions ``wo`` (M, 3) for one ``wi`` (3,)."""
        s_f = np.linalg.norm(wo + wi, axis=-1)
        s_b = np.linalg.norm(wo - wi, axis=-1)
        j, t = self._row(lam)
        x = self._x(lam)
        return self._blend("P_f", j, t, x, s_f), self._blend("P_b", j, t, x, s_b), s_f <= s_b

    def lattice_nodes(self, wi, wavelength: float) -> dict:
        """A quadrature of the lattice layer's lobes over the sphere of directions, for one ``wi``.

        On a fixed lattice (one size, ``C = P``) the lobe is
        ``Z = P (1 - e^{-q²δ²}) + P Σ_G W_G g_G(q)`` (forward lobe's ``P_f`` or backward
        lobe's ``P_b`` by the chord, :meth:`_lobes`), ``W_G = (2π)² n e^{-G²δ²}`` and ``g_G`` the
        unit Gaussian of the broadened peak (:class:`corona.Lattice`).  Since
        ``d²q = k² |cos θo| dΩ`` (``q = k (wo + wi)_xy``), order ``G`` carries
        ``∫ P W_G g_G(q) d²q / (k² |cos θo|)``, summed over the directions on both sides of the
        layer that it reaches (``|q/k - wi_xy| < 1``): ``LATTICE_PEAK_NODES``² Gauss–Legendre
        nodes over ``±LATTICE_PEAK_REACH`` rms widths per peak and side.  The diffuse part
        ``P (1 - e^{-q²δ²})`` of a jittered lattice is integrated on the tables' chord grid
        about ``∓wi`` (``dΩ = s ds dφ``, ``LATTICE_DIFFUSE_PHI`` azimuths).  In the narrow-peak
        limit ``F_s`` times an order's energy is the kinematic grating efficiency
        ``η_G = λ² |f(Θ_G)|² e^{-G²δ²} / (A² μ_i |cos θ_G|)`` (``|f|² = (|S1|² + |S2|²) / 2k²``
        the sphere's differential cross-section at the order's scattering angle, ``A`` the cell
        area; e.g. Ashcroft & Mermin ch. 6, Guinier ch. 7).

        Returns
        -------
        dict: ``wo`` (M, 3) the nodes' directions, ``energy`` (M,) their ``Z dΩ`` (the layer's
        lobes before ``F_s w``), ``forward`` (M,) the lobe they belong to, ``bragg`` (M,) True for
        the orders' nodes (False: the diffuse part's).
        """
        wi = np.asarray(wi, dtype=np.float64)
        lam = float(np.clip(wavelength, tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX))
        key = (tuple(np.round(wi, 12)), lam)
        if key in self._lattice_cache:
            return self._lattice_cache[key]
        k = 2 * np.pi / (lam * 1e-3)
        lat = self.lattice
        w = lat.peak_width
        reach = LATTICE_PEAK_REACH * w
        G, W = lat.bragg_peaks(2.0 * k + reach)
        pc = G / k - wi[:2]
        keep = np.hypot(pc[:, 0], pc[:, 1]) < 1.0 + reach / k
        G, W = G[keep], W[keep]
        p, cz, wq = _bragg_nodes(G, W, pc[keep], k, w, reach, wi)
        parts_wo, parts_e, parts_f = [], [], []
        for side in (1.0, -1.0):
            wo = np.concatenate([p, side * cz[:, None]], axis=-1)
            P_f, P_b, fwd = self._mie_at(wi, wo, lam)
            parts_wo.append(wo)
            parts_e.append(np.where(fwd, P_f, P_b) * wq)
            parts_f.append(fwd)
        if lat.jitter > 0.0:
            self._diffuse_nodes(wi, lam, k, parts_wo, parts_e, parts_f)
        n_bragg = 2 * p.shape[0]
        out = {"wo": np.concatenate(parts_wo), "energy": np.concatenate(parts_e),
               "forward": np.concatenate(parts_f)}
        out["bragg"] = np.arange(out["energy"].size) < n_bragg
        if len(self._lattice_cache) > 256:
            self._lattice_cache.clear()
        self._lattice_cache[key] = out
        return out

    def _diffuse_nodes(self, wi, lam: float, k: float, parts_wo: list, parts_e: list, parts_f: list) -> None:
        """The diffuse part ``P (1 - e^{-q²δ²})`` of a jittered lattice on the tables' chord grid
        about ``∓wi`` (``dΩ = s ds dφ``, ``LATTICE_DIFFUSE_PHI`` azimuths), appended to the parts of
        :meth:`lattice_nodes`."""
        K = self.rows["P_f"].shape[1]
        s = np.linspace(0.0, CHORD_MAX, K)
        ws = np.full(s.size, s[1] - s[0])
        ws[0] = ws[-1] = 0.5 * ws[0]
        phi = (np.arange(LATTICE_DIFFUSE_PHI) + 0.5) * (2 * np.pi / LATTICE_DIFFUSE_PHI)
        cos_t, sin_t = 1 - 0.5 * s * s, s * np.sqrt(1 - 0.25 * s * s)
        for axis in (-wi, wi):
            e1, e2 = frame(axis)
            wo = (cos_t[:, None, None] * axis + sin_t[:, None, None]
                  * (np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2)).reshape(-1, 3)
            dw = np.repeat(ws * s * (2 * np.pi / LATTICE_DIFFUSE_PHI), phi.size)
            P_f, P_b, fwd = self._mie_at(wi, wo, lam)
            mine = fwd if axis[2] == -wi[2] else ~fwd     # each lobe on its own grid
            q2 = k * k * np.sum((wo + wi)[:, :2] ** 2, axis=-1)
            diffuse = np.where(fwd, P_f, P_b) * -np.expm1(-q2 * self.lattice.jitter ** 2)
            parts_wo.append(wo)
            parts_e.append(np.where(mine, diffuse * dw, 0.0))
            parts_f.append(fwd)

    def lattice_energy(self, wi, wavelength: float) -> float:
        """``e = ∫ Z dΩ`` of both lobes on the lattice for one ``wi`` (3,) (:meth:`lattice_nodes`)."""
        return float(np.sum(self.lattice_nodes(wi, wavelength)["energy"]))

    def _lattice_weight(self, wi, wavelength, shape):
        """The cap ``w = min(1, (1 - |t|²) / (ENERGY_MARGIN F_s e))`` of the lattice layer at each
        (``wi``, λ) (broadcast to ``shape``); ``e`` by :meth:`lattice_energy`."""
        wi = np.broadcast_to(np.asarray(wi, dtype=np.float64), shape + (3,)).reshape(-1, 3)
        lam = np.broadcast_to(np.asarray(wavelength, dtype=np.float64), shape).reshape(-1)
        keys = np.concatenate([wi, lam[:, None]], axis=-1)
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        out = np.empty(uniq.shape[0])
        for n, row in enumerate(uniq):
            e = self.energies(row[2], row[3])
            scattered = e["slant"] * self.lattice_energy(row[:3], row[3]) * ENERGY_MARGIN
            out[n] = min(1.0, max(1.0 - float(e["coherent"]), 0.0) / max(float(scattered), 1e-300))
        return out[inv.reshape(-1)].reshape(shape)

    # ------------------------------------------------------------------
    # the pane (docs/physics.md#the-layer-on-glass-substrateglass), as corona.Material's
    # ------------------------------------------------------------------
    def coherent_weight(self, cos_theta_i, wavelength=550.0) -> float | np.ndarray:
        """The layer's own coherent weight ``C = |1 - F_s s₀(λ)|²`` for light from ``cos_theta_i`` at
        ``wavelength`` [nm] (the mean field depends on both), without the pane."""
        return self.energies(cos_theta_i, wavelength)["coherent"]

    @property
    def coherent_transmittance(self) -> float:
        """The layer's coherent weight ``C`` at normal incidence and 550 nm (it depends on both)."""
        return float(self.energies(1.0, 550.0)["coherent"])

    # ------------------------------------------------------------------
    # the BSDF
    # ------------------------------------------------------------------
    def _lobes(self, wi, wo, wavelength, exact=False):
        """(forward Z, backward Z, forward mask) at the directions, per steradian."""
        wi = check_finite_array("wi", wi)
        wo = check_finite_array("wo", wo)
        if wi.shape[-1:] != (3,) or wo.shape[-1:] != (3,):
            raise CoronaError(f"wi and wo must have shape (..., 3), got {wi.shape} and {wo.shape}")
        wi, wo = np.broadcast_arrays(wi, wo)
        lam = np.broadcast_to(np.asarray(wavelength, dtype=np.float64), wi.shape[:-1])
        s_f = np.linalg.norm(wo + wi, axis=-1)           # |wo - wt|, wt = -wi
        s_b = np.linalg.norm(wo - wi, axis=-1)
        forward = s_f <= s_b
        dxy = np.linalg.norm((wo + wi)[..., :2], axis=-1)
        u = 2 * np.pi * self.length_scale * dxy / (np.clip(lam, tabulated.WAVELENGTH_MIN,
                                                           tabulated.WAVELENGTH_MAX) * 1e-3)
        if self.lattice is None:
            S = self.structure_factor(u)
        else:   # the fixed lattice's S at the in-plane momentum transfer q = 2π (wo + wi)_xy / λ
            lam_um = np.clip(lam, tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX) * 1e-3
            S = self.lattice.structure_factor_at(2 * np.pi * (wo + wi)[..., :2] / lam_um[..., None])
        if exact:
            P_f, C_f, P_b = self.exact_parts(s_f, s_b, lam)
        else:
            j, t = self._row(lam)
            x = self._x(lam)
            P_f = self._blend("P_f", j, t, x, s_f)
            C_f = self._blend("C_f", j, t, x, s_f) if self.rows["C_f"].size else P_f
            P_b = self._blend("P_b", j, t, x, s_b)
        Z_f = decoupled_lobe(P_f, C_f, S)        # per steradian: R = 1
        if self.lattice is not None:
            # the reflected orders: one size, C = P (a lattice takes no size spread)
            return Z_f, decoupled_lobe(P_b, P_b, S), forward
        return Z_f, P_b, forward

    def exact_parts(self, s_f, s_b, lam):
        """Mie ``P_f``, ``C_f`` (forward) and ``P_b`` (backward) at the chords ``s_f = |wo + wi|``,
        ``s_b = |wo - wi|`` and wavelengths ``lam`` [nm], from Mie theory at each direction (float64,
        no rows; a size distribution averaged): what :meth:`eval` uses with ``exact=True``."""
        r = self.sphere.radius
        s_nodes, s_w = (np.ones(1), np.ones(1)) if self.sizes is None else \
            self.sizes._nodes(2.0 * 2 * np.pi / (tabulated.WAVELENGTH_MIN * 1e-3))
        out = [np.zeros(s_f.shape) for _ in range(3)]
        A1, A2 = np.zeros(s_f.shape, complex), np.zeros(s_f.shape, complex)
        flat = lam.ravel()
        for lv in np.unique(flat):
            sel = lam == lv
            x0 = 2 * np.pi * r / (lv * 1e-3)
            m = complex(self.sphere.index(lv))
            x2 = x0 * x0 * float(np.sum(s_w * s_nodes**2))
            mu_f = 1 - 0.5 * s_f[sel] ** 2
            mu_b = -(1 - 0.5 * s_b[sel] ** 2)
            for s, w in zip(s_nodes, s_w):
                S1, S2 = mie.amplitudes(m, x0 * s, np.concatenate([mu_f, mu_b]))
                k = mu_f.size
                out[0][sel] += w * (np.abs(S1[:k]) ** 2 + np.abs(S2[:k]) ** 2) / (2 * np.pi * x2)
                out[2][sel] += w * (np.abs(S1[k:]) ** 2 + np.abs(S2[k:]) ** 2) / (2 * np.pi * x2)
                A1[sel] += w * S1[:k] / math.sqrt(2 * np.pi * x2)
                A2[sel] += w * S2[:k] / math.sqrt(2 * np.pi * x2)
        out[1] = np.abs(A1) ** 2 + np.abs(A2) ** 2
        out[0] = np.where(s_f <= CHORD_MAX, out[0], 0.0)
        out[1] = np.where(s_f <= CHORD_MAX, out[1], 0.0)
        out[2] = np.where(s_b <= CHORD_MAX, out[2], 0.0)
        return out

    def _layer_eval(self, wi, wo, wavelength, exact=False):
        """The layer alone: ``F_s w Z`` (forward or backward lobe) and the coherent weight ``C``."""
        Z_f, Z_b, forward = self._lobes(wi, wo, wavelength, exact)
        wi = np.asarray(wi, dtype=np.float64)
        e = self.energies(np.broadcast_to(wi[..., 2], Z_f.shape), wavelength)
        weight = e["weight"] if self.lattice is None else self._lattice_weight(wi, wavelength, Z_f.shape)
        return e["slant"] * weight * np.where(forward, Z_f, Z_b), e["coherent"]

    def eval(self, wi, wo, wavelength, exact: bool = False) -> np.ndarray:
        """The smooth BSDF times the cosine, ``f |cos θo|``: ``F_s w Z`` (forward or backward lobe).

        ``wi``, ``wo`` (..., 3) unit vectors (Mitsuba's convention), ``wavelength`` [nm].
        ``exact=True`` evaluates Mie theory at each direction instead of the tables
        (the weight ``w`` still comes from the tables' energies).

        On a pane (``C`` the coherent weight at ``θi``, ``R'``, ``T'`` the pane's, ``wo'`` the
        mirror image of ``wo`` in the layer's plane), as :meth:`corona.Material.eval`:

        =====================  ==================================  ======================
        lobes' part            light meets the layer first         meets the glass first
        =====================  ==================================  ======================
        on the far side        ``f T'(θo)``                        ``T'(θi) f``
        on the side of ``wi``  ``f + F f(wo')``                    ``T'(θi) f T'(θo)``
        =====================  ==================================  ======================

        with ``F = min(R(θi), R(θo)) + C [P(θi) + P(θo)]``, ``R`` the front face's Fresnel
        reflectance and ``P = R' - R`` the round trips (:meth:`corona.GlassPane.reflected_lobe_factor`).
        """
        val, coherent = self._layer_eval(wi, wo, wavelength, exact)
        return self.substrate_part.lobes_on_pane(val, lambda wo_m: self._layer_eval(wi, wo_m, wavelength, exact)[0],
                                                 wi, wo, coherent)

    def lobe(self, d, wavelength) -> np.ndarray:
        """The transmitted lobe at normal incidence per unit ``d²d`` (docs/physics.md's ``lobe(d)``).

        ``wi = +z``, ``wo = (d, -√(1 - |d|²))``: ``lobe = f = eval / |cos θo|`` (0 for ``|d| >= 1``).
        """
        d = check_finite_array("d", d)
        if d.ndim == 0 or d.shape[-1] != 2:
            raise CoronaError(f"d must have shape (..., 2), got {d.shape}")
        r2 = np.sum(d * d, axis=-1)
        cz = np.sqrt(np.maximum(1.0 - r2, 0.0))
        wo = np.concatenate([d, -cz[..., None]], axis=-1)
        val = self._layer_eval(np.array([0.0, 0.0, 1.0]), wo, wavelength)[0]      # the layer alone
        return np.where(r2 < 1.0, val / np.maximum(cz, 1e-300), 0.0)

    # ------------------------------------------------------------------
    # sampling (the plugin's scheme in float64)
    # ------------------------------------------------------------------
    @functools.lru_cache(maxsize=64)
    def _radial(self, which: str, j: int) -> tabulated.RadialTable:
        return tabulated.RadialTable(float(self.rows["ds"]), self.rows["P_f" if which == "f" else "P_b"][j])

    def pdf_lobe(self, which: str, wi, wo, wavelength) -> np.ndarray:
        """Solid-angle density of :meth:`sample_lobe` (``which`` "f" or "b") at one wavelength [nm]:
        the rows' interpolated P over their interpolated total."""
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        s = np.linalg.norm(wo + wi if which == "f" else wo - wi, axis=-1)
        j, t = self._row(wavelength)
        key = "P_f" if which == "f" else "P_b"
        T = self._derived["T_f" if which == "f" else "T_b"]
        val = self._blend(key, j, t, self._x(wavelength), s, cubic=False)
        return val / (T[j] * (1 - t) + T[j + 1] * t)

    def sample_lobe(self, which: str, wi, xi, wavelength: float) -> np.ndarray:
        """Directions ``wo`` (n, 3) of the forward ("f") or backward ("b") lobe for one ``wi`` (3,).

        ``xi`` (n, 3) uniform: xi[:, 0] picks the row, xi[:, 1:] the chord and azimuth.
        """
        wi = np.asarray(wi, dtype=np.float64)
        xi = np.asarray(xi, dtype=np.float64)
        j, t = self._row(float(wavelength))
        j, t = int(j), float(t)
        T = self._derived["T_f" if which == "f" else "T_b"]
        p_next = t * T[j + 1] / ((1 - t) * T[j] + t * T[j + 1])
        rows = np.where(xi[:, 0] < p_next, j + 1, j)
        s = np.empty(len(xi))
        for row in np.unique(rows):
            sel = rows == row
            s[sel] = self._radial(which, int(row)).sample_radius(xi[sel, 1])
        s = np.minimum(s * self.rows["x"][rows] / float(self._x(wavelength)), 2.0)   # the row's chord, scaled
        phi = 2 * np.pi * xi[:, 2]
        axis = -wi if which == "f" else wi
        cos_t = 1 - 0.5 * s * s
        sin_t = s * np.sqrt(np.maximum(1 - 0.25 * s * s, 0.0))
        e1, e2 = frame(axis)
        return (cos_t[:, None] * axis + sin_t[:, None] * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))

    # ------------------------------------------------------------------
    # energy checks
    # ------------------------------------------------------------------
    def directional_albedo(self, cos_theta_i: float, wavelength: float = 550.0, phi_i: float = 0.0,
                           n_phi: int | None = None, pane: bool = True) -> dict:
        """Energy of each component for light from ``cos_theta_i`` (the white furnace).

        The tabulated lobes are integrated over the sphere of directions on
        their own chord grids (``dΩ = s ds dφ``, trapezoid in s at twice the
        table's resolution, midpoint in φ, ``n_phi`` azimuths); on a pane the
        lobes' far-side part also enters the lobe in reflection (:meth:`eval`).

        Parameters
        ----------
        cos_theta_i : float in [-1, 1], not 0
            Signed cosine of ``wi``.
        wavelength : float
            Wavelength [nm].
        phi_i : float
            Azimuth of ``wi`` (the layer is isotropic: the result does not depend on it).
        n_phi : int, optional
            Azimuths of the quadrature (default 256).
        pane : bool
            False: the layer alone (without its substrate).

        Returns
        -------
        dict: :class:`corona.Material`'s keys ``coherent``, ``specular``, ``lobe_transmission``,
        ``lobe_reflection``, ``diffuse`` (0: no opaque part) and ``total`` (<= 1), plus the
        layer's own lobes ``forward`` and ``backward`` (without the pane's factors).
        """
        ci = check_range("cos_theta_i", cos_theta_i, -1.0, 1.0)
        if ci == 0.0:
            raise CoronaError("cos_theta_i=0 is out of range; allowed [-1, 0) or (0, 1]")
        n_phi = 256 if n_phi is None else n_phi
        wi = np.array([math.sqrt(max(0.0, 1 - ci * ci)), 0.0, ci])
        K = self.rows["P_f"].shape[1]
        s = np.linspace(0.0, CHORD_MAX, 2 * K - 1)
        ws = np.full(s.size, s[1] - s[0])
        ws[0] = ws[-1] = 0.5 * ws[0]
        phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
        part = self.substrate_part if pane else BareLayer()
        coherent = float(self.energies(ci, wavelength)["coherent"])
        t_i = float(part.fresnel(ci)[1])
        out = {"coherent": coherent * t_i,
               "specular": float(part.specular_reflection(self, ci, wavelength)),
               "lobe_transmission": 0.0, "lobe_reflection": 0.0, "diffuse": 0.0,
               "forward": 0.0, "backward": 0.0}
        if self.lattice is not None:
            # the orders and the diffuse part on their own quadrature (a Bragg peak is far
            # narrower than the chord grid's azimuths): lattice_nodes, scaled by F_s w
            st = math.sqrt(max(0.0, 1 - ci * ci))
            wi = np.array([st * math.cos(phi_i), st * math.sin(phi_i), ci])
            nodes = self.lattice_nodes(wi, wavelength)
            wo = nodes["wo"]
            e = nodes["energy"] * float(self._slant(ci)) * float(self._lattice_weight(wi, wavelength, ()))
            out["forward"] = float(np.sum(e[nodes["forward"]]))
            out["backward"] = float(np.sum(e[~nodes["forward"]]))
            lobes = [(wo, e)]
        else:
            lobes = []
        for which, axis in (("forward", -wi), ("backward", wi)) if self.lattice is None else ():
            e1, e2 = frame(axis)
            cos_t = 1 - 0.5 * s * s
            sin_t = s * np.sqrt(1 - 0.25 * s * s)
            wo = (cos_t[:, None, None] * axis + sin_t[:, None, None]
                  * (np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2))
            val = self._layer_eval(wi, wo, wavelength)[0]
            dw = (ws * s)[:, None] * (2 * np.pi / n_phi)
            # the chord s = √2 is shared by both lobes: eval assigns it to one, the other's
            # trapezoid end weight there is 0.5 of a thin ring, negligible
            e = val * dw
            out[which] = float(np.sum(e))
            lobes.append((wo, e))
        for wo, e in lobes:
            same = np.sign(wo[..., 2]) == np.sign(ci)
            # each direction's energy as eval splits it (the mirrored part: wo' on the far side)
            through, own, mirrored = part.lobe_factors(np.full(wo.shape[:-1], ci), wo[..., 2], coherent)
            out["lobe_reflection"] += float(np.sum(np.where(same, e * own, e * mirrored)))
            out["lobe_transmission"] += float(np.sum(np.where(same, 0.0, e * through)))
        out["total"] = sum(out[k] for k in ("coherent", "specular", "lobe_transmission", "lobe_reflection",
                                             "diffuse"))
        return out

    def diffuse_transmittance(self, wavelength=550.0, cos_theta_i=None, phi_i=0.0) -> float | np.ndarray:
        """The lobes' energy leaving through the far side (``lobe_transmission`` of
        :meth:`directional_albedo`) for light from ``cos_theta_i`` (None: normal incidence).
        ``phi_i`` is accepted for the shared signature (the layer is isotropic)."""
        ci = 1.0 if cos_theta_i is None else float(cos_theta_i)
        # at normal incidence the lobes are symmetric about the axis: a few azimuths suffice
        return self.directional_albedo(ci, wavelength, n_phi=4 if abs(ci) == 1.0 else 256)["lobe_transmission"]

    @property
    def reflectance(self) -> float:
        """The layer's lobes' energy back to the incident side at normal incidence and 550 nm (the
        backward lobe: glory, fogbow; the layer alone); the spheres absorb what ``ior_imag`` takes."""
        return self.directional_albedo(1.0, 550.0, n_phi=4, pane=False)["lobe_reflection"]

    @property
    def lobe_weight(self) -> float:
        """The lobe's prefactor ``F_a`` (the energy cap ``w`` is part of :meth:`lobe`)."""
        return float(self.area_fraction)

    def lobe_dimensionless_radial(self, u, wavelength: float = 550.0) -> np.ndarray:
        """``v(|u|)`` with ``lobe(d, λ) = F_a (R/λ)² v(2π R |d| / λ)`` at ``wavelength`` [nm]
        (the shared protocol of :class:`corona.Material`; a sphere's pattern is not a function of
        ``u`` alone, so ``v`` belongs to one wavelength).  0 where ``|d| >= 1``."""
        if self.lattice is not None:
            raise CoronaError(f"{self!r}: a fixed lattice's lobe is anisotropic; use lobe_dimensionless(u) "
                              "with u of shape (..., 2)")
        u = np.abs(check_finite_array("u", u))
        lam = float(wavelength) * 1e-3
        rho = u * lam / (2 * np.pi * self.length_scale)
        d = np.stack([np.minimum(rho, 1.0), 0 * rho], -1)
        val = self.lobe(d, float(wavelength))
        return np.where(rho < 1.0, val / (self.area_fraction * (self.length_scale / lam) ** 2), 0.0)

    def lobe_dimensionless(self, u, wavelength: float = 550.0) -> np.ndarray:
        """``v(u)`` at ``u`` (..., 2): the radial one at ``|u|`` for an isotropic layer; on a fixed
        lattice the lobe at ``d = u λ / (2π R)`` itself (0 where ``|d| >= 1``)."""
        u = check_finite_array("u", u)
        if self.lattice is None:
            return self.lobe_dimensionless_radial(np.hypot(u[..., 0], u[..., 1]), wavelength)
        if u.ndim == 0 or u.shape[-1] != 2:
            raise CoronaError(f"u must have shape (..., 2), got {u.shape}")
        lam = float(wavelength) * 1e-3
        d = u * lam / (2 * np.pi * self.length_scale)
        inside = np.sum(d * d, axis=-1) < 1.0
        val = self.lobe(np.where(inside[..., None], d, 0.0), float(wavelength))
        return np.where(inside, val / (self.area_fraction * (self.length_scale / lam) ** 2), 0.0)

    def lobe_tabulated(self, d, wavelength) -> np.ndarray:
        """The lobe as the renderer evaluates it: :meth:`lobe` reads the same tables."""
        return self.lobe(d, wavelength)


def _sphere_from(p: dict) -> Sphere:
    """The factory of ``shape=sphere`` (:mod:`corona.model.registry`)."""
    if p.get("ior") is None and p.get("ior_imag"):
        raise CoronaError(f"ior_imag={p['ior_imag']!r} needs ior=<real part> (the default, water, "
                          "does not absorb)")
    if p["radius"] > SPHERE_RADIUS_MAX:   # the Mie tables' range (their build time)
        raise CoronaError(f"radius={p['radius']!r} is out of range for shape='sphere'; allowed "
                          f"(0, {SPHERE_RADIUS_MAX:g}] µm (larger droplets: use shape='circle', "
                          "whose Fraunhofer corona theirs approaches)")
    ior = None if p.get("ior") is None else complex(p["ior"], p.get("ior_imag") or 0.0)
    return Sphere(p["radius"], ior=ior)


def _sphere_material(shape, process, p: dict, given: dict, substrate) -> SphereMaterial:
    # droplets in air: particles; the mode given must say so.  Every process: a fixed lattice
    # (the plugin's own path, corona.mitsuba.sphere_lattice), a point file's S(q) is radial
    return SphereMaterial(shape, process, mode=given.get("mode") or "particle", substrate=substrate)


# --- the family (corona.model.registry): shape=sphere --------------------------------------------
# edge_width, orientation, angle, aspect and albedo mean nothing for a Mie sphere (a sharp surface,
# the same from every side, reflecting by Mie theory): it does not read them, so a given value gets
# the one unused-parameter warning and is ignored
registry.add_shape(registry.ShapeFamily("sphere", _sphere_from, ("radius", "ior", "ior_imag"), cls=Sphere,
                                        bsdf="corona.mitsuba.sphere:sphere_bsdf_class",
                                        material=_sphere_material, layer=SphereMaterial))
