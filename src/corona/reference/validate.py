"""The model against the brute force, case by case: ``corona validate`` (docs/physics.md#validation-figures).

For each case an ensemble of random screens is rasterised and Fourier
transformed (:func:`corona.reference.wave.brute_force`) and compared with the model's
lobe ``F_a T_a(d) T_s(d)`` (:meth:`corona.Material.lobe`) on the same FFT grid.

The case matrix
---------------
Shapes circle, square, regular hexagon and an irregular binary mask (all of
circumradius ``R = 2.5 µm``; the mask has 18 pixels per circumradius) ×
area fractions 0.1, 0.3, 0.45, 0.6 × aperture and particle × wavelengths
400, 550, 700 nm, positions from the hard-disk simulation (the process whose
``S`` is the shipped simulated table).  The hard-disk packing fraction
``η = F_a (π σ²/4)/|A|`` (σ = circumscribed diameter) must stay ≤ 0.72, which
rules out F_a = 0.6 for the square (η = 0.94), the hexagon (0.73) and the mask;
those cases are listed as skipped with the reason.  One ensemble serves both
modes (the screens are complements) and all wavelengths (``d = qλ/2π``).

Extra cases exercise the other processes and shapes, where the model uses an
approximation or a different estimate (Poisson with overlaps, RSA table,
measured point set, jittered lattice, soft edge, random orientation, size
distribution, mixture, a small radius with an evanescent part).

Metrics (per case, mode and wavelength)
---------------------------------------
* Bins: rings in ``u = |q| R`` of width 0.1 (merged at small u until each bin
  holds ≥ 300 grid points per sector) × angular sectors (6 per symmetry period
  of ``|Â|²``: 90° square, 60° hexagon, 180° mask; one sector for radial
  lobes).  Brute force and model are both averaged over exactly the grid
  points of each bin, so the binning itself adds no bias.  The DC bin is left
  out (it holds the coherent peak).
* Region: bins where the binned model exceeds 1 % of its largest bin value,
  with ``|u| ≤ 16`` and inside the propagating disk ``|d| ≤ 1`` (normal
  incidence).
* Lobe error: RMS and max over the region of ``brute / model - 1``.
* Noise: the same RMS of ``(brute_even - brute_odd) / (2 model)`` (split-half
  estimate of the statistical error of the mean of all realisations).
* Coherent weight: ``⟨mean t⟩²`` against ``F_a²`` / ``(1 - F_a)²``.
* Sum rule: the diffuse energy in ``|u| ≤ 16`` (brute force) against the
  model integrated over the same grid points, the model's whole-plane
  ``∫ lobe`` against ``F_a (1 - F_a)``, and the brute force's Parseval total
  ``⟨mean t²⟩ - ⟨mean t⟩²`` of the rasterised screen.
* Propagating diffuse transmittance at each wavelength (``|d| ≤ 1``):
  brute force against :meth:`corona.Material.diffuse_transmittance`.
"""
from __future__ import annotations

import datetime
import io
import json
import math
import os
import platform
import tempfile
import time
import warnings
from dataclasses import dataclass

import numpy as np

from corona._validation import CoronaError, CoronaWarning, check_range

WAVELENGTHS = (400.0, 550.0, 700.0)
RADIUS = 2.5                      # circumradius of the matrix shapes [µm]
U_COMPARE = 16.0                  # |u| range of the lobe comparison
U_IMAGE = 12.0                    # |u| range of the 2D pictures
REGION_FRACTION = 0.01            # region: model above 1 % of its peak
BIN_DU = 0.1
BIN_MIN_POINTS = 300
SECTORS = 6
GOAL_RMS = 0.02
MATRIX_SHAPES = ("circle", "square", "hexagon", "mask")
MATRIX_FRACTIONS = (0.1, 0.3, 0.45, 0.6)
QUICK_SHAPES = ("circle", "hexagon")
QUICK_FRACTIONS = (0.3,)
REALISATIONS = 64
QUICK_REALISATIONS = 16


# ==========================================================================
# shapes and cases
# ==========================================================================
def blob_mask_image(n: int = 40, r0: float = 14.0) -> np.ndarray:
    """A binary, irregular (no symmetry) blob:
    ``r ≤ r0 (1 + 0.18 cos(2θ - 0.3) + 0.09 cos(3θ + 1.1))`` (pixels)."""
    j, i = np.meshgrid(np.arange(n), np.arange(n), indexing="xy")
    x, y = j - (n - 1) / 2, (n - 1) / 2 - i
    th = np.arctan2(y, x)
    rb = r0 * (1 + 0.18 * np.cos(2 * th - 0.3) + 0.09 * np.cos(3 * th + 1.1))
    return (np.hypot(x, y) <= rb).astype(np.float64)


def make_shape(name: str, radius: float = RADIUS):
    """Matrix shapes of circumradius ``radius`` [µm]."""
    from corona.model import shapes
    if name == "circle":
        return shapes.Circle(radius)
    if name == "square":
        return shapes.Square(radius / math.sqrt(2.0))   # half-width R/√2: circumradius R
    if name == "hexagon":
        return shapes.RegularPolygon(6, radius)
    if name == "mask":
        img = blob_mask_image()
        r_px = shapes.Mask(img, 1.0).length_scale          # circumradius in pixels
        return shapes.Mask(img, radius / r_px)
    raise CoronaError(f"shape={name!r} is not one of 'circle', 'square', 'hexagon', 'mask'")


@dataclass
class Case:
    """One brute-force ensemble (serving both modes and all wavelengths)."""
    name: str
    label: str
    build: object                  # callable () -> (shape, process)
    kind: str = "matrix"           # "matrix" (hard-disk table, goal applies) or "extra"
    note: str = ""
    overlaps: str = "clip"
    n_scatterers: int = 2000
    realisations: int | None = None
    shape_name: str = ""
    fraction: float = float("nan")


def _hd(shape_name, fa):
    def build():
        from corona.model.processes import HardDisk
        return make_shape(shape_name), HardDisk(fa)
    return build


def matrix_cases(quick: bool = False) -> list[Case]:
    shapes_ = QUICK_SHAPES if quick else MATRIX_SHAPES
    fracs = QUICK_FRACTIONS if quick else MATRIX_FRACTIONS
    return [Case(f"{s}-hd-{fa:.2f}", f"{s}, hard disks, F_a={fa:g}", _hd(s, fa), "matrix",
                 shape_name=s, fraction=fa) for s in shapes_ for fa in fracs]


