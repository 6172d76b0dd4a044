"""Structure factors of the scatterers' positions (DESIGN §3).

A point process provides

* ``area_fraction(shape)`` — ``F_a = n |A|``;
* ``structure_factor_at(q, shape)`` — ``S(q)`` at wave vectors ``q``
  [rad/µm] of shape (..., 2), without the forward delta, ``S → 1`` at large q;
* ``structure_factor_radial(q_abs, shape)`` for isotropic processes;
* ``isotropic`` — True when S depends on ``|q|`` only;
* ``validate(shape)`` — a :class:`~corona.CoronaError` naming the parameter,
  its value and the allowed range when the process cannot hold ``shape``;
* ``key()`` — the parameters that identify it (for table caching);
* (:class:`SequentialAdsorption` only) ``sample(shape, box_size, seed)`` —
  one realisation of the centres in a periodic box, for brute-force references.

Processes defined here:

* :class:`Poisson` — independent centres, ``S = 1`` (dilute limit only);
* :class:`SequentialAdsorption` — random sequential adsorption (RSA) of disks,
  ``S(qσ, η)`` from a shipped Monte Carlo table;
* :class:`Lattice` — square / hexagonal lattices with Gaussian jitter
  (Debye–Waller background plus broadened Bragg peaks);
* :class:`PointSet` — measured centres, ``S`` estimated by a windowed direct sum.

(The equilibrium hard-disk fluid lives in :mod:`corona.hard_disk`.)
"""
from __future__ import annotations

import math
import os

import numpy as np

from ._validation import CoronaError, check_choice, check_positive, check_range
class Process:
    """Base class of a point process of scatterer centres."""

    isotropic: bool = True

    def area_fraction(self, shape) -> float:
        raise NotImplementedError

    def structure_factor_at(self, q, shape) -> np.ndarray:
        """``S(q)`` at ``q`` [rad/µm] of shape (..., 2)."""
        q = np.asarray(q, dtype=np.float64)
        return self.structure_factor_radial(np.hypot(q[..., 0], q[..., 1]), shape)

    def structure_factor_radial(self, q_abs, shape) -> np.ndarray:
        """``S(|q|)`` for isotropic processes, ``q_abs`` in rad/µm."""
        raise NotImplementedError

    def validate(self, shape) -> None:
        """Raise a clear error if this process cannot hold ``shape`` as given."""

    def key(self) -> dict:
        from .shapes import _keyable
        return {"type": type(self).__name__, **{k: _keyable(v) for k, v in vars(self).items()
                                                if not k.startswith("_")}}


class Poisson(Process):
    """Independent, uniformly random centres (overlaps allowed): ``S(q) = 1``.

    Only the dilute limit of a real layer: overlapping scatterers make the
    sum rule ``∫ T_a T_s = 1 - F_a`` fail (the lobe integrates to 1 instead).

    Parameters
    ----------
    area_fraction : float, default 0.1
        ``F_a = n |A|`` in (0, 1).
    """

    isotropic = True

    def __init__(self, area_fraction: float = 0.1):
        self.fraction = check_range("area_fraction", area_fraction, 0.0, 1.0,
                                    lo_open=True, hi_open=True)

    def __repr__(self):
        return f"Poisson(area_fraction={self.fraction:g})"

    def area_fraction(self, shape) -> float:
        return self.fraction

    def structure_factor_radial(self, q_abs, shape) -> np.ndarray:
        return np.ones_like(np.asarray(q_abs, dtype=np.float64))

    def structure_factor_at(self, q, shape) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        return np.ones(q.shape[:-1])


# =====================================================================
# numba kernels (compiled lazily on first use, cached on disk)
# =====================================================================
prange = range  # replaced by numba.prange when the kernels are compiled

_JIT_SERIAL = ("_wrap", "_rsa_free", "_rsa_covered", "_rsa_fill", "_rsa_sk_prefix",
               "_rsa_pair_hist", "_sinc", "_hann_ft")
_JIT_PARALLEL = ("_windowed_sk", "_radial_periodogram")
_JIT_DONE = False


def _jit() -> None:
    """Compile the numba kernels of this module (once; numba caches them on disk)."""
    global _JIT_DONE
    if _JIT_DONE:
        return
    import numba
    g = globals()
    g["prange"] = numba.prange
    for name in _JIT_SERIAL:
        g[name] = numba.njit(cache=True, nogil=True)(g[name])
    for name in _JIT_PARALLEL:
        g[name] = numba.njit(cache=True, nogil=True, parallel=True)(g[name])
    _JIT_DONE = True


def _wrap(d, L):
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
                dx = _wrap(pos[p, 0] - x, L)
                dy = _wrap(pos[p, 1] - y, L)
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
                dx = abs(_wrap(pos[p, 0] - cx, L)) + 0.5 * v
                dy = abs(_wrap(pos[p, 1] - cy, L)) + 0.5 * v
                if dx * dx + dy * dy < 1.0:
                    return True
    return False


