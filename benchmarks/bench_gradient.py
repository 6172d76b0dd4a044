"""Cost of a ``prb`` gradient render: the uniform corona layer vs ``roughdielectric``.

bench_render's scene (``street_light_scene``, ``prb`` integrator, max depth 4),
128², 16 spp by default.  Reverse mode in ``llvm_ad_spectral`` (``dr.backward``
of the image mean with respect to ``area_fraction.value``, resp. the
roughness ``alpha``); forward mode in ``llvm_ad_rgb`` (``dr.forward`` from the
same parameter: Mitsuba's ``prb`` forward mode fails in spectral variants).
Each (BSDF, mode) runs in its own process with an empty Dr.Jit kernel cache,
``--rounds`` rounds interleave them; in each process the first gradient render
pays the JIT compilation (reported apart), then ``--repeats`` are timed.
Ratios of medians go to benchmarks/results/gradient.json with the load.
Goal: corona / roughdielectric <= 1.3 in each mode.

    python benchmarks/bench_gradient.py [--res 128] [--spp 16] [--rounds 2] [--repeats 2]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

BSDFS = {
    "corona": ({"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                "mode": "particle"}, "area_fraction.value"),
    "roughdielectric": ({"type": "roughdielectric", "alpha": 0.05, "int_ior": 1.5}, "alpha.value"),
}
MODES = {"reverse": "llvm_ad_spectral", "forward": "llvm_ad_rgb"}


def child(args) -> dict:
    import corona  # noqa: F401  (sets up libLLVM first)
    import drjit as dr
    import mitsuba as mi
    from corona.apps.render import setup_variant
    from corona.apps.scenes import street_light_scene
    setup_variant(MODES[args.mode])
    bsdf, key = BSDFS[args.child]
    scene_dict = street_light_scene(resolution=args.res, bsdf=bsdf)
    scene_dict["integrator"] = {"type": "prb", "max_depth": 4}
    scene = mi.load_dict(scene_dict)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith(key))
    params.keep([key])

    def timed(seed):
        t0 = time.perf_counter()
        dr.enable_grad(params[key])
        params.update()
        img = mi.render(scene, params, spp=args.spp, seed=seed, seed_grad=seed + 1000)
        if args.mode == "reverse":
            dr.backward(dr.mean(img, axis=None))
            g = dr.grad(params[key])
        else:
            dr.forward(params[key])
            g = dr.grad(img)
        dr.eval(g)
        dr.sync_thread()
        dr.disable_grad(params[key])
        return time.perf_counter() - t0, float(dr.sum(g.array if hasattr(g, "array") else g, axis=None)[0])

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    first, grad = timed(0)
    hist = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    compile_ms = sum(k.get("codegen_time", 0.0) + k.get("backend_time", 0.0) for k in hist)
    times = [timed(i + 1)[0] for i in range(args.repeats)]
    return {"first_s": first, "jit_compile_s": compile_ms * 1e-3, "times_s": times, "gradient": grad}


def run_child(args, name: str, mode: str) -> dict:
    with tempfile.TemporaryDirectory() as home:   # empty Dr.Jit kernel cache
        out = subprocess.run(
            [sys.executable, os.path.abspath(__file__), "--child", name, "--mode", mode, "--res", str(args.res),
             "--spp", str(args.spp), "--repeats", str(args.repeats)],
            env={**os.environ, "HOME": home}, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--name", default="gradient")
    ap.add_argument("--child", choices=list(BSDFS), help=argparse.SUPPRESS)
    ap.add_argument("--mode", choices=list(MODES), default="reverse", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args)))
        return
    from common import summarise, write
    load_start = os.getloadavg()[0]
    runs = {(n, m): [] for m in MODES for n in BSDFS}
    for r in range(args.rounds):
        for (name, mode) in runs:
            runs[name, mode].append(run_child(args, name, mode))
            print(f"round {r + 1}/{args.rounds} {mode:8s} {name:16s} {runs[name, mode][-1]['times_s']}", flush=True)
    results = {}
    for (name, mode), rs in runs.items():
        results[f"{mode} {name}"] = {**summarise(rs, "jit_compile_s", "first_s"),
                                     "gradient": rs[0]["gradient"], "variant": MODES[mode]}
    ratios = {}
    for mode in MODES:
        c, ref = results[f"{mode} corona"], results[f"{mode} roughdielectric"]
        ratios[mode] = {"ratio": c["median_s"] / ref["median_s"], "ratio_of_minima": c["min_s"] / ref["min_s"],
                        "jit_ratio": c["jit_compile_s"] / ref["jit_compile_s"], "goal": 1.3}
        print(f"{mode}: corona / roughdielectric = {ratios[mode]['ratio']:.3f} (medians), "
              f"{ratios[mode]['ratio_of_minima']:.3f} (minima), JIT {ratios[mode]['jit_ratio']:.2f}; goal <= 1.3")
    write(args.name, {"scene": "street_light_scene", "integrator": "prb", "resolution": args.res, "spp": args.spp,
                      "rounds": args.rounds, "repeats": args.repeats, "results": results, "ratios": ratios,
                      "load_average_1min": {"start": load_start, "end": os.getloadavg()[0]},
                      "goal": "prb gradient render, corona (uniform) <= 1.3 x roughdielectric, reverse (spectral) "
                              "and forward (RGB) mode"})


if __name__ == "__main__":
    main()