def extra_cases(quick: bool = False) -> list[Case]:
    from corona.model import shapes
    from corona.model.processes import HardDisk, Lattice, PointSet, Poisson, SequentialAdsorption
    from corona.reference.wave import hard_disk_configurations, lattice_box
    R = RADIUS

    def poisson(fa):
        return lambda: (shapes.Circle(R), Poisson(fa))

    def rsa():
        return shapes.Circle(R), SequentialAdsorption(0.3)

    def pointset():
        snaps, L = hard_disk_configurations(0.3, 1, 2000, seed=12345)
        sigma = 2 * R
        return shapes.Circle(R), PointSet(snaps[0] * sigma, (L * sigma, L * sigma))

    def lattice():
        fa = 0.3
        a = math.sqrt(math.pi * R * R / fa)
        probe = Lattice("square", a, jitter=0.1 * a)
        Lx, _ = lattice_box(probe, 2000)
        return shapes.Circle(R), Lattice("square", a, jitter=0.1 * a, domain_size=Lx / 4)

    def soft():
        return shapes.SoftEdge(shapes.Circle(R), 0.1), HardDisk(0.3)

    def rotated():
        return shapes.RandomOrientation(shapes.Square(R / math.sqrt(2))), HardDisk(0.3)

    def sized():
        return shapes.SizeDistribution(shapes.Circle(R), 0.1), HardDisk(0.3)

    def mixture():
        return shapes.Mixture([(shapes.Circle(R), 0.5), (shapes.Circle(0.6 * R), 0.5)]), HardDisk(0.3)

    def small():
        return shapes.Circle(0.5), HardDisk(0.3)

    out = [
        Case("circle-poisson-0.10", "circle, Poisson, F_a=0.1 (overlaps clipped)", poisson(0.1), "extra",
             "Poisson centres overlap; the screen transmits the union (t = min(1, Σ A)), the model "
             "assumes t = Σ A (dilute limit)."),
        Case("circle-poisson-0.30", "circle, Poisson, F_a=0.3 (overlaps clipped)", poisson(0.3), "extra",
             "As above at a higher density: the union of overlapping openings transmits less and "
             "correlates the screen."),
        Case("circle-poisson-0.30-add", "circle, Poisson, F_a=0.3, linear t = Σ A", poisson(0.3), "extra",
             "The model's own assumption (overlaps add, t may exceed 1): must agree exactly.",
             overlaps="add"),
        Case("circle-rsa-0.30", "circle, RSA, F_a=0.3", rsa, "extra",
             "S from the shipped RSA Monte Carlo table (3000 runs, smoothed)."),
        Case("circle-pointset-0.30", "circle, measured point set (one hard-disk snapshot)", pointset,
             "extra", "One realisation only: the model uses the tapered, angle-averaged periodogram of "
             "the same points, the brute force the periodic |FFT|² of the same points (noisy).",
             realisations=1),
        Case("circle-lattice-0.30", "circle, square lattice, jitter 0.1 a, F_a=0.3", lattice, "extra",
             "Bragg peaks: the brute force has exact deltas on the box wave vectors, the model "
             "Gaussians of width √(2π)/D (D = box/4); compared bin by bin as integrated weights."),
        Case("softedge-hd-0.30", "soft-edge circle (w=0.1 µm), hard disks, F_a=0.3", soft, "extra",
             "Exact in the model (deterministic profile)."),
        Case("square-random-hd-0.30", "randomly oriented square, hard disks, F_a=0.3", rotated, "extra",
             "Decoupling rule; exact here because orientations are independent of positions and the "
             "exclusion diameter is the circumscribed one."),
        Case("circle-size-hd-0.30", "circle, lognormal sizes (10 %), hard disks, F_a=0.3", sized,
             "extra", "Decoupling rule with σ of the mean size: larger particles overlap (clipped)."),
        Case("mixture-hd-0.30", "mixture of circles R and 0.6 R (1:1), hard disks, F_a=0.3", mixture,
             "extra", "Decoupling rule, σ of the larger circle for all (no overlaps)."),
        Case("circle-small-hd-0.30", "circle R=0.5 µm, hard disks, F_a=0.3 (evanescent part)", small,
             "extra", "Half of the lobe is evanescent at 700 nm (|d| > 1); both drop it (Fraunhofer); "
             "the table is the propagating diffuse transmittance."),
    ]
    if quick:
        keep = {"circle-poisson-0.30", "circle-poisson-0.30-add", "softedge-hd-0.30"}
        out = [c for c in out if c.name in keep]
    return out


def all_cases(quick: bool = False) -> list[Case]:
    return matrix_cases(quick) + extra_cases(quick)


def select_cases(cases: list[Case], patterns) -> list[Case]:
    """Cases whose name contains any of ``patterns`` (all when empty)."""
    pats = [p.strip() for p in (patterns or []) if p and p.strip()]
    if not pats:
        return cases
    out = [c for c in cases if any(p in c.name for p in pats)]
    if not out:
        raise CoronaError(f"cases={','.join(pats)!r} matches no case; allowed names: "
                          + ", ".join(c.name for c in cases))
    return out


# ==========================================================================
# binning and metrics
# ==========================================================================
def _period(shape) -> float | None:
    """Angular period of |Â|² (None: radial)."""
    if shape.isotropic:
        return None
    m = int(getattr(shape, "_symmetry", 1))
    if m <= 0:
        return None
    m2 = m * 2 // math.gcd(m, 2)
    return 2 * math.pi / m2


def _labels(ua, phi, period, u_max, dc, sectors=SECTORS, du=BIN_DU, n_min=BIN_MIN_POINTS):
    """Bin label per grid point (-1 = unused), and the (u_lo, u_hi, sector) of each bin."""
    n_sec = 1 if period is None else sectors
    edges = np.arange(0.0, u_max + du, du)
    ring = np.digitize(ua, edges) - 1
    ok = (ring >= 0) & (ring < len(edges) - 1) & ~dc
    counts = np.bincount(ring[ok], minlength=len(edges) - 1)
    # merge rings at small u until each sector holds n_min points
    new_edges = [0.0]
    acc = 0
    for k in range(len(edges) - 1):
        acc += counts[k]
        if acc >= n_min * n_sec or k == len(edges) - 2:
            new_edges.append(edges[k + 1])
            acc = 0
    new_edges = np.array(new_edges)
    ring = np.digitize(ua, new_edges) - 1
    ok = (ring >= 0) & (ring < len(new_edges) - 1) & ~dc
    if period is None:
        sec = np.zeros_like(ring)
    else:
        sec = np.minimum((np.mod(phi, period) / period * n_sec).astype(np.int64), n_sec - 1)
    lab = np.where(ok, ring * n_sec + sec, -1)
    nb = (len(new_edges) - 1) * n_sec
    info = {"u_lo": np.repeat(new_edges[:-1], n_sec), "u_hi": np.repeat(new_edges[1:], n_sec),
            "sector": np.tile(np.arange(n_sec), len(new_edges) - 1), "n_sectors": n_sec,
            "period": period}
    return lab, nb, info


