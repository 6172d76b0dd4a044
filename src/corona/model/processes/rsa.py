"""Random sequential adsorption of disks: S(qσ, η) from a shipped Monte Carlo table."""
from __future__ import annotations

import math
import os

import numpy as np

from corona._validation import CoronaError, check_positive, check_range
from corona.model import registry
from corona.model.processes.base import Process, _check_exclusion

#: Largest accepted RSA packing fraction (saturation is 0.547069, see
#: :class:`SequentialAdsorption`).
RSA_JAMMING_LIMIT = 0.547
#: Saturation (jamming) coverage of RSA disks, Zhang & Torquato (2013).
RSA_SATURATION = 0.547069

_RSA_TABLE_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "data", "rsa_structure_factor.npz")
_RSA_TABLE = None


def _rsa_table():
    global _RSA_TABLE
    if _RSA_TABLE is None:
        if not os.path.exists(_RSA_TABLE_PATH):
            raise CoronaError(f"the RSA structure-factor table {_RSA_TABLE_PATH} is missing; "
                              "regenerate it with scripts/make_rsa_table.py")
        with np.load(_RSA_TABLE_PATH) as z:
            _RSA_TABLE = (np.asarray(z["q_sigma"], np.float64), np.asarray(z["eta"], np.float64),
                          np.asarray(z["S"], np.float64))
    return _RSA_TABLE


_RSA_DIGEST = None


def _rsa_table_digest() -> str:
    global _RSA_DIGEST
    if _RSA_DIGEST is None:
        import hashlib
        try:
            with open(_RSA_TABLE_PATH, "rb") as fh:
                _RSA_DIGEST = hashlib.sha256(fh.read()).hexdigest()[:16]
        except OSError:
            _RSA_DIGEST = "missing"
    return _RSA_DIGEST


def rsa_structure_factor(q_sigma, packing_fraction) -> np.ndarray:
    """Structure factor of random sequential adsorption (RSA) of disks.

    ``S(qσ, η)`` interpolated (linearly in ``qσ`` and ``η``) in the table
    ``corona/data/rsa_structure_factor.npz`` made by
    ``scripts/make_rsa_table.py`` from Monte Carlo RSA in a periodic box
    (grid ``qσ ∈ [0, 200]`` step 0.1; ``η = 0, 0.01, …, 0.54`` and the
    saturated state, mean coverage ``η = 0.54704``).  ``S = 1`` beyond
    ``qσ = 200`` (where ``|S - 1| < 0.01``).

    Parameters
    ----------
    q_sigma : array_like
        Dimensionless ``|q| σ`` (σ the exclusion diameter).
    packing_fraction : float
        ``η = n π σ²/4`` in ``[0, 0.547]``.

    Returns
    -------
    numpy.ndarray
        ``S`` with the shape of ``q_sigma`` (no forward delta; → 1 at large q).
    """
    eta = check_range("packing_fraction", packing_fraction, 0.0, RSA_JAMMING_LIMIT)
    q = np.abs(np.asarray(q_sigma, dtype=np.float64))
    if eta == 0.0:
        return np.ones_like(q)
    qg, etas, S = _rsa_table()
    i = int(np.clip(np.searchsorted(etas, eta, side="right") - 1, 0, len(etas) - 2))
    t = (eta - etas[i]) / (etas[i + 1] - etas[i])
    row = (1.0 - t) * S[i] + t * S[i + 1]
    return np.interp(q, qg, row, right=1.0)


