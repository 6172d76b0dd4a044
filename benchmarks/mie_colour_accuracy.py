"""What a spectral render sees of the Mie sphere lobes: their CIE 1931 XYZ against Mie theory.

A spectral render integrates each pixel over wavelength with the camera's colour matching
functions, so the ripple of a large droplet's lobes in x (narrower than the rows of the table, a
fraction of a nanometre; docs/mie.md, "Why 12–25 µm miss at single wavelengths") is averaged.  This script
measures the lobes' colours: for one-size water spheres in a dilute Poisson layer (F_a = 0.01,
normal incidence; the set-up of benchmarks/mie_accuracy.py), per scattering angle Θ

    X(Θ) = ∫ P(λ, Θ) x̄(λ) dλ   (and Y, Z with ȳ, z̄; 360–830 nm, equal-energy illuminant;
                                  x̄ȳz̄ from corona.color.cie1931_xyz)

once from the tables (``SphereMaterial._lobes``, what the plugin evaluates) and once from Mie
theory at the same wavelengths: ``corona.model.mie.theory.amplitudes`` called here directly with
water's index ``theory.water_ior(λ)`` (the dispersion ``corona.Sphere`` uses), ``P = (|S1|² +
|S2|²) / (2π x²)`` per steradian; nothing of the table builder or of the material's own
``exact=True`` path is used for the reference.

The wavelength integral is stratified Monte Carlo: N strata over 360–830 nm, one uniform draw
in each, the same draws for table and theory; K independent replicates (different seeds).  The
figures are computed from one replicate (N wavelengths), from the first two pooled (2N) and from
all (K N): their agreement is the convergence check, and the spread over the replicates gives
the Monte Carlo standard error.  Per lobe (forward = transmitted hemisphere, backward =
reflected):

* ``rms_X``, ``rms_Y``, ``rms_Z``: energy-weighted RMS ``sqrt(Σ w (Y_tab/Y_mie − 1)²)``,
  ``w ∝ Y_mie sin Θ dΘ`` (and the same for X and Z);
* ``rms_Y_noise``: the Monte Carlo part of ``rms_Y`` (``sqrt(Σ w SE²)``, SE of ``Y_tab/Y_mie`` at
  each angle from the replicates' spread) and ``rms_Y_debiased = sqrt(rms_Y² − noise²)``;
* ``scale_Y``: ``∫ Y_tab dΩ / ∫ Y_mie dΩ − 1`` (with its standard error ``scale_Y_se``);
* ``dx``, ``dy``: the largest ``|Δx|``, ``|Δy|`` of the CIE xy chromaticity where ``Y_mie`` is
  above 1e-3 of the lobe's peak;
* ``per_lambda_above_goal``: the fraction of those wavelengths whose RMS is above 1 %, and
  ``per_lambda_rms_quantiles`` (50, 90, 99 %);
* ``per_lambda_rms_mean`` (and ``_ybar``, weighted by ȳ; ``_max``): the energy-weighted RMS of
  ``P_tab/P_mie − 1`` at each single wavelength (as mie_accuracy.py), averaged over the same
  wavelengths.

Angles: the grid of mie_accuracy.py at the bluest wavelength (``n = min(200000, max(20000,
400 x(360 nm)))`` midpoints over 90° from each lobe's axis), every 40th point, and every 10th in
the glory (170–180°) and the fogbow/rainbow (130–145°) of the backward lobe; each point weighted
by the width it stands for (the last ``n mod 40`` points, the 0.02° next to 90°, are left out).

Run (one BLAS thread; the first build of a radius caches in CORONA_CACHE_DIR)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/mie_colour_accuracy.py [--radii 5,8,12,20,25]
        [--n 4096] [--reps 4] [--seed 0] [--name mie_colour_accuracy]

It prints a markdown table and rewrites benchmarks/results/mie_colour_accuracy.json after each
radius.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

import corona
from corona.color import cie1931_xyz
from corona.model.mie import theory as mie

LAM_MIN, LAM_MAX = 360.0, 830.0
COARSE, FINE = 40, 10                       # strides on mie_accuracy.py's angle grid
FINE_BACK_DEG = ((170.0, 180.0), (130.0, 145.0))   # scattering angles kept on the finer stride


def angle_grid(radius: float):
    """(scattering angles Θ, widths dΘ, lobe of each: 0 forward, 1 backward) for ``radius`` [µm]."""
    x_max = 2 * np.pi * radius / (LAM_MIN * 1e-3)
    n = int(min(200000, max(20000, 400 * x_max)))
    h = 0.5 * np.pi / n
    angs, widths, lobes = [], [], []
    for lobe in (0, 1):
        for start in range(0, n - n % COARSE, COARSE):       # blocks of COARSE points
            centre = (start + 0.5 * COARSE) * h              # angle from the lobe's axis
            scat = np.degrees(centre if lobe == 0 else np.pi - centre)
            fine = lobe == 1 and any(a <= scat <= b for a, b in FINE_BACK_DEG)
            step = FINE if fine else COARSE
            i = np.arange(start + step // 2, start + COARSE, step)
            th = (i + 0.5) * h
            angs.append(th if lobe == 0 else np.pi - th)
            widths.append(np.full(i.size, step * h))
            lobes.append(np.full(i.size, lobe))
    return np.concatenate(angs), np.concatenate(widths), np.concatenate(lobes)


def mie_lobe(radius: float, lam: np.ndarray, ang: np.ndarray) -> np.ndarray:
    """Mie theory's lobe per steradian, ``(|S1|² + |S2|²) / (2π x²)`` (the tables' normalisation),
    at wavelengths ``lam`` (B,) [nm] and scattering angles ``ang`` (M,)."""
    x = 2 * np.pi * radius / (lam * 1e-3)
    m = mie.water_ior(lam).astype(np.complex128)
    S1, S2 = mie.amplitudes(m, x, np.cos(ang))
    return (np.abs(S1) ** 2 + np.abs(S2) ** 2) / (2 * np.pi * x[:, None] ** 2)


def table_lobe(material, lam: np.ndarray, ang: np.ndarray) -> np.ndarray:
    """The tabulated lobe (``SphereMaterial._lobes``) at wavelengths ``lam`` (B,) and angles (M,)."""
    wi = np.array([0.0, 0.0, 1.0])
    wo = np.stack([np.sin(ang), 0 * ang, -np.cos(ang)], -1)
    Zf, Zb, fwd = material._lobes(wi, np.broadcast_to(wo, (lam.size,) + wo.shape), lam[:, None])
    return np.where(fwd, Zf, Zb)


def _rms(tab, ref, w):
    """Weighted RMS of ``tab/ref - 1`` along the last axis (one figure per row of a (B, M) array)."""
    ok = ref > 0
    rel = np.where(ok, tab / np.where(ok, ref, 1) - 1, 0)
    return np.sqrt(np.sum(w * rel ** 2, -1) / np.sum(w, -1))


def colour_figures(tab, ref, sinw, noise_eps=None) -> dict:
    """Figures of one lobe from XYZ (3, M) of the table and of Mie theory; ``sinw = sin Θ dΘ``."""
    out = {f"rms_{c}": float(_rms(tab[k], ref[k], ref[k] * sinw)) for k, c in enumerate("XYZ")}
    out["scale_Y"] = float(np.sum(tab[1] * sinw) / np.sum(ref[1] * sinw) - 1)
    keep = ref[1] > 1e-3 * ref[1].max()
    ct, cr = tab[:, keep] / tab[:, keep].sum(0), ref[:, keep] / ref[:, keep].sum(0)
    out["dx"] = float(np.max(np.abs(ct[0] - cr[0])))
    out["dy"] = float(np.max(np.abs(ct[1] - cr[1])))
    if noise_eps is not None:       # SE² of Y_tab/Y_mie at each angle
        w = ref[1] * sinw
        noise = float(np.sqrt(np.sum(w * noise_eps) / w.sum()))
        out["rms_Y_noise"] = noise
        out["rms_Y_debiased"] = float(np.sqrt(max(out["rms_Y"] ** 2 - noise ** 2, 0.0)))
    return out


def measure(radius: float, n: int, reps: int, seed: int) -> dict:
    c_build, t_build = time.process_time(), time.perf_counter()
    mat = corona.Material(corona.Sphere(radius), corona.Poisson(area_fraction=0.01))
    _ = mat.rows
    _ = mat._derived
    build_cpu, build = time.process_time() - c_build, time.perf_counter() - t_build
    c0 = time.process_time()
    ang, dth, lobe = angle_grid(radius)
    sinw = np.sin(np.where(lobe == 0, ang, np.pi - ang)) * dth
    M = ang.size
    chunk = max(1, 1_500_000 // M)
    width = (LAM_MAX - LAM_MIN) / n
    xyz_tab = np.zeros((reps, 3, M))
    xyz_mie = np.zeros((reps, 3, M))
    per_lam = {0: [], 1: []}
    lams_all = []
    for k in range(reps):
        rng = np.random.default_rng([seed, k])
        lams = LAM_MIN + (np.arange(n) + rng.random(n)) * width
        lams_all.append(lams)
        for s in range(0, n, chunk):
            lam = lams[s:s + chunk]
            P_tab = table_lobe(mat, lam, ang)
            P_mie = mie_lobe(radius, lam, ang)
            cmf = cie1931_xyz(lam) * width                     # (B, 3)
            xyz_tab[k] += cmf.T @ P_tab
            xyz_mie[k] += cmf.T @ P_mie
            for which in (0, 1):
                sel = lobe == which
                per_lam[which].append(_rms(P_tab[:, sel], P_mie[:, sel], P_mie[:, sel] * sinw[sel]))
    lams_all = np.concatenate(lams_all)
    ybar = cie1931_xyz(lams_all)[:, 1]
    out = {"radius": radius, "ior": "water", "n": n, "reps": reps, "seed": seed,
           "build_s": build, "build_cpu_s": build_cpu, "rows": int(mat.rows["P_f"].shape[0]),
           "angles": {"forward": int(np.sum(lobe == 0)), "backward": int(np.sum(lobe == 1))}}
    for which, name in ((0, "forward"), (1, "backward")):
        sel = lobe == which
        t, r = xyz_tab[:, :, sel], xyz_mie[:, :, sel]
        eps = t[:, 1] / r[:, 1] - 1                           # (reps, M) per replicate
        se2 = eps.var(0, ddof=1) / reps if reps > 1 else None
        fig = {"N": colour_figures(t[0], r[0], sinw[sel]),
               f"{reps}N": colour_figures(t.sum(0), r.sum(0), sinw[sel], se2)}
        if reps >= 4:
            fig["2N"] = colour_figures(t[:2].sum(0), r[:2].sum(0), sinw[sel])
        if reps > 1:                  # each replicate's figures (the first is fig["N"])
            each = [fig["N"]] + [colour_figures(t[j], r[j], sinw[sel]) for j in range(1, reps)]
            fig[f"{reps}N"]["scale_Y_se"] = float(np.std([e["scale_Y"] for e in each], ddof=1) / np.sqrt(reps))
            fig["N_each"] = {key: [e[key] for e in each] for key in ("rms_Y", "scale_Y", "dx", "dy")}
        pl = np.concatenate(per_lam[which])
        fig["per_lambda_rms_mean"] = float(pl.mean())
        fig["per_lambda_rms_ybar"] = float(np.sum(pl * ybar) / np.sum(ybar))
        fig["per_lambda_rms_max"] = float(pl.max())
        # how many single wavelengths meet the goal (1 %), and the distribution's quantiles
        fig["per_lambda_above_goal"] = float(np.mean(pl > 0.01))
        fig["per_lambda_rms_quantiles"] = {str(q): float(np.quantile(pl, q)) for q in (0.5, 0.9, 0.99)}
        out[name] = fig
    out["cpu_s"] = time.process_time() - c0
    return out


def _pm(v: float, digits: int) -> str:
    """`` (±v %)`` of a Monte Carlo error, empty where one replicate gives none."""
    return "" if not np.isfinite(v) else f" (±{100 * v:.{digits}f})"


def row(res: dict) -> list[str]:
    lines = []
    for name in ("forward", "backward"):
        f = res[name]
        a = f[f"{res['reps']}N"]
        noise = a.get("rms_Y_noise", float("nan"))
        se = a.get("scale_Y_se", float("nan"))
        lines.append(
            f"| {res['radius']:g} | {name} | {100 * a['rms_Y']:.2f}{_pm(noise, 2)} | "
            f"{100 * a['rms_X']:.2f} | {100 * a['rms_Z']:.2f} | {100 * a['scale_Y']:+.3f}{_pm(se, 3)} | "
            f"{a['dx']:.1e} | {a['dy']:.1e} | {100 * f['N']['rms_Y']:.2f} | "
            f"{100 * f['per_lambda_rms_mean']:.2f} | {100 * f['per_lambda_rms_max']:.1f} | "
            f"{100 * f['per_lambda_above_goal']:.1f} | "
            f"{res['build_s']:.1f} |")
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--radii", default="5,8,12,20,25", help="comma-separated radii [µm]")
    ap.add_argument("--n", type=int, default=4096, help="strata (wavelengths) per replicate")
    ap.add_argument("--reps", type=int, default=4, help="independent replicates")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument("--name", default="mie_colour_accuracy", help="the JSON file's name in benchmarks/results")
    args = ap.parse_args(argv)
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import write
    results = []
    print(f"N = {args.n} strata, {args.reps} replicates (figures from all {args.reps} N; "
          "± the Monte Carlo noise)")
    print("| radius µm | lobe | Y RMS % | X RMS % | Z RMS % | Y scale % | max Δx | max Δy | "
          "Y RMS % (N) | per-λ RMS mean % | per-λ RMS max % | λ above 1 % | build s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in (float(v) for v in args.radii.split(",")):
        res = measure(r, args.n, args.reps, args.seed)
        results.append(res)
        print("\n".join(row(res)), f"<!-- cpu {res['cpu_s']:.0f} s -->", flush=True)
        if not args.no_write:
            write(args.name, {"results": results, "goal": {"rms": 0.01, "scale": 0.005}, "argv": sys.argv[1:]})


if __name__ == "__main__":
    main()
