"""Efficiency of the anisotropic layers' sampling-table size: variance × time at equal spp.

The opaque anisotropic layers sample ``u`` from a bilinear table of the lobe (512² nodes from
the material's tables); :meth:`corona.mitsuba.kernels.LobeKernel.use_sampling_table` can put
the same interpolant on fewer nodes (``n``² spanning the same square).  A coarser table is
cheaper to read (the pdf's lookup at four wavelengths per evaluation, the sampler's), but
follows the lobe's fringes less closely, so every render gets noisier.  This benchmark weighs
the two in one process, the kernel's table swapped in place between the renders (nothing
else of the BSDF changes):

* the lobe's sample weights: ``bsdf.sample`` at fixed incident directions (0°, 20°, 40°),
  ``--lanes`` lanes of uniform sample numbers and wavelengths in [360, 830] nm; over the lanes
  that sampled the lobe, the relative variance of the weight ``Var(w) / E[w]²`` (mean over the
  spectral channels), and the mean over all lanes (the lobe's energy: both tables must agree
  within their errors, the estimator is unbiased either way);
* renders of ``--scene`` (:data:`SCENES`: ``bench_render.py``'s ``street_light_scene`` or its large
  lamp, path, ``--res``, ``--spp``):
  a reference at ``--ref-spp`` with the full table, then ``--rounds`` interleaved rounds of
  one render with each table (other seeds), each timed (``--render-threads``: by default one
  Dr.Jit thread and the process's CPU time, steadier than wall time on a shared machine; 0: all
  threads, wall time; JIT excluded by a warm-up render of each); the relative MSE against the reference,
  ``Σ (img - ref)² / Σ ref²``, and the efficiency ratio
  ``(MSE_n × time_n) / (MSE_full × time_full)`` (below 1: the coarse table wins);
* the BSDF alone with each table (``--bsdf-rounds`` interleaved rounds, one thread, CPU time):
  ``eval_pdf`` at ``bench_kernels.inputs``' directions and at sampled ones, ``sample``.

    python benchmarks/bench_sampling_table.py [--n 256] [--bsdfs corona-square ...] [--res 256]
        [--spp 64] [--ref-spp 1024] [--scene bench|large-lamp] [--rounds 4] [--lanes 18] [--bsdf-rounds 9] [--render-threads 1]
        [--name sampling_table]

writes benchmarks/results/<name>.json.  No timing is asserted anywhere.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from bench_render import BSDFS  # noqa: E402
from common import machine, write  # noqa: E402

#: scenes: bench_render.py's (a lamp of 0.14°: emitter sampling finds it, the BSDF's samples
#: rarely matter) and bench_sampling.py's large lamp (26.6°, wider than the lobe: the BSDF's decide)
SCENES = {"bench": {}, "large-lamp": {"light_radius": 10.0, "fov": 30.0}}
ANISOTROPIC = ("corona-square", "corona-hexagon", "corona-square-spread", "corona-square-textured")


def _corona_bsdf(mi, scene):
    for shape in scene.shapes():
        b = shape.bsdf()
        if hasattr(b, "kernel"):
            return b
    raise RuntimeError("no corona BSDF with an anisotropic kernel in the scene")


def _weights(dr, mi, np, bsdf, lanes, seed):
    """Per incident angle: mean and relative variance of the lobe's sample weights."""
    rng = np.random.default_rng(seed)
    n = 1 << lanes
    out = {}
    for deg in (0.0, 20.0, 40.0):
        th = np.radians(deg)
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(float(np.sin(th)), 0.0, float(np.cos(th)))
        si.n = mi.Normal3f(0, 0, 1)
        si.sh_frame = mi.Frame3f(si.n)
        si.uv = mi.Point2f(rng.random((2, n)).astype(np.float32))
        si.wavelengths = mi.Spectrum(rng.uniform(360, 830, (4, n)).astype(np.float32))
        s1 = mi.Float(rng.random(n).astype(np.float32))
        s2 = mi.Point2f(rng.random((2, n)).astype(np.float32))
        bs, w = bsdf.sample(mi.BSDFContext(), si, s1, s2)
        dr.eval(bs, w)
        lobe = (bs.sampled_component.numpy() == 1)
        wv = np.asarray(w.numpy(), dtype=np.float64)
        wv = (wv.reshape(1, -1) if wv.ndim == 1 else wv)[:, lobe]
        # the lobe's energy per sample (the lanes that picked another component count 0)
        full = np.zeros((wv.shape[0], n))
        full[:, lobe] = wv
        mean = full.mean(axis=1)
        # over the lobe's lanes only (the component's pick, the same for both tables, left out)
        rel = wv.var(axis=1) / np.maximum(wv.mean(axis=1), 1e-300) ** 2
        out[f"{deg:g}"] = {"lobe_lanes": int(lobe.sum()), "mean": mean.tolist(),
                           "mean_stderr": (full.std(axis=1) / np.sqrt(n)).tolist(),
                           "relative_variance": float(np.mean(rel)),
                           "relative_variance_all_lanes": float(np.mean(full.var(axis=1)
                                                                        / np.maximum(mean, 1e-300) ** 2))}
    return out


