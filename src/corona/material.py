"""The reference material: the whole corona BSDF in numpy, float64 (DESIGN §3).

This is the readable, exact model that the Mitsuba plugin is tested against.
"""
from __future__ import annotations

import functools
import math
import warnings

import numpy as np

from . import tables
from ._validation import CoronaError, CoronaWarning, check_choice, check_finite_array, check_range
from .processes import Poisson, Process
from .shapes import Shape

MODES = ("aperture", "particle")

#: Scatterers whose equivalent radius ``sqrt(|A|/π)`` is below this many
#: wavelengths (at the red end of the tables, 830 nm) get one
#: :class:`corona.CoronaWarning` per process: scalar Fraunhofer diffraction
#: loses accuracy there, but the model stays computable.
SMALL_RADIUS_WAVELENGTHS = 2.0
#: Table builds longer than this [s] show a progress bar on stderr.
PROGRESS_DELAY = 2.0
_small_radius_warned = False


class Material:
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
        Keep expensive tables in the on-disk cache (:mod:`corona.tables`).

    Notes
    -----
    With ``d = (wo + wi).xy`` the projected offset and λ in nm (converted to
    µm inside), the components are (DESIGN §3)

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
    """

    def __init__(self, shape: Shape, process: Process | None = None, mode: str = "aperture",
                 albedo: float = 0.0, use_cache: bool = True):
        if not isinstance(shape, Shape):
            raise CoronaError(f"shape={shape!r} is not a corona shape (e.g. corona.Circle(radius=0.5))")
        if process is None:
            process = Poisson()
        if not isinstance(process, Process):
            raise CoronaError(f"process={process!r} is not a corona point process (e.g. corona.Poisson())")
        self.shape = shape
        self.process = process
        self.mode = check_choice("mode", mode, MODES)
        self.albedo = check_range("albedo", albedo, 0.0, 1.0)
        self.use_cache = bool(use_cache)
        process.validate(shape)
        fa = float(process.area_fraction(shape))
        if not (0.0 < fa < 1.0):
            raise CoronaError(f"area_fraction={fa:g} (from {process!r} with {shape!r}) is out of range; "
                              "allowed (0, 1)")
        self.area_fraction = fa
        _warn_if_small(shape)

    def __repr__(self):
        return (f"Material({self.shape!r}, {self.process!r}, mode={self.mode!r}, "
                f"albedo={self.albedo:g})")

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
        plane = fa * self.table.total / (4 * np.pi**2)
        return float(fa if plane <= budget else fa * budget / plane)

    @property
    def reflectance(self) -> float:
        """Hemispherical reflectance ``ρ · opaque_fraction``, capped so the total stays <= 1."""
        budget = 1.0 - self.coherent_transmittance - self.diffuse_transmittance()
        return float(max(0.0, min(self.albedo * self.opaque_fraction, budget)))

    # ------------------------------------------------------------------
    # the exact lobe
    # ------------------------------------------------------------------
    def lobe_dimensionless(self, u) -> np.ndarray:
        """Exact ``v(u) = [P + C (S - 1)] / R²`` at ``u`` (..., 2) (see :mod:`corona.tables`)."""
        u = np.asarray(u, dtype=np.float64)
        R = self.length_scale
        q = u / R
        P, C = self._form_factors(q, radial=False)
        S = self.process.structure_factor_at(q, self.shape)
        return np.maximum(P + C * (S - 1.0), 0.0) / R**2

    def lobe_dimensionless_radial(self, u) -> np.ndarray:
        """Exact radial ``v(|u|)`` for isotropic materials."""
        u = np.asarray(u, dtype=np.float64)
        R = self.length_scale
        q = u / R
        P, C = self._form_factors(q, radial=True)
        S = self.process.structure_factor_radial(q, self.shape)
        return np.maximum(P + C * (S - 1.0), 0.0) / R**2

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
        allowed = f"allowed [{tables.WAVELENGTH_MIN:g}, {tables.WAVELENGTH_MAX:g}] nm"
        try:
            lam = np.asarray(wavelength, dtype=np.float64)
        except (TypeError, ValueError):
            raise CoronaError(f"wavelength={wavelength!r} is not a number; {allowed}") from None
        ok = (lam >= tables.WAVELENGTH_MIN) & (lam <= tables.WAVELENGTH_MAX)   # False for NaN
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
        return {"shape": self.shape.key(), "process": self.process.key(),
                "isotropic": self.isotropic, "du": tables.RADIAL_DU,
                "max_samples": tables.RADIAL_MAX_SAMPLES, "grid": tables.GRID2D_SIZE,
                "wavelength_min": tables.WAVELENGTH_MIN}

    @functools.cached_property
    def table(self) -> tables.RadialTable | tables.GridTable:
        """The dimensionless lobe table ``v(u)`` (cached on disk)."""
        arrays = tables.cached(self.table_params(), self._build_table, use_cache=self.use_cache)
        return tables.table_from_arrays(arrays)

    def _build_table(self) -> dict:
        u_max = tables.u_max_for(self.length_scale)
        if self.isotropic:
            n = int(np.ceil(u_max / tables.RADIAL_DU)) + 1
            n = min(n, tables.RADIAL_MAX_SAMPLES)
            du = u_max / (n - 1)
            u = np.arange(n) * du
            return tables.RadialTable(du, self._in_chunks(self.lobe_dimensionless_radial, u)).arrays()
        n = tables.GRID2D_SIZE
        u_range = min(u_max, 0.25 * n / 2)  # cells no coarser than 0.25 in u
        cell = 2 * u_range / n
        c = -u_range + (np.arange(n) + 0.5) * cell
        ux, uy = np.meshgrid(c, c, indexing="xy")
        u = np.stack([ux, uy], -1)
        if not hasattr(self.process, "bragg_cell_mean"):
            return tables.GridTable(u_range, self._in_chunks(self.lobe_dimensionless, u)).arrays()
        # Bragg peaks narrower than a cell: each vertex carries the cell mean of
        # the lobe, P + C (S_bg - 1) + Σ_G C(G) W_G ⟨g_G⟩_cell, i.e. every peak
        # with its exact weight C(G) W_G (C at the peak, not at the cell centre)
        R = self.length_scale
        q = u / R
        P, C = np.moveaxis(self._in_chunks(lambda x: np.stack(self._form_factors(x, radial=False), -1), q),
                           -1, 0)
        S_bg = self.process.background_cell_mean(q, cell / R)
        bragg = self.process.bragg_cell_mean(q, cell / R, peak_factor=self.shape.coherent_form_factor)
        return tables.GridTable(u_range, np.maximum(P + C * (S_bg - 1.0) + bragg, 0.0) / R**2).arrays()

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
        """The lobe as the renderer evaluates it: interpolated from :attr:`table`."""
        u, lam = self._u(d, wavelength)
        t = self.table
        v = t.eval(np.hypot(u[..., 0], u[..., 1])) if self.isotropic else t.eval(u)
        return self.lobe_weight * (self.length_scale / lam) ** 2 * v

    def diffuse_transmittance(self, wavelength=550.0, cos_theta_i=None, phi_i=0.0) -> float | np.ndarray:
        """Integral of the lobe (the diffuse transmittance).

        With ``cos_theta_i=None``: over the whole d plane covered by the table,
        ``F_a ∫ v d²u / (4π²)`` (wavelength-independent; ``F_a (1 - F_a)`` for
        hard, non-overlapping scatterers).  With an incident direction
        (``cos_theta_i``, azimuth ``phi_i`` [rad]): only over the propagating
        directions ``|d - wi.xy| <= 1``, i.e. the energy the BSDF transmits
        diffusely at that wavelength [nm].
        """
        t = self.table
        fa = self.lobe_weight
        if cos_theta_i is None:
            return fa * t.total / (4 * np.pi**2)
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
            c = t.centres()
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


def _warn_if_small(shape) -> None:
    """One :class:`CoronaWarning` per process for scatterers below ~2 wavelengths."""
    global _small_radius_warned
    if _small_radius_warned:
        return
    limit = SMALL_RADIUS_WAVELENGTHS * tables.WAVELENGTH_MAX * 1e-3          # µm
    r_eq = math.sqrt(float(shape.area) / math.pi)
    if r_eq < limit:
        warnings.warn(f"{shape!r}: equivalent radius sqrt(|A|/pi) = {r_eq:.3g} µm is below "
                      f"{SMALL_RADIUS_WAVELENGTHS:g} wavelengths ({limit:g} µm at "
                      f"{tables.WAVELENGTH_MAX:g} nm); Fraunhofer diffraction loses accuracy there "
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
