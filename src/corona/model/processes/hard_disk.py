"""The equilibrium hard-disk fluid: ``S(qσ, η)`` from the shipped simulation table.

:class:`HardDisk` is the point process; :func:`structure_factor_table`
interpolates ``data/hard_disk_structure_factor.npz`` (made by
``scripts/make_hard_disk_table.py`` with the event-chain Monte Carlo of
:mod:`corona.reference.hard_disk`).  numpy and scipy.special only.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from corona._validation import CoronaError, check_positive, check_range
from corona.model import registry
from corona.model.processes.base import Process, _check_exclusion, shipped_table

TABLE_FORMAT_VERSION = 1
#: Largest packing fraction of the table (above the fluid–hexatic transition).
ETA_MAX = 0.72
#: Decay length (in qσ) of the continuity correction beyond the table.
TAIL_JOIN_DECAY = 4.0


def tail_basis(q):
    """``(J1(q)/q, J0(q)/q²)``: leading terms of ``S - 1`` at large qσ."""
    from scipy import special
    q = np.asarray(q, dtype=np.float64)
    return special.j1(q) / q, special.j0(q) / q**2



@functools.cache
def load_table() -> dict:
    """The shipped table (loaded once, the one route every reader takes):
    arrays ``eta``, ``q_sigma``, ``S`` (n_eta × n_q), ``tail``, per-row
    diagnostics, and ``metadata`` (dict)."""
    return shipped_table("hard_disk_structure_factor.npz", TABLE_FORMAT_VERSION, "hard-disk", "scripts/make_hard_disk_table.py")


def _pchip_slopes(x, y):
    """Slopes of the monotone piecewise-cubic (PCHIP, Fritsch–Carlson as in
    scipy) interpolant of ``y`` (n × m) over ``x`` (n,), along axis 0."""
    h = np.diff(x)[:, None]
    d = np.diff(y, axis=0) / h
    m = np.zeros_like(y)
    w1 = 2.0 * h[1:] + h[:-1]
    w2 = h[1:] + 2.0 * h[:-1]
    same = (np.sign(d[:-1]) * np.sign(d[1:])) > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        m[1:-1] = np.where(same, (w1 + w2) / (w1 / d[:-1] + w2 / d[1:]), 0.0)

    def edge(h0, h1, m0, m1):
        e = ((2.0 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
        e = np.where(np.sign(e) != np.sign(m0), 0.0, e)
        big = (np.sign(m0) != np.sign(m1)) & (np.abs(e) > 3.0 * np.abs(m0))
        return np.where(big, 3.0 * m0, e)

    m[0] = edge(h[0], h[1], d[0], d[1])
    m[-1] = edge(h[-1], h[-2], d[-1], d[-2])
    return m


def _hermite(y0, y1, m0, m1, h, t):
    t2 = t * t
    return ((1.0 + 2.0 * t) * (1.0 - t) ** 2 * y0 + t * (1.0 - t) ** 2 * h * m0
            + t2 * (3.0 - 2.0 * t) * y1 + t2 * (t - 1.0) * h * m1)


@functools.cache
def _lookup_arrays():
    """The table's rows with the PCHIP slopes in η precomputed."""
    t = load_table()
    eta, S, tail = t["eta"], t["S"], t["tail"]
    return eta, t["q_sigma"], S, _pchip_slopes(eta, S), tail, _pchip_slopes(eta, tail)


@functools.cache
def _table_id() -> str:
    """``format_version:date`` of the shipped table."""
    m = load_table()["metadata"]
    return f"{m.get('format_version')}:{m.get('date')}"


@functools.lru_cache(maxsize=128)
def _row(eta: float):
    """The table at ``eta``: PCHIP in η between rows (shape-preserving, no
    overshoot), then along qσ a cubic Hermite interpolant with fourth-order
    finite-difference slopes (``S'(0) = 0``: S is even in q)."""
    etas, qg, S, dS, tail, dtail = _lookup_arrays()
    k = int(np.clip(np.searchsorted(etas, eta, side="right") - 1, 0, etas.size - 2))
    h = etas[k + 1] - etas[k]
    t = (eta - etas[k]) / h
    row = _hermite(S[k], S[k + 1], dS[k], dS[k + 1], h, t)
    A, B, _ = _hermite(tail[k], tail[k + 1], dtail[k], dtail[k + 1], h, t)
    dq = qg[1] - qg[0]
    ext = np.concatenate([row[2:0:-1], row])           # even extension to q < 0
    slope = np.empty_like(row)
    slope[:-2] = (ext[:-4] - 8.0 * ext[1:-3] + 8.0 * ext[3:-1] - ext[4:]) / (12.0 * dq)
    slope[0] = 0.0
    r = row
    slope[-2] = (r[-5] - 6.0 * r[-4] + 18.0 * r[-3] - 10.0 * r[-2] - 3.0 * r[-1]) / (-12.0 * dq)
    slope[-1] = (3.0 * r[-5] - 16.0 * r[-4] + 36.0 * r[-3] - 48.0 * r[-2] + 25.0 * r[-1]) / (12.0 * dq)
    b1, b2 = tail_basis(qg[-1])
    offset = float(row[-1] - (1.0 + A * b1 + B * b2))
    return row, slope, float(dq), float(qg[-1]), float(A), float(B), offset


