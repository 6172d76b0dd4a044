"""The corona BSDF alone: ``eval_pdf`` and ``sample`` over 2^18 lanes, optionally against an earlier revision.

The layers of ``bench_kernels.py`` (:data:`bench_kernels.LAYERS`, Mitsuba's
``roughdielectric`` the reference) are loaded once each; their inputs are
``bench_kernels.inputs`` (random incident directions within 40° of the
normal, outgoing ones near the coherent beam, wavelengths in [360, 830] nm,
uv scanning [0, 1)² as a 512-wide image would), evaluated before the timing so
that a kernel holds only the BSDF.  Every method's first call pays the JIT
compile (not timed); then ``--rounds`` rounds interleave all layers (and both
revisions), each round timing every kernel ``--repeats`` times and keeping the
fastest: a load change on a shared machine hits every layer alike.  A
layer's time is the median over the rounds of those fastest runs; the ratios
to roughdielectric are taken round by round, and their minimum, median and
maximum go to the JSON file.  By default Dr.Jit runs on one thread and the time is the
process's CPU time (``time.process_time``): on a shared, loaded machine that is far steadier
than wall time; ``--threads N`` (N > 1) times wall-clock on N threads instead.

With ``--base REV`` the revision's ``src`` (``git archive``) is imported first
and its BSDFs loaded; then its modules are dropped from ``sys.modules`` and
this checkout's corona is imported and registered in their place.  Both
revisions' BSDF objects live in the one process (their classes are distinct),
so "after / before" compares the two on the same inputs, caches and load.

With ``--pieces`` the anisotropic layers' kernels (``LobeKernel``) are timed on their own
too: ``value``, ``pdf`` and ``sample`` on 2^20 points (u normal with σ = 5 around the forward
peak, where the lobe is; uniform sample numbers), one wavelength each, for both revisions.

    python benchmarks/bench_bsdf.py [--base REV] [--pieces] [--layers ...] [--lanes 18] [--rounds 5] [--repeats 5] [--threads 1]
        [--variant llvm_ad_spectral] [--name bsdf]

writes benchmarks/results/<name>.json.  No timing is asserted anywhere.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

from bench_kernels import LAYERS, inputs  # noqa: E402

METHODS = ("eval_pdf", "sample")


def _load(mi, names, tag):
    out = {}
    for name in names:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out[(name, tag)] = mi.load_dict(LAYERS[name])
    return out


def _swap_to(src: str):
    """Drop every imported corona module and put ``src`` first on the path (the next import loads it)."""
    for key in [k for k in sys.modules if k == "corona" or k.startswith("corona.")]:
        del sys.modules[key]
    sys.path.insert(0, src)


def _pieces(dr, mi, np, bsdfs, args, clock) -> dict:
    """The fastest of ``rounds × repeats`` runs [ms] of each anisotropic kernel's ``value``, ``pdf`` and
    ``sample`` on 2^20 points, rounds interleaved over the layers and revisions."""
    rng = np.random.default_rng(7)
    u = rng.normal(0.0, 5.0, (2, 1 << 20)).astype(np.float32)
    ux, uy = mi.Float(u[0]), mi.Float(u[1])
    xi = mi.Point2f(rng.random((2, 1 << 20)).astype(np.float32))
    on = mi.Bool(True)
    dr.eval(ux, uy, xi)
    calls = {"value": lambda k: k.value(ux, uy, on), "pdf": lambda k: k.pdf(ux, uy, on),
             "sample": lambda k: k.sample(xi, on)}
    kernels = {(name if tag == "now" else f"{name} (base)"): b.kernel for (name, tag), b in bsdfs.items()
               if getattr(b, "kernel", None) is not None}
    best = {label: {m: float("inf") for m in calls} for label in kernels}
    for r in range(args.rounds + 1):                 # (round 0: the JIT compile, untimed)
        for label, k in kernels.items():
            for m, fn in calls.items():
                for _ in range(args.repeats if r else 1):
                    t0 = clock()
                    dr.eval(fn(k))
                    dr.sync_thread()
                    if r:
                        best[label][m] = min(best[label][m], (clock() - t0) * 1e3)
    return best


def _spread(xs):
    return {"min": min(xs), "median": statistics.median(xs), "max": max(xs)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", help="a git revision whose BSDFs to time in the same process")
    ap.add_argument("--layers", nargs="*", default=[n for n in LAYERS if n != "Mie spheres"], choices=list(LAYERS))
    ap.add_argument("--lanes", type=int, default=18, help="log2 of the lanes per call")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=5, help="timed calls per kernel and round (fastest kept)")
    ap.add_argument("--pieces", action="store_true", help="time the anisotropic kernels' value / pdf / sample too")
    ap.add_argument("--threads", type=int, default=1,
                    help="Dr.Jit's threads: 1 times CPU time, more wall-clock time")
    ap.add_argument("--variant", default="llvm_ad_spectral")
    ap.add_argument("--name", default="bsdf")
    args = ap.parse_args()
    names = list(dict.fromkeys([*args.layers, "roughdielectric"]))
    tmp = tempfile.TemporaryDirectory()
    bsdfs = {}
    if args.base:
        archive = subprocess.run(["git", "-C", ROOT, "archive", args.base, "src"], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp.name], input=archive, check=True)
        _swap_to(os.path.join(tmp.name, "src"))
    else:
        _swap_to(os.path.join(ROOT, "src"))
    import corona
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    mi.set_variant(args.variant)
    corona.register()
    if args.threads > 0:
        dr.set_thread_count(args.threads)
    clock = time.process_time if args.threads == 1 else time.perf_counter
    if args.base:
        bsdfs.update(_load(mi, [n for n in names if n != "roughdielectric"], "base"))
        _swap_to(os.path.join(ROOT, "src"))
        import corona as corona_now
        corona_now.register()
    bsdfs.update(_load(mi, names, "now"))
    dr.eval()
    si, wo, s1, s2 = inputs(dr, mi, np, n=1 << args.lanes)
    ctx = mi.BSDFContext()
    calls = {"eval_pdf": lambda b: b.eval_pdf(ctx, si, wo), "sample": lambda b: b.sample(ctx, si, s1, s2)}

    def run(b, method):
        out = calls[method](b)
        dr.eval(out)
        dr.sync_thread()

    for b in bsdfs.values():        # the JIT compile of every kernel, untimed
        for m in METHODS:
            run(b, m)
    load_start = os.getloadavg()[0]
    times = {key: {m: [] for m in METHODS} for key in bsdfs}
    for r in range(args.rounds):
        for key, b in bsdfs.items():
            for m in METHODS:
                best = float("inf")
                for _ in range(args.repeats):
                    t0 = clock()
                    run(b, m)
                    best = min(best, clock() - t0)
                times[key][m].append(best * 1e3)
        print(f"round {r + 1}/{args.rounds} done", flush=True)
    pieces = _pieces(dr, mi, np, bsdfs, args, clock) if args.pieces else {}
    ref = times[("roughdielectric", "now")]
    results = {}
    for (name, tag), row in times.items():
        label = name if tag == "now" else f"{name} (base)"
        res = {}
        for m in METHODS:
            res[m] = {"median_ms": statistics.median(row[m]), "min_ms": min(row[m]), "round_ms": row[m],
                      "over_roughdielectric": _spread([a / b for a, b in zip(row[m], ref[m])])}
            if tag == "now" and (name, "base") in times:
                res[m]["over_base"] = _spread([a / b for a, b in zip(row[m], times[(name, "base")][m])])
        results[label] = res
    for label, res in results.items():
        print(f"{label:40s} " + "  ".join(
            f"{m} {res[m]['median_ms']:7.2f} ms ({res[m]['over_roughdielectric']['median']:.2f}x rd"
            + (f", {res[m]['over_base']['median']:.2f}x base" if "over_base" in res[m] else "") + ")"
            for m in METHODS))
    for label, row in pieces.items():
        print(f"{label:40s} kernel " + "  ".join(f"{m} {v:6.2f} ms" for m, v in row.items()))
    from common import write
    write(args.name, {"kernel_pieces_ms_per_2^20": pieces, "lanes": 1 << args.lanes, "variant": args.variant, "base": args.base, "rounds": args.rounds,
                      "repeats": args.repeats, "threads": args.threads,
                      "clock": "process CPU time" if args.threads == 1 else "wall", "layers": {n: LAYERS[n] for n in names}, "results": results,
                      "load_average_1min": {"start": load_start, "end": os.getloadavg()[0]},
                      "note": "ms per call over all lanes: the median over rounds of each round's fastest of "
                              "`repeats`; ratios round by round (min / median / max over rounds)"})
    tmp.cleanup()


if __name__ == "__main__":
    main()
