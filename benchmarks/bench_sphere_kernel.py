"""The sphere layer's BSDF kernel alone: this checkout's sphere module against a git revision's, in one process.

The revision's ``src/corona/mitsuba/sphere.py`` (``git show REV:...``) is loaded beside this
checkout's module; both build the same layer (``bench_kernels.py``'s "Mie spheres": water,
5 µm, hard-disk, F_a 0.4) from the same tables and run ``eval_pdf`` and ``sample`` on the
same 2^18 lanes (``bench_kernels.inputs``: incident directions within 40° of the normal,
outgoing ones in the halo, random wavelengths), interleaved round by round so that load
on a shared machine hits both alike.  Reported per module and method: the kernels'
operation count and their run time from Dr.Jit's kernel history (after a warm-up call; the
median and minimum over the rounds), and the largest difference of the results (value,
pdf) between the two on the halo's directions and on directions uniform over the sphere.

Variants of the inputs show what the time is spent on: ``--wavelengths`` ``random``
(the default), ``550-array`` (every wavelength 550 nm, as an array: the rows in the caches,
the same instructions) or ``550-literal`` (a Dr.Jit literal: the kernel is constant-folded,
which is not a memory effect).

With ``--render RES`` it renders ``bench_render.py``'s street-light scene with its
``corona-mie`` layer instead (RES², 64 spp, path), built once from each module in this one
process, the two scenes in turn (the order swapped every round), and reports the renders'
wall time, the process's CPU time and the render kernels' run time (kernel history).

    python benchmarks/bench_sphere_kernel.py [--base REV] [--rounds 5] [--render RES] [--name sphere_kernel]

writes benchmarks/results/<name>.json.  No timing is asserted anywhere.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import types
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)


def _module_at(rev: str):
    """The sphere plugin module of the git revision ``rev``, loaded under another name."""
    src = subprocess.run(["git", "-C", ROOT, "show", f"{rev}:src/corona/mitsuba/sphere.py"],
                         capture_output=True, text=True, check=True).stdout
    mod = types.ModuleType("corona_sphere_base")
    mod.__file__ = f"{rev}:src/corona/mitsuba/sphere.py"
    exec(compile(src, mod.__file__, "exec"), mod.__dict__)
    return mod


def _bsdf(mod, layer: dict):
    """The sphere BSDF of ``layer`` (a ``corona`` dict) built by the module ``mod``'s mixin."""
    import mitsuba as mi
    from corona.mitsuba.common import variant_class
    cls = variant_class(mod.SphereBSDFMixin, "BSDF", f"CoronaSphereBSDF_{id(mod)}")
    props = mi.Properties("corona")
    for k, v in layer.items():
        if k != "type":
            props[k] = v
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return cls(props)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", default="HEAD", help="the git revision to compare with")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--wavelengths", default="random", choices=["random", "550-array", "550-literal"])
    ap.add_argument("--render", type=int, default=0, help="render RES² instead of the BSDF alone")
    ap.add_argument("--name", default="sphere_kernel")
    args = ap.parse_args()
    if args.render:
        return render(args)
    import corona
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    mi.set_variant("llvm_ad_spectral")
    corona.register()
    import bench_kernels as bk
    from common import write
    from corona.mitsuba import sphere as this
    n = 1 << 18
    si, wo, s1, s2 = bk.inputs(dr, mi, np, n=n)
    if args.wavelengths != "random":
        lam = mi.Spectrum(550.0) if args.wavelengths == "550-literal" else \
            mi.Spectrum(np.full((4, n), 550.0, dtype=np.float32))
        si.wavelengths = lam
        dr.eval(si)
    layer = bk.LAYERS["Mie spheres"]

    bsdfs = {"base": _bsdf(_module_at(args.base), layer), "this": _bsdf(this, layer)}
    ctx = mi.BSDFContext()
    dr.set_flag(dr.JitFlag.KernelHistory, True)

    def run(fn):
        dr.kernel_history()
        out = fn()
        dr.eval(out)
        dr.sync_thread()
        h = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
        return int(sum(k["operation_count"] for k in h)), float(sum(k.get("execution_time", 0) for k in h))
    res: dict = {}
    for _ in range(args.rounds):
        for name, b in bsdfs.items():
            for meth, fn in (("eval_pdf", lambda: b.eval_pdf(ctx, si, wo)),
                             ("sample", lambda: b.sample(ctx, si, s1, s2))):
                run(fn)
                ops, ms = run(fn)
                r = res.setdefault(f"{name} / {meth}", {"operations": ops, "run_ms": []})
                r["run_ms"].append(ms)
    for r in res.values():
        r["median_ms"], r["min_ms"] = float(np.median(r["run_ms"])), float(min(r["run_ms"]))
    ratios = {meth: {"median": res[f"this / {meth}"]["median_ms"] / res[f"base / {meth}"]["median_ms"],
                     "min": res[f"this / {meth}"]["min_ms"] / res[f"base / {meth}"]["min_ms"]}
              for meth in ("eval_pdf", "sample")}
    # the same results: the halo's directions and directions uniform over the sphere
    rng = np.random.default_rng(9)
    v = rng.normal(size=(3, n))
    v /= np.linalg.norm(v, axis=0)
    same = {}
    for label, w in (("halo", wo), ("sphere", mi.Vector3f(v.astype(np.float32)))):
        (va, pa), (vb, pb) = bsdfs["base"].eval_pdf(ctx, si, w), bsdfs["this"].eval_pdf(ctx, si, w)
        va, vb, pa, pb = (np.asarray(a, dtype=np.float64) for a in (va, vb, pa, pb))
        same[label] = {"value_max_abs_diff": float(np.max(np.abs(va - vb))), "value_max": float(np.max(np.abs(va))),
                       "pdf_max_abs_diff": float(np.max(np.abs(pa - pb))), "pdf_max": float(np.max(pa))}
    for key, r in res.items():
        print(f"{key:18s} {r['operations']:5d} ops  run {r['median_ms']:7.2f} ms (min {r['min_ms']:7.2f})")
    for meth, q in ratios.items():
        print(f"{meth}: this / base {q['median']:.3f} (minima {q['min']:.3f})")
    print("same results:", same)
    write(args.name, {"base": args.base, "lanes": n, "wavelengths": args.wavelengths, "layer": layer,
                      "load_average_1min": os.getloadavg()[0], "results": res, "ratios": ratios, "same": same,
                      "note": "run_ms: Dr.Jit kernel history execution time of the method's kernels, after a "
                              "warm-up call, interleaved rounds; operations: Dr.Jit IR operations per lane"})


