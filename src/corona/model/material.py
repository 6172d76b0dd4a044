"""The reference material: the whole corona BSDF in numpy, float64 (docs/physics.md#the-model).

This is the readable, exact model that the Mitsuba plugin is tested against.
"""
from __future__ import annotations

import abc
import functools
import math
import warnings

import numpy as np

from corona._validation import CoronaError, CoronaWarning, check_choice, check_finite_array, check_range
from corona.model.layer import decoupled_lobe
from corona.model import render_lobe as rlobe
from corona.model import tabulated
from corona.model.processes import Poisson, Process
from corona.model import registry
from corona.model.shapes import Shape
from corona.model.substrate import BareLayer, GlassPane, double_pass_visibility, layer_substrate

MODES = ("aperture", "particle")

#: Scatterers whose equivalent radius ``sqrt(|A|/π)`` is below this many
#: wavelengths (at the red end of the tables, 830 nm) get one
#: :class:`corona.CoronaWarning` per process: scalar Fraunhofer diffraction
#: loses accuracy there, but the model stays computable.
SMALL_RADIUS_WAVELENGTHS = 2.0

ROW_TOLERANCE = tabulated.ROW_TOLERANCE
PROGRESS_DELAY = tabulated.PROGRESS_DELAY
_small_radius_warned = False


class Layer(abc.ABC):
    """One protocol for every layer of scatterers: what the plugin, the apps and the tests call.

    The flat (Fraunhofer) :class:`Material` and the Mie spheres'
    :class:`corona.model.mie.material.SphereMaterial` implement it with the same signatures and
    result keys (``tests/model/test_material_protocol.py``); each has its own members beyond it
    (a flat layer's one table of ``v(u)``, a Mie layer's rows), none it does not mean.
    ``corona.Material(shape, ...)`` builds the layer class the shape's family registers
    (:func:`corona.model.registry.layer_class`), a flat :class:`Material` otherwise.

    The substrate is one component, chosen when the layer is built: ``substrate_part``
    (:func:`corona.model.substrate.layer_substrate`: none, a pane, a pane with its double pass or
    a mirror), asked for every pane term; ``substrate`` is the pane given (None, a
    :class:`corona.GlassPane`, a :class:`corona.Mirror`).
    """

    @property
    @abc.abstractmethod
    def length_scale(self) -> float:
        """``R`` [µm] of the dimensionless ``u = 2π R |d| / λ``."""

    @property
    @abc.abstractmethod
    def coherent_transmittance(self) -> float:
        """The coherent weight ``C`` at normal incidence (and 550 nm)."""

    @property
    @abc.abstractmethod
    def opaque_fraction(self) -> float:
        """Fraction of the layer that is opaque."""

    @property
    @abc.abstractmethod
    def reflectance(self) -> float:
        """The layer's reflected energy at normal incidence (without the pane)."""

    @property
    @abc.abstractmethod
    def lobe_weight(self) -> float:
        """The lobe's prefactor (``F_a``, capped where the flat layer needs it)."""

    @property
    @abc.abstractmethod
    def render_kind(self) -> str:
        """How the renderer evaluates the lobe ("radial", "analytic", "grid", "table", "mie")."""

    @abc.abstractmethod
    def coherent_weight(self, cos_theta_i, wavelength=550.0) -> float | np.ndarray:
        """The layer's own coherent weight ``C`` for light from ``cos_theta_i`` at ``wavelength``
        [nm], without the pane."""

    @abc.abstractmethod
    def lobe(self, d, wavelength) -> np.ndarray:
        """The transmitted lobe at normal incidence per unit ``d²d`` (no cosine factors)."""

    @abc.abstractmethod
    def lobe_dimensionless(self, u, wavelength: float = 550.0) -> np.ndarray:
        """``v(u)`` at ``u`` (..., 2), ``lobe = F_a (R/λ)² v``."""

    @abc.abstractmethod
    def lobe_dimensionless_radial(self, u, wavelength: float = 550.0) -> np.ndarray:
        """``v(|u|)`` of an isotropic layer."""

    @abc.abstractmethod
    def lobe_tabulated(self, d, wavelength) -> np.ndarray:
        """The lobe as the renderer evaluates it."""

    @abc.abstractmethod
    def eval(self, wi, wo, wavelength, exact: bool = False) -> np.ndarray:
        """The smooth part of the BSDF times the cosine, ``f_s(wi, wo) |cos θo|``."""

    @abc.abstractmethod
    def diffuse_transmittance(self, wavelength=550.0, cos_theta_i=None, phi_i=0.0) -> float | np.ndarray:
        """The lobe's energy through the layer."""

    @abc.abstractmethod
    def directional_albedo(self, cos_theta_i: float, wavelength: float = 550.0, phi_i: float = 0.0,
                           n_phi: int | None = None, pane: bool = True) -> dict:
        """Energy of each component for light from ``cos_theta_i`` (the white furnace)."""

    def coherent_transmission(self, cos_theta_i, wavelength=550.0) -> np.ndarray:
        """Weight of the delta transmission along ``-wi``: ``C T'(θi)``.

        ``C`` is :meth:`coherent_weight` (a flat layer's :attr:`coherent_transmittance` at every
        incidence and wavelength, a Mie layer's ``|1 - F_s s₀(λ)|²``), ``T'`` the pane's
        transmittance (1 without a substrate); ``cos_theta_i`` is signed (+: light from the +z
        side).  The pane does not deflect the beam, and the layer has no specular reflection, so
        this path is exact.
        """
        return self.coherent_weight(cos_theta_i, wavelength) * self.substrate_part.fresnel(cos_theta_i)[1]

    def specular_reflection(self, cos_theta_i, wavelength=550.0) -> np.ndarray:
        """Weight of the delta reflection (the mirror direction of ``wi``).

        0 without a substrate; ``C R(θi) + C² (R'(θi) - R(θi))`` when the light meets the
        layer first (the front face's ``R`` reflects it back through the same place of the
        layer, which it crosses once; the round trips cross it coherently twice:
        :meth:`corona.GlassPane.specular_through_layer`); ``R'(θi)`` when it meets the glass
        first.  ``R' = 2R/(1 + R)`` is the thin pane's reflectance
        (:meth:`corona.GlassPane.reflectance`; a :class:`corona.Mirror`'s at ``wavelength`` [nm]);
        ``C`` the layer's :meth:`coherent_weight`.
        """
        return self.substrate_part.specular_reflection(self, cos_theta_i, wavelength)