def structure_factor_table(q_sigma, eta):
    """Hard-disk ``S(qσ)`` at packing fraction ``eta`` from the shipped
    simulation table (see :class:`HardDisk`).  ``qσ`` may be any array;
    beyond the table (qσ > 40) the asymptotic tail joins continuously."""
    try:
        e = float(eta)
    except (TypeError, ValueError):
        raise CoronaError(f"packing_fraction={eta!r} is not a number") from None
    if not (math.isfinite(e) and 0.0 <= e <= ETA_MAX + 1e-12):
        raise CoronaError(f"packing_fraction={eta!r} is out of range; the hard-disk fluid table "
                          f"covers [0, {ETA_MAX:g}]")
    q = np.abs(np.asarray(q_sigma, dtype=np.float64))
    if e == 0.0:
        return np.ones_like(q)
    row, slope, dq, qmax, A, B, offset = _row(round(min(e, ETA_MAX), 12))
    out = np.empty_like(q)
    inside = q <= qmax
    qi = q[inside] / dq
    i = np.minimum(qi.astype(np.int64), row.size - 2)
    out[inside] = _hermite(row[i], row[i + 1], slope[i], slope[i + 1], dq, qi - i)
    qo = q[~inside]
    if qo.size:
        b1, b2 = tail_basis(qo)
        out[~inside] = 1.0 + A * b1 + B * b2 + offset * np.exp(-(qo - qmax) / TAIL_JOIN_DECAY)
    return out