def render(args):
    """The street-light scene with each module's sphere layer, rendered in turn in this process."""
    import time
    import corona  # noqa: F401  (sets up libLLVM first)
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    from corona.apps.render import setup_variant
    setup_variant("llvm_ad_spectral")
    import bench_render as br
    from common import write
    from corona.apps.scenes import street_light_scene
    from corona.mitsuba import sphere as this
    layer = br.BSDFS["corona-mie"]

    def scene(mod):
        bsdf = _bsdf(mod, layer)
        d = street_light_scene(resolution=args.render, bsdf=layer)

        def swap(node):   # the instance where the scene's corona BSDF was
            for k, v in node.items():
                if isinstance(v, dict):
                    if v.get("type") == "corona":
                        node[k] = bsdf
                    else:
                        swap(v)
        swap(d)
        return mi.load_dict(d)
    scenes = {"base": scene(_module_at(args.base)), "this": scene(this)}
    dr.set_flag(dr.JitFlag.KernelHistory, True)

    def once(sc, seed):
        dr.kernel_history()
        c0, t0 = time.process_time(), time.perf_counter()
        img = mi.render(sc, spp=64, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        h = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
        return {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                "kernel_s": sum(k.get("execution_time", 0) for k in h) * 1e-3}
    for sc in scenes.values():
        once(sc, 0)                 # compile
    runs = {k: [] for k in scenes}
    load0 = os.getloadavg()[0]
    for rnd in range(args.rounds):
        order = list(scenes) if rnd % 2 == 0 else list(reversed(list(scenes)))
        for k in order:
            runs[k].append(once(scenes[k], rnd + 1))
    summary = {k: {f: {"median": float(np.median([r[f] for r in v])), "min": float(min(r[f] for r in v))}
                   for f in ("wall_s", "cpu_s", "kernel_s")} for k, v in runs.items()}
    ratios = {f: {q: summary["this"][f][q] / summary["base"][f][q] for q in ("median", "min")}
              for f in ("wall_s", "cpu_s", "kernel_s")}
    for f, q in ratios.items():
        print(f"{f}: this / base {q['median']:.3f} (minima {q['min']:.3f})")
    write(args.name, {"base": args.base, "render": args.render, "spp": 64, "layer": layer, "runs": runs,
                      "summary": summary, "ratios": ratios, "load_average_1min": [load0, os.getloadavg()[0]]})


if __name__ == "__main__":
    main()