class SequentialAdsorption(Process):
    """Random sequential adsorption (RSA) of hard disks.

    Disks of exclusion diameter σ are placed one after another at uniformly
    random positions and kept only where they overlap no earlier disk; they
    never move.  Coverage saturates at the jamming limit
    ``η_J = 0.547069`` (Feder 1980; Hinrichsen, Feder & Jøssang 1986;
    Zhang & Torquato 2013).  Unlike the equilibrium hard-disk fluid, RSA is
    not a Gibbs ensemble: its pair correlation differs already at first
    order in density, and its ``S(0)`` is lower at low η (below).

    ``S(q)`` depends on ``qσ`` and on the exclusion packing fraction
    ``η = F_a · (π σ²/4) / |A|`` (``η = F_a`` for circles with σ = 2R).  It
    is read from a Monte Carlo table (:func:`rsa_structure_factor`; made by
    ``scripts/make_rsa_table.py``: exact RSA to saturation in periodic boxes
    of side 60σ; ``S`` from the direct sum over box wave vectors below
    ``qσ = 1.5`` — a polynomial in ``q²`` through the bins, giving ``S(0)`` —
    and from the Hankel transform of the measured ``g(r)`` above ``qσ = 2``,
    blended in between; ensemble averages over 3000 runs).  Checks: ``S(0) = 1 - 4η + 4.4106 η² + O(η³)``
    at low density (first-order kinetic expansion of the RSA pair
    correlation, ``g = 1 + (2/3) n A_ov(r)`` for ``r > σ`` — two thirds of
    the equilibrium value; Widom 1966, J. Chem. Phys. 44, 3888), and
    ``S(0) ≈ 0.059`` at saturation (Torquato, Uche & Stillinger 2006,
    Phys. Rev. E 74, 061308; Zhang & Torquato 2013, Phys. Rev. E 88, 053312).

    Parameters
    ----------
    area_fraction : float
        ``F_a = n |A|`` in ``(0, 0.547]``.
    exclusion_diameter : float or None
        σ [µm]; None uses the shape's ``exclusion_diameter`` (its
        circumscribed diameter).  Must not be smaller than that.
    """

    isotropic = True

    def __init__(self, area_fraction: float = 0.3, exclusion_diameter: float | None = None):
        self.fraction = check_range("area_fraction", area_fraction, 0.0, RSA_JAMMING_LIMIT,
                                    lo_open=True)
        self.exclusion_diameter = (None if exclusion_diameter is None
                                   else check_positive("exclusion_diameter", exclusion_diameter, "µm"))

    def __repr__(self):
        s = f"SequentialAdsorption(area_fraction={self.fraction:g}"
        if self.exclusion_diameter is not None:
            s += f", exclusion_diameter={self.exclusion_diameter:g}"
        return s + ")"

    def area_fraction(self, shape) -> float:
        return self.fraction

    varying_area_fraction = True

    def with_area_fraction(self, area_fraction: float) -> "SequentialAdsorption":
        return SequentialAdsorption(area_fraction, exclusion_diameter=self.exclusion_diameter)

    def _fa_per_eta(self, shape) -> float:
        s = self.sigma(shape)
        return float(shape.area) / (np.pi * s * s / 4.0)

    def area_fraction_limit(self, shape) -> float:
        return min(RSA_JAMMING_LIMIT * self._fa_per_eta(shape), RSA_JAMMING_LIMIT)   # the constructor's bound too

    def area_fraction_nodes(self, shape):
        etas = _rsa_table()[1]
        fas = np.asarray(etas[etas <= RSA_JAMMING_LIMIT], dtype=np.float64) * self._fa_per_eta(shape)
        return fas[fas <= self.area_fraction_limit(shape)]

    def sigma(self, shape) -> float:
        """The exclusion diameter σ [µm] used with ``shape``."""
        return shape.exclusion_diameter if self.exclusion_diameter is None else self.exclusion_diameter

    def packing_fraction(self, shape) -> float:
        """``η = F_a · (π σ²/4) / |A|`` (number density times exclusion-disk area)."""
        s = self.sigma(shape)
        return self.fraction * (np.pi * s * s / 4.0) / shape.area

    def validate(self, shape) -> None:
        s = self.sigma(shape)
        _check_exclusion("SequentialAdsorption", s, shape)
        eta = self.packing_fraction(shape)
        if eta > RSA_JAMMING_LIMIT * (1.0 + 1e-12):
            fmax = RSA_JAMMING_LIMIT * shape.area / (np.pi * s * s / 4.0)
            raise CoronaError(
                f"SequentialAdsorption: area_fraction={self.fraction:g} is out of range for this shape; "
                f"the exclusion packing fraction η = F_a·(πσ²/4)/|A| = {eta:.4g} (σ = {s:g} µm) "
                f"exceeds the RSA jamming limit {RSA_JAMMING_LIMIT}; allowed area_fraction <= {fmax:.4g}")

    def structure_factor(self, q_sigma, packing_fraction: float | None = None) -> np.ndarray:
        """``S`` at dimensionless ``qσ``; ``packing_fraction`` defaults to the
        area fraction (σ equal to the scatterer, e.g. circles with σ = 2R)."""
        eta = self.fraction if packing_fraction is None else packing_fraction
        return rsa_structure_factor(q_sigma, eta)

    def structure_factor_radial(self, q_abs, shape) -> np.ndarray:
        self.validate(shape)
        s = self.sigma(shape)
        return rsa_structure_factor(np.asarray(q_abs, dtype=np.float64) * s,
                                    min(self.packing_fraction(shape), RSA_JAMMING_LIMIT))

    def key(self) -> dict:
        """Parameters plus a digest of the shipped table (so caches follow a regenerated table)."""
        return {**super().key(), "table": _rsa_table_digest()}

    def sample(self, shape, box_size: float, seed=None) -> np.ndarray:
        """Centres [µm] (N, 2) of one RSA realisation in the periodic box
        ``[0, box_size)²`` with this process's density."""
        self.validate(shape)
        return rsa_configuration(box_size, min(self.packing_fraction(shape), RSA_JAMMING_LIMIT),
                                 sigma=self.sigma(shape), seed=seed)