def _rsa_fill(L, n_stop, seed):
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


def _rsa_sk_prefix(pos, L, targets, mn):
    """``|Σ_{j<N_t} e^{-i k·r_j}|² / N_t`` at the box wave vectors
    ``k = 2π/L (m, n)`` listed in ``mn`` (K, 2), for every prefix length
    ``N_t`` in ``targets`` (sorted) — RSA never removes a disk, so the first
    ``N_t`` centres are the configuration at coverage ``N_t π/4 / L²``."""
    K = mn.shape[0]
    T = targets.shape[0]
    mmax = 0
    for k in range(K):
        mmax = max(mmax, abs(mn[k, 0]), abs(mn[k, 1]))
    out = np.zeros((T, K))
    acc = np.zeros(K, np.complex128)
    px = np.empty(mmax + 1, np.complex128)
    py = np.empty(2 * mmax + 1, np.complex128)
    t = 0
    N = pos.shape[0]
    for j in range(N):
        ex = np.exp(-2j * np.pi * pos[j, 0] / L)
        ey = np.exp(-2j * np.pi * pos[j, 1] / L)
        px[0] = 1.0
        py[mmax] = 1.0
        for a in range(1, mmax + 1):
            px[a] = px[a - 1] * ex
            py[mmax + a] = py[mmax + a - 1] * ey
            py[mmax - a] = np.conj(py[mmax + a])
        for k in range(K):
            acc[k] += px[mn[k, 0]] * py[mmax + mn[k, 1]]
        while t < T and targets[t] == j + 1:
            for k in range(K):
                out[t, k] = (acc[k].real ** 2 + acc[k].imag ** 2) / (j + 1)
            t += 1
    return out


def _rsa_pair_hist(pos, L, targets, dr, nbins):
    """Histogram of pair distances (bin ``dr``) of every prefix configuration
    (counts per target, pairs counted once)."""
    T = targets.shape[0]
    H = np.zeros((T, nbins))
    rmax2 = (dr * nbins) ** 2
    N = pos.shape[0]
    tb = 0
    for j in range(N):
        while tb < T and targets[tb] <= j:
            tb += 1
        if tb >= T:
            break
        for i in range(j):
            dx = _wrap(pos[i, 0] - pos[j, 0], L)
            dy = _wrap(pos[i, 1] - pos[j, 1], L)
            r2 = dx * dx + dy * dy
            if r2 < rmax2:
                b = int(math.sqrt(r2) / dr)
                if b < nbins:
                    H[tb, b] += 1.0
    for t in range(1, T):
        for b in range(nbins):
            H[t, b] += H[t - 1, b]
    return H


def _sinc(x):
    if abs(x) < 1e-8:
        return 1.0 - x * x / 6.0
    return math.sin(x) / x


def _hann_ft(k, L):
    """Fourier transform of the Hann window ``sin²(π x/L)`` on ``[-L/2, L/2]``
    shifted to be centred at 0: ``∫ w(x) e^{-ikx} dx`` (real)."""
    a = 0.5 * k * L
    return L * (0.5 * _sinc(a) + 0.25 * (_sinc(a - math.pi) + _sinc(a + math.pi)))


def _windowed_sk(px, py, w, sumw2, nbar, Lx, Ly, qx, qy):
    """``|Σ_j w_j e^{-i q·s_j} - n̄ Ŵ(q)|² / Σ_j w_j²`` at each ``(qx, qy)``;
    positions are relative to the window centre."""
    M = qx.shape[0]
    out = np.empty(M)
    N = px.shape[0]
    for m in prange(M):
        re = 0.0
        im = 0.0
        a = qx[m]
        b = qy[m]
        for j in range(N):
            ph = a * px[j] + b * py[j]
            re += w[j] * math.cos(ph)
            im -= w[j] * math.sin(ph)
        re -= nbar * _hann_ft(a, Lx) * _hann_ft(b, Ly)
        out[m] = (re * re + im * im) / sumw2
    return out


def _radial_periodogram(px, py, w, sumw2, nbar, Lx, Ly, dq, nq, n_ang):
    """Tapered periodogram on the polar grid ``|q| = k dq`` (k < nq),
    ``θ_a = π (a + 1/2) / n_ang``; returns (n_ang, nq).  The phases along
    each ray are advanced by a complex recurrence."""
    out = np.empty((n_ang, nq))
    N = px.shape[0]
    for a in prange(n_ang):
        th = math.pi * (a + 0.5) / n_ang
        c = math.cos(th)
        s = math.sin(th)
        acc_re = np.zeros(nq)
        acc_im = np.zeros(nq)
        for j in range(N):
            p = c * px[j] + s * py[j]
            st_re = math.cos(dq * p)
            st_im = -math.sin(dq * p)
            z_re = w[j]
            z_im = 0.0
            for k in range(nq):
                acc_re[k] += z_re
                acc_im[k] += z_im
                t = z_re * st_re - z_im * st_im
                z_im = z_re * st_im + z_im * st_re
                z_re = t
        for k in range(nq):
            q = k * dq
            re = acc_re[k] - nbar * _hann_ft(q * c, Lx) * _hann_ft(q * s, Ly)
            out[a, k] = (re * re + acc_im[k] * acc_im[k]) / sumw2
    return out