class Material(Layer):
    """A layer of scatterers: shape × point process, as apertures or particles.

    Parameters
    ----------
    shape : corona.Shape
        The scatterer (e.g. ``corona.Circle(radius=0.5)``, lengths in µm).
    process : corona.Process, default ``corona.Poisson()``
        The statistics of the scatterers' centres; it fixes the area
        fraction ``F_a = n |A|``.
    mode : {"aperture", "particle"}
        Aperture: the scatterers transmit in an opaque screen,
        ``t(x) = Σ A(x - s_j)``.  Particle: they block light in a clear
        layer, ``t(x) = 1 - Σ A(x - s_j)``.
    albedo : float in [0, 1], default 0
        Diffuse (Lambertian) reflectance of the opaque part of the layer.
    use_cache : bool, default True
        Keep expensive tables in the on-disk cache (:mod:`corona.model.tabulated`).
    substrate : corona.GlassPane, optional
        A thin glass pane the layer sits on (default: none, the layer
        alone).  It adds a specular reflection and weights every other
        component with the pane's Fresnel factors; see :meth:`eval` and
        ``docs/physics.md#the-layer-on-glass-substrateglass``.

    Notes
    -----
    With ``d = (wo + wi).xy`` the projected offset and λ in nm (converted to
    µm inside), the components are (docs/physics.md#the-model)

    * coherent transmission along ``-wi`` with weight ``F_a²`` (aperture) or
      ``(1 - F_a)²`` (particle);
    * the diffraction lobe ``f = F_a T_a(d) T_s(d)``, no cosine factors,
      where ``T_a T_s`` generalises, for random shapes, to the decoupling
      rule ``[⟨|Â|²⟩ + |⟨Â⟩|² (S - 1)] / (⟨|A|⟩ λ²)``;
    * diffuse reflection ``ρ/π`` of the opaque part, weight ``(1 - F_a)``
      (aperture) or ``F_a`` (particle).

    Energy policy: the lobe outside the propagating disk ``|wo.xy| <= 1`` is
    evanescent and dropped (not renormalised).  For processes that allow
    overlaps (Poisson) the lobe integrates to ``F_a`` instead of
    ``F_a (1 - F_a)``; the reflected weight is then capped so that coherent
    + lobe + reflection never exceeds 1, and the lobe's weight ``F_a`` is
    lowered so that coherent + lobe <= 1 (:attr:`lobe_weight`; this only
    bites for Poisson apertures with ``F_a > (√5 - 1)/2 ≈ 0.618``, where
    ``F_a² + F_a > 1``, or measured point sets with overlapping pairs).

    Scatterers smaller than about two wavelengths (equivalent radius
    ``sqrt(|A|/π) < 2 × 830 nm = 1.66 µm``) get one
    :class:`corona.CoronaWarning` per process: Fraunhofer (scalar)
    diffraction loses accuracy there, but the model is still computed.

    References
    ----------
    R. Yang, J. Kim, A. Pediredla, W. Jarosz, "A wave-optics BSDF for
    correlated scatterers", Computer Graphics Forum 44(4), 2025.

    Examples
    --------
    Holes of radius 20 µm in an opaque screen, their centres an equilibrium
    hard-disk fluid at ``F_a = 0.3``.  The coherent beam keeps ``F_a²``; the
    lobe carries ``F_a (1 - F_a) = 0.21`` (the sum rule of non-overlapping
    scatterers; here 0.2097: the evanescent Airy tail ``|d| > 2`` is left out):

    >>> import numpy as np, corona
    >>> m = corona.Material(corona.Circle(radius=20.0), corona.HardDisk(area_fraction=0.3))
    >>> round(m.coherent_transmittance, 12), round(m.diffuse_transmittance(), 3)
    (0.09, 0.21)

    As particles (Babinet): the coherent beam is ``(1 - F_a)²``, the lobe the same:

    >>> p = corona.Material(m.shape, m.process, mode="particle")
    >>> round(p.coherent_transmittance, 12), round(p.diffuse_transmittance(), 3)
    (0.49, 0.21)

    The lobe ``F_a T_a T_s`` at ``d = 0`` is ``F_a (π R²/λ²) S(0)``, with
    ``S(0) = 0.258`` (Henderson's compressibility: 0.258); it vanishes on the
    first dark ring of the Airy pattern, ``2π R |d| / λ = 3.8317``:

    >>> lam = 550.0                                      # nm
    >>> f0 = m.lobe([[0.0, 0.0]], lam)[0]                 # sr⁻¹, no cosine factors
    >>> round(float(f0 / (0.3 * np.pi * 20.0**2 / 0.55**2)), 3)
    0.258
    >>> d1 = 3.8317 * 0.55 / (2 * np.pi * 20.0)
    >>> bool(m.lobe([[d1, 0.0]], lam)[0] < 1e-9 * f0)
    True

    The same material from the plugin's flat parameters (defaults: circles,
    hard disks, particles; here apertures, named):

    >>> from corona.parameters import material_from_parameters
    >>> material_from_parameters(radius=20.0, area_fraction=0.3, mode="aperture")
    Material(Circle(radius=20), HardDisk(area_fraction=0.3), mode='aperture', albedo=0)
    """

    def __new__(cls, shape=None, *args, **kwargs):
        # a family with a layer of its own registers its class (corona.model.registry): a
        # transparent sphere is a Mie scatterer, not a planar profile
        # (docs/physics.md#transparent-droplets-mie-spheres); everything else is this class
        layer = registry.layer_class(shape) if cls is Material else None
        if layer is None:
            return super().__new__(cls)
        built = layer.__new__(layer)
        built.__init__(shape, *args, **kwargs)   # not a Material: Python does not run __init__ again
        return built

    def __init__(self, shape: Shape, process: Process | None = None, mode: str = "aperture",
                 albedo: float = 0.0, use_cache: bool = True, substrate: GlassPane | None = None):
        if not isinstance(shape, Shape):
            raise CoronaError(f"shape={shape!r} is not a corona shape (e.g. corona.Circle(radius=0.5))")
        if process is None:
            process = Poisson()
        if not isinstance(process, Process):
            raise CoronaError(f"process={process!r} is not a corona point process (e.g. corona.Poisson())")
        shape = process.layer_shape(shape)      # a process that sets the sizes gives its own
        self.shape = shape
        self.process = process
        self.mode = check_choice("mode", mode, MODES)
        self.albedo = check_range("albedo", albedo, 0.0, 1.0)
        self.use_cache = bool(use_cache)
        if substrate is not None and not isinstance(substrate, GlassPane):
            raise CoronaError(f"substrate={substrate!r} is not a corona substrate "
                              "(None or corona.GlassPane(ior=1.52, side='front'))")
        self.substrate = substrate
        #: the substrate's part (corona.model.substrate.layer_substrate), chosen once
        self.substrate_part = layer_substrate(substrate)
        self.area_fraction = process.layer_area_fraction(shape)
        _warn_if_small(shape)

    def __repr__(self):
        pane = "" if self.substrate is None else f", substrate={self.substrate!r}"
        return (f"Material({self.shape!r}, {self.process!r}, mode={self.mode!r}, "
                f"albedo={self.albedo:g}{pane})")

    # ------------------------------------------------------------------
    # scalars
    # ------------------------------------------------------------------
    @property
    def isotropic(self) -> bool:
        """True when the lobe depends on |d| only (radial table)."""
        return bool(self.shape.isotropic and self.process.isotropic)

    @property
    def length_scale(self) -> float:
        """``R`` [µm] of the dimensionless ``u = 2π R |d| / λ``."""
        return float(self.shape.length_scale)

    @property
    def coherent_transmittance(self) -> float:
        """Weight of the delta transmission: ``F_a²`` (aperture), ``(1 - F_a)²`` (particle)."""
        fa = self.area_fraction
        return fa**2 if self.mode == "aperture" else (1.0 - fa) ** 2

    @property
    def opaque_fraction(self) -> float:
        """Fraction of the layer that is opaque: ``1 - F_a`` (aperture), ``F_a`` (particle)."""
        return 1.0 - self.area_fraction if self.mode == "aperture" else self.area_fraction

    @functools.cached_property
    def lobe_weight(self) -> float:
        """Prefactor of the lobe: ``F_a``, lowered where coherent + lobe would exceed 1.

        The lobe's plane integral ``F_a ∫ T_a T_s d²d`` is ``F_a (1 - F_a)``
        for non-overlapping scatterers, but ``F_a`` for Poisson (overlaps
        counted twice): Poisson apertures with ``F_a > (√5 - 1)/2 ≈ 0.618``
        would transmit ``F_a² + F_a > 1``, and measured point sets with
        overlapping pairs can exceed ``1 - F_a`` too.  There the weight is
        scaled so that the plane integral is ``1 - coherent_transmittance``.
        """
        fa = self.area_fraction
        budget = max(0.0, 1.0 - self.coherent_transmittance)
        plane = fa * self.plane_integral / (4 * np.pi**2)
        return float(fa if plane <= budget else fa * budget / plane)

    @functools.cached_property
    def plane_integral(self) -> float:
        """``∫ v d²u`` over the whole plane: the tables' integral plus the form
        factor's (evanescent) tail beyond them, ``4π² self_overlap - ∫_table P/R²``
        (Parseval; ``S → 1`` there)."""
        tail = max(0.0, 4 * np.pi**2 * self.shape.self_overlap - float(self._arrays["form_total"]))
        return float(self.table.total + tail)

    @property
    def reflectance(self) -> float:
        """Hemispherical reflectance ``ρ · opaque_fraction``, capped so the total stays <= 1."""
        budget = 1.0 - self.coherent_transmittance - self.diffuse_transmittance()
        return float(max(0.0, min(self.albedo * self.opaque_fraction, budget)))

    # ------------------------------------------------------------------
    # the exact lobe
    # ------------------------------------------------------------------
    def lobe_terms(self, u, radial: bool = False, cell: float | None = None,
                   structure_factor: bool = True) -> dict:
        """The factors of the dimensionless lobe and the lobe itself at ``u``.

        The decoupling rule (docs/physics.md, :func:`corona.model.layer.decoupled_lobe`)::

            v(u) = max(P + C (S - 1), 0) / R²,   q = u / R

        with ``P = ⟨|Â(q)|²⟩/⟨|A|⟩`` the form factor, ``C = |⟨Â(q)⟩|²/⟨|A|⟩``
        the coherent form factor (``C = P`` for identical scatterers), both in
        µm², and ``S(q)`` the structure factor.  The BSDF's lobe is
        ``F_a (R/λ)² v(u)`` (:meth:`lobe`); ``P/λ²`` is ``T_a`` and ``S`` is ``T_s``.

        Parameters
        ----------
        u : array_like
            Dimensionless offsets ``u = 2π R d / λ``: shape (..., 2), or
            ``|u|`` (...) with ``radial=True`` (isotropic materials only).
        radial : bool
            Evaluate the radial forms ``P(|q|)``, ``C(|q|)``, ``S(|q|)``.
        cell : float, optional
            Side of the table cells in ``u`` (2-D only).  For a fixed lattice
            ``S`` is then the mean over each cell and every Bragg peak enters
            ``v`` with its exact weight ``C(G) W_G`` (``C`` at the peak, not at
            the cell centre): ``v = max(P + C (S_bg - 1) + Σ_G C(G) W_G ⟨g_G⟩_cell, 0) / R²``,
            as in the renderer's tables.
        structure_factor : bool
            With ``False`` the cell-mean ``S`` of a fixed lattice, which
            costs a second pass over the peaks and does not enter ``v``, is
            not computed (``S`` is then None); table builds use this.

        Returns
        -------
        dict
            ``P``, ``C`` [µm²], ``S`` and ``v`` (dimensionless), each of the
            shape of ``u`` without its last axis (or of ``|u|``).

        Examples
        --------
        Circles of radius R = 2 µm at ``F_a = 0.3``: ``P(0) = |A| = π R²``,
        ``C = P``, and at the first zero of the Airy pattern (u = 3.8317) the
        lobe vanishes whatever ``S``:

        >>> import corona
        >>> m = corona.Material(corona.Circle(radius=2.0), corona.Poisson(area_fraction=0.3))
        >>> t = m.lobe_terms([0.0, 3.8317], radial=True)
        >>> (t["P"] / np.pi).round(6)                # P(0) = |A| = π R², R² = 4 µm²
        array([4., 0.])
        >>> bool(np.all(t["C"] == t["P"])), t["S"]  # identical circles; Poisson: S = 1
        (True, array([1., 1.]))
        >>> t["v"].round(6)                          # v(0) = P(0) / R² = π
        array([3.141593, 0.      ])
        """
        u = np.asarray(u, dtype=np.float64)
        R = self.length_scale
        q = u / R
        shape, process = self.shape, self.process
        bragg = 0.0
        if radial:
            if not self.isotropic:
                raise CoronaError(f"radial lobe terms need an isotropic material; {self!r} is not")
            P, C = self._form_factors(q, radial=True)
            S = S_smooth = process.structure_factor_radial(q, shape)
        else:
            if q.ndim == 0 or q.shape[-1] != 2:
                raise CoronaError(f"u must have shape (..., 2), got {q.shape}")
            P, C = self._form_factors(q, radial=False)
            if cell is not None and not process.isotropic and hasattr(process, "bragg_cell_mean"):
                S_smooth = process.background_cell_mean(q, cell / R)
                S = S_smooth + process.bragg_cell_mean(q, cell / R) if structure_factor else None
                bragg = process.bragg_cell_mean(q, cell / R, peak_factor=shape.coherent_form_factor)
            else:
                S = S_smooth = process.structure_factor_at(q, shape)
        own = (process.lobe_intensity_radial(q if radial else np.hypot(q[..., 0], q[..., 1]), shape)
               if process.own_lobe else None)
        if own is not None:             # the process's own rule (a breath figure's), not the decoupling
            return {"P": P, "C": C, "S": S, "v": decoupled_lobe(own, 0.0, 1.0, R)}
        v = decoupled_lobe(P, C, S_smooth, R, bragg)
        return {"P": P, "C": C, "S": S, "v": v}

    def lobe_dimensionless(self, u, wavelength: float = 550.0) -> np.ndarray:
        """Exact ``v(u) = [P + C (S - 1)] / R²`` at ``u`` (..., 2) (:meth:`lobe_terms`).

        ``wavelength`` [nm] is part of the one protocol: a planar profile's ``v(u)`` is the same
        at every wavelength (a Mie sphere's is not), so here it changes nothing."""
        return self.lobe_terms(u)["v"]

    def lobe_dimensionless_radial(self, u, wavelength: float = 550.0) -> np.ndarray:
        """Exact radial ``v(|u|)`` for isotropic materials (:meth:`lobe_terms`; ``wavelength`` as
        in :meth:`lobe_dimensionless`)."""
        return self.lobe_terms(u, radial=True)["v"]

    def _form_factors(self, q, radial: bool):
        """(form factor ``⟨|Â|²⟩/⟨|A|⟩``, coherent form factor ``|⟨Â⟩|²/⟨|A|⟩``) [µm²]
        at ``q`` (..., 2), or at ``|q|`` when ``radial``, from one pass over the shape."""
        intensity, amplitude = self.shape._both_radial(q) if radial else self.shape._both(q)
        area = float(self.shape.area)
        return intensity / area, np.abs(amplitude) ** 2 / area

    def _u(self, d, wavelength):
        d = check_finite_array("d", d)
        if d.ndim == 0 or d.shape[-1] != 2:
            raise CoronaError(f"d must have shape (..., 2), got {d.shape}")
        lam = self._wavelength(wavelength)
        scale = 2.0 * np.pi * self.length_scale / lam          # u = 2π R d / λ
        return d * scale[..., None], lam

    @staticmethod
    def _wavelength(wavelength) -> np.ndarray:
        allowed = f"allowed [{tabulated.WAVELENGTH_MIN:g}, {tabulated.WAVELENGTH_MAX:g}] nm"
        try:
            lam = np.asarray(wavelength, dtype=np.float64)
        except (TypeError, ValueError):
            raise CoronaError(f"wavelength={wavelength!r} is not a number; {allowed}") from None
        ok = (lam >= tabulated.WAVELENGTH_MIN) & (lam <= tabulated.WAVELENGTH_MAX)   # False for NaN
        if not np.all(ok):
            bad = float(np.ravel(lam[~ok] if lam.ndim else lam)[0])
            raise CoronaError(f"wavelength={bad!r} is out of range; {allowed}")
        return lam * 1e-3  # nm -> µm

    def lobe(self, d, wavelength) -> np.ndarray:
        """Diffraction-lobe BSDF value ``F_a T_a(d) T_s(d)`` (no cosine factors).

        Parameters
        ----------
        d : array (..., 2)
            Projected offsets ``(wo + wi).xy``.
        wavelength : float or array broadcastable to ``d.shape[:-1]``
            Wavelength [nm].
        """
        u, lam = self._u(d, wavelength)
        R = self.length_scale
        if self.isotropic:
            v = self.lobe_dimensionless_radial(np.hypot(u[..., 0], u[..., 1]))
        else:
            v = self.lobe_dimensionless(u)
        return self.lobe_weight * (R / lam) ** 2 * v        # F_a (R/λ)² v(u)

    # ------------------------------------------------------------------
    # the table (what the renderer evaluates and samples)
    # ------------------------------------------------------------------
    def table_params(self) -> dict:
        return {"shape": tabulated.identity(self.shape), "process": tabulated.identity(self.process),
                "isotropic": self.isotropic, "du": tabulated.RADIAL_DU,
                "max_samples": tabulated.RADIAL_MAX_SAMPLES, "grid": tabulated.GRID2D_SIZE,
                "wavelength_min": tabulated.WAVELENGTH_MIN, "render": self.render_kind,
                "supersample": rlobe.SUPERSAMPLE}

    @functools.cached_property
    def _arrays(self) -> dict:
        """Every table of this material, from the on-disk cache or built."""
        return tabulated.cached(self.table_params(), self._build_table, use_cache=self.use_cache)

    @functools.cached_property
    def table(self) -> tabulated.RadialTable | tabulated.GridTable:
        """The dimensionless lobe table ``v(u)`` (cached on disk) that the
        renderer samples (and, for radial and lattice tables, evaluates)."""
        return tabulated.table_from_arrays(self._arrays)

    @functools.cached_property
    def analytic_terms(self):
        """The shape as closed-form outlines (:func:`corona.model.render_lobe.analytic_terms`), or None."""
        return rlobe.analytic_terms(self.shape)

    @property
    def render_kind(self) -> str:
        """How the renderer evaluates the lobe: "radial", "analytic", "grid" or
        "table" (see :mod:`corona.model.render_lobe`)."""
        if self.isotropic:
            return "radial"
        if not self.process.isotropic:
            return "table"
        return "analytic" if self.analytic_terms is not None else "grid"

    @functools.cached_property
    def render_lobe(self) -> rlobe.RenderLobe:
        """The lobe ``v(u)`` as the renderer evaluates it (:mod:`corona.model.render_lobe`)."""
        a = self._arrays
        kind = self.render_kind
        rl = rlobe.RenderLobe(kind, self.length_scale, float(self.shape.area))
        if kind == "radial":
            rl.radial = self.table
        elif kind == "table":
            rl.table = self.table
        else:
            if "s_minus_one" in a:
                rl.s_du, rl.s_minus_one = float(a["s_du"]), np.array(a["s_minus_one"])
            if kind == "analytic":
                rl.terms = self.analytic_terms
            else:
                t = self.table
                rl.P = rlobe.CubicGrid(t.lo, t.cell, np.array(a["P_coef"]))
                rl.C = rlobe.CubicGrid(t.lo, t.cell, np.array(a["C_coef"])) if "C_coef" in a else None
        return rl

    def radial_s_minus_one(self) -> tuple[float, np.ndarray]:
        """``(s_du, S(|u|/R) - 1 at |u| = i·s_du)``: the isotropic process's structure factor on the
        step of the radial tables up to ``u_max`` (what :attr:`render_lobe` holds for anisotropic shapes)."""
        R = self.length_scale
        u_max = tabulated.u_max_for(R)
        du_target = min(tabulated.RADIAL_DU, 0.25 * getattr(self.process, "q_step", np.inf) * R)
        ns = min(int(np.ceil(u_max / du_target)) + 1, tabulated.RADIAL_MAX_SAMPLES)
        s_du = u_max / (ns - 1)
        return s_du, self.process.structure_factor_radial(np.arange(ns) * s_du / R, self.shape) - 1.0

    def _build_table(self) -> dict:
        u_max = tabulated.u_max_for(self.length_scale)
        R = self.length_scale
        # a process whose S is itself piecewise linear on a q grid (a measured
        # point set) gets a u step of a quarter of that grid's, so the kinks cost
        # little in the linear tables (RADIAL_DU otherwise)
        du_target = min(tabulated.RADIAL_DU, 0.25 * getattr(self.process, "q_step", np.inf) * R)
        if self.isotropic:
            n = int(np.ceil(u_max / du_target)) + 1
            n = min(n, tabulated.RADIAL_MAX_SAMPLES)
            du = u_max / (n - 1)
            u = np.arange(n) * du
            # v and the form factor P/R² in one pass over the shape (P's integral: the tail)
            vp = self._in_chunks(lambda x: (lambda t: np.stack([t["v"], t["P"] / R**2], -1))(
                self.lobe_terms(x, radial=True)), u)
            out = tabulated.RadialTable(du, vp[:, 0]).arrays()
            out["form_total"] = np.array(tabulated.RadialTable(du, vp[:, 1]).total)
            return out
        n = tabulated.GRID2D_SIZE
        u_range = min(u_max, 0.25 * n / 2)  # cells no coarser than 0.25 in u
        cell = 2 * u_range / n
        c = -u_range + (np.arange(n) + 0.5) * cell
        ux, uy = np.meshgrid(c, c, indexing="xy")
        u = np.stack([ux, uy], -1)
        q = u / R
        kind = self.render_kind
        half = (n + 1) // 2       # v(-u) = v(u): the rows below the centre mirror those above
        if kind == "analytic":
            inten, amp = rlobe.terms_amplitudes(self.analytic_terms, q[:half])
            P, C = np.empty((n, n)), np.empty((n, n))
            P[:half], C[:half] = inten / self.shape.area, np.abs(amp) ** 2 / self.shape.area
            P[half:], C[half:] = P[:n - half][::-1, ::-1], C[:n - half][::-1, ::-1]
        elif self.shape.isotropic:
            P, C = self._grid_form_factors_radial(n, cell / R)
        else:   # in blocks, with a progress bar for slow shapes (half the grid: v(-u) = v(u))
            P, C = np.moveaxis(self._in_chunks(lambda x: np.stack(self._form_factors(x, radial=False), -1), q),
                               -1, 0)
        edge = np.ones(n)
        edge[0] = edge[-1] = 0.5
        form_total = float(np.sum(P * np.outer(edge, edge)) * cell**2 / R**2)   # trapezoid = bilinear
        if kind == "table":
            # Bragg peaks narrower than a cell: each vertex carries the cell mean of
            # the lobe, P + C (S_bg - 1) + Σ_G C(G) W_G ⟨g_G⟩_cell, i.e. every peak
            # with its exact weight C(G) W_G (C at the peak, not at the cell centre)
            if hasattr(self.process, "bragg_cell_mean"):
                S_bg = self.process.background_cell_mean(q, cell / R)
                bragg = self.process.bragg_cell_mean(q, cell / R, peak_factor=self.shape.coherent_form_factor)
                v = decoupled_lobe(P, C, S_bg, R, bragg)
            else:
                v = decoupled_lobe(P, C, self.process.structure_factor_at(q, self.shape), R)
            out = tabulated.GridTable(u_range, v).arrays()
            out["form_total"] = np.array(form_total)
            return out
        # isotropic process: S - 1 on the radial tables' step, the sampling grid of v
        s_du, s1 = self.radial_s_minus_one()
        poisson = bool(np.all(s1 == 0.0))
        rl = rlobe.RenderLobe(kind, R, float(self.shape.area), terms=self.analytic_terms or [],
                                    s_du=s_du, s_minus_one=None if poisson else s1)
        if kind == "analytic" and u_max > u_range * (1 + 1e-9):
            # the analytic lobe reaches beyond the grid: sample it from a table
            # uniform in t = u / (1 + |u|/c) instead (cells of 0.25 near u = 0,
            # the outer vertices at u_max), each vertex the local mean of the
            # density in t over its cell (positive wherever the lobe is)
            g = tabulated.GridTable(u_range, np.zeros((2, 2)), tabulated.warp_for(c[-1], u_max))   # last vertex at u_max
            k = rlobe.SUPERSAMPLE
            sub = ((np.arange(k) + 0.5) / k - 0.5) * cell
            acc = np.zeros((n, n))
            for sy in sub:       # the sub-samples are symmetric about each vertex: acc is even too
                for sx in sub:
                    tx, ty = np.meshgrid(c + sx, c[:half] + sy, indexing="xy")
                    uu = g.to_u(np.stack([tx, ty], -1))
                    acc[:half] += rl.eval(uu) * g.jacobian(uu)
            acc[half:] = acc[:n - half][::-1, ::-1]
            out = tabulated.GridTable(u_range, acc / k**2, g.warp).arrays()
        else:
            v = decoupled_lobe(P, C, 1.0 + rl.s1(np.hypot(ux, uy)), R)
            out = tabulated.GridTable(u_range, v).arrays()
        out["form_total"] = np.array(form_total)
        if not poisson:
            out["s_du"], out["s_minus_one"] = np.array(s_du), s1
        if kind == "grid":
            out["P_coef"] = rlobe.CubicGrid.from_values(c[0], cell, P / R**2).coef
            if not self.shape._deterministic:
                out["C_coef"] = rlobe.CubicGrid.from_values(c[0], cell, C / R**2).coef
        return out


    # ------------------------------------------------------------------
    # rows over the area fraction (layers whose F_a varies over a surface)
    # ------------------------------------------------------------------
    def _table_grid(self):
        """The u samples of the radial :attr:`table` and its step."""
        u_max = tabulated.u_max_for(self.length_scale)
        n = min(int(np.ceil(u_max / tabulated.RADIAL_DU)) + 1, tabulated.RADIAL_MAX_SAMPLES)
        du = u_max / (n - 1)
        return np.arange(n) * du, du

    def _row_values(self, u, area_fractions):
        """Radial ``v(u)`` of this material at each area fraction (P and C computed once)."""
        R = self.length_scale
        q = u / R
        P, C = self._form_factors(q, radial=True)
        out = []
        for fa in area_fractions:
            S = 1.0 if fa <= 0.0 else self.process.with_area_fraction(float(fa)).structure_factor_radial(q, self.shape)
            out.append(decoupled_lobe(P, C, S, R))
        return out

    def area_fraction_rows(self, lo: float = 0.0, hi: float | None = None,
                           tolerance: float = ROW_TOLERANCE, max_rows: int = 160, include=()):
        """Radial lobe tables at rows of area fraction, for layers whose ``F_a`` varies.

        Between two rows the renderer interpolates the dimensionless lobe
        linearly in ``F_a``.  The rows cover ``[lo, hi]`` (default: 0 to
        :meth:`Process.area_fraction_limit`); they start at the process's own
        tabulation nodes and are bisected until the interpolated lobe at every
        interval's midpoint is within ``tolerance`` (relative) of the exact
        one wherever that exceeds 1e-3 of its peak.

        ``include`` adds rows at these area fractions (e.g. a layer's own value,
        where the renderer is then exact).

        Returns
        -------
        area_fractions : ndarray (n_rows,)
            Increasing, covering ``[lo, hi]``.
        tables : list of RadialTable or GridTable
            The lobe table at each row.
        error : float
            The largest relative midpoint error of the final rows.
        """
        if not (self.process.varying_area_fraction and self.isotropic):
            # anisotropic lobes (corona.model.render_lobe) and processes whose geometry F_a sets: one row
            return np.array([self.area_fraction]), [self.table], 0.0
        limit = float(self.process.area_fraction_limit(self.shape))
        hi = limit if hi is None else min(float(hi), limit)
        lo = max(0.0, min(float(lo), hi))
        include = sorted(float(f) for f in include if lo <= f <= hi)
        arrays = tabulated.cached({**self.table_params(), "rows": [lo, hi], "tolerance": tolerance,
                                "max_rows": max_rows, "include": include},
                               lambda: self._build_rows(lo, hi, tolerance, max_rows, include),
                               use_cache=self.use_cache)
        fas = np.asarray(arrays["area_fraction"], dtype=np.float64)
        vals = np.asarray(arrays["values"], dtype=np.float64)
        geo = float(arrays["geometry"])
        return fas, [tabulated.RadialTable(geo, v) for v in vals], float(arrays["error"])

    def _build_rows(self, lo, hi, tolerance, max_rows, include=()):
        u, geo = self._table_grid()
        nodes = np.concatenate([self.process.area_fraction_nodes(self.shape), include]).astype(np.float64)
        inner = nodes[(nodes > lo) & (nodes < hi)]
        # the nodes bracketing [lo, hi] too, so interpolation there follows the process's own rows
        below, above = nodes[nodes <= lo], nodes[nodes >= hi]
        ends = [below.max() if below.size else lo, above.min() if above.size else hi]
        fas = np.unique(np.concatenate([ends, inner, [lo, hi]]))
        vals = dict(zip(fas.tolist(), self._row_values(u, fas)))

        def error(lerp, e):          # relative, where the lobe is above 1e-3 of its peak
            sel = e > 1e-3 * e.max()
            return np.max(np.abs(lerp[sel] - e[sel]) / e[sel]) if np.any(sel) else 0.0

        keys, worst = tabulated.bisect_rows(vals, lambda mids: self._row_values(u, mids), error,
                                         tolerance, max_rows)
        return {"area_fraction": np.array(keys), "values": np.stack([vals[k] for k in keys]).astype(np.float32),
                "geometry": np.array(geo), "error": np.array(worst)}

    def _grid_form_factors_radial(self, n: int, step: float):
        """(P, C) of an isotropic shape (a circle, a random orientation, their size spreads) on the
        centred ``n`` × ``n`` grid of vertices ``q = (2i + 1 - n, 2j + 1 - n) step/2`` of a 2-D table
        (an anisotropic process: a lattice): they depend on ``|q|`` only, so they are evaluated
        radially (the shape's radial path, as its radial tables are) once per distinct distance of
        a vertex from the centre, about a fifth of the vertices.  A random orientation's 2-D path
        would average the orientations at every vertex (the build times, before and after:
        ``benchmarks/results/slow_inputs_lattice*.json``); the two paths agree to the orientation
        quadrature's own error."""
        odd = 2 * np.arange(n) + 1 - n
        key = odd[None, :] ** 2 + odd[:, None] ** 2
        distinct, where = np.unique(key, return_inverse=True)
        q = np.sqrt(distinct) * (0.5 * step)
        PC = self._in_chunks(lambda x: np.stack(self._form_factors(x, radial=True), -1), q)
        where = where.reshape(n, n)
        return PC[where, 0], PC[where, 1]

    def _in_chunks(self, f, points) -> np.ndarray:
        """``f(points)`` evaluated in blocks, with a progress bar (on stderr) when
        the table takes longer than ``PROGRESS_DELAY`` seconds.

        ``points`` is (n,) (radial) or a centred (rows, cols, 2) grid (the
        table's vertices, ``u[n-1-i, n-1-j] = -u[i, j]``).  Radial blocks run
        from the largest u down, so that a process caching its structure factor
        up to the largest q (a measured point set) computes it once.  On a grid
        only the first half of the rows is evaluated: the lobe of a real
        profile and a real point pattern is even, ``v(-u) = v(u)``
        (``Â(-q) = Â(q)*``, ``S(-q) = S(q)``), so the other half is its mirror.
        """
        from tqdm import tqdm
        points = np.asarray(points)
        n = points.shape[0]
        grid = points.ndim == 3
        rows = (n + 1) // 2 if grid else n
        per_block = max(1, 8192 // (points.shape[1] if grid else 1))
        starts = list(range(0, rows, per_block))
        if not grid:
            starts.reverse()
        out = None
        with tqdm(total=rows * (points.shape[1] if grid else 1), unit="pt", leave=False,
                  delay=PROGRESS_DELAY, desc="corona: building the lobe table") as bar:
            for a in starts:
                b = min(a + per_block, rows)
                block = np.asarray(f(points[a:b]))
                if out is None:
                    out = np.empty((n,) + block.shape[1:], dtype=block.dtype)
                out[a:b] = block
                bar.update(block.shape[0] * (block.shape[1] if grid else 1))
        if grid:
            out[rows:] = out[:n - rows][::-1, ::-1]
        return out

    def lobe_tabulated(self, d, wavelength) -> np.ndarray:
        """The lobe as the renderer evaluates it (:attr:`render_lobe`)."""
        u, lam = self._u(d, wavelength)
        return self.lobe_weight * (self.length_scale / lam) ** 2 * self.render_lobe.eval(u)

    @property
    def tabulated_transmittance(self) -> float:
        """The diffuse transmittance the renderer holds: ``F_a ∫ v d²u / 4π²``
        over its tables (``|u| <= u_max``, i.e. ``|d| <= 2.1`` at 360 nm, so
        every propagating direction at every incidence and wavelength), by the
        sampling table's quadrature.  The plugin chooses between its
        components with it."""
        return self.lobe_weight * self.table.total / (4 * np.pi**2)

    def diffuse_transmittance(self, wavelength=550.0, cos_theta_i=None, phi_i=0.0) -> float | np.ndarray:
        """Integral of the lobe (the diffuse transmittance).

        With ``cos_theta_i=None``: over the whole d plane,
        ``F_a ∫ v d²u / (4π²)`` (wavelength-independent): the tables' integral
        plus the form factor's tail beyond them, ``4π² ∫T_a - ∫_table P/R²``
        (Parseval: ``∫T_a d²d = self_overlap``; ``S → 1`` there), which is
        evanescent (``|d| > 2``).  This is ``F_a (1 - F_a)`` for hard,
        non-overlapping scatterers (the sum rule), ``F_a`` for Poisson.  With an
        incident direction (``cos_theta_i``, azimuth ``phi_i`` [rad]): only over
        the propagating directions ``|d - wi.xy| <= 1``, i.e. the energy the
        BSDF transmits diffusely at that wavelength [nm].
        """
        t = self.table
        fa = self.lobe_weight
        if cos_theta_i is None:
            return fa * self.plane_integral / (4 * np.pi**2)
        lam = self._wavelength(wavelength)
        ct = check_range("cos_theta_i", cos_theta_i, 0.0, 1.0)
        s = np.sqrt(max(0.0, 1.0 - ct * ct))
        d_per_u = lam / (2 * np.pi * self.length_scale)   # |d| per unit u
        if self.isotropic:
            u = np.arange(t.values.size) * t.du
            rho = u[None, :] * np.atleast_1d(d_per_u)[:, None]
            frac = _arc_fraction_inside(rho, s)
            integrand = 2 * np.pi * u[None, :] * t.values[None, :] * frac
            val = np.trapezoid(integrand, u, axis=-1) * fa / (4 * np.pi**2)
        else:
            c = t.to_u(t.centres())
            ux, uy = np.meshgrid(c, c, indexing="xy")
            # trapezoid weights: exact for the bilinear table (the same integral as t.total)
            edge = np.ones(t.n)
            edge[0] = edge[-1] = 0.5
            weights = np.outer(edge, edge) * t.cell**2
            out = []
            for dpu in np.atleast_1d(d_per_u):
                dx, dy = ux * dpu - s * np.cos(phi_i), uy * dpu - s * np.sin(phi_i)
                inside = dx * dx + dy * dy <= 1.0
                out.append(np.sum(t.values * inside * weights))
            val = np.asarray(out) * fa / (4 * np.pi**2)
        return float(val[0]) if np.ndim(wavelength) == 0 else val

    def sample(self, xi, wavelength) -> np.ndarray:
        """Importance-sample ``d`` (..., 2) from the lobe table by CDF inversion.

        ``xi`` (..., 2) uniform in [0, 1)²; the density is :meth:`pdf`.
        """
        xi = check_finite_array("xi", xi)
        if xi.ndim == 0 or xi.shape[-1] != 2:
            raise CoronaError(f"xi must have shape (..., 2), got {xi.shape}")
        if np.any(xi < 0) or np.any(xi > 1):
            raise CoronaError(f"xi={float(xi[(xi < 0) | (xi > 1)][0])!r} is out of range; allowed [0, 1]")
        lam = self._wavelength(wavelength)
        u = self.table.sample(xi)
        return u * (lam / (2 * np.pi * self.length_scale))[..., None]

    def pdf(self, d, wavelength) -> np.ndarray:
        """Density of :meth:`sample` in the d plane: ``p_d = p_u (2π R / λ)²``."""
        u, lam = self._u(d, wavelength)
        t = self.table
        pu = t.pdf(np.hypot(u[..., 0], u[..., 1])) if self.isotropic else t.pdf(u)
        return pu * (2 * np.pi * self.length_scale / lam) ** 2

    # ------------------------------------------------------------------
    # the whole BSDF: the layer, alone or on its pane (docs/physics.md#the-layer-on-glass-substrateglass)
    # ------------------------------------------------------------------
    @functools.cached_property
    def double_pass_visibility(self) -> float:
        """Visibility cap of the coherent double pass (:func:`corona.model.substrate.double_pass_visibility`)."""
        lobe = self.lobe_weight * self.plane_integral / (4 * np.pi**2)
        return double_pass_visibility(self.coherent_transmittance, lobe, self.reflectance)

    def coherent_weight(self, cos_theta_i, wavelength=550.0) -> float | np.ndarray:
        """The layer's own coherent weight ``C`` (:attr:`coherent_transmittance`) for light from
        ``cos_theta_i`` at ``wavelength`` [nm], without the pane: the same for every incidence and
        wavelength here (a Mie layer's depends on both)."""
        return self.coherent_transmittance

    def eval(self, wi, wo, wavelength, exact: bool = False) -> np.ndarray:
        """The smooth part of the BSDF times the cosine, ``f_s(wi, wo) |cos θo|``.

        Parameters
        ----------
        wi, wo : array (..., 3)
            Unit vectors in the layer's frame (z the normal), ``wi`` towards
            where the light comes from (Mitsuba's convention).
        wavelength : float or array
            Wavelength [nm].
        exact : bool
            Part of the one protocol: a layer that reads its lobe from tables (Mie spheres)
            evaluates the theory instead.  A flat layer's ``eval`` is the exact model either
            way (:meth:`lobe_tabulated` is the renderer's).

        Notes
        -----
        With ``f(d)`` the lobe (:meth:`lobe`, ``d = (wo + wi).xy``), ``C`` the
        coherent transmittance, ``ρ`` the opaque part's :attr:`reflectance`
        and ``R'``, ``T' = 1 - R'`` the pane's reflectance and transmittance
        at ``θi`` or ``θo`` (``R' = 0`` without a substrate):

        ==================  ===============================  =====================
        component           light meets the layer first      meets the glass first
        ==================  ===============================  =====================
        lobe, transmitted   ``f T'(θo)``                     ``T'(θi) f``
        lobe, reflected     ``f [R_min + C (P_i + P_o)]``    0
        diffuse reflection  ``ρ / π``                        ``T'(θi) ρ/π T'(θo)``
        ==================  ===============================  =====================

        ``R_min = min(R(θi), R(θo))`` is the front face's own Fresnel reflectance (a layer on
        the face is crossed once on that path), ``P = R' - R`` the round trips through the glass.
        On a pane with a thickness (always on a :class:`corona.Mirror`) the reflected lobe's
        ``C (P_i + P_o)`` gains the double pass's interference ``2 C V Q``
        (:meth:`corona.GlassPane.reflected_lobe_factor`: Quetelet rings); a mirror
        transmits nothing.  The delta parts are :meth:`coherent_transmission` and
        :meth:`specular_reflection`.  Paths that meet the layer again after a
        reflection off the pane are kept only where they cross the layer
        coherently once (the reflected lobe); ``docs/physics.md#the-layer-on-glass-substrateglass`` lists what
        is dropped.  Every entry is symmetric under ``wi ↔ wo`` with the sides
        swapped (reciprocity).
        """
        wi = check_finite_array("wi", wi)
        wo = check_finite_array("wo", wo)
        if wi.shape[-1:] != (3,) or wo.shape[-1:] != (3,):
            raise CoronaError(f"wi and wo must have shape (..., 3), got {wi.shape} and {wo.shape}")
        wi, wo = np.broadcast_arrays(wi, wo)
        ci, co = wi[..., 2], wo[..., 2]
        transmit = ci * co < 0
        reflect = ci * co > 0
        pane = self.substrate_part
        first = pane.layer_first(ci)
        lam = self._wavelength(wavelength) * 1e3                 # checked, nm
        _, ti = pane.fresnel(ci, lam)
        _, to = pane.fresnel(co, lam)
        f = self.lobe(wi[..., :2] + wo[..., :2], wavelength)
        lobe_t = f * np.where(first, to, ti)
        lobe_r = f * np.where(first, pane.reflected_lobe_factor(self, ci, co, lam), 0.0)
        diffuse = self.reflectance / np.pi * np.where(first, 1.0, ti * to)
        value = np.where(transmit, lobe_t, 0.0) + np.where(reflect, lobe_r + diffuse, 0.0)
        return value * np.abs(co)

    def _lobe_integrals(self, wavelength: float, wi_xy, weights, n_phi: int = 512) -> list:
        """``∫ f(d) g(|cos θo|) d²d`` over the propagating ``|d - wi.xy| <= 1`` for each g.

        The lobe is the tabulated one (what the renderer evaluates):
        isotropic tables on their radial grid × ``n_phi`` azimuths, 2D tables
        on their vertices with trapezoid weights.
        """
        t = self.table
        lam = float(self._wavelength(wavelength))
        d_per_u = lam / (2 * np.pi * self.length_scale)
        wx, wy = float(wi_xy[0]), float(wi_xy[1])
        out = np.zeros(len(weights))
        scale = self.lobe_weight / (4 * np.pi**2)

        def accumulate(dx, dy, w):   # w: table weight × measure of each point
            ox, oy = dx - wx, dy - wy
            r2 = ox * ox + oy * oy
            inside = r2 <= 1.0
            co = np.sqrt(np.maximum(0.0, 1.0 - r2))
            for k, g in enumerate(weights):
                out[k] += np.sum(w * np.where(inside, g(co), 0.0))

        if self.isotropic:
            u_reach = (1.0 + np.hypot(wx, wy)) / d_per_u
            n = min(t.values.size, int(np.ceil(u_reach / t.du)) + 2)
            u = np.arange(n) * t.du
            vals = t.values[:n]
            trap = np.full(n, t.du)
            trap[0] = trap[-1] = 0.5 * t.du
            phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
            cp, sp = np.cos(phi), np.sin(phi)
            for lo in range(0, n, 2048):
                uu = u[lo:lo + 2048, None]
                w = (vals[lo:lo + 2048] * uu[:, 0] * trap[lo:lo + 2048])[:, None] * (2 * np.pi / n_phi)
                accumulate(uu * d_per_u * cp, uu * d_per_u * sp, np.broadcast_to(w, (uu.shape[0], n_phi)))
        else:
            c = t.centres()
            edge = np.ones(t.n)
            edge[0] = edge[-1] = 0.5
            ux, uy = np.meshgrid(c, c, indexing="xy")
            accumulate(ux * d_per_u, uy * d_per_u, t.values * np.outer(edge, edge) * t.cell**2)
        return list(out * scale)

    def directional_albedo(self, cos_theta_i: float, wavelength: float = 550.0, phi_i: float = 0.0,
                           n_phi: int | None = None, pane: bool = True) -> dict:
        """Energy of each component for light arriving from ``wi`` (the white furnace).

        Parameters
        ----------
        cos_theta_i : float in [-1, 1], not 0
            Signed cosine of ``wi`` (+: from the +z side).
        wavelength : float
            Wavelength [nm].
        phi_i : float
            Azimuth of ``wi`` [rad] (matters for anisotropic lobes).
        n_phi : int, optional
            Azimuths of the quadrature of a radial table (default 512; 2-D tables are
            integrated on their vertices and ignore it).
        pane : bool
            False: the layer alone, without its substrate.

        Returns
        -------
        dict with ``coherent``, ``specular``, ``lobe_transmission``,
        ``lobe_reflection``, ``diffuse`` and their ``total`` (<= 1): the
        integrals over ``wo`` of the components of :meth:`eval` plus the delta
        weights, the lobes integrated numerically from the table; and the
        layer's own lobes without the pane's factors, ``forward`` (through the
        layer) and ``backward`` (back to the incident side: 0 for a planar
        screen, whose Fraunhofer lobe is transmitted only), not in ``total``.
        The keys are the same for every material.
        """
        part = self.substrate_part if pane else BareLayer()
        n_phi = 512 if n_phi is None else int(check_range("n_phi", n_phi, 1, 1e6))
        ci = check_range("cos_theta_i", cos_theta_i, -1.0, 1.0)
        if ci == 0.0:
            raise CoronaError("cos_theta_i=0 is out of range; allowed [-1, 0) or (0, 1] (grazing light "
                              "carries no energy)")
        s = np.sqrt(max(0.0, 1.0 - ci * ci))
        wi_xy = (s * np.cos(phi_i), s * np.sin(phi_i))
        first = bool(part.layer_first(ci))
        ri, ti = (float(x) for x in part.fresnel(ci, wavelength))
        c = self.coherent_transmittance

        def pane_t(co):
            return part.fresnel(co, wavelength)[1]

        def pane_r(co):   # min(R_i, R_o) + C (P_i + P_o) (a thick pane's interference: below)
            return part.front_and_round_trips(ci, co, wavelength, c)

        plain, transmitted, reflected = self._lobe_integrals(wavelength, wi_xy, [np.ones_like, pane_t, pane_r],
                                                             n_phi)
        out = {"coherent": c * ti, "specular": float(part.specular_reflection(self, ci, wavelength))}
        if first:
            out["lobe_transmission"] = transmitted                  # ∫ f T'(θo)
            # ∫ f [R_min + C (P_i + P_o)], + 2 V C ∫ f Q on a pane with a thickness
            out["lobe_reflection"] = part.reflected_lobe_energy(self, reflected, ci, wavelength, phi_i)
            out["diffuse"] = self.reflectance
        else:
            out["lobe_transmission"] = ti * plain
            out["lobe_reflection"] = 0.0
            # ∫ T'(θi) ρ/π T'(θo) cos θo dω = T'(θi) ρ 2∫₀¹ T'(μ) μ dμ
            mu, w = np.polynomial.legendre.leggauss(64)
            mu, w = 0.5 * (mu + 1.0), 0.5 * w
            out["diffuse"] = ti * self.reflectance * float(2.0 * np.sum(w * mu * part.fresnel(mu)[1]))
        out = {k: float(v) for k, v in out.items()}
        out["total"] = sum(out.values())
        out["forward"], out["backward"] = float(plain), 0.0
        return out


def _warn_if_small(shape) -> None:
    """One :class:`CoronaWarning` per process for scatterers below ~2 wavelengths."""
    global _small_radius_warned
    if _small_radius_warned:
        return
    limit = SMALL_RADIUS_WAVELENGTHS * tabulated.WAVELENGTH_MAX * 1e-3          # µm
    r_eq = math.sqrt(float(shape.area) / math.pi)
    if r_eq < limit:
        warnings.warn(f"{shape!r}: equivalent radius sqrt(|A|/pi) = {r_eq:.3g} µm is below "
                      f"{SMALL_RADIUS_WAVELENGTHS:g} wavelengths ({limit:g} µm at "
                      f"{tabulated.WAVELENGTH_MAX:g} nm); Fraunhofer diffraction loses accuracy there "
                      "(warned once per process)", CoronaWarning, stacklevel=3)
        _small_radius_warned = True


def _arc_fraction_inside(rho, s):
    """Fraction of the circle |d| = rho inside the unit disk centred at distance s."""
    rho = np.asarray(rho, dtype=np.float64)
    out = np.zeros_like(rho)
    full = rho + s <= 1.0
    out[full] = 1.0
    part = ~full & (rho < 1.0 + s) & (rho > 0)
    if s > 0:
        c = (rho[part] ** 2 + s * s - 1.0) / (2 * rho[part] * s)
        out[part] = np.arccos(np.clip(c, -1.0, 1.0)) / np.pi
    return out