# =====================================================================
# the generator: numba kernels (the ``reference`` extra), compiled lazily on first use
# =====================================================================
_KERNELS = ("minimum_image", "_rsa_free", "_rsa_covered", "rsa_fill")
_JIT_DONE = False


def compile_kernels() -> None:
    """Compile the numba kernels of this module (once; numba caches them on disk)."""
    global _JIT_DONE
    if _JIT_DONE:
        return
    try:
        import numba
    except ImportError:
        raise CoronaError("sampling random sequential adsorption needs numba, which is not installed; "
                          "install the reference extra: pip install 'corona-bsdf[reference]'") from None
    g = globals()
    for name in _KERNELS:
        g[name] = numba.njit(cache=True, nogil=True)(g[name])
    _JIT_DONE = True


def minimum_image(d, L):
    """Minimum-image convention for a separation ``d`` in a period ``L``."""
    if d > 0.5 * L:
        return d - L
    if d < -0.5 * L:
        return d + L
    return d


def _rsa_free(x, y, pos, cell, nc, h, L):
    """True when a unit-diameter disk centred at (x, y) overlaps no placed disk."""
    ci = int(x / h) % nc
    cj = int(y / h) % nc
    for di in range(-2, 3):
        for dj in range(-2, 3):
            if (di == 2 or di == -2) and (dj == 2 or dj == -2):
                continue  # corner cells are farther than h*sqrt(5) > 1
            p = cell[(ci + di) % nc, (cj + dj) % nc]
            if p >= 0:
                dx = minimum_image(pos[p, 0] - x, L)
                dy = minimum_image(pos[p, 1] - y, L)
                if dx * dx + dy * dy < 1.0:
                    return False
    return True


def _rsa_covered(vx, vy, v, pos, cell, nc, h, L):
    """True when the square voxel [vx, vx+v) x [vy, vy+v) lies inside the
    exclusion disk (radius 1) of a single placed centre."""
    cx = vx + 0.5 * v
    cy = vy + 0.5 * v
    ci = int(cx / h) % nc
    cj = int(cy / h) % nc
    for di in range(-2, 3):
        for dj in range(-2, 3):
            p = cell[(ci + di) % nc, (cj + dj) % nc]
            if p >= 0:
                dx = abs(minimum_image(pos[p, 0] - cx, L)) + 0.5 * v
                dy = abs(minimum_image(pos[p, 1] - cy, L)) + 0.5 * v
                if dx * dx + dy * dy < 1.0:
                    return True
    return False