# =====================================================================
# random sequential adsorption
# =====================================================================
#: Largest accepted RSA packing fraction (saturation is 0.547069, see
#: :class:`SequentialAdsorption`).
RSA_JAMMING_LIMIT = 0.547
#: Saturation (jamming) coverage of RSA disks, Zhang & Torquato (2013).
RSA_SATURATION = 0.547069

_RSA_TABLE_PATH = os.path.join(os.path.dirname(__file__), "data", "rsa_structure_factor.npz")
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
    _jit()
    return _rsa_fill(float(L), int(n_stop), int(seed)) * sigma


def _check_exclusion(process_name, sigma, shape):
    sd = shape.exclusion_diameter
    if sigma < sd * (1.0 - 1e-9):
        raise CoronaError(f"{process_name}: exclusion_diameter={sigma:g} µm is out of range; "
                          f"expected >= the shape's exclusion diameter {sd:g} µm "
                          "(smaller values let scatterers overlap)")


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
# lattices
# =====================================================================
class Lattice(Process):
    """Square or hexagonal lattice of centres with Gaussian jitter.

    Every centre is displaced from its lattice site ``R`` by an independent
    Gaussian of rms ``δ`` per axis (``jitter``).  Then

        S(q) = 1 - e^{-q²δ²} + e^{-q²δ²} (2π)² n Σ_{G≠0} δ²(q - G)

    (Debye–Waller factor ``e^{-q²δ²}``, reciprocal lattice vectors ``G`` with
    ``G·a_i ∈ 2πℤ``, number density ``n = 1 / cell area``; e.g. Ashcroft &
    Mermin, ch. 6 & App. N; Guinier, *X-ray diffraction*, ch. 7).  A Bragg
    delta cannot be rendered, so each is broadened into a normalised 2-D
    Gaussian of rms width ``w = √(2π) / D`` per axis, ``D = domain_size``
    (default 20 spacings): the peak keeps its integrated weight
    ``(2π)² n e^{-G²δ²}`` and its height equals the Laue peak height
    ``n D²`` of a ``D × D`` crystallite.  The forward (``G = 0``) peak is left
    out.  ``S → 0`` as ``q → 0`` (a lattice is hyperuniform).

    With ``orientation="random"`` (a powder of randomly rotated domains) the
    peaks are averaged over rotation into rings: ``S`` is radial,

        S(q) = 1 - e^{-q²δ²} + Σ_shells m (2π)² n e^{-G²δ²} / (2π|G|) · g_w(q - |G|)

    with shell multiplicity ``m`` and a 1-D normalised Gaussian ``g_w``.

    Parameters
    ----------
    kind : {"square", "hexagonal"}
        Lattice type; hexagonal has primitive vectors ``a(1, 0)``,
        ``a(1/2, √3/2)``.
    spacing : float
        Nearest-neighbour distance ``a`` [µm].
    jitter : float, default 0
        rms displacement per axis ``δ`` [µm].
    domain_size : float or None
        Crystallite size ``D`` [µm] setting the peak width; None → 20·spacing.
    orientation : {"fixed", "random"}
        Fixed lattice (anisotropic ``S``) or powder average (radial ``S``).
    angle : float, default 0
        Rotation of the fixed lattice [rad], counter-clockwise (as the
        ``angle`` of :mod:`corona.shapes`).
    """

    def __init__(self, kind: str = "square", spacing: float = 1.0, jitter: float = 0.0,
                 domain_size: float | None = None, orientation: str = "fixed", angle: float = 0.0):
        self.kind = check_choice("kind", kind, ("square", "hexagonal"))
        self.spacing = check_positive("spacing", spacing, "µm")
        self.jitter = check_range("jitter", jitter, 0.0, math.inf, hi_open=True, unit="µm")
        if domain_size is None:
            domain_size = 20.0 * self.spacing
        self.domain_size = check_range("domain_size", domain_size, self.spacing, math.inf,
                                       lo_open=True, hi_open=True, unit="µm")
        self.orientation = check_choice("orientation", orientation, ("fixed", "random"))
        self.angle = check_range("angle", angle, -math.inf, math.inf, lo_open=True, hi_open=True,
                                 unit="rad")

    def __repr__(self):
        return (f"Lattice(kind={self.kind!r}, spacing={self.spacing:g}, jitter={self.jitter:g}, "
                f"domain_size={self.domain_size:g}, orientation={self.orientation!r}, "
                f"angle={self.angle:g})")

    @property
    def isotropic(self) -> bool:
        return self.orientation == "random"

    # --- geometry ------------------------------------------------------
    @property
    def lattice_vectors(self) -> np.ndarray:
        """Primitive vectors ``a_1, a_2`` as rows [µm] (rotated by ``angle``)."""
        a = self.spacing
        A = (np.array([[a, 0.0], [0.0, a]]) if self.kind == "square"
             else np.array([[a, 0.0], [0.5 * a, 0.5 * np.sqrt(3.0) * a]]))
        c, s = np.cos(self.angle), np.sin(self.angle)
        return A @ np.array([[c, s], [-s, c]])

    @property
    def reciprocal_vectors(self) -> np.ndarray:
        """Primitive reciprocal vectors ``b_1, b_2`` as rows [rad/µm]
        (``a_i · b_j = 2π δ_ij``)."""
        return 2.0 * np.pi * np.linalg.inv(self.lattice_vectors).T

    @property
    def cell_area(self) -> float:
        """Area of the primitive cell [µm²]: ``a²`` or ``(√3/2) a²``."""
        return float(abs(np.linalg.det(self.lattice_vectors)))

    @property
    def number_density(self) -> float:
        """``n = 1 / cell area`` [µm⁻²]."""
        return 1.0 / self.cell_area

    @property
    def peak_width(self) -> float:
        """rms width ``w = √(2π)/D`` [rad/µm] of a broadened Bragg peak (per axis)."""
        return np.sqrt(2.0 * np.pi) / self.domain_size

    def bragg_peaks(self, q_max: float):
        """Reciprocal lattice vectors ``0 < |G| <= q_max`` and their weights.

        Returns
        -------
        G : numpy.ndarray (M, 2)
            Peak positions [rad/µm].
        weight : numpy.ndarray (M,)
            Integrated weight ``(2π)² n e^{-G²δ²}`` [rad²/µm²] of each peak.
        """
        B = self.reciprocal_vectors
        bmin = min(np.linalg.norm(B[0]), np.linalg.norm(B[1]))
        hmax = int(np.ceil(q_max * self.spacing / (2.0 * np.pi) * 2.0)) + 2
        h = np.arange(-hmax, hmax + 1)
        hk = np.stack(np.meshgrid(h, h, indexing="ij"), -1).reshape(-1, 2)
        G = hk @ B
        g = np.hypot(G[:, 0], G[:, 1])
        keep = (g > 0.5 * bmin) & (g <= q_max)
        G, g = G[keep], g[keep]
        order = np.lexsort((np.arctan2(G[:, 1], G[:, 0]), g))
        G, g = G[order], g[order]
        return G, (2.0 * np.pi) ** 2 * self.number_density * np.exp(-(g * self.jitter) ** 2)

    # --- process interface ----------------------------------------------
    def area_fraction(self, shape) -> float:
        return shape.area / self.cell_area

    def validate(self, shape) -> None:
        sd = shape.exclusion_diameter
        if sd > self.spacing * (1.0 + 1e-12):
            raise CoronaError(f"Lattice: spacing={self.spacing:g} µm is out of range for this shape; "
                              f"expected >= its exclusion diameter {sd:g} µm (neighbours would overlap)")
        fa = self.area_fraction(shape)
        if fa >= 1.0:
            raise CoronaError(f"Lattice: area fraction |A|/cell area = {fa:.4g} is out of range; "
                              "expected < 1")

    def _background(self, q2):
        dw = np.exp(-q2 * self.jitter ** 2)
        return 1.0 - dw

    def structure_factor_at(self, q, shape=None) -> np.ndarray:
        """``S(q)`` at ``q`` [rad/µm] of shape (..., 2) (radial for random orientation)."""
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 0 or q.shape[-1] != 2:
            raise CoronaError(f"q must have shape (..., 2), got {q.shape}")
        if self.isotropic:
            return self.structure_factor_radial(np.hypot(q[..., 0], q[..., 1]), shape)
        q2 = q[..., 0] ** 2 + q[..., 1] ** 2
        out = self._background(q2)
        A = self.lattice_vectors
        B = self.reciprocal_vectors
        w = self.peak_width
        amp = (2.0 * np.pi) ** 2 * self.number_density / (2.0 * np.pi * w * w)
        # fractional reciprocal coordinates: q = f_1 b_1 + f_2 b_2, f_i = q·a_i / 2π
        f = q @ A.T / (2.0 * np.pi)
        f0 = np.rint(f)
        m = max(1, int(np.ceil(0.5 + 6.0 * w * self.spacing / (2.0 * np.pi))))
        for dh in range(-m, m + 1):
            for dk in range(-m, m + 1):
                hk = f0 + np.array([dh, dk], dtype=np.float64)
                G = hk @ B
                G2 = G[..., 0] ** 2 + G[..., 1] ** 2
                d2 = (q[..., 0] - G[..., 0]) ** 2 + (q[..., 1] - G[..., 1]) ** 2
                peak = amp * np.exp(-G2 * self.jitter ** 2) * np.exp(-0.5 * d2 / (w * w))
                peak = np.where((hk[..., 0] == 0) & (hk[..., 1] == 0), 0.0, peak)
                out = out + peak
        return out

    def structure_factor_cell_mean(self, q, cell: float, shape=None) -> np.ndarray:
        """Mean of ``S`` over square cells ``[q - cell/2, q + cell/2]²``.

        The broadened Bragg peaks (rms width :attr:`peak_width`) are often
        narrower than the cells of a 2-D table; sampling ``S`` at cell centres
        then misses or overweights them.  The cell mean is exact here: the
        peaks and the Debye–Waller factor are separable Gaussians, whose cell
        means are differences of error functions.  Tables built from it keep
        every peak's integrated weight.

        Parameters
        ----------
        q : array_like (..., 2)
            Cell centres [rad/µm] (axes of the layer frame).
        cell : float
            Cell side [rad/µm].
        """
        return self.background_cell_mean(q, cell) + self.bragg_cell_mean(q, cell)

    def _check_cells(self, q, cell):
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 0 or q.shape[-1] != 2:
            raise CoronaError(f"q must have shape (..., 2), got {q.shape}")
        c = check_positive("cell", cell, "rad/µm")
        if self.isotropic:
            raise CoronaError("Lattice: cell means are for orientation='fixed'")
        return q, c

    def background_cell_mean(self, q, cell: float) -> np.ndarray:
        """Cell mean of the diffuse background ``1 - e^{-q²δ²}`` (see :meth:`structure_factor_cell_mean`)."""
        from scipy.special import erf
        q, c = self._check_cells(q, cell)
        h, d = 0.5 * c, self.jitter
        dw = np.ones(q.shape[:-1])
        if d > 0.0:
            for i in range(2):
                x = q[..., i]
                # √π/(2δc) [erf((x+h)δ) - erf((x-h)δ)]; for (|x|+h)δ << 1 (a tiny
                # jitter, where the quotient is 0/0 in floating point) its series
                # e^{-δ²(x² + c²/12)}
                small = (np.abs(x) + h) * d < 1e-4
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    exact = np.sqrt(np.pi) / (2.0 * d * c) * (erf((x + h) * d) - erf((x - h) * d))
                dw = dw * np.where(small, np.exp(-d * d * (x * x + c * c / 12.0)), exact)
        return 1.0 - dw

    #: above this many Bragg peaks per table cell their sum is taken as smooth
    PEAKS_PER_CELL_MAX = 16.0

    def bragg_cell_mean(self, q, cell: float, peak_factor=None) -> np.ndarray:
        """Cell mean of the Bragg peaks, each scaled by ``peak_factor(G)``.

        ``Σ_G f(G) W_G ⟨g_G⟩_cell`` with ``W_G = (2π)² n e^{-G²δ²}`` the peak's
        weight and ``g_G`` its unit Gaussian; ``peak_factor`` (default 1) maps
        peak positions (M, 2) [rad/µm] to factors (M,).  A table that
        multiplies each peak by the form factor at the peak itself (not at the
        cell centre) keeps the exact weight ``f(G) W_G`` of every peak.  Where
        the peaks outnumber the cells, the peaks of a cell share the factor at
        the cell's centre; above :attr:`PEAKS_PER_CELL_MAX` peaks per cell (a
        sparse lattice, small area fraction) their sum is the cell mean of its
        smooth envelope ``e^{-q²δ²}`` (the same total weight).
        """
        from scipy.special import erf
        q, c = self._check_cells(q, cell)
        h, d = 0.5 * c, self.jitter

        def mean_gauss_1d(x, centre, sig):  # cell mean of exp(-(x-centre)²/(2 sig²)) / (√(2π) sig)
            s2 = np.sqrt(2.0) * sig
            return 0.5 * (erf((x + h - centre) / s2) - erf((x - h - centre) / s2)) / c

        A = self.lattice_vectors
        B = self.reciprocal_vectors
        w = self.peak_width
        wt = (2.0 * np.pi) ** 2 * self.number_density
        if c * c > self.PEAKS_PER_CELL_MAX * abs(np.linalg.det(B)):
            # a sparse lattice: many peaks per cell, whose cell mean is that of
            # their smooth envelope e^{-q²δ²} (total weight kept), less the
            # q = 0 peak (the coherent beam, not part of S)
            out = (1.0 - self.background_cell_mean(q, c)
                   - wt * mean_gauss_1d(q[..., 0], 0.0, w) * mean_gauss_1d(q[..., 1], 0.0, w))
            if peak_factor is not None:
                out = out * np.asarray(peak_factor(q.reshape(-1, 2)), dtype=np.float64).reshape(q.shape[:-1])
            return np.maximum(out, 0.0)
        f0 = np.rint(q @ A.T / (2.0 * np.pi))
        m = max(1, int(np.ceil(0.5 + (6.0 * w + h * np.sqrt(2.0)) * self.spacing / (2.0 * np.pi))))
        factor = centre_factor = None
        if peak_factor is not None and f0.size:
            # the factor on every reciprocal lattice point the cells can reach
            lo = f0.reshape(-1, 2).min(axis=0).astype(int) - m
            hi = f0.reshape(-1, 2).max(axis=0).astype(int) + m
            if np.prod(hi - lo + 1) <= max(q.size // 2, 1024):
                hh, kk = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
                G_all = np.stack([hh, kk], -1).reshape(-1, 2) @ B
                factor = np.asarray(peak_factor(G_all), dtype=np.float64).reshape(hh.shape)
            else:
                # more peaks than cells: the many peaks of a cell share the factor at its centre
                centre_factor = np.asarray(peak_factor(q.reshape(-1, 2)), dtype=np.float64).reshape(q.shape[:-1])
        out = np.zeros(q.shape[:-1])
        for dh in range(-m, m + 1):
            for dk in range(-m, m + 1):
                hk = f0 + np.array([dh, dk], dtype=np.float64)
                G = hk @ B
                G2 = G[..., 0] ** 2 + G[..., 1] ** 2
                peak = (wt * np.exp(-G2 * d * d) * mean_gauss_1d(q[..., 0], G[..., 0], w)
                        * mean_gauss_1d(q[..., 1], G[..., 1], w))
                if factor is not None:
                    ih = hk[..., 0].astype(int) - lo[0]
                    ik = hk[..., 1].astype(int) - lo[1]
                    peak = peak * factor[ih, ik]
                out = out + np.where((hk[..., 0] == 0) & (hk[..., 1] == 0), 0.0, peak)
        return out if centre_factor is None else out * centre_factor

    def structure_factor_radial(self, q_abs, shape=None) -> np.ndarray:
        """Powder-averaged ``S(|q|)`` (only for ``orientation="random"``)."""
        if not self.isotropic:
            raise CoronaError("Lattice: structure_factor_radial needs orientation='random'; "
                              "a fixed lattice is anisotropic, use structure_factor_at")
        q = np.abs(np.asarray(q_abs, dtype=np.float64))
        out = self._background(q * q)
        w = self.peak_width
        qmax = float(q.max()) if q.size else 0.0
        G, weight = self.bragg_peaks(qmax + 8.0 * w)
        if len(G) == 0:
            return out
        g = np.hypot(G[:, 0], G[:, 1])
        shells, inv = np.unique(np.round(g / self.spacing ** -1, 9), return_inverse=True)
        gs = np.zeros(len(shells))
        ws = np.zeros(len(shells))
        np.add.at(ws, inv, weight)
        np.add.at(gs, inv, g)
        counts = np.bincount(inv, minlength=len(shells))
        gs /= counts
        norm = 1.0 / (np.sqrt(2.0 * np.pi) * w)
        flat = q.reshape(-1)
        res = out.reshape(-1).copy()
        for gk, wk in zip(gs, ws):
            sel = np.abs(flat - gk) < 8.0 * w
            if np.any(sel):
                res[sel] += wk / (2.0 * np.pi * gk) * norm * np.exp(-0.5 * ((flat[sel] - gk) / w) ** 2)
        return res.reshape(q.shape)


# =====================================================================
# measured point sets
# =====================================================================
def _parse_box(box):
    try:
        b = np.asarray(box, dtype=np.float64)
    except (TypeError, ValueError):
        raise CoronaError(f"box={box!r} is not (Lx, Ly) or ((x0, x1), (y0, y1))") from None
    if b.shape == (2,):
        b = np.array([[0.0, b[0]], [0.0, b[1]]])
    if b.shape != (2, 2) or not np.all(np.isfinite(b)) or np.any(b[:, 1] <= b[:, 0]):
        raise CoronaError(f"box={box!r} is out of range; expected (Lx, Ly) > 0 or "
                          "((x0, x1), (y0, y1)) with x1 > x0, y1 > y0 [µm]")
    return b


class PointSet(Process):
    """Measured scatterer centres in a rectangular window.

    ``S(q)`` is the tapered periodogram of the one realisation,

        S(q) = |Σ_j w(s_j) e^{-i q·s_j} - n̄ Ŵ(q)|² / Σ_j w(s_j)²,

    with the separable Hann window ``w(x, y) = sin²(π x'/L_x) sin²(π y'/L_y)``
    (``x', y'`` measured from the box corner), its Fourier transform ``Ŵ``
    (analytic) and ``n̄ = N / box area``.  The taper suppresses the box-edge
    leakage of the plain ``|Σ e^{-iq·s}|²/N``; subtracting ``n̄ Ŵ(q)`` removes
    the forward (mean-density) peak.  The estimate is ``S`` convolved with
    ``|Ŵ|²/∫w²`` (resolution ≈ 4π/L), so values at ``|q| ≲ 4π/L`` are not
    meaningful; see Percival & Walden, *Spectral analysis for physical
    applications* (1993), ch. 6, and T. Rajala, S. Olhede, J. Grainger,
    D. Murrell, "What is the Fourier transform of a spatial point process?",
    IEEE Trans. Inf. Theory (2023), arXiv:2009.01474 (tapering, isotropic
    averages).

    With ``isotropic=True`` (default) ``S`` is the average over ``n_angles``
    directions of ``q`` (default 256, on a half circle since ``S(-q) = S(q)``),
    computed once on a radial grid of step ``π/L`` (``L`` the longer box
    side), smoothed with weights (1/4, 1/2, 1/4) and interpolated linearly;
    cost ``∝ N · n_angles · q_max L``.  With ``isotropic=False`` the raw
    periodogram is evaluated at each ``q`` (anisotropic, and noisy: one
    realisation's periodogram has ~100 % scatter at each ``q``).

    Parameters
    ----------
    points : array_like (N, 2)
        Centres [µm], inside the box.
    box : (Lx, Ly) or ((x0, x1), (y0, y1))
        Observation window [µm].
    isotropic : bool, default True
        Angular average (radial ``S``) or the raw anisotropic estimate.
    n_angles : int or None
        Directions of the angular average (None: 256).
    """

    def __init__(self, points, box, isotropic: bool = True, n_angles: int | None = None):
        try:
            p = np.array(points, dtype=np.float64)
        except (TypeError, ValueError):
            raise CoronaError("points must be a numeric array of shape (N, 2)") from None
        if p.ndim != 2 or p.shape[1] != 2:
            raise CoronaError(f"points must have shape (N, 2), got {p.shape}")
        if p.shape[0] < 1:
            raise CoronaError("points is empty; a PointSet needs at least one centre")
        if not np.all(np.isfinite(p)):
            raise CoronaError("points contains non-finite values")
        b = _parse_box(box)
        tol = 1e-9 * float(np.max(b[:, 1] - b[:, 0]))
        outside = ((p[:, 0] < b[0, 0] - tol) | (p[:, 0] > b[0, 1] + tol)
                   | (p[:, 1] < b[1, 0] - tol) | (p[:, 1] > b[1, 1] + tol))
        if np.any(outside):
            k = int(np.argmax(outside))
            raise CoronaError(f"points[{k}] = {tuple(p[k])} lies outside box "
                              f"x in [{b[0, 0]:g}, {b[0, 1]:g}], y in [{b[1, 0]:g}, {b[1, 1]:g}] µm")
        p.setflags(write=False)
        self.points = p
        self.box = (tuple(b[0]), tuple(b[1]))
        self.isotropic = bool(isotropic)
        if n_angles is not None:
            n_angles = int(check_range("n_angles", n_angles, 1, 1e6))
        self.n_angles = n_angles
        self._radial = None  # (q grid, S grid)

    def __repr__(self):
        return (f"PointSet(<{len(self.points)} points>, box={self.box}, "
                f"isotropic={self.isotropic})")

    # --- construction -----------------------------------------------------
    @classmethod
    def from_file(cls, path, box=None, **kwargs) -> "PointSet":
        """Read centres [µm] from a text file (CSV, semicolon-, tab- or
        whitespace-separated; ``#`` comments and one header line allowed; the
        first two columns are x, y) or a ``.npy`` array (N, ≥2).

        ``box=None`` estimates the window from the points: per axis the
        unbiased range of N uniform points, ``(max - min)(N + 1)/(N - 1)``,
        centred on the points.
        """
        path = os.fspath(path)
        if not os.path.exists(path):
            raise CoronaError(f"point file {path!r} does not exist")
        if os.path.isdir(path):
            raise CoronaError(f"point file {path!r} is a directory")
        if path.lower().endswith(".npy"):
            try:
                arr = np.load(path, allow_pickle=False)
            except Exception as e:  # noqa: BLE001
                raise CoronaError(f"point file {path!r} is not a readable .npy array: {e}") from None
            try:
                arr = np.asarray(arr, dtype=np.float64)
            except (TypeError, ValueError):
                raise CoronaError(f"point file {path!r} does not hold numbers") from None
            if arr.size == 0:
                raise CoronaError(f"point file {path!r} contains no points")
            if arr.ndim != 2 or arr.shape[1] < 2:
                raise CoronaError(f"point file {path!r} holds an array of shape {arr.shape}; "
                                  "expected (N, 2) or more columns")
            pts = arr[:, :2]
        else:
            pts = _read_point_text(path)
        if not np.all(np.isfinite(pts)):
            raise CoronaError(f"point file {path!r} contains non-finite coordinates")
        if box is None:
            n = len(pts)
            if n < 2:
                raise CoronaError(f"point file {path!r} has {n} point; give box= explicitly")
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            if np.any(hi <= lo):
                raise CoronaError(f"point file {path!r}: the points do not span an area; give box=")
            half = 0.5 * (hi - lo) * (n + 1) / (n - 1)
            mid = 0.5 * (hi + lo)
            box = ((mid[0] - half[0], mid[0] + half[0]), (mid[1] - half[1], mid[1] + half[1]))
        return cls(pts, box, **kwargs)

    # --- geometry -----------------------------------------------------------
    @property
    def box_size(self):
        """``(Lx, Ly)`` [µm]."""
        return (self.box[0][1] - self.box[0][0], self.box[1][1] - self.box[1][0])

    @property
    def box_area(self) -> float:
        Lx, Ly = self.box_size
        return Lx * Ly

    @property
    def number_density(self) -> float:
        """``n = N / box area`` [µm⁻²]."""
        return len(self.points) / self.box_area

    def area_fraction(self, shape) -> float:
        return len(self.points) * shape.area / self.box_area

    def validate(self, shape) -> None:
        fa = self.area_fraction(shape)
        if fa >= 1.0:
            raise CoronaError(f"PointSet: area fraction N|A|/box area = {fa:.4g} is out of range; "
                              "expected < 1 (shape too large for these centres)")

    # --- structure factor ----------------------------------------------------
    def _window(self):
        (x0, x1), (y0, y1) = self.box
        Lx, Ly = x1 - x0, y1 - y0
        px = self.points[:, 0] - 0.5 * (x0 + x1)
        py = self.points[:, 1] - 0.5 * (y0 + y1)
        w = np.cos(np.pi * px / Lx) ** 2 * np.cos(np.pi * py / Ly) ** 2
        return px, py, w, Lx, Ly

    def periodogram(self, q) -> np.ndarray:
        """The tapered periodogram at ``q`` [rad/µm] of shape (..., 2) (no averaging)."""
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 0 or q.shape[-1] != 2:
            raise CoronaError(f"q must have shape (..., 2), got {q.shape}")
        px, py, w, Lx, Ly = self._window()
        sw2 = float(np.sum(w * w))
        if sw2 <= 0.0:
            return np.ones(q.shape[:-1])
        _jit()
        flat = q.reshape(-1, 2)
        out = _windowed_sk(px, py, w, sw2, self.number_density, Lx, Ly,
                           np.ascontiguousarray(flat[:, 0]), np.ascontiguousarray(flat[:, 1]))
        return out.reshape(q.shape[:-1])

    def _radial_table(self, q_max):
        if self._radial is not None and self._radial[0][-1] >= q_max:
            return self._radial
        px, py, w, Lx, Ly = self._window()
        L = max(Lx, Ly)
        dq = np.pi / L
        nq = int(np.ceil(1.25 * q_max / dq)) + 3
        n_ang = 256 if self.n_angles is None else self.n_angles
        sw2 = float(np.sum(w * w))
        _jit()
        P = _radial_periodogram(px, py, w, sw2, self.number_density, Lx, Ly, dq, nq, n_ang)
        S = P.mean(axis=0)
        # light radial smoothing (1/4, 1/2, 1/4): width ≈ 2π/L, below the taper's resolution
        Ss = S.copy()
        Ss[1:-1] = 0.25 * S[:-2] + 0.5 * S[1:-1] + 0.25 * S[2:]
        self._radial = (np.arange(nq) * dq, Ss)
        return self._radial

    def structure_factor_radial(self, q_abs, shape=None) -> np.ndarray:
        """Angle-averaged estimate of ``S(|q|)`` (``q_abs`` in rad/µm)."""
        q = np.abs(np.asarray(q_abs, dtype=np.float64))
        if q.size == 0:
            return np.zeros(q.shape)
        qg, S = self._radial_table(float(q.max()))
        return np.interp(q, qg, S)

    def structure_factor_at(self, q, shape=None) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 0 or q.shape[-1] != 2:
            raise CoronaError(f"q must have shape (..., 2), got {q.shape}")
        if self.isotropic:
            return self.structure_factor_radial(np.hypot(q[..., 0], q[..., 1]), shape)
        return self.periodogram(q)


def _read_point_text(path) -> np.ndarray:
    rows = []
    header_skipped = False
    try:
        with open(path, "r", encoding="utf-8-sig") as fh:
            for lineno, line in enumerate(fh, 1):
                s = line.split("#", 1)[0].strip()
                if not s:
                    continue
                tokens = s.replace(",", " ").replace(";", " ").split()
                try:
                    vals = [float(t) for t in tokens[:2]]
                    if len(tokens) < 2:
                        raise ValueError
                except ValueError:
                    if not rows and not header_skipped and len(tokens) >= 2 and not any(
                            _is_number(t) for t in tokens[:2]):
                        header_skipped = True  # a header line such as "x,y"
                        continue
                    raise CoronaError(f"point file {path!r}, line {lineno}: cannot read two numbers "
                                      f"(x, y) from {line.strip()!r}") from None
                rows.append(vals)
    except UnicodeDecodeError:
        raise CoronaError(f"point file {path!r} is not a text file (use .npy for binary arrays)") from None
    if not rows:
        raise CoronaError(f"point file {path!r} contains no points")
    return np.array(rows, dtype=np.float64)


def _is_number(t) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False