class HardDisk(Process):
    """Equilibrium hard-disk fluid: centres at least ``σ`` apart (docs/physics.md#the-model).

    ``S(q)`` depends on ``qσ`` and on the packing fraction of the exclusion
    disks ``η = F_a · (π σ²/4) / |A|`` (``η = F_a`` for circles with the
    default ``σ = 2R``).  It comes from a table of event-chain Monte Carlo
    simulations (``src/corona/data/hard_disk_structure_factor.npz``, made by
    ``scripts/make_hard_disk_table.py``; see :func:`simulate_hard_disks` and
    :func:`smooth_structure_factor_row`):

    * rows in η from 0 to :data:`ETA_MAX`, each a periodic box of N = 2000
      disks, ``S(k)`` on the box wave vectors binned in ``qσ`` and smoothed,
      ``qσ ∈ [0, 40]`` on a 0.05 grid; each row stores its standard error
      (``S_err``, a parametric bootstrap of the smoothing);
    * between rows: monotone cubic (PCHIP) interpolation in η, then a
      cubic Hermite interpolant in ``qσ`` (fourth-order slopes, ``S'(0) = 0``);
    * beyond ``qσ = 40``: ``S - 1 = -8η [g(σ⁺) J1(qσ)/qσ + b J0(qσ)/(qσ)²]``
      with the measured contact value, joined continuously.

    The rows at η ≥ 0.69 are not the equilibrium bulk fluid: there the
    N = 2000 system is in the fluid–hexatic coexistence / hexatic range, and
    these rows are the structure factor of that finite, partly ordered system,
    its sharp first peak kept by its area (a kernel average of width 0.1 in
    ``qσ``) so that the model stays continuous up to :data:`ETA_MAX`.  They
    carry no accuracy claim; use :class:`Lattice` for a crystalline layer.

    How the table compares with Henderson's equation of state, the
    compressibility sum rule, Percus–Yevick and an independent Metropolis
    sampler, with the figures of the shipped table, is in
    ``docs/tables.md#the-hard-disk-table`` (checked by
    ``tests/model/test_hard_disk.py``, ``tests/tables/test_hard_disk_table.py`` and
    ``benchmarks/bench_hard_disk.py``).

    Parameters
    ----------
    area_fraction : float
        ``F_a = n |A|`` in (0, 1); the packing fraction must stay ≤ 0.72.
    exclusion_diameter : float, optional
        Hard-core diameter ``σ`` [µm]; default ``shape.exclusion_diameter``
        (the circumscribed diameter).

    Examples
    --------
    Circles (σ = 2R, so η = F_a) at F_a = 0.3: ``S(0)`` is the reduced
    compressibility, ``1/(d(ηZ)/dη) = 0.258`` by Henderson's equation of state
    ``Z = (1 + η²/8)/(1 - η)²``; far out ``S → 1``:

    >>> import numpy as np, corona
    >>> hd = corona.HardDisk(area_fraction=0.3)
    >>> S = hd.structure_factor_radial(np.array([0.0, 50.0]), corona.Circle(radius=1.0))  # q [rad/µm]
    >>> eta = 0.3
    >>> henderson = (1 - eta) ** 3 / ((1 + 3 * eta**2 / 8) * (1 - eta) + 2 * eta * (1 + eta**2 / 8))
    >>> round(henderson, 3), round(float(S[0]), 3), round(float(S[1]), 2)
    (0.258, 0.258, 1.0)
    """

    isotropic = True

    def __init__(self, area_fraction: float, exclusion_diameter: float | None = None):
        self.fraction = check_range("area_fraction", area_fraction, 0.0, 1.0,
                                    lo_open=True, hi_open=True)
        self.exclusion_diameter = (None if exclusion_diameter is None else
                                   check_positive("exclusion_diameter", exclusion_diameter, "µm"))

    def __repr__(self):
        sd = "" if self.exclusion_diameter is None else \
            f", exclusion_diameter={self.exclusion_diameter:g}"
        return f"HardDisk(area_fraction={self.fraction:g}{sd})"

    def key(self) -> dict:
        """Parameters plus the identity of the shipped table (so that cached
        lobe tables follow a regenerated structure-factor table)."""
        return {**super().key(), "table": _table_id()}

    # --- geometry -----------------------------------------------------------
    def diameter(self, shape) -> float:
        """Exclusion diameter ``σ`` [µm] used with ``shape``."""
        return self.exclusion_diameter if self.exclusion_diameter is not None \
            else float(shape.exclusion_diameter)

    def area_fraction(self, shape) -> float:
        return self.fraction

    varying_area_fraction = True

    def with_area_fraction(self, area_fraction: float) -> "HardDisk":
        return HardDisk(area_fraction, exclusion_diameter=self.exclusion_diameter)

    def _fa_per_eta(self, shape) -> float:
        s = self.diameter(shape)
        return float(shape.area) / (math.pi * s * s / 4.0)

    def area_fraction_limit(self, shape) -> float:
        return min(ETA_MAX * self._fa_per_eta(shape), 1.0 - 1e-6)

    def area_fraction_nodes(self, shape):
        eta = load_table()["eta"]
        return np.asarray(eta[eta <= ETA_MAX], dtype=np.float64) * self._fa_per_eta(shape)

    def packing_fraction(self, shape) -> float:
        """``η = F_a · (π σ²/4) / |A|``."""
        s = self.diameter(shape)
        return self.fraction * (math.pi * s * s / 4.0) / float(shape.area)

    def validate(self, shape) -> None:
        _check_exclusion("HardDisk", self.diameter(shape), shape)   # σ smaller: scatterers overlap
        eta = self.packing_fraction(shape)
        if eta > ETA_MAX + 1e-12:
            allowed = self.fraction * ETA_MAX / eta
            raise CoronaError(
                f"area_fraction={self.fraction:g} gives packing fraction {eta:.4g} > {ETA_MAX:g}, "
                f"the limit of the hard-disk fluid table; allowed area_fraction ≤ {allowed:.4g}"
                + ("" if self.exclusion_diameter is None else
                   f" (with exclusion_diameter={self.exclusion_diameter:g} µm)"))

    # --- structure factor --------------------------------------------------
    def structure_factor(self, q_sigma, packing_fraction=None) -> np.ndarray:
        """``S`` at the dimensionless ``qσ`` (array).

        ``packing_fraction`` defaults to the area fraction (the packing
        fraction of circles with ``σ = 2R``).
        """
        eta = self.fraction if packing_fraction is None else packing_fraction
        return structure_factor_table(q_sigma, eta)

    def structure_factor_radial(self, q_abs, shape) -> np.ndarray:
        """``S(|q|)`` for ``q_abs`` in rad/µm (σ from the shape)."""
        self.validate(shape)
        q = np.asarray(q_abs, dtype=np.float64)
        return structure_factor_table(q * self.diameter(shape), self.packing_fraction(shape))


# --- the family (corona.model.registry): process=hard-disk ---------------------------------------
registry.add_process(registry.ProcessFamily(
    "hard-disk", lambda p, shape: HardDisk(p["area_fraction"], exclusion_diameter=p.get("exclusion_diameter")),
    ("area_fraction", "exclusion_diameter"), cls=HardDisk))