def _lattice_labels(QX, QY, ua, phi, period, u_max, dc, lattice, R):
    """Bins for a fixed lattice: one bin per Bragg peak (the grid points within
    5 peak widths of G: the brute force's delta and the model's Gaussian both
    lie inside, so the bin means compare integrated weights), and the rings ×
    sectors of :func:`_labels` for the diffuse background elsewhere."""
    w = lattice.peak_width
    G, _ = lattice.bragg_peaks(u_max / R + 6 * w)
    near = np.full(QX.shape, -1, dtype=np.int64)
    r2 = (5.0 * w) ** 2
    for k, (gx, gy) in enumerate(G):
        sel = (QX - gx) ** 2 + (QY - gy) ** 2 <= r2
        near[sel] = k
    lab, nb, info = _labels(ua, phi, period, u_max, dc | (near >= 0))
    P = len(G)
    lab = np.where(near >= 0, nb + near, lab)
    gu = np.hypot(G[:, 0], G[:, 1]) * R
    info = {"u_lo": np.concatenate([info["u_lo"], gu]), "u_hi": np.concatenate([info["u_hi"], gu]),
            "sector": np.concatenate([info["sector"], -np.ones(P, dtype=np.int64)]),
            "n_sectors": info["n_sectors"], "period": period, "bragg_peaks": P}
    return lab, nb + P, info


