"""The cost of spheres on a lattice in the renderer (corona.mitsuba.sphere_lattice.LatticeLayer)
against the plain sphere layer, in one process: ``eval_pdf`` and ``sample`` on 65536 lanes (four
wavelengths 450/520/600/700 nm, ``θi`` ≈ 17°, 1 µm spheres, hexagonal 4 µm against Poisson at the
same area fraction), each kernel's op count and execution time from Dr.Jit's kernel history.

Run ``python benchmarks/lattice_layer_cost.py``.
"""
from __future__ import annotations

import os
import sys
import time
import warnings

import numpy as np

import corona
import drjit as dr
import mitsuba as mi

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))


def main(n: int = 65536):
    mi.set_variant(corona.default_variant(prefer_gpu=False))
    corona.register()
    from bsdf_checks import interaction
    warnings.simplefilter("ignore")
    base = {"type": "corona", "shape": "sphere", "radius": 1.0, "area_fraction": float(np.pi / (np.sqrt(3) / 2 * 16))}
    layers = {"plain": mi.load_dict({**base, "process": "poisson"}),
              "lattice": mi.load_dict({**base, "process": "lattice-hex"})}
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    wo = mi.Vector3f(*(mi.Float(d[:, i].astype(np.float32)) for i in range(3)))
    ctx = mi.BSDFContext()
    wi = (0.3, 0.0, float(np.sqrt(1 - 0.09)))
    dr.set_flag(dr.JitFlag.KernelHistory, True)

    def measure(run):
        dr.kernel_history()
        t0 = time.time()
        dr.eval(*run())
        dr.sync_thread()
        wall = time.time() - t0
        h = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
        return wall, sum(k.get("operation_count", 0) for k in h), sum(k.get("execution_time", 0) for k in h)

    for name, b in layers.items():
        for rep in range(3):
            wall, ops, ex = measure(lambda: b.eval_pdf(ctx, interaction(n, wi), wo))
            print(f"{name:8s} eval_pdf: wall {wall:7.3f} s, ops {ops:6d}, kernel time {ex:9.1f} ms")
        for rep in range(2):
            u1 = mi.Float(rng.random(n).astype(np.float32))
            u2 = mi.Point2f(rng.random((2, n)).astype(np.float32))
            wall, ops, ex = measure(lambda: b.sample(ctx, interaction(n, wi), u1, u2))
            print(f"{name:8s} sample:   wall {wall:7.3f} s, ops {ops:6d}, kernel time {ex:9.1f} ms")


if __name__ == "__main__":
    main()
