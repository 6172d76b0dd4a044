"""What the corona BSDF's kernels do per lane: Dr.Jit's kernel history for eval, pdf, eval_pdf, sample.

For each layer family (the BSDFs of :data:`LAYERS`, the ones ``bench_render.py``
times) and for Mitsuba's ``roughdielectric`` as the reference, one kernel per
method is traced on 2^16 lanes of random incident directions (within 40° of
the normal), outgoing directions (near the coherent beam, where the lobe is),
wavelengths in [360, 830] nm and uv scanning [0, 1)² row by row, the inputs evaluated first so
that the kernel holds only the BSDF.  ``dr.kernel_history()`` (the
``KernelHistory`` flag) gives each kernel's operation count (Dr.Jit IR
instructions), its compile time (codegen + LLVM backend) and its run time;
its LLVM IR gives the gathers: calls of ``llvm.masked.gather`` (one per
gathered scalar) and of Dr.Jit's packet gathers ``gather_4xf32`` (a
``Vector4f`` read as one 4-wide load per lane, counted as ``packet``).  Counts are per lane (the kernel is
vectorised, one lane per sample) and static: an operation inside a loop (the
radial sampler's bisection) counts once however often it runs; a method that
needs a second kernel adds its counts.

    python benchmarks/bench_kernels.py [--variant llvm_ad_spectral] [--name kernels]

writes benchmarks/results/<name>.json.  No timing is asserted anywhere.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

FOG = os.path.normpath(os.path.join(HERE, os.pardir, "scenes", "textures", "wiped_fog.png"))
_FOG_TEX = {"type": "bitmap", "filename": FOG, "raw": True}
_CHECKER = {"type": "checkerboard", "color0": 0.1, "color1": 0.3}
LAYERS = {
    "uniform circle": {"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                       "mode": "particle"},
    "textured circle": {"type": "corona", "radius": 5.0, "process": "hard-disk", "mode": "particle",
                        "area_fraction": _FOG_TEX},
    "square": {"type": "corona", "shape": "square", "radius": 2.5, "area_fraction": 0.3, "process": "hard-disk"},
    "hexagon": {"type": "corona", "shape": "polygon", "sides": 6, "radius": 2.5, "area_fraction": 0.3,
                "process": "hard-disk"},
    "square, 20 % spread": {"type": "corona", "shape": "square", "radius": 2.5, "size_spread": 0.2,
                            "area_fraction": 0.3, "process": "hard-disk"},
    "Mie spheres": {"type": "corona", "shape": "sphere", "radius": 5.0, "area_fraction": 0.4,
                    "process": "hard-disk"},
    "glass pane": {"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                   "mode": "particle", "substrate": "glass"},
    # (the fog reaches F_a 0.59, beyond hard-disk squares' 0.46: a checkerboard of 0.1 and 0.3)
    "textured anisotropic (square)": {"type": "corona", "shape": "square", "radius": 2.5,
                                      "process": "hard-disk", "area_fraction": _CHECKER},
    "roughdielectric": {"type": "roughdielectric", "alpha": 0.05, "int_ior": 1.5},
}
N = 1 << 16
_GATHER = re.compile(r"= call <\d+ x \w+> @llvm\.masked\.gather")        # calls, not the declaration
_PACKET = re.compile(r"= call fastcc \[\d+ x <\d+ x \w+>\] @gather_\d+x")     # packet gathers


def inputs(dr, mi, np, n=N, seed=1):
    rng = np.random.default_rng(seed)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    th = np.arccos(rng.uniform(np.cos(np.radians(40)), 1.0, n))
    ph = rng.uniform(0, 2 * np.pi, n)
    wi = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)]).astype(np.float32)
    si.wi = mi.Vector3f(wi)
    # outgoing: -wi tilted by up to ~3° (the halo), on the far side
    dxy = rng.normal(0.0, 0.02, (2, n)).astype(np.float32)
    ox, oy = -wi[0] + dxy[0], -wi[1] + dxy[1]
    oz = -np.sqrt(np.maximum(1.0 - ox * ox - oy * oy, 1e-6))
    wo = mi.Vector3f(np.stack([ox, oy, oz]).astype(np.float32))
    # uv of a 256-wide image scan (neighbouring lanes, neighbouring texels: as in a render)
    side = int(np.sqrt(n))
    lane = np.arange(n)
    si.uv = mi.Point2f(np.stack([(lane % side + 0.5) / side, (lane // side % side + 0.5) / side]).astype(np.float32))
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(si.n)
    if mi.is_spectral:   # (RGB / mono: no wavelengths; dr.zeros left them empty)
        si.wavelengths = mi.Spectrum(rng.uniform(360, 830, (4, n)).astype(np.float32))
    s1 = mi.Float(rng.random(n).astype(np.float32))
    s2 = mi.Point2f(rng.random((2, n)).astype(np.float32))
    dr.eval(si, wo, s1, s2)
    dr.sync_thread()
    return si, wo, s1, s2


def profile(dr, mi, fn):
    """Run ``fn`` (it returns what to evaluate) four times: the first with an empty kernel cache
    for the compile time and the counts, then the fastest of three for the run time; kernel
    history summed over the kernels of a call."""
    dr.kernel_history()
    out = fn()
    dr.eval(out)
    dr.sync_thread()
    first = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    run = []
    for _ in range(3):
        out = fn()
        dr.eval(out)
        dr.sync_thread()
        run.append(sum(k.get("execution_time", 0) for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT))
    gathers = packets = 0
    for k in first:
        ir = k["ir"].getvalue() if hasattr(k["ir"], "getvalue") else str(k["ir"])
        gathers += len(_GATHER.findall(ir))
        packets += len(_PACKET.findall(ir))
    return {"kernels": len(first),
            "operations": int(sum(k["operation_count"] for k in first)),
            "gathers": gathers,
            "packet_gathers": packets,
            "compile_ms": float(sum(k.get("codegen_time", 0) + k.get("backend_time", 0) for k in first)),
            "cache_hit": bool(any(k.get("cache_hit") for k in first)),
            "run_ms": float(min(run))}


def flat(results: dict) -> dict:
    """``{layer: {method: figures}}`` as ``{"layer / method": figures}`` (one table row each)."""
    return {f"{layer} / {method}": figures for layer, row in results.items() for method, figures in row.items()}


def main():
    if not os.environ.get("CORONA_BENCH_COLD_HOME"):
        # Dr.Jit's kernel cache lives under $HOME: an empty one, so that compile times are cold
        import subprocess
        import tempfile
        with tempfile.TemporaryDirectory() as home:
            env = {**os.environ, "HOME": home, "CORONA_BENCH_COLD_HOME": "1"}
            raise SystemExit(subprocess.run([sys.executable, os.path.abspath(__file__), *sys.argv[1:]],
                                            env=env).returncode)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", default="llvm_ad_spectral")
    ap.add_argument("--name", default="kernels")
    ap.add_argument("--layers", nargs="*", default=list(LAYERS), choices=list(LAYERS))
    args = ap.parse_args()
    import corona
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    mi.set_variant(args.variant)
    corona.register()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    # no kernel cache on disk or in memory between layers: compile times are cold
    dr.set_flag(dr.JitFlag.KernelFreezing, False) if hasattr(dr.JitFlag, "KernelFreezing") else None
    si, wo, s1, s2 = inputs(dr, mi, np)
    ctx = mi.BSDFContext()
    results = {}
    for name in args.layers:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            bsdf = mi.load_dict(LAYERS[name])
        dr.eval()
        dr.sync_thread()
        dr.kernel_history()
        row = {}
        row["eval"] = profile(dr, mi, lambda: bsdf.eval(ctx, si, wo))
        row["pdf"] = profile(dr, mi, lambda: bsdf.pdf(ctx, si, wo))
        row["eval_pdf"] = profile(dr, mi, lambda: bsdf.eval_pdf(ctx, si, wo))
        row["sample"] = profile(dr, mi, lambda: bsdf.sample(ctx, si, s1, s2))
        results[name] = row
        print(f"{name:32s} " + "  ".join(f"{m} {r['operations']:5d} ops {r['gathers']:3d} g {r['packet_gathers']:2d} p "
                                         f"{r['compile_ms']:6.0f} ms JIT {r['run_ms']:6.2f} ms"
                                         for m, r in row.items()), flush=True)
        dr.flush_kernel_cache()
        del bsdf
    from common import write
    write(args.name, {"lanes": N, "variant": args.variant, "load_average_1min": os.getloadavg()[0],
                      "layers": {n: LAYERS[n] for n in args.layers}, "results": flat(results),
                      "note": "per lane: Dr.Jit IR operations, llvm.masked.gather calls and packet "
                              "gathers (gather_4xf32 calls) in the kernel's LLVM IR (one lane = one sample); compile_ms cold "
                              "(kernel caches flushed between layers), run_ms of 2^16 lanes (fastest of 3)"})


if __name__ == "__main__":
    main()
