"""Render cost of corona vs Mitsuba's built-in roughdielectric / thindielectric.

One scene (a small bright emitter seen through a screen, `street_light_scene`),
256², 64 spp, `path` integrator, llvm_ad_spectral by default; the screen is
one of :data:`BSDFS`: ``corona`` with a uniform layer of droplets, with the
area fraction from a bitmap (scenes/textures/wiped_fog.png), squares,
hexagons, squares with a 20 % size spread, Mie spheres, the droplets on a
glass pane, squares with a textured area fraction, and Mitsuba's
``roughdielectric`` (the reference) and ``thindielectric``.  :data:`GOALS`
holds each layer's goal over its reference (the spheres: over the opaque
layer ``corona``).  The 1-minute load average at the start and the end goes
to the JSON file with the figures.

Each measurement runs in its own process that loads only one BSDF's scene
(with several scenes alive, Dr.Jit's symbolic calls would compile every
BSDF into every kernel) and whose Dr.Jit kernel cache is empty (a throw-away
``$HOME``).  Its first render pays the JIT compilation, which Dr.Jit's kernel
history reports; then ``--repeats`` timed renders follow.  ``--rounds``
rounds interleave the BSDFs so load changes on the machine hit all of them
alike.  Medians over all timed renders and the ratios to roughdielectric go
to benchmarks/results/render.json, with each ratio's spread over the rounds (the ratio of
a round's median render to the reference's median in the same round: min, median and max).

Next to the whole render, each child times its BSDF alone (``--bsdf-lanes``, default 2^18
lanes of ``bench_kernels.inputs``; the fastest of five calls of ``eval_pdf`` and of
``sample``, CPU time on one Dr.Jit thread as ``bench_bsdf.py`` does: on a loaded machine a
short kernel's wall time on several threads waits for whichever thread the system preempted,
up to 6× its run time), so a ratio of renders can be read against the ratio of what the BSDF
itself costs.

    python benchmarks/bench_render.py [--res 256] [--spp 64] [--rounds 5] [--repeats 3] [--variant V]
        [--bsdfs ...] [--bsdf-lanes 18]
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

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

FOG = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "scenes", "textures", "wiped_fog.png")
BSDFS = {
    # condensation on a pane: 5 µm droplets, hard-disk positions, particle mode
    "corona": {"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
               "mode": "particle"},
    # anisotropic lobes (issue 18): closed-form form factors in the kernel × the
    # radial S table, sampled from the bilinear table(s); a size spread puts
    # the form factor on cubic B-spline grids instead
    "corona-square": {"type": "corona", "shape": "square", "radius": 2.5, "area_fraction": 0.3,
                      "process": "hard-disk"},
    "corona-hexagon": {"type": "corona", "shape": "polygon", "sides": 6, "radius": 2.5,
                       "area_fraction": 0.3, "process": "hard-disk"},
    "corona-square-spread": {"type": "corona", "shape": "square", "radius": 2.5, "size_spread": 0.2,
                             "area_fraction": 0.3, "process": "hard-disk"},
    # the same with the area fraction from a bitmap (the wiped window's fog, F_a 0.005 to 0.6:
    # about 100 table rows, looked up per shading point)
    "corona_textured": {"type": "corona", "radius": 5.0, "process": "hard-disk", "mode": "particle",
                        "area_fraction": {"type": "bitmap", "filename": os.path.normpath(FOG), "raw": True}},
    # Mie spheres (water, 5 µm) on the opaque layer's positions: compared with "corona"
    "corona-mie": {"type": "corona", "shape": "sphere", "radius": 5.0, "area_fraction": 0.4,
                   "process": "hard-disk"},
    # the uniform droplet layer on a thin glass pane (five components)
    "corona-glass": {"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                     "mode": "particle", "substrate": "glass"},
    # squares with the area fraction from a texture (rows of S - 1; the fog's 0.6 is beyond
    # hard-disk squares' 0.46, so a checkerboard of 0.1 and 0.3)
    "corona-square-textured": {"type": "corona", "shape": "square", "radius": 2.5, "process": "hard-disk",
                               "area_fraction": {"type": "checkerboard", "color0": 0.1, "color1": 0.3}},
    "roughdielectric": {"type": "roughdielectric", "alpha": 0.05, "int_ior": 1.5},
    "thindielectric": {"type": "thindielectric", "int_ior": 1.5},
}


#: Goals: each layer's render time over its reference's (roughdielectric unless named).
GOALS = {"corona": (1.10, "roughdielectric"), "corona_textured": (1.25, "roughdielectric"),
         "corona-square": (1.25, "roughdielectric"), "corona-hexagon": (1.25, "roughdielectric"),
         "corona-square-spread": (1.30, "roughdielectric"), "corona-mie": (1.20, "corona")}


def bsdf_alone(dr, mi, bsdf: dict, lanes: int) -> dict:
    """The fastest of five calls [ms] of ``eval_pdf`` and ``sample`` of ``bsdf`` alone on
    ``2^lanes`` lanes of ``bench_kernels.inputs`` (CPU time on one Dr.Jit thread; JIT untimed)."""
    import warnings
    import numpy as np
    from bench_kernels import inputs
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = mi.load_dict(bsdf)
    si, wo, s1, s2 = inputs(dr, mi, np, n=1 << lanes)
    ctx = mi.BSDFContext()
    out = {}
    threads = dr.thread_count()
    dr.set_thread_count(1)
    for method, fn in (("eval_pdf", lambda: b.eval_pdf(ctx, si, wo)), ("sample", lambda: b.sample(ctx, si, s1, s2))):
        best = float("inf")
        for k in range(6):
            t0 = time.process_time()
            dr.eval(fn())
            dr.sync_thread()
            if k:
                best = min(best, time.process_time() - t0)
        out[f"{method}_ms"] = best * 1e3
    dr.set_thread_count(threads)
    return out


def child(args) -> dict:
    """Render one BSDF's scene: the first render (with JIT) then ``repeats`` timed ones; then the
    BSDF alone (:func:`bsdf_alone`)."""
    import corona  # noqa: F401  (sets up libLLVM first)
    import drjit as dr
    import mitsuba as mi
    from corona.apps.render import setup_variant
    from corona.apps.scenes import street_light_scene
    setup_variant(args.variant)
    if args.threads:
        dr.set_thread_count(args.threads)
    scene = mi.load_dict(street_light_scene(resolution=args.res, bsdf=BSDFS[args.child]))

    cpu = []

    def timed(seed):
        t0, c0 = time.perf_counter(), time.process_time()
        img = mi.render(scene, spp=args.spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        cpu.append(time.process_time() - c0)
        return time.perf_counter() - t0

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    first = timed(0)
    hist = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    compile_ms = sum(k.get("codegen_time", 0.0) + k.get("backend_time", 0.0) for k in hist)
    times = [timed(i + 1) for i in range(args.repeats)]
    alone = bsdf_alone(dr, mi, BSDFS[args.child], args.bsdf_lanes) if args.bsdf_lanes > 0 else {}
    return {"first_render_s": first, "jit_compile_s": compile_ms * 1e-3, "times_s": times, "cpu_s": cpu[1:],
            "bsdf_alone": alone}


def round_spread(rounds, ref_rounds) -> dict:
    """min / median / max over the rounds of a round's median render over the reference's median in
    the same round (the two ran seconds apart, under about the same load)."""
    ratios = [statistics.median(a["times_s"]) / statistics.median(b["times_s"]) for a, b in zip(rounds, ref_rounds)]
    return {"min": min(ratios), "median": statistics.median(ratios), "max": max(ratios), "rounds": ratios}


def run_child(args, name: str) -> dict:
    with tempfile.TemporaryDirectory() as home:   # empty Dr.Jit kernel cache
        out = subprocess.run(
            [sys.executable, os.path.abspath(__file__), "--child", name, "--res", str(args.res),
             "--spp", str(args.spp), "--repeats", str(args.repeats), "--variant", args.variant,
             "--bsdf-lanes", str(args.bsdf_lanes), "--threads", str(args.threads)],
            env={**os.environ, "HOME": home}, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3, help="timed renders per process")
    ap.add_argument("--variant", default="llvm_ad_spectral")
    ap.add_argument("--name", default="render")
    ap.add_argument("--bsdfs", nargs="*", default=list(BSDFS), choices=list(BSDFS),
                    help="which BSDFs to time (roughdielectric is always included)")
    ap.add_argument("--bsdf-lanes", type=int, default=18,
                    help="log2 of the lanes of the BSDF-alone timing (0: none)")
    ap.add_argument("--threads", type=int, default=0, help="Dr.Jit threads of the renders (0: all); with 1, "
                    "a render's CPU time is little disturbed by other load on a shared machine")
    ap.add_argument("--child", choices=list(BSDFS), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args)))
        return

    from common import summarise, write
    load_start = os.getloadavg()[0]
    names = [n for n in BSDFS if n in args.bsdfs or n == "roughdielectric"
             or (n == "corona" and "corona-mie" in args.bsdfs)]
    runs = {name: [] for name in names}
    for r in range(args.rounds):
        for name in names:
            runs[name].append(run_child(args, name))
            print(f"round {r + 1}/{args.rounds} {name:16s} {runs[name][-1]['times_s']}", flush=True)
    results = {}
    for name, rs in runs.items():
        results[name] = summarise(rs, "first_render_s", "jit_compile_s")
        for method in ("eval_pdf_ms", "sample_ms"):
            if all(method in r.get("bsdf_alone", {}) for r in rs):
                results[name].setdefault("bsdf_alone", {})[method] = statistics.median(
                    r["bsdf_alone"][method] for r in rs)
    ref = results["roughdielectric"]["median_s"]
    for name, res in results.items():
        res["ratio_to_roughdielectric"] = res["median_s"] / ref
        # the fastest render of each is least disturbed by other load on a shared machine
        res["ratio_of_minima"] = res["min_s"] / results["roughdielectric"]["min_s"]
        res["ratio_over_rounds"] = round_spread(runs[name], runs["roughdielectric"])
        alone, alone_ref = res.get("bsdf_alone", {}), results["roughdielectric"].get("bsdf_alone", {})
        for method in list(alone):
            if method in alone_ref:
                alone[method.replace("_ms", "_over_roughdielectric")] = alone[method] / alone_ref[method]
        print(f"{name:16s} median {res['median_s']:7.3f} s  first render {res['first_render_s']:6.3f} s "
              f"(JIT compile {res['jit_compile_s']:6.3f} s)  ratio {res['ratio_to_roughdielectric']:.3f} "
              f"(rounds {res['ratio_over_rounds']['min']:.3f}-{res['ratio_over_rounds']['max']:.3f})"
              + "".join(f"  {m} {v:.2f}" for m, v in alone.items()))
    goals = {}
    for name in names:
        if name in GOALS and GOALS[name][1] in results:
            goal, ref_name = GOALS[name]
            ratio = results[name]["median_s"] / results[ref_name]["median_s"]
            ratio_min = results[name]["min_s"] / results[ref_name]["min_s"]
            spread = round_spread(runs[name], runs[ref_name])
            goals[name] = {"reference": ref_name, "ratio": ratio, "ratio_of_minima": ratio_min,
                           "ratio_over_rounds": spread, "goal": goal, "met": bool(ratio <= goal),
                           "decided": bool(spread["max"] <= goal or spread["min"] > goal)}
            print(f"{name} / {ref_name} = {ratio:.3f} (medians), {ratio_min:.3f} (minima), rounds "
                  f"{spread['min']:.3f}-{spread['max']:.3f}; goal <= {goal}"
                  + ("" if goals[name]["decided"] else " (the rounds straddle the goal: undecided)"))
    write(args.name, {"scene": "street_light_scene", "bsdfs": {n: BSDFS[n] for n in names}, "resolution": args.res,
                      "spp": args.spp, "integrator": "path", "rounds": args.rounds, "bsdf_lanes": 1 << args.bsdf_lanes,
                      "repeats": args.repeats, "results": results, "goals": goals,
                      "load_average_1min": {"start": load_start, "end": os.getloadavg()[0]},
                      "goal": "render time over roughdielectric's (corona-mie: over the opaque layer's, "
                              "'corona'), JIT compile excluded: " + ", ".join(
                                  f"{n} <= {g}" for n, (g, _) in GOALS.items())})


if __name__ == "__main__":
    main()