def rsa_fill(L, n_stop, seed):
    """Random sequential adsorption of unit-diameter disks in the periodic box
    ``[0, L)²``; returns the centres (N, 2) in insertion order.

    Stops after ``n_stop`` disks (``n_stop <= 0``: at saturation).  Phase 1
    makes plain uniform attempts up to coverage 0.40; phase 2 is the exact
    voxel method (Wang 1994; Zhang & Torquato 2013): attempts are drawn
    uniformly in a list of equal square voxels that together contain all of
    the still-available area; voxels inside one exclusion disk are dropped
    and, when fewer than a quarter of the attempts of a sweep succeed, every
    voxel is split in four.  Since the voxels cover the whole available area
    and are of equal size, this samples the same process as plain RSA; it
    ends when no voxel is left, i.e. at saturation.
    """
    np.random.seed(seed)
    nc = int(L * math.sqrt(2.0)) + 1  # cell side h < 1/sqrt(2): at most one centre per cell
    h = L / nc
    cell = -np.ones((nc, nc), np.int64)
    n_max = int(L * L / (math.pi / 4.0) * 0.5471 * 1.1) + 16
    if 0 < n_stop < n_max:
        n_max = n_stop
    pos = np.empty((n_max, 2))
    n = 0
    n_switch = int(0.40 * L * L / (math.pi / 4.0))
    fails = 0
    while n < n_max and n < n_switch and fails < 2000:
        x = np.random.random() * L
        y = np.random.random() * L
        if _rsa_free(x, y, pos, cell, nc, h, L):
            pos[n, 0] = x
            pos[n, 1] = y
            cell[int(x / h) % nc, int(y / h) % nc] = n
            n += 1
            fails = 0
        else:
            fails += 1
    if n >= n_max:
        return pos[:n]
    v = 0.5 * h
    nv1 = 2 * nc
    vox = np.empty((nv1 * nv1, 2))
    m = 0
    for i in range(nv1):
        for j in range(nv1):
            vx = i * v
            vy = j * v
            if not _rsa_covered(vx, vy, v, pos, cell, nc, h, L):
                vox[m, 0] = vx
                vox[m, 1] = vy
                m += 1
    depth = 0
    while m > 0 and n < n_max:
        acc = 0
        for _ in range(m):
            k = int(np.random.random() * m)
            x = vox[k, 0] + np.random.random() * v
            y = vox[k, 1] + np.random.random() * v
            if x >= L:
                x -= L
            if y >= L:
                y -= L
            if _rsa_free(x, y, pos, cell, nc, h, L):
                pos[n, 0] = x
                pos[n, 1] = y
                cell[int(x / h) % nc, int(y / h) % nc] = n
                n += 1
                acc += 1
                if n >= n_max:
                    break
        m2 = 0
        for k in range(m):
            if not _rsa_covered(vox[k, 0], vox[k, 1], v, pos, cell, nc, h, L):
                vox[m2, 0] = vox[k, 0]
                vox[m2, 1] = vox[k, 1]
                m2 += 1
        m = m2
        if m > 0 and acc < 0.25 * m and depth < 40:
            v2 = 0.5 * v
            out = np.empty((4 * m, 2))
            m2 = 0
            for k in range(m):
                for a in range(2):
                    for b in range(2):
                        vx = vox[k, 0] + a * v2
                        vy = vox[k, 1] + b * v2
                        if not _rsa_covered(vx, vy, v2, pos, cell, nc, h, L):
                            out[m2, 0] = vx
                            out[m2, 1] = vy
                            m2 += 1
            vox = out
            m = m2
            v = v2
            depth += 1
    return pos[:n]


def rsa_configuration(box_size: float, packing_fraction: float | None = None, *,
                      sigma: float = 1.0, seed=None) -> np.ndarray:
    """One RSA configuration of disks of diameter ``sigma`` in the periodic box
    ``[0, box_size)²``.

    Parameters
    ----------
    box_size : float
        Side of the square periodic box (same unit as ``sigma``).
    packing_fraction : float or None
        Stop at ``N = round(η box_size² / (π σ²/4))`` disks; None runs to
        saturation (``η ≈ 0.5471`` for a large box).
    sigma : float
        Disk (exclusion) diameter.
    seed : int or None
        Seed of the (numba) random generator.

    Returns
    -------
    numpy.ndarray
        Centres (N, 2) in insertion order (fewer than requested if a small
        box saturates first).
    """
    sigma = check_positive("sigma", sigma)
    box_size = check_positive("box_size", box_size)
    L = box_size / sigma
    if L < 3.0:
        raise CoronaError(f"box_size={box_size!r} is out of range; expected >= 3 sigma = {3 * sigma:g}")
    n_stop = 0
    if packing_fraction is not None:
        eta = check_range("packing_fraction", packing_fraction, 0.0, RSA_JAMMING_LIMIT)
        n_stop = int(round(eta * L * L / (np.pi / 4.0)))
        if n_stop == 0:
            return np.zeros((0, 2))
    if seed is None:
        seed = int(np.random.default_rng().integers(2**31 - 1))
    compile_kernels()
    return rsa_fill(float(L), int(n_stop), int(seed)) * sigma




# --- the family (corona.model.registry): process=rsa ---------------------------------------------
registry.add_process(registry.ProcessFamily(
    "rsa", lambda p, shape: SequentialAdsorption(p["area_fraction"],
                                                 exclusion_diameter=p.get("exclusion_diameter")),
    ("area_fraction", "exclusion_diameter"), cls=SequentialAdsorption))