def _bsdf_times(dr, mi, np, bsdf, use, rounds, lanes):
    """The BSDF alone with each table (``bench_kernels.inputs``, 2^lanes lanes, one Dr.Jit thread, CPU
    time): per round the fastest of 3 calls of ``eval_pdf`` (at the inputs' directions and at
    sampled ones) and of ``sample`` for each table, the tables alternating; the median over the
    rounds of each round's coarse / full ratio."""
    from bench_kernels import inputs
    si, wo, s1, s2 = inputs(dr, mi, np, n=1 << lanes)
    ctx = mi.BSDFContext()
    bs, _ = bsdf.sample(ctx, si, s1, s2)
    wo_s = mi.Vector3f(bs.wo)
    dr.eval(wo_s)
    calls = {"eval_pdf": lambda: bsdf.eval_pdf(ctx, si, wo), "eval_pdf_sampled": lambda: bsdf.eval_pdf(ctx, si, wo_s),
             "sample": lambda: bsdf.sample(ctx, si, s1, s2)}
    threads = dr.thread_count()
    dr.set_thread_count(1)
    ms = {w: {m: [] for m in calls} for w in ("full", "coarse")}
    for which in ("full", "coarse"):                      # compile
        use(which)
        for fn in calls.values():
            dr.eval(fn())
    for r in range(rounds):
        for which in (("full", "coarse") if r % 2 == 0 else ("coarse", "full")):
            use(which)
            for m, fn in calls.items():
                best = float("inf")
                for _ in range(3):
                    t0 = time.process_time()
                    dr.eval(fn())
                    dr.sync_thread()
                    best = min(best, time.process_time() - t0)
                ms[which][m].append(best * 1e3)
    dr.set_thread_count(threads)
    ratio = {m: statistics.median([c / f for c, f in zip(ms["coarse"][m], ms["full"][m])]) for m in calls}
    return {"ms": ms, "ratio": ratio,
            "median_ms": {w: {m: statistics.median(v) for m, v in ms[w].items()} for w in ms}}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--bsdfs", nargs="+", default=list(ANISOTROPIC))
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--lanes", type=int, default=18)
    ap.add_argument("--bsdf-rounds", type=int, default=9)
    ap.add_argument("--render-threads", type=int, default=1)
    ap.add_argument("--scene", choices=sorted(SCENES), default="bench")
    ap.add_argument("--variant", default="llvm_ad_spectral")
    ap.add_argument("--name", default="sampling_table")
    args = ap.parse_args()

    import corona  # noqa: F401
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    from corona.apps.render import setup_variant
    from corona.apps.scenes import street_light_scene
    setup_variant(args.variant)
    load0 = os.getloadavg()[0]
    results = {}
    for name in args.bsdfs:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = mi.load_dict(street_light_scene(resolution=args.res, bsdf=BSDFS[name],
                                                  **SCENES[args.scene]))
        bsdf = _corona_bsdf(mi, scene)
        k = bsdf.kernel
        source, full_n = k.sampling_source, int(k.near["n"])
        tables = {"full": full_n, "coarse": args.n}

        def use(which):
            k.use_sampling_table(source, tables[which])

        def render(spp, seed, timed=True):
            threads = dr.thread_count()
            if timed and args.render_threads:
                dr.set_thread_count(args.render_threads)
            clock = time.process_time if timed and args.render_threads == 1 else time.perf_counter
            t0 = clock()
            img = mi.render(scene, spp=spp, seed=seed)
            dr.eval(img)
            dr.sync_thread()
            s = clock() - t0
            dr.set_thread_count(threads)
            return np.asarray(img, dtype=np.float64), s

        row = {"nodes": tables, "weights": {}}
        for which in ("full", "coarse"):
            use(which)
            row["weights"][which] = _weights(dr, mi, np, bsdf, args.lanes, seed=11)
        row["bsdf_alone"] = _bsdf_times(dr, mi, np, bsdf, use, args.bsdf_rounds, args.lanes) if args.bsdf_rounds else {}
        use("full")
        ref, ref_s = render(args.ref_spp, 10_000, timed=False)
        norm = float(np.sum(ref ** 2))
        for which in ("full", "coarse"):          # warm-up: each table's kernels compiled
            use(which)
            render(args.spp, 9_999)
        mse = {"full": [], "coarse": []}
        secs = {"full": [], "coarse": []}
        for r in range(args.rounds):
            for which in (("full", "coarse") if r % 2 == 0 else ("coarse", "full")):
                use(which)
                img, s = render(args.spp, 1 + r)          # the same seeds for both tables
                mse[which].append(float(np.sum((img - ref) ** 2)) / norm)
                secs[which].append(s)
        med = {w: (statistics.median(mse[w]), statistics.median(secs[w])) for w in mse}
        time_ratio = statistics.median([c / f for c, f in zip(secs["coarse"], secs["full"])])
        mse_ratio = med["coarse"][0] / med["full"][0]
        rv = {w: statistics.mean(v["relative_variance"] for v in row["weights"][w].values())
              for w in ("full", "coarse")}
        row.update(reference_spp=args.ref_spp, reference_s=ref_s, relative_mse=mse, render_s=secs,
                   mse_ratio=mse_ratio, time_ratio=time_ratio, efficiency_ratio=mse_ratio * time_ratio,
                   weight_variance_ratio=rv["coarse"] / rv["full"])
        results[name] = row
        use("full")
        print(f"{name}: nodes {full_n} -> {args.n}: weight rel. variance {rv['full']:.4g} -> {rv['coarse']:.4g}"
              f" ({rv['coarse'] / rv['full']:.3f}); render MSE ratio {mse_ratio:.3f}, time ratio {time_ratio:.3f},"
              f" efficiency (MSE x time) ratio {mse_ratio * time_ratio:.3f}; BSDF alone coarse / full "
              f"{row['bsdf_alone'].get('ratio')}", flush=True)
        del scene, bsdf, k
    payload = {"args": vars(args), "machine": machine(), "load_start": load0, "load_end": os.getloadavg()[0],
               "results": results}
    print(write(args.name, payload))


if __name__ == "__main__":
    main()