def _binmean(lab, nb, values):
    ok = lab >= 0
    cnt = np.bincount(lab[ok], minlength=nb)
    s = np.bincount(lab[ok], weights=values[ok], minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        return s / cnt, cnt


def _quiet_lobe(material, d, lam):
    """``material.lobe(d, lam)`` without its CoronaWarnings."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CoronaWarning)
        return material.lobe(d, lam)


def _compared_region(info, cnt, Mb, dmax) -> np.ndarray:
    """The bins compared: populated, the model above REGION_FRACTION of its peak (Bragg-peak bins and
    background bins each against their own), and propagating (``dmax <= 1``)."""
    nb = Mb.size
    region = np.zeros(nb, dtype=bool)
    groups = [np.ones(nb, dtype=bool)]
    if "bragg_peaks" in info:   # Bragg-peak bins and background bins, each against its own peak
        groups = [info["sector"] < 0, info["sector"] >= 0]
    for g in groups:
        gg = g & (cnt > 0)
        if np.any(gg):
            region |= gg & (Mb > REGION_FRACTION * np.nanmax(Mb[gg])) & (dmax <= 1.0)
    return region


def _wavelength_metrics(material, bf, lam, grid: dict, bins: tuple, u_compare) -> tuple:
    """The comparison at ``lam`` [nm] (module notes): (metrics, model lobe, brute-force intensity,
    model and brute force per bin, compared bins) on ``grid`` = {"q", "ua", "dc", "P", "Ph"} (the
    cropped spectrum) with ``bins`` = (labels, count, info, radial labels, count, info)."""
    lab, nb, info, rlab, rnb, rinfo = bins
    R = bf.length_scale
    lam_um = lam * 1e-3
    mod = _quiet_lobe(material, grid["q"] * (lam_um / (2 * np.pi)), lam)
    I = grid["P"] / lam_um**2
    Ih = grid["Ph"] / lam_um**2
    Mb, cnt = _binmean(lab, nb, mod)
    Bb, _ = _binmean(lab, nb, I)
    Ha, _ = _binmean(lab, nb, Ih[0])
    Hb, _ = _binmean(lab, nb, Ih[1])
    region = _compared_region(info, cnt, Mb, info["u_hi"] * lam_um / (2 * np.pi * R))
    with np.errstate(invalid="ignore", divide="ignore"):
        err = Bb / Mb - 1.0
        if bf.realisations > 1:
            noise = np.abs(Ha - Hb) / (2.0 * Mb)
        else:   # one screen: speckle, |T̂|² exponential, cnt/2 independent points per bin
            noise = np.sqrt(2.0 / cnt) * np.ones(nb)
    e = err[region]
    # the same on rings only (azimuthal averages)
    Mr_, rc_ = _binmean(rlab, rnb, mod)
    Br_, _ = _binmean(rlab, rnb, I)
    rd = rinfo["u_hi"] * lam_um / (2 * np.pi * R)
    rreg = (rc_ > 0) & (Mr_ > REGION_FRACTION * np.nanmax(np.where(rc_ > 0, Mr_, np.nan))) & (rd <= 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        er = (Br_ / Mr_ - 1.0)[rreg]
    m = {
        "rms_radial": float(np.sqrt(np.mean(er**2))) if er.size else float("nan"),
        "rms": float(np.sqrt(np.mean(e**2))) if e.size else float("nan"),
        "max": float(np.max(np.abs(e))) if e.size else float("nan"),
        "mean": float(np.mean(e)) if e.size else float("nan"),
        "noise": float(np.sqrt(np.mean(noise[region] ** 2))) if e.size else float("nan"),
        "bins": int(region.sum()),
        "u_region": [float(info["u_lo"][region].min()) if e.size else 0.0,
                     float(info["u_hi"][region].max()) if e.size else 0.0],
    }
    # energies: the grid points of |u| <= u_compare (one cell = λ²/A_box in d)
    inside = (grid["ua"] <= u_compare) & ~grid["dc"]
    cell = lam_um**2 / (bf.grid.box[0] * bf.grid.box[1])
    m["window_brute"] = float(np.sum(I[inside]) * cell)
    m["window_model"] = float(np.sum(mod[inside]) * cell)
    # propagating diffuse transmittance at normal incidence: |q| <= 2π/λ
    covered = bool(2 * np.pi / lam_um <= min(np.max(bf.qx), np.max(bf.qy)))
    m["propagating_brute"] = _energy_within(bf, 2 * np.pi / lam_um) if covered else float("nan")
    m["propagating_model"] = float(material.diffuse_transmittance(lam, cos_theta_i=1.0))
    m["propagating_covered"] = covered
    return m, mod, I, Ih, Mb, Bb, region


def compare(material, bf, wavelengths=WAVELENGTHS, particle=None, u_compare=U_COMPARE,
            u_image=U_IMAGE) -> dict:
    """Compare ``material`` (aperture) — and the particle twin — with the ensemble ``bf``.

    Returns a dict with per-wavelength metrics, the binned profiles and the
    2D maps for the pictures (see the module notes for the definitions).
    """
    from corona.model.processes import Lattice
    R = bf.length_scale
    qx, qy = bf.qx, bf.qy
    ix = np.nonzero(np.abs(qx) * R <= u_compare)[0]
    iy = np.nonzero(np.abs(qy) * R <= u_compare)[0]
    sub = (slice(iy[0], iy[-1] + 1), slice(ix[0], ix[-1] + 1))
    QX, QY = np.meshgrid(qx[sub[1]], qy[sub[0]], indexing="xy")
    ua = np.hypot(QX, QY) * R
    phi = np.arctan2(QY, QX)
    dc = (QX == 0) & (QY == 0)
    grid = {"q": np.stack([QX, QY], -1), "ua": ua, "dc": dc, "P": bf.power[sub],
            "Ph": bf.power_halves[:, sub[0], sub[1]]}
    period = _period(material.shape)
    is_lattice = isinstance(material.process, Lattice) and material.process.orientation == "fixed"
    if is_lattice:
        lab, nb, info = _lattice_labels(QX, QY, ua, phi, period, u_compare, dc, material.process, R)
    else:
        lab, nb, info = _labels(ua, phi, period, u_compare, dc)
    rlab, rnb, rinfo = _labels(ua, phi, None, u_compare, dc)
    out = {"wavelengths": {}, "bins": info, "radial_bins": rinfo}
    model_u = None
    for lam in wavelengths:
        m, mod, I, Ih, Mb, Bb, region = _wavelength_metrics(material, bf, lam, grid,
                                                            (lab, nb, info, rlab, rnb, rinfo), u_compare)
        out["wavelengths"][lam] = m
        if lam == wavelengths[len(wavelengths) // 2]:
            out["maps"] = _maps(qx[sub[1]], qy[sub[0]], mod, I, lab, Mb, Bb, region, R, lam, u_image)
            Mr, rc = _binmean(rlab, rnb, mod)
            Br, _ = _binmean(rlab, rnb, I)
            Ar, _ = _binmean(rlab, rnb, Ih[0])
            Cr, _ = _binmean(rlab, rnb, Ih[1])
            out["radial"] = {"u_lo": rinfo["u_lo"], "u_hi": rinfo["u_hi"], "count": rc,
                             "model": Mr, "brute": Br, "half_a": Ar, "half_b": Cr, "wavelength": lam}
            model_u = mod
    if particle is not None:
        lam = wavelengths[len(wavelengths) // 2]
        mp = _quiet_lobe(particle, grid["q"] * (lam * 1e-3 / (2 * np.pi)), lam)
        out["particle_lobe_equal"] = bool(np.allclose(mp, model_u, rtol=1e-12, atol=0.0))
    out["grid"] = {"nx": bf.grid.nx, "ny": bf.grid.ny, "h_um": bf.grid.h,
                   "samples_per_radius": bf.samples_per_radius, "box_um": list(bf.grid.box)}
    return out


def _energy_within(bf, q_lim: float) -> float:
    """Σ P(q)/A_box over the grid points with 0 < |q| <= q_lim (the crop must cover it)."""
    QX, QY = np.meshgrid(bf.qx, bf.qy, indexing="xy")
    sel = (QX * QX + QY * QY <= q_lim * q_lim) & ~((QX == 0) & (QY == 0))
    A_box = bf.grid.box[0] * bf.grid.box[1]
    return float(np.sum(bf.power[sel]) / A_box)


def _maps(qx, qy, mod, I, lab, Mb, Bb, region, R, lam, u_image):
    """2D maps for the pictures, block-averaged to at most ~240 points per side."""
    ix = np.nonzero(np.abs(qx) * R <= u_image)[0]
    iy = np.nonzero(np.abs(qy) * R <= u_image)[0]
    s = (slice(iy[0], iy[-1] + 1), slice(ix[0], ix[-1] + 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio_bins = np.where(region, Bb / Mb, np.nan)
    lab_s = lab[s]
    ratio = np.where(lab_s >= 0, ratio_bins[np.maximum(lab_s, 0)], np.nan)
    m, b = mod[s], I[s]
    k = max(1, int(math.ceil(max(m.shape) / 240)))
    if k > 1:
        ny, nx = (m.shape[0] // k) * k, (m.shape[1] // k) * k
        m = m[:ny, :nx].reshape(ny // k, k, nx // k, k).mean(axis=(1, 3))
        b = b[:ny, :nx].reshape(ny // k, k, nx // k, k).mean(axis=(1, 3))
        ratio = ratio[:ny:k, :nx:k]
    lam_um = lam * 1e-3
    ext = float(u_image * lam_um / (2 * np.pi * R))
    return {"model": m, "brute": b, "ratio": ratio, "extent_d": ext, "block": k}


# ==========================================================================
# pictures
# ==========================================================================
def case_figure(path, title, res) -> str:
    """model | brute force | binned ratio (2D, 550 nm) and radial profiles (PNG)."""
    from matplotlib.colors import LogNorm, TwoSlopeNorm
    from matplotlib.figure import Figure

    mp = res["maps"]
    fig = Figure(figsize=(12.5, 7.6), dpi=64)   # no pyplot: no backend switch, no global state
    gs = fig.add_gridspec(2, 3, height_ratios=[1.0, 0.85], hspace=0.32, wspace=0.28)
    e = mp["extent_d"]
    vmax = float(np.nanmax(mp["model"]))
    norm = LogNorm(vmin=vmax * 1e-3, vmax=vmax)
    lam0 = res["radial"]["wavelength"]
    for k, (key, name) in enumerate([("model", f"model F_a T_a T_s ({lam0:g} nm)"),
                                     ("brute", f"brute force <|T̂|²>/(Aλ²) ({lam0:g} nm)")]):
        ax = fig.add_subplot(gs[0, k])
        im = ax.imshow(np.maximum(mp[key], vmax * 1e-4), origin="lower", extent=[-e, e, -e, e],
                       norm=norm, cmap="magma", interpolation="nearest")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("d_x")
        if k == 0:
            ax.set_ylabel("d_y")
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
    ax = fig.add_subplot(gs[0, 2])
    im = ax.imshow(mp["ratio"], origin="lower", extent=[-e, e, -e, e], cmap="RdBu_r",
                   norm=TwoSlopeNorm(1.0, 0.9, 1.1), interpolation="nearest")
    ax.set_facecolor("0.85")
    ax.set_title("brute / model (binned; grey: < 1 % of peak)", fontsize=10)
    ax.set_xlabel("d_x")
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
    # radial profiles in d for each wavelength
    rad = res["radial"]
    uc = 0.5 * (rad["u_lo"] + rad["u_hi"])
    ok = rad["count"] > 0
    R = res["length_scale"]
    lam0 = rad["wavelength"]
    ax = fig.add_subplot(gs[1, 0:2])
    colors = {400.0: "tab:blue", 550.0: "tab:green", 700.0: "tab:red"}
    for lam in sorted(res["wavelengths"]):
        s = (lam0 / lam) ** 2          # I(d) ∝ 1/λ² at fixed u
        dd = uc * lam * 1e-3 / (2 * np.pi * R)
        c = colors.get(lam, None)
        ax.semilogy(dd[ok], rad["model"][ok] * s, "-", color=c, lw=1.2, label=f"model {lam:g} nm")
        ax.semilogy(dd[ok], rad["brute"][ok] * s, ".", color=c, ms=3.5, label=f"brute {lam:g} nm")
    if ax.get_xlim()[1] > 1.0:
        ax.axvline(1.0, color="k", lw=0.8, ls=":")
    ax.set_xlabel("|d|  (azimuthal average; |d| > 1 evanescent at normal incidence)")
    ax.set_ylabel("lobe")
    ax.legend(fontsize=7, ncol=3)
    ax.set_ylim(np.nanmax(rad["model"][ok]) * 1e-4 * (lam0 / 700) ** 2,
                np.nanmax(rad["model"][ok]) * 2 * (lam0 / 400) ** 2)
    ax = fig.add_subplot(gs[1, 2])
    with np.errstate(invalid="ignore", divide="ignore"):
        r = rad["brute"] / rad["model"]
        nz = np.abs(rad["half_a"] - rad["half_b"]) / (2 * rad["model"])
    big = ok & (rad["model"] > REGION_FRACTION * np.nanmax(rad["model"][ok]))
    ax.fill_between(uc[big], 1 - 2 * nz[big], 1 + 2 * nz[big], color="0.8", label="±2σ noise")
    ax.plot(uc[big], r[big], ".-", ms=3, lw=0.8, color="k", label="brute / model")
    ax.axhline(1.0, color="tab:green", lw=0.8)
    for y in (0.98, 1.02):
        ax.axhline(y, color="tab:green", lw=0.6, ls="--")
    ax.set_ylim(0.9, 1.1)
    ax.set_xlabel("u = 2πR|d|/λ")
    ax.set_title("radial ratio (region > 1 % of peak)", fontsize=10)
    ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=11)
    buf = io.BytesIO()
    fig.savefig(buf, dpi=64, format="png")
    try:    # 256-colour palette: a third of the size, no visible change
        from PIL import Image
        buf.seek(0)
        Image.open(buf).convert("RGB").quantize(256).save(path, optimize=True)
    except Exception:  # noqa: BLE001
        with open(path, "wb") as f:
            f.write(buf.getvalue())
    return path


# ==========================================================================
# the run and the report
# ==========================================================================
def run(out_dir: str = "out/validate", *, quick: bool = False, cases=None,
        realisations: int | None = None, n_scatterers: int | None = None, seed: int = 0,
        progress: bool = True, echo=print, executor=None) -> dict:
    """Run the comparison for the selected cases and write the report folder.

    Parameters
    ----------
    out_dir : str
        Report folder: ``README.md``, ``summary.json`` and one PNG per case.
    quick : bool
        Reduced matrix (circle and hexagon at F_a = 0.3, three extra cases,
        16 realisations).
    cases : list of str, optional
        Substrings of case names to keep (``corona validate --cases circle-hd``).
    realisations : int, optional
        Screens per ensemble (default 64, quick 16).
    n_scatterers : int, optional
        Scatterers per screen (default 2000).
    seed : int
        Seed of every ensemble.
    executor : corona._executor.Executor, optional
        Where the cases run, one case per task (:func:`run_case`); default: in
        this process, one after the other.  Every case depends only on its
        name and these arguments, so the report is the same either way
        (timings apart).
    """
    from corona._executor import Executor
    chosen = select_cases(all_cases(quick), cases)
    M_default = QUICK_REALISATIONS if quick else REALISATIONS
    if realisations is not None:
        M_default = int(check_range("realisations", realisations, 1, 100000))
    if n_scatterers is not None:
        n_scatterers = int(check_range("n_scatterers", n_scatterers, 16, 10**7))
    os.makedirs(out_dir, exist_ok=True)
    t_start = time.perf_counter()
    executor = executor or Executor(workers=0)
    # here: the brute force's bars, case after case; on a cluster: one bar over the cases
    inner = progress and executor.in_process

    def store(o):
        if not o.ok:
            echo(f"[failed] {o.label}: {o.error}")
            return
        entry, figure, line = o.value
        if figure is not None:
            with open(os.path.join(out_dir, entry["figure"]), "wb") as f:
                f.write(figure)
        echo(line)

    outcomes = executor.map(run_case, [(c.name, quick, M_default, n_scatterers, seed, inner)
                                       for c in chosen],
                            [c.name for c in chosen], desc="validate", progress=progress and not inner,
                            on_result=store)
    results, failed = [], []
    for case, o in zip(chosen, outcomes):
        if o.ok:
            results.append(o.value[0])
        else:
            failed.append(f"{case.name}: {o.error}")
            results.append({"name": case.name, "label": case.label, "kind": case.kind,
                            "note": case.note, "overlaps": case.overlaps, "skipped": f"failed: {o.error}"})
    summary = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
               "python": platform.python_version(), "cores": os.cpu_count(), "quick": quick,
               "seconds": time.perf_counter() - t_start, "wavelengths": list(WAVELENGTHS),
               "goal_rms": GOAL_RMS, "cases": results}
    with open(os.path.join(out_dir, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1, default=_json_default)
    write_report(out_dir, summary)
    if failed:
        raise CoronaError(f"{len(failed)} validation case(s) failed: {'; '.join(failed)} "
                          f"(the others are in {out_dir})")
    return summary


def run_case(name: str, quick: bool, realisations: int, n_scatterers: int | None, seed: int,
             progress: bool = False):
    """One case of :func:`run` (one task of the executor; runs on a worker).

    Returns ``(entry, figure_png_bytes, log_line)``; ``figure`` is None for a
    skipped case.  Depends only on its arguments (the brute force is seeded
    by ``seed``), so any worker gives the same numbers.
    """
    from corona.reference import wave
    from corona.model.material import Material
    case = _case_named(all_cases(quick), name)
    t0 = time.perf_counter()
    entry = {"name": case.name, "label": case.label, "kind": case.kind, "note": case.note,
             "overlaps": case.overlaps}
    try:
        shape, process = case.build()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CoronaWarning)
            ap = Material(shape, process, mode="aperture")
            pa = Material(shape, process, mode="particle")
    except CoronaError as err:
        entry["skipped"] = str(err)
        return entry, None, f"[skip] {case.name}: {err}"
    M = case.realisations or realisations
    R = ap.length_scale
    q_keep = max(U_COMPARE, 2 * np.pi * R / (min(WAVELENGTHS) * 1e-3)) / R * 1.02
    bf = wave.brute_force(ap, realisations=M, n_scatterers=n_scatterers or case.n_scatterers,
                          q_max=q_keep, seed=seed, overlaps=case.overlaps, progress=progress)
    res = compare(ap, bf, WAVELENGTHS, particle=pa)
    res["length_scale"] = R
    with tempfile.TemporaryDirectory() as tmp:     # the figure travels back as bytes
        with open(case_figure(os.path.join(tmp, "case.png"), case.label, res), "rb") as f:
            figure = f.read()
    hard = _is_hard(process)
    fa = ap.area_fraction
    entry.update({
        "material": repr(ap), "area_fraction": fa, "area_fraction_screen": bf.area_fraction_screen,
        "packing_fraction": _packing(process, shape), "realisations": bf.realisations,
        "n_scatterers": bf.n_scatterers, "positions": bf.positions, "grid": res["grid"],
        "pixel_transfer": bf.pixel_transfer, "overlap_loss": bf.overlap_loss,
        "coherent": {"aperture": [bf.coherent["aperture"], ap.coherent_transmittance],
                     "particle": [bf.coherent["particle"], pa.coherent_transmittance]},
        "diffuse_parseval": bf.diffuse_total["aperture"],
        "model_total": float(ap.diffuse_transmittance()),
        "expected_total": fa * (float(shape.self_overlap) - fa) if hard else None,
        "particle_lobe_equal": res.get("particle_lobe_equal"),
        "wavelengths": {str(k): v for k, v in res["wavelengths"].items()},
        "figure": f"{case.name}.png", "seconds": time.perf_counter() - t0,
        "brute_seconds": bf.seconds,
    })
    w = res["wavelengths"][550.0]
    line = (f"{case.name:26s} M={bf.realisations:3d} grid={bf.grid.nx}x{bf.grid.ny} "
            f"RMS={100 * w['rms']:.2f}% max={100 * w['max']:.2f}% noise={100 * w['noise']:.2f}% "
            f"coh={bf.coherent['aperture']:.4f}/{ap.coherent_transmittance:.4f} "
            f"({time.perf_counter() - t0:.0f} s)")
    return entry, figure, line


def _case_named(cases, name: str) -> Case:
    for c in cases:
        if c.name == name:
            return c
    raise CoronaError(f"case={name!r} is not a validation case; allowed: {', '.join(c.name for c in cases)}")


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return str(o)


def _is_hard(process) -> bool:
    """Processes whose scatterers never overlap (sum rule F_a(1 - F_a))."""
    from corona.model.processes import HardDisk, Lattice, SequentialAdsorption
    return isinstance(process, (HardDisk, SequentialAdsorption, Lattice))


def _packing(process, shape):
    f = getattr(process, "packing_fraction", None)
    try:
        return float(f(shape)) if callable(f) else None
    except Exception:  # noqa: BLE001
        return None


def _pct(x, digits=2):
    return "—" if x is None or not np.isfinite(x) else f"{100 * x:.{digits}f}"


def write_report(out_dir: str, summary: dict) -> str:
    """The markdown summary ``README.md`` of a run (see :func:`run`)."""
    lines = []
    cases = summary["cases"]
    lams = [str(float(x)) for x in summary["wavelengths"]]
    lam_names = "/".join(f"{float(x):g}" for x in summary["wavelengths"])
    done = [c for c in cases if "skipped" not in c]
    matrix = [c for c in done if c["kind"] == "matrix"]
    extra = [c for c in done if c["kind"] == "extra"]
    skipped = [c for c in cases if "skipped" in c]
    worst = max((c["wavelengths"][lam]["rms"] for c in matrix for lam in lams), default=float("nan"))
    failing = sorted({c["name"] for c in matrix for lam in lams
                      if not c["wavelengths"][lam]["rms"] <= summary["goal_rms"]})
    lines += [
        "# Validation: the model against a brute-force wave-optics reference",
        "",
        f"Generated by `corona validate{' --quick' if summary['quick'] else ''}` on "
        f"{summary['date']} (Python {summary['python']}, {summary['cores']} cores, "
        f"{summary['seconds'] / 60:.1f} min).  Numbers: `summary.json`; one picture per case.",
        "",
        "## Method",
        "",
        "* **Brute force** (`corona.reference.wave`): random screens of 2000 scatterers in a periodic box "
        "(hard-disk configurations from the event-chain simulation, the same N as the shipped table), "
        "each translated at random, rasterised with anti-aliased edges at 16 samples per circumradius "
        "(masks exactly, at their own pixel pitch), FFT'd; `⟨|T̂(q)|²⟩/(A_screen λ²)` averaged over "
        "the realisations is the d-space intensity `I(d)` of docs/physics.md#validation-figures.  The anti-aliasing edge ramp "
        "is divided out (`sinc²(|q|h/2)`).  The coherent peak is the DC bin only: "
        "coherent weight `⟨mean t⟩²`; nothing is subtracted at q ≠ 0.",
        "* **Model**: `Material.lobe(d, λ)` = `F_a T_a T_s` evaluated at the very grid points of "
        "the FFT, for each wavelength.  The particle-mode lobe is the aperture lobe (Babinet; "
        "checked point by point); the two modes share one ensemble (`t_particle = 1 - t_aperture`).",
        f"* **Bins**: rings of Δu = {BIN_DU} in `u = 2πR|d|/λ` (merged at small u to ≥ "
        f"{BIN_MIN_POINTS} grid points per bin) × {SECTORS} angular sectors per symmetry period of "
        "|Â|² for anisotropic shapes; model and brute force averaged over the same points.",
        f"* **Region**: bins where the model exceeds 1 % of its peak, |u| ≤ {U_COMPARE:g}, |d| ≤ 1.",
        "* **RMS / max**: of `brute/model - 1` over the region.  **noise**: split-half estimate of "
        "the statistical error of the brute force (RMS over the region of `(even - odd)/(2 model)`); "
        "an RMS close to the noise means no detectable bias.",
        "* **coherent**: brute `⟨mean t⟩²` vs model `F_a²` (aperture) / `(1 - F_a)²` (particle).",
        f"* **sum rule**: diffuse energy inside |u| ≤ {U_COMPARE:g} (brute vs model on the same "
        "points), and the model's whole-plane `∫ lobe d²d` vs `F_a(1 - F_a)`.",
        "* **T_prop**: diffuse transmittance into propagating directions (|d| ≤ 1, normal "
        "incidence), brute vs `Material.diffuse_transmittance(λ, cos_theta_i=1)`.",
        "",
        "## Goal",
        "",
        f"Hard-disk matrix: RMS ≤ {100 * summary['goal_rms']:g} % for every case and wavelength.  "
        f"Worst RMS: **{_pct(worst)} %**; "
        + ("**all matrix cases meet the goal.**" if not failing and matrix else
           f"**not met for: {', '.join(failing)}**" if matrix else "no matrix case was run."),
        "",
        "## Hard-disk matrix",
        "",
        f"Circumradius R = {RADIUS:g} µm for every shape.  Both modes share the lobe (one row "
        "each for the coherent weight).  RMS / max in %, per wavelength "
        f"{lam_names} nm.",
        "",
        _HEADER.format(lams=lam_names),
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in matrix:
        lines += _rows(c, lams)
    if skipped:
        lines += ["", "### Skipped (unreachable)", ""]
        for c in skipped:
            lines.append(f"* `{c['name']}` ({c['label']}): {c['skipped']}")
    if extra:
        lines += ["", "## Other processes and shapes (approximations stated)", "",
                  _HEADER.format(lams=lam_names),
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for c in extra:
            lines += _rows(c, lams)
        lines += ["", "Notes per case:", ""]
        for c in extra:
            lines.append(f"* `{c['name']}` — {c['label']}: {c['note']} Overlap loss (clipped "
                         f"mass) {_pct(c['overlap_loss'], 3)} %; positions: {c['positions']}.")
    lines += ["", "## Findings", ""] + _findings(summary, matrix, extra, skipped, lams)
    lines += ["", "## Pictures", ""]
    for c in done:
        lines += [f"### {c['label']}", "", f"![{c['name']}]({c['figure']})", ""]
    path = os.path.join(out_dir, "README.md")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path


_HEADER = ("| case | η | mode | grid (R/h) | M | RMS % | max % | noise % | coherent brute / model "
           "| window ∫ brute / model | model table ∫ / F_a(so-F_a) | T_prop brute / model ({lams}) |")


def _case(cases, name):
    return next((c for c in cases if c["name"] == name), None)


def _findings(summary, matrix, extra, skipped, lams) -> list[str]:
    """Plain statements of what the numbers show (only for the cases that were run)."""
    mid = lams[len(lams) // 2]
    out = _matrix_findings(summary, matrix, lams, mid)
    if skipped:
        out.append("* **Unreachable cases**: " + "; ".join(
            f"`{c['name']}`" for c in skipped) + " — the hard-disk table ends at η = 0.72 and "
            "σ is the circumscribed diameter, so non-circular shapes reach lower F_a (square "
            "≤ 0.458, hexagon ≤ 0.595, this mask ≤ 0.473).")
    out += _poisson_findings(extra, mid) + _extra_findings(extra, mid) + _limit_findings(extra, lams, mid)
    out += _sum_rule_findings(matrix + extra, mid)
    out.append("* **Wavelengths**: model and brute force depend on λ only through d = qλ/2π, so the "
               "per-wavelength numbers are the same except where |d| ≤ 1 cuts the region (R = 2.5 µm "
               "keeps the compared region propagating at all three wavelengths).")
    return out


def _matrix_findings(summary, matrix, lams, mid) -> list[str]:
    """:func:`_findings` of the hard-disk matrix: the cases within the goal, the coherent weights and
    each case that misses the goal."""
    out = []
    goal = summary["goal_rms"]
    ok = [c for c in matrix if all(c["wavelengths"][lam]["rms"] <= goal for lam in lams)]
    bad = [c for c in matrix if c not in ok]
    if ok:
        worst = max(ok, key=lambda c: c["wavelengths"][mid]["rms"])
        out.append(f"* **Hard-disk matrix**: {len(ok)} of {len(matrix)} cases are within the goal; the "
                   f"largest RMS among them is {_pct(worst['wavelengths'][mid]['rms'])} % "
                   f"(`{worst['name']}`, noise {_pct(worst['wavelengths'][mid]['noise'])} %).  Their "
                   "RMS errors are at the level of the statistical noise: no bias of the model is "
                   "detectable at this precision (≈ 1 %).")
    if matrix:
        coh = max(abs(c["coherent"][m][0] / c["coherent"][m][1] - 1) for c in matrix
                  for m in ("aperture", "particle"))
        out.append(f"* **Coherent weights**: brute force `⟨mean t⟩²` against F_a² and (1 - F_a)²: "
                   f"largest relative difference {_pct(coh, 3)} % over the matrix (the anti-aliased "
                   "edges and the mask's pixels change ∫t by ≲ 0.1 %).")
    for c in bad:
        w = c["wavelengths"][mid]
        eta = c.get("packing_fraction") or float("nan")
        out.append(
            f"* **`{c['name']}` misses the goal**: RMS {_pct(w['rms'])} % (noise {_pct(w['noise'])} %), "
            f"max {_pct(w['max'])} %.  "
            + (f"Its packing fraction η = {eta:.3f} lies in the fluid–hexatic range of the "
               "hard-disk system (η ≳ 0.69): the first peak of S is sharp (S ≈ 8 at qσ ≈ 6.5) and "
               "the shipped table keeps only its area there (a kernel average between the rows "
               "η = 0.70 and 0.71, see `HardDisk`).  S measured directly from the simulated "
               "configurations (measured separately) differs from the table by -16 % … +10 % across "
               "the peak (bins of 0.2 in qσ; unchanged with 3× longer equilibration) and by < 2 % "
               "elsewhere except the smallest box wave vectors, "
               "which is the lobe error seen here (largest at u ≈ 3.3, the peak).  The brute force "
               "uses 6 independent chains started from compressed fluids so that the hexatic "
               "director is not pinned to the box axes (one chain from a lattice start, M = 16, gave "
               "RMS 22 %: six-fold spots on the ring).  A model "
               "limitation of the table near freezing, not of F_a T_a T_s."
               if eta >= 0.69 else "See its picture."))
    return out


def _poisson_findings(extra, mid) -> list[str]:
    """:func:`_findings` of the Poisson (overlapping) cases."""
    out = []
    p1, p3, pa = (_case(extra, n) for n in ("circle-poisson-0.10", "circle-poisson-0.30",
                                             "circle-poisson-0.30-add"))
    if p1 or p3:
        txt = []
        for c in (p1, p3):
            if c:
                fa = c["area_fraction"]
                w = c["wavelengths"][mid]
                txt.append(f"F_a = {fa:g}: lobe {_pct(w['mean'], 1)} % on average (max "
                           f"{_pct(w['max'], 1)} %), coherent {c['coherent']['aperture'][0]:.4f} vs "
                           f"F_a² = {c['coherent']['aperture'][1]:.4f} (Boolean model: "
                           f"(1 - e^(-F_a))² = {(1 - math.exp(-fa)) ** 2:.4f}), particle "
                           f"{c['coherent']['particle'][0]:.4f} vs {c['coherent']['particle'][1]:.4f}")
        out.append("* **Poisson (overlaps) is a model limitation**: overlapping openings transmit "
                   "their union, so the real screen has mean transmission 1 - e^(-F_a) < F_a and a "
                   "weaker, reshaped lobe; the model (t = Σ A) is its dilute limit.  " + "; ".join(txt)
                   + "."
                   + (f"  With the model's own linear superposition (`circle-poisson-0.30-add`) the "
                      f"brute force agrees: RMS {_pct(pa['wavelengths'][mid]['rms'])} %, noise "
                      f"{_pct(pa['wavelengths'][mid]['noise'])} %." if pa else ""))
    return out


def _extra_findings(extra, mid) -> list[str]:
    """:func:`_findings` of the size distribution, random orientation, mixture, soft edge and RSA."""
    out = []
    sz = _case(extra, "circle-size-hd-0.30")
    if sz:
        w = sz["wavelengths"][mid]
        out.append(f"* **Size distribution (decoupling rule)**: RMS {_pct(w['rms'])} % against a noise "
                   f"of {_pct(w['noise'])} %, mean {_pct(w['mean'])} %: a small but detectable "
                   "deviation.  Sizes are drawn independently of the positions, for which the "
                   "decoupling rule is exact, so the deviation comes from the larger particles "
                   "overlapping (σ is the mean size's diameter; clipped mass "
                   f"{_pct(sz['overlap_loss'], 3)} %).  Real polydisperse layers also correlate size "
                   "with position, which this reference does not model.")
    for name, what in (("square-random-hd-0.30", "random orientation"),
                       ("mixture-hd-0.30", "mixture"), ("softedge-hd-0.30", "soft edge"),
                       ("circle-rsa-0.30", "RSA table")):
        c = _case(extra, name)
        if c:
            w = c["wavelengths"][mid]
            out.append(f"* **{what}** (`{name}`): RMS {_pct(w['rms'])} %, noise {_pct(w['noise'])} %.")
    return out


def _limit_findings(extra, lams, mid) -> list[str]:
    """:func:`_findings` of the evanescent part, the jittered lattice and the measured point set."""
    out = []
    sm = _case(extra, "circle-small-hd-0.30")
    if sm:
        fr = [1 - sm["wavelengths"][lam]["propagating_model"] / sm["model_total"] for lam in lams]
        wl = sm["wavelengths"]
        tp = max(abs(wl[lam]["propagating_brute"] / wl[lam]["propagating_model"] - 1) for lam in lams)
        out.append("* **Evanescent part** (`circle-small-hd-0.30`, R = 0.5 µm): "
                   + ", ".join(f"{100 * f:.0f} %" for f in fr)
                   + " of the model's diffuse energy lies at |d| > 1 at "
                   + "/".join(f"{float(x):g}" for x in lams) + " nm.  "
                   "The scalar Fraunhofer brute force puts the same energy there (T_prop agrees to "
                   f"{_pct(tp, 2)} %), so it cannot test what a real screen does with it at grazing angles "
                   "(obliquity, vector effects); the model drops it (documented energy policy).")
    lat = _case(extra, "circle-lattice-0.30")
    if lat:
        w = lat["wavelengths"][mid]
        rel = w["propagating_model"] / w["propagating_brute"] - 1.0
        verdict = ("they agree" if abs(rel) < 0.005 else
                   "the exact lobe summed on the same grid gives the brute-force value, so this is "
                   "a table effect worth a look")
        out.append(f"* **Jittered lattice**: Bragg-peak weights and the diffuse background agree "
                   f"(RMS {_pct(w['rms'])} %).  The renderer's 2D table integrates to a propagating "
                   f"diffuse transmittance {w['propagating_model']:.4f} vs {w['propagating_brute']:.4f} "
                   f"for the brute force ({rel * 100:+.2f} %): {verdict}.")
    ps = _case(extra, "circle-pointset-0.30")
    if ps:
        w = ps["wavelengths"][mid]
        out.append(f"* **Measured point set**: one realisation, so both sides are speckle-limited: "
                   f"RMS {_pct(w['rms'])} % against an expected speckle noise of {_pct(w['noise'])} % "
                   "(χ² estimate, 1/√(points/2) per bin; the model's tapered periodogram has its own "
                   "noise).")
    return out


def _sum_rule_findings(cases, mid) -> list[str]:
    """:func:`_findings` of the sum rule over the non-overlapping cases with an expected total."""
    out = []
    hard = [c for c in cases if c.get("expected_total") and c["overlap_loss"] < 1e-6]
    if hard:
        win = [abs(c["wavelengths"][mid]["window_brute"] / c["wavelengths"][mid]["window_model"] - 1)
               for c in hard]
        tab = [c["model_total"] / c["expected_total"] - 1 for c in hard]
        worst = hard[int(np.argmax(win))]["name"]
        out.append("* **Sum rule**: on the same grid points (|u| ≤ "
                   f"{U_COMPARE:g}) brute force and model carry the same diffuse energy to "
                   f"{_pct(float(np.median(win)), 2)} % (median over the non-overlapping cases; "
                   f"largest {_pct(max(win), 2)} %, `{worst}`).  The model's table integral is "
                   f"{_pct(min(tab), 1)} … {_pct(max(tab), 1)} % off F_a(1 - F_a) because the table "
                   "stops at u_max (|d| = 2 at 360 nm) and the Airy tail beyond holds ≈ 2/(π u_max) "
                   "of T_a; the exact whole-plane sum rule of the model is checked in "
                   "`benchmarks/results/hard_disk.json`.")
    return out


def _rows(c, lams):
    w = c["wavelengths"]
    rms = " / ".join(_pct(w[lam]["rms"]) for lam in lams)
    mx = " / ".join(_pct(w[lam]["max"]) for lam in lams)
    noise = _pct(w[lams[len(lams) // 2]]["noise"])
    win = w[lams[len(lams) // 2]]
    tprop = " ; ".join(f"{w[lam]['propagating_brute']:.4f} / {w[lam]['propagating_model']:.4f}"
                       for lam in lams)
    g = c["grid"]
    eta = "—" if c.get("packing_fraction") is None else f"{c['packing_fraction']:.3f}"
    tot = "—" if c.get("expected_total") is None else \
        f"{c['model_total']:.4f} / {c['expected_total']:.4f}"
    rows = []
    for mode in ("aperture", "particle"):
        cb, cm = c["coherent"][mode]
        first = mode == "aperture"
        rows.append(
            f"| {c['name'] if first else ''} | {eta if first else ''} | {mode} | "
            + (f"{g['nx']}² ({g['samples_per_radius']:.1f})" if first else "") + " | "
            + (f"{c['realisations']}" if first else "") + " | "
            + (f"{rms} | {mx} | {noise}" if first else "″ | ″ | ″") + " | "
            f"{cb:.4f} / {cm:.4f} | "
            + (f"{win['window_brute']:.4f} / {win['window_model']:.4f} | {tot} | {tprop}" if first
               else "″ | ″ | ″") + " |")
    return rows
