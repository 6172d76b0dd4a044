"""Breath figures: condensed droplets at a time after the breath, from the shipped simulation table.

:class:`BreathFigure` is ``process=breath-figure`` (docs/physics.md#breath-figures).  It sets the
droplets' sizes as well as their positions: the layer's scatterers are opaque disks of the
droplets' contact radii (:meth:`BreathFigure.layer_shape`), and its lobe sums the partial structure
factors of 12 size classes measured on the simulations, the closest of three rules to the exact far
field of simulated droplets at 10 and 20 s (benchmarks/results/breath_figure_lobe.json;
docs/physics.md#breath-figures-processbreath-figure).  The table
``data/breath_figure.npz`` is made by ``scripts/make_breath_figure_table.py`` with the simulator of
:mod:`corona.reference.breath_figure`; numpy and scipy only here.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from corona._validation import CoronaError, check_range
from corona.model import registry
from corona.model.processes.base import Process, shipped_table

TABLE_FORMAT_VERSION = 2
#: Evaporation rate of water from a fogged pane [µm/s] (the film thickness it removes per second):
#: vapour diffusing through the still-air boundary layer over the pane (collective evaporation of a
#: dense droplet array approaches that of a film; Hu & Larson, J. Phys. Chem. B 106, 1334, 2002, for
#: one drop): ``E = D c_sat (1 - RH) / (ρ δ)`` with D = 2.5e-5 m²/s, c_sat = 17.3 g/m³ (20 °C),
#: RH = 0.5 and δ = 2 mm gives 0.11 µm/s.
EVAPORATION_RATE = 0.1
#: The fading rows reach this fraction of the water evaporated (beyond it too few droplets are left
#: in the simulated box for a structure factor).
DRY_FRACTION_MAX = 0.9
#: Contact angles [degree] the table's time mapping covers (a cap of θ > 90° overhangs its
#: footprint, which the simulated merging does not see).
CONTACT_ANGLE_MIN, CONTACT_ANGLE_MAX = 10.0, 90.0


@functools.cache
def load_table() -> dict:
    """The shipped table: ``times`` [s], ``R`` (⟨a³⟩/⟨a²⟩ [µm]), ``mean_radius`` [µm], ``coverage``,
    ``density`` [µm⁻²], ``water`` [µm], ``fraction`` and ``x`` (size classes: number fractions and
    mean a/R), ``S`` over ``u = q R``, ``partial``; the fading phase's ``dry_*`` over
    (``dry_starts``, ``dry_fractions``) (:func:`corona.reference.breath_figure_optics.evaporation_rows`);
    ``metadata``."""
    return shipped_table("breath_figure.npz", TABLE_FORMAT_VERSION, "breath-figure", "scripts/make_breath_figure_table.py")


def _cap_factor(theta_deg: float) -> float:
    """``k`` of ``V = k a³`` (a spherical cap of contact angle θ)."""
    th = math.radians(theta_deg)
    c, s = math.cos(th), math.sin(th)
    return math.pi * (1.0 - c) ** 2 * (2.0 + c) / (3.0 * s ** 3)


def water(breath_time: float, contact_angle: float = 90.0) -> float:
    """Water per area [µm] (the film it would make) condensed by ``breath_time`` [s] at ``contact_angle``
    (the table's, linear in log t; ≈ 0.1 µm/s · t, plus the nuclei)."""
    t = load_table()
    f = _cap_factor(contact_angle) / _cap_factor(90.0)
    t90 = breath_time / f
    return float(np.exp(np.interp(math.log(t90), np.log(t["times"]), np.log(t["water"])))) * f


def dry_time_range(breath_time: float = 20.0, contact_angle: float = 90.0,
                   evaporation_rate: float = EVAPORATION_RATE) -> tuple[float, float]:
    """The dry times [s] the table covers after ``breath_time`` [s] of growth: up to
    :data:`DRY_FRACTION_MAX` of the water gone (all of it goes at ``water / evaporation_rate``)."""
    return 0.0, DRY_FRACTION_MAX * water(breath_time, contact_angle) / evaporation_rate


def time_range(contact_angle: float = 90.0) -> tuple[float, float]:
    """The breath times [s] the table covers at ``contact_angle`` [degree]."""
    t = load_table()["times"]
    f = _cap_factor(contact_angle) / _cap_factor(90.0)
    return float(t[0] * f), float(t[-1] * f)


class BreathFigure(Process):
    """Droplets condensed on a pane, ``breath_time`` seconds after the breath began.

    The droplets nucleate, grow, touch and merge (:mod:`corona.reference.breath_figure`; water
    on a pane, 0.1 µm/s of condensed film, nuclei of 0.25 µm at 0.05 µm⁻² s⁻¹ on the free area).
    The shipped table holds, at times from 5 to 80 s of the hemispherical run (the coalescence
    regime: the area-weighted mean radius ``R`` grows ∝ t, from 1.8 to 17 µm), the size
    distribution in ``a/R``, the coverage and the structure factor of the centres; in between,
    ``R`` is interpolated in log t, the rest linearly in log t.

    A contact angle θ < 90° puts the same water into wider, flatter caps (``V = k(θ) a³``): the
    simulated merging depends on the contact radii only, so the layer at time ``t`` is the
    hemispherical run's at ``t · k(90°)/k(θ)`` (exact for the condensed water; the renucleated
    droplets' number is that of the hemispherical run at that time, an approximation).

    **The fading phase.**  ``dry_time`` seconds after the vapour stopped, the water leaves at
    ``evaporation_rate`` (µm of film per second; the drops share the loss as they shared the growth,
    ``dV/dt ∝ -a``, so the small ones vanish first), so the state is that of the evaporated
    fraction ``f = evaporation_rate · dry_time / water(breath_time)`` of the water condensed by then
    (:func:`water`).  The table holds runs that evaporate from 5, 20 and 80 s, measured at
    ``f`` = 0.1, 0.25, 0.5, 0.75, 0.9; a layer is the growth row at ``breath_time`` with the fading runs'
    ratios of ``R = ⟨a³⟩/⟨a²⟩`` and of the number density (their logarithms interpolated linearly in
    ``f`` and in log of the start time), its size distribution and structure factors the fading
    rows' (the growth row's at ``f = 0``), and the coverage from the water left over ``R``
    (``coverage ∝ (1 - f) / R``, exact for caps of one angle): the layer holds the water the rate
    leaves it.  Why a 2-D table and not one run rescaled: the runs are not self-similar enough
    (``R`` at ``f = 0.3`` is 0.96 of its start's from 10 s, 1.14 from 80 s, where many small
    renucleated droplets vanish first).  Coverage falls monotonically; ``R`` first rises a little
    (the small droplets go first), then falls.  The ring does not follow ``R`` here, as it does in
    growth: the droplets stay where they are, so the peak of the lobe, set by their spacing, stays
    (and moves in a little as small droplets vanish), while the small droplets' wide glow goes first
    and the ring fades with the coverage (the exact far field agrees: ``ring`` in
    benchmarks/results/breath_figure_lobe.json).

    Seen from above each droplet is an opaque disk of its contact radius (the footprint of a cap of
    θ <= 90°).  The lobe is :meth:`intensity` by :attr:`RULE`: the partial structure factors of the
    table's 12 size classes (docs/physics.md#breath-figures-processbreath-figure says why, and what
    the other rules measure).

    Parameters
    ----------
    breath_time : float
        Time since condensation began [s], within :func:`time_range` (5–80 s at θ = 90°).
    contact_angle : float
        Contact angle of the droplets [degree], in [10, 90]; 90: silanised glass (Beysens &
        Knobler 1986), clean glass is nearer 20–40.
    dry_time : float
        Time since the vapour stopped [s] (after ``breath_time`` of growth), within
        :func:`dry_time_range` (0: still growing).
    evaporation_rate : float
        Rate at which the water leaves [µm/s] (film thickness per second), > 0;
        :data:`EVAPORATION_RATE` (still air, 20 °C, 50 % relative humidity).
    """

    isotropic = True
    own_lobe = True

    def __init__(self, breath_time: float = 20.0, contact_angle: float = 90.0, dry_time: float = 0.0,
                 evaporation_rate: float = EVAPORATION_RATE):
        self.contact_angle = check_range("contact_angle", contact_angle, CONTACT_ANGLE_MIN, CONTACT_ANGLE_MAX,
                                         unit="degree")
        lo, hi = time_range(self.contact_angle)
        self.breath_time = check_range("breath_time", breath_time, lo * (1 - 1e-12), hi * (1 + 1e-12),
                                       unit=f"s at contact_angle={self.contact_angle:g}")
        t = load_table()
        # the hemispherical run's time, and the interpolation weight between two rows (log t)
        t90 = self.breath_time * _cap_factor(90.0) / _cap_factor(self.contact_angle)
        #: the time [s] of the hemispherical run this layer is; the box [µm] of the table's runs
        self.simulation_time = t90
        self.table_box = float(t["metadata"]["box_um"])
        lt = np.log(t["times"])
        k = int(np.clip(np.searchsorted(lt, math.log(t90)) - 1, 0, lt.size - 2))
        w = float(np.clip((math.log(t90) - lt[k]) / (lt[k + 1] - lt[k]), 0.0, 1.0))

        def mix(a):
            return (1.0 - w) * a[k] + w * a[k + 1]
        self._R = float(np.exp(mix(np.log(t["R"]))))
        self._coverage = float(mix(t["coverage"]))
        self._fraction = mix(t["fraction"])
        self._radii = mix(t["x"]) * self._R
        self._S = mix(t["S"])
        self._partial = mix(t["partial"].astype(np.float64))
        self._density = float(np.exp(mix(np.log(t["density"]))))
        self._u = t["u"]
        self.evaporation_rate = check_range("evaporation_rate", evaporation_rate, 0.0, 100.0, lo_open=True,
                                            unit="µm/s")
        d_hi = dry_time_range(self.breath_time, self.contact_angle, self.evaporation_rate)[1]
        self.dry_time = check_range(
            "dry_time", dry_time, 0.0, d_hi * (1 + 1e-12),
            unit=(f"s after breath_time={self.breath_time:g} s at evaporation_rate={self.evaporation_rate:g} µm/s "
                  f"(the droplets are gone at {d_hi / DRY_FRACTION_MAX:g} s; the table covers "
                  f"{DRY_FRACTION_MAX:.0%} of the water)"))
        #: the fraction of the water evaporated
        self.evaporated = 0.0
        if self.dry_time > 0:
            self._fade(t)
        keep = self._fraction > 0
        x = (self._radii / self._R)[keep]
        edges = t["class_edges"]
        self._class = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
        self._fraction, self._radii = self._fraction[keep] / self._fraction[keep].sum(), self._radii[keep]

    def _fade(self, t):
        """Move the growth state to the fading phase at ``dry_time`` (class docstring)."""
        f = self.evaporation_rate * self.dry_time / water(self.breath_time, self.contact_angle)
        self.evaporated = f
        ls = np.log(t["dry_starts"])
        x = float(np.clip(math.log(self.simulation_time), ls[0], ls[-1]))
        j = int(np.clip(np.searchsorted(ls, x) - 1, 0, ls.size - 2))
        ws = (x - ls[j]) / (ls[j + 1] - ls[j])

        def start(a):                  # the rows at this start time (linear in log t between runs)
            return (1.0 - ws) * a[j] + ws * a[j + 1]
        fr = np.concatenate([[0.0], t["dry_fractions"]])
        k = int(np.clip(np.searchsorted(fr, f) - 1, 0, fr.size - 2))
        wf = float(np.clip((f - fr[k]) / (fr[k + 1] - fr[k]), 0.0, 1.0))

        def ratio(name):               # (geometric: the number of droplets falls by 10-70x)
            r = np.concatenate([[0.0], start(np.log(t["dry_" + name + "_ratio"]))])
            return math.exp((1.0 - wf) * r[k] + wf * r[k + 1])

        def row(name, own):            # the fading rows, the growth row's own at f = 0
            lo = own if k == 0 else start(t["dry_" + name][:, k - 1])
            return (1.0 - wf) * lo + wf * start(t["dry_" + name][:, k])
        fraction = row("fraction", self._fraction)
        x_rel = row("x", self._radii / self._R)
        # R = <a³>/<a²> is the water over the coverage (times k/π): the water is exact (1 - f of it
        # left), R the runs' ratio (smooth in f), so the coverage follows; the number density is the
        # runs' ratio too (all as ratios to the growth row, so f -> 0 is that row)
        rr = ratio("R")
        self._R *= rr
        self._coverage *= (1.0 - f) / rr
        self._density *= ratio("density")
        self._fraction, self._radii = fraction, x_rel * self._R
        self._S = row("S", self._S)
        self._partial = row("partial", self._partial)

    def __repr__(self):
        dry = (f", dry_time={self.dry_time:g}, evaporation_rate={self.evaporation_rate:g}" if self.dry_time > 0
               else "")
        return f"BreathFigure(breath_time={self.breath_time:g}, contact_angle={self.contact_angle:g}{dry})"

    def key(self) -> dict:
        m = load_table()["metadata"]
        return {**super().key(), "rule": self.RULE, "join": self.PARTIAL_JOIN, "tail": "local-monodisperse", "sum_rule": True,
                "table": f"{m.get('format_version')}:{m.get('date')}"}

    # --- the droplets -------------------------------------------------------------
    @property
    def mean_radius(self) -> float:
        """Area-weighted mean contact radius ``⟨a³⟩/⟨a²⟩`` [µm]."""
        return self._R

    @property
    def size_classes(self) -> tuple[np.ndarray, np.ndarray]:
        """(contact radii [µm], number fractions) of the size classes."""
        return self._radii.copy(), self._fraction.copy()

    def layer_shape(self, shape):
        """The droplets' footprints: a number-weighted mixture of circles of the size classes.

        ``shape`` must be a circle (the process sets the sizes; its radius is not used)."""
        from corona.model.shapes import Circle, Mixture
        if isinstance(shape, Mixture) and getattr(shape, "_breath_figure", None) == self.key():
            return shape
        if type(shape) is not Circle:
            raise CoronaError(f"process='breath-figure' places round droplets (opaque disks of their contact "
                              f"radii, sizes from the process): shape must be 'circle' without size_spread, "
                              f"edge_width or orientation; got {shape!r}")
        mix = Mixture([(Circle(radius=float(r)), float(f)) for r, f in zip(self._radii, self._fraction)])
        mix._breath_figure = self.key()
        return mix

    def area_fraction(self, shape) -> float:
        return self._coverage

    def validate(self, shape) -> None:
        self.layer_shape(shape)

    # --- structure ---------------------------------------------------------------
    def structure_factor_radial(self, q_abs, shape=None) -> np.ndarray:
        """The measured ``S(|q|)`` of all the droplets' centres (linear in ``u = q R`` between rings,
        1 beyond them); the lobe does not use it (:meth:`lobe_intensity_radial`)."""
        u = np.abs(np.asarray(q_abs, dtype=np.float64)) * self._R
        ok = np.isfinite(self._S)
        return np.interp(u, self._u[ok], self._S[ok], left=self._S[ok][0], right=1.0)

    #: The rule of the layer's lobe (:meth:`intensity`): the closest of the three to the exact far
    #: field of simulated droplets (benchmarks/results/breath_figure_lobe.json).
    RULE = "partial"
    RULES = ("local-monodisperse", "decoupling", "partial")
    #: Width in ``u = q R`` over which the partial structure factors join the local monodisperse rule.
    PARTIAL_JOIN = 2.0

    @property
    def number_density(self) -> float:
        """Droplets per area [µm⁻²]."""
        return self._density

    def _amplitudes(self, q):
        from scipy.special import j1
        z = q[..., None] * self._radii
        return np.pi * self._radii ** 2 * np.where(z > 1e-8, 2.0 * j1(z) / np.maximum(z, 1e-300), 1.0)

    def intensity(self, q_abs, rule: str | None = None, *, _raw: bool = False) -> np.ndarray:
        """The diffuse intensity per droplet ``⟨|Σ_j Â_j e^{-iq·r_j}|²⟩ / N`` [µm⁴] at ``|q|``
        [rad/µm] by ``rule`` (default :attr:`RULE`):

        * ``"local-monodisperse"`` (Pedersen 1994): ``Σ_i x_i |Â_i|² S_HD(2 a_i q; η)``, η the
          coverage (clipped to the hard-disk table's 0.72);
        * ``"decoupling"`` (Kotlarchyk & Chen 1983): ``⟨|Â|²⟩ + |⟨Â⟩|² (S - 1)``, S of all the centres;
        * ``"partial"``: ``Σ_ik F̄_i F̄_k S_ik + Σ_k X_k (⟨|Â|²⟩_k - F̄_k²)`` over the table's 12 size
          classes (number fractions ``X_k``, mean amplitudes ``F̄_k``, measured partial structure
          factors ``S_ik``); beyond the table's rings (``qR > 12``), where the small droplets are still
          correlated, the local monodisperse rule, joined linearly over :attr:`PARTIAL_JOIN`; the
          part inside scaled to the sum rule (:meth:`_partial_scale`).
        """
        from corona._validation import check_choice
        rule = check_choice("rule", self.RULE if rule is None else rule, self.RULES)
        q = np.abs(np.asarray(q_abs, dtype=np.float64))
        F = self._amplitudes(q)                                  # (..., n_sizes)
        x = self._fraction
        if rule == "local-monodisperse":
            from corona.model.processes.hard_disk import ETA_MAX, structure_factor_table
            eta = min(self._coverage, ETA_MAX)
            S = np.stack([structure_factor_table(2.0 * q * a, eta) for a in self._radii], -1)
            return np.sum(x * F * F * S, axis=-1)
        if rule == "decoupling":
            P = np.sum(x * F * F, axis=-1)
            C = np.sum(x * F, axis=-1) ** 2
            return P + C * (self.structure_factor_radial(q) - 1.0)
        K = self._partial.shape[-1]
        onehot = np.zeros((x.size, K))
        onehot[np.arange(x.size), self._class] = 1.0
        X = x @ onehot                                           # class fractions
        Xs = np.where(X > 0, X, 1.0)
        Fk = (x * F) @ onehot / Xs                               # (..., K) mean amplitudes
        F2k = (x * F * F) @ onehot / Xs
        u = q * self._R
        ok = np.isfinite(self._partial[:, 0, 0])
        ug = self._u[ok]
        Sik = np.empty(q.shape + (K, K))
        for i in range(K):
            for k in range(K):
                Sik[..., i, k] = np.interp(u, ug, self._partial[ok, i, k])
        inside = np.einsum("...i,...ik,...k->...", Fk, Sik, Fk) + np.sum(X * (F2k - Fk * Fk), axis=-1)
        if _raw:
            return inside
        inside = inside * self._partial_scale()
        # beyond the rings (u > 12) the small droplets are still correlated (their dry zones, at
        # q a ~ 1): the local monodisperse rule there, joined linearly over PARTIAL_JOIN in u
        w = np.clip((u - ug[-1]) / self.PARTIAL_JOIN, 0.0, 1.0)
        if not np.any(w > 0):
            return inside
        return (1.0 - w) * inside + w * self.intensity(q, "local-monodisperse")

    def _partial_scale(self) -> float:
        """The factor that gives the partial rule the sum rule of non-overlapping droplets.

        The class averages and the table's noise leave the partial rule's lobe 3-16 % above
        ``F_a (1 - F_a)``, more light than the open area lets through; the local monodisperse rule
        keeps the sum rule (each class's hard-disk S obeys it) and equals the partial rule beyond the
        join, so the partial part inside the join is scaled to carry the local monodisperse rule's
        energy there: ``∫ (1 - w) I_partial q dq = ∫ (1 - w) I_lm q dq``."""
        if getattr(self, "_scale", None) is None:
            from scipy.integrate import trapezoid
            ok = np.isfinite(self._partial[:, 0, 0])
            u_end = self._u[ok][-1]
            q = np.linspace(0.0, (u_end + self.PARTIAL_JOIN) / self._R, 4001)
            w = 1.0 - np.clip((q * self._R - u_end) / self.PARTIAL_JOIN, 0.0, 1.0)
            lm = trapezoid(w * self.intensity(q, "local-monodisperse") * q, q)
            part = trapezoid(w * self.intensity(q, "partial", _raw=True) * q, q)
            self._scale = float(lm / part)
        return self._scale

    def lobe_intensity_radial(self, q_abs, shape) -> np.ndarray:
        """:meth:`intensity` by :attr:`RULE` over ``⟨|A|⟩ = Σ_i x_i π a_i²`` [µm²]."""
        return self.intensity(q_abs) / float(np.sum(self._fraction * np.pi * self._radii ** 2))


def _factory(p, shape):
    return BreathFigure(p["breath_time"], p["contact_angle"], p["dry_time"], p["evaporation_rate"])


# --- the family (corona.model.registry): process=breath-figure -----------------------------------
registry.add_process(registry.ProcessFamily(
    "breath-figure", _factory, ("breath_time", "contact_angle", "dry_time", "evaporation_rate"),
    (dict(name="breath_time", kind="float", unit="s", default=20.0,
          meaning="breath-figure: time since condensation began (5-80 s at contact_angle 90; "
                  "scaled by the cap volume at other angles)", low=0.0, low_open=True, high=1e4),
     dict(name="contact_angle", kind="float", unit="degree", default=90.0,
          meaning="breath-figure: contact angle of the droplets (90: silanised glass)",
          low=CONTACT_ANGLE_MIN, high=CONTACT_ANGLE_MAX),
     dict(name="dry_time", kind="float", unit="s", default=0.0,
          meaning="breath-figure: time since the vapour stopped (the droplets evaporate; up to 90 % of "
                  "the water gone: 18 s after 20 s of growth at the default rate)", low=0.0, high=1e4),
     dict(name="evaporation_rate", kind="float", unit="µm/s", default=EVAPORATION_RATE,
          meaning="breath-figure: rate at which the water leaves in the fading phase (film thickness "
                  "per second; 0.1: still air, 20 °C, 50 % humidity)", low=0.0, low_open=True, high=100.0)),
    cls=BreathFigure, absolute=True))
