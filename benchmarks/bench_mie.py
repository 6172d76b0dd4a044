"""Mie sphere layers: table build time for a new (radius, index), and render cost vs an opaque layer.

1. Table build: ``SphereMaterial.rows`` (Mie rows over wavelength) plus the
   derived energies and the structure-factor table, without the cache, for
   water droplets of radius 2, 5, 10, 20 µm and a constant index 1.5 + 0.001i
   at 5 µm (hard-disk centres, F_a = 0.3); ``--repeats`` builds each, the
   median is reported (wall and CPU seconds); and the size-spread tables of 20 µm droplets, 10 %
   lognormal, water and n = 1.5.  Goal: <= 2 s on 2 cores.  ``--builds-only`` prints these
   and stops (nothing written; ``PYTHONPATH=OTHER/src`` times another checkout in the same run).
2. Render cost: the street-light scene of bench_render (256², 64 spp, path)
   through a layer of 5 µm water spheres (hard disk, F_a = 0.4) against the
   same layer of opaque disks (``mode=particle``), each in its own process
   with an empty kernel cache (bench_render's child), ``--rounds`` interleaved
   rounds.  Goal: sphere / opaque <= 1.3 (JIT compile excluded).  The sphere
   layer scatters all the light it receives (the opaque one absorbs F_a of
   it), so its paths are longer; hence also
3. BSDF cost per call: ``sample`` + ``eval_pdf`` of 2²⁰ lanes (one incident
   direction, four wavelengths), compiled once, then the median of
   ``--repeats`` + 2 timed calls, for both layers.

    python benchmarks/bench_mie.py [--repeats 3] [--rounds 3] [--res 256] [--spp 64] [--builds-only]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

LAYERS = {
    "opaque": {"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk", "mode": "particle"},
    "sphere": {"type": "corona", "shape": "sphere", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk"},
}


def build_times(repeats: int) -> dict:
    import corona
    out = {}
    cases = [(f"water r={r:g} µm", corona.Sphere(r)) for r in (2.0, 5.0, 10.0, 20.0)]
    cases.append(("n=1.5+0.001i r=5 µm", corona.Sphere(5.0, ior=1.5 + 0.001j)))
    cases += [(f"{name} r=20 µm, 10 % spread", corona.SizeDistribution(corona.Sphere(20.0, ior=ior), 0.1))
              for name, ior in (("water", None), ("n=1.5", 1.5))]
    for name, sphere in cases:
        times, cpus = [], []
        for _ in range(repeats):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m = corona.Material(sphere, corona.HardDisk(0.3), use_cache=False)
            t0, c0 = time.perf_counter(), time.process_time()
            m.rows
            m._derived
            times.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        out[name] = {"median_s": statistics.median(times), "times_s": times, "cpu_s": cpus,
                     "rows": int(m.rows["P_f"].shape[0]), "chord_nodes": int(m.rows["P_f"].shape[1])}
        print(f"{name:30s} build {out[name]['median_s']:.3f} s, CPU {statistics.median(cpus):.3f} s  "
              f"({out[name]['rows']} rows x {out[name]['chord_nodes']} chords)", flush=True)
    return out


def call_cost(repeats: int, variant: str) -> dict:
    import corona
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    mi.set_variant(variant)
    corona.register()
    n = 1 << 20
    rng = np.random.default_rng(0)
    out = {}
    for name, layer in LAYERS.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            bsdf = mi.load_dict(layer)
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(0.3, 0.1, 0.9486833)
        si.wavelengths = mi.Spectrum(450.0, 520.0, 600.0, 700.0)
        s1 = mi.Float(rng.random(n).astype(np.float32))
        s2 = mi.Point2f(rng.random((2, n)).astype(np.float32))
        times = []
        for _ in range(repeats + 3):
            t0 = time.perf_counter()
            bs, w = bsdf.sample(mi.BSDFContext(), si, s1, s2)
            v, p = bsdf.eval_pdf(mi.BSDFContext(), si, bs.wo)
            dr.eval(bs, w, v, p)
            dr.sync_thread()
            times.append(time.perf_counter() - t0)
        out[name] = {"median_s": statistics.median(times[1:]), "times_s": times[1:], "lanes": n}
    out["ratio"] = out["sphere"]["median_s"] / out["opaque"]["median_s"]
    print(f"per call (sample + eval_pdf, 2^20 lanes): sphere / opaque = {out['ratio']:.3f}", flush=True)
    return out


def run_child(args, name: str) -> dict:
    """bench_render's child process, with our layer as its 'corona' BSDF."""
    code = ("import sys, json; sys.path.insert(0, {here!r}); import bench_render as b; "
            "b.BSDFS['corona'] = json.loads({layer!r}); sys.argv = ['bench_render.py', '--child', 'corona', "
            "'--res', {res!r}, '--spp', {spp!r}, '--repeats', {rep!r}, '--variant', {var!r}]; b.main()"
            ).format(here=HERE, layer=json.dumps(LAYERS[name]), res=str(args.res), spp=str(args.spp),
                     rep=str(args.repeats), var=args.variant)
    with tempfile.TemporaryDirectory() as home:
        out = subprocess.run([sys.executable, "-c", code], env={**os.environ, "HOME": home}, check=True,
                             capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--variant", default="llvm_ad_spectral")
    ap.add_argument("--builds-only", action="store_true", help="time the table builds, print, stop")
    args = ap.parse_args()
    from common import summarise, write
    builds = build_times(args.repeats)
    if args.builds_only:
        return
    # warm the on-disk cache so that the render processes time rendering, not the build
    import corona
    from corona.parameters import material_from_parameters
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for layer in LAYERS.values():
            m = material_from_parameters(**{k: v for k, v in layer.items() if k != "type"})
            m.rows if layer.get("shape") == "sphere" else m.table     # (a Mie layer has no single table)
    runs = {name: [] for name in LAYERS}
    for r in range(args.rounds):
        for name in LAYERS:
            runs[name].append(run_child(args, name))
            print(f"round {r + 1}/{args.rounds} {name:8s} {runs[name][-1]['times_s']}", flush=True)
    render = {}
    for name, rs in runs.items():
        render[name] = summarise(rs, "jit_compile_s")
    ratio = render["sphere"]["median_s"] / render["opaque"]["median_s"]
    ratio_min = render["sphere"]["min_s"] / render["opaque"]["min_s"]
    print(f"sphere / opaque = {ratio:.3f} (medians), {ratio_min:.3f} (minima); goal <= 1.3")
    calls = call_cost(args.repeats, args.variant)
    write("mie", {"table_build": builds, "build_goal_s": 2.0, "render": render, "layers": LAYERS,
                  "bsdf_call": calls,
                  "render_ratio": ratio, "render_ratio_minima": ratio_min, "render_goal": 1.3,
                  "scene": "street_light_scene", "resolution": args.res, "spp": args.spp,
                  "rounds": args.rounds, "corona": corona.__version__})


if __name__ == "__main__":
    main()
