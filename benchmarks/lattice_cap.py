"""How tight the lattice cap's bound is (corona.model.mie.lattice_cap) against the cap's own
quadrature of the lobes' energy (SphereMaterial.lattice_energy), on random lanes.

For each crystal (1 µm spheres), 30 lanes with λ uniform in 400–800 nm, θi in 0–80° and any
azimuth: the ratio ``ē / e`` (≥ 1 is a bound; its excess is how much dimmer a layer capped with
it renders where the cap is active), for

* ``per-lane``: the far orders at the lane (``far_energy``) + the near orders' bound at the lane
  itself (``near_bound_at``, cells of no width) + the diffuse part's row bound;
* ``table``: the table read as the renderer would read it (``cap_table``, far orders trilinear
  between nodes, near orders per cell), over 540–562 nm in three 7.3 nm cells (as the full table's);
  also the far part's interpolation error against ``far_energy`` at the lane.

Run ``python benchmarks/lattice_cap.py`` (about a minute per crystal on one core);
``python benchmarks/lattice_cap.py --full`` builds the full default table (360–830 nm) of the
hexagonal 4 µm crystal instead and reads it on 60 lanes in 400–800 nm (a few minutes).
"""
from __future__ import annotations

import time

import numpy as np

import corona
from corona.model.mie import lattice_cap as lc

CRYSTALS = [("hexagonal", 4.0, 0.0), ("square", 3.0, 0.15), ("hexagonal", 2.2, 0.0)]


def _lanes(rng, n, lam_lo, lam_hi):
    for _ in range(n):
        lam = rng.uniform(lam_lo, lam_hi)
        th, ph = np.radians(rng.uniform(0.0, 80.0)), rng.uniform(0.0, 2 * np.pi)
        yield lam, np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])


def main():
    print("| crystal | per-lane ē/e min / median / max | table ē/e min / median / max | far interpolation error | table build |")
    print("|---|---|---|---|---|")
    for kind, a, jitter in CRYSTALS:
        m = corona.Material(corona.Sphere(1.0), corona.Lattice(kind, a, jitter=jitter))
        D = lc.diffuse_bound_rows(m.rows, m.length_scale, jitter)
        lane = []
        for lam, wi in _lanes(np.random.default_rng(3), 30, 400.0, 800.0):
            j, t = m._row(lam)
            far = float(lc.far_energy(m, wi[None, :2], lam)[0])
            near = float(lc.near_bound_at(m, wi[None, :2], lam)[0])
            lane.append((far + near + D[j] * (1 - t) + D[j + 1] * t) / m.lattice_energy(wi, lam))
        t0 = time.perf_counter()
        tab = lc.cap_table(m, lam_range=(540.0, 562.03), n_lam=3)
        build = time.perf_counter() - t0
        table, err = [], []
        for lam, wi in _lanes(np.random.default_rng(4), 30, 540.0, 562.0):
            j, t = m._row(lam)
            far, near, diffuse = lc.cap_parts(tab, D, wi, lam, j, t)
            table.append((far + near + diffuse) / m.lattice_energy(wi, lam))
            err.append(far / float(lc.far_energy(m, wi[None, :2], lam)[0]) - 1.0)
        f = lambda v: f"{min(v):.3f} / {np.median(v):.3f} / {max(v):.3f}"
        print(f"| {kind} a={a:g} µm δ={jitter:g} µm | {f(lane)} | {f(table)} | "
              f"{100 * min(err):+.1f} … {100 * max(err):+.1f} % | {build:.1f} s (3 λ cells) |", flush=True)


def full():
    m = corona.Material(corona.Sphere(1.0), corona.Lattice("hexagonal", 4.0))
    t0 = time.perf_counter()
    tab = lc.cap_table(m)
    build = time.perf_counter() - t0
    D = lc.diffuse_bound_rows(m.rows, m.length_scale, 0.0)
    ratios = []
    for lam, wi in _lanes(np.random.default_rng(1), 60, 400.0, 800.0):
        j, t = m._row(lam)
        ratios.append(lc.cap_energy(tab, D, wi, lam, j, t) / m.lattice_energy(wi, lam))
    print(f"full table of the hexagonal 4 µm crystal: built in {build:.0f} s; ē/e min {min(ratios):.3f}, "
          f"median {np.median(ratios):.3f}, max {max(ratios):.3f} (60 lanes)")


if __name__ == "__main__":
    import sys
    full() if "--full" in sys.argv[1:] else main()
