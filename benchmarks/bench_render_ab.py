"""Render cost of this checkout against an earlier revision, interleaved in one run.

``bench_render.py``'s children (one scene a process, an empty Dr.Jit kernel
cache, the first render's JIT compile from the kernel history, then timed
renders; this checkout's script for both trees) run for the BSDFs named by
``--bsdfs`` on both source trees: the revision ``--base`` (``git archive`` into
a temporary folder, with its own table cache) and this checkout.  Each round
runs each family's two trees back to back, which one first alternating from
round to round, so load on a shared machine hits both alike; ``corona`` and
``roughdielectric`` from this checkout are also the references.  Written per
family: ``over_base``, this checkout's render over the base's (medians, minima,
and each round's ratio of medians: min, median, max; the same for the renders'
process CPU time), within ``--goal`` when the median over rounds is; per label
the ratios over ``corona`` and ``roughdielectric`` and the JIT compile, and the
BSDF alone for this checkout (``bench_render.py``'s ``--bsdf-lanes``).
Renders are 256² unless only the Mie layer is timed (128²).

    python benchmarks/bench_render_ab.py --base REV [--bsdfs corona-mie] [--rounds 3] [--repeats 2]
        [--res 256] [--spp 64] [--variant llvm_ad_spectral] [--goal 1.03]

writes benchmarks/results/<name>.json (default ``render_ab``).  No timing is asserted anywhere.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)


def child(root: str, name: str, args, cache: str | None = None) -> dict:
    """One ``bench_render.py --child`` process (this checkout's script) on the tree ``root`` (its ``src`` first on the path;
    this checkout's also times the BSDF alone); ``cache``: its own table cache folder (the base
    revision's tables may be laid out otherwise)."""
    extra = ["--bsdf-lanes", str(args.bsdf_lanes)] if root == ROOT else []
    with tempfile.TemporaryDirectory() as home:
        env = {**os.environ, "HOME": home, "PYTHONPATH": os.path.join(root, "src")}
        if cache:
            env.update(CORONA_CACHE_DIR=cache, NUMBA_CACHE_DIR=os.path.join(cache, "numba"))
        out = subprocess.run([sys.executable, os.path.join(HERE, "bench_render.py"), "--child", name,
                              "--res", str(args.res), "--spp", str(args.spp), "--repeats", str(args.repeats),
                              "--variant", args.variant, "--threads", str(args.threads), *extra], env=env, check=True, capture_output=True,
                             text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the git revision to compare with")
    ap.add_argument("--bsdfs", nargs="*", default=["corona-mie"], help="bench_render.py's BSDF names")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--res", type=int, default=None, help="image width and height (default 256; 128 for the Mie "
                                                             "layer alone)")
    ap.add_argument("--bsdf-lanes", type=int, default=18, help="log2 of the BSDF-alone timing's lanes (0: none)")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--variant", default="llvm_ad_spectral")
    ap.add_argument("--name", default="render_ab")
    ap.add_argument("--threads", type=int, default=0, help="Dr.Jit threads of the renders (0: all)")
    ap.add_argument("--goal", type=float, default=1.03, help="the most this checkout's render may take over the "
                    "base's (the median over rounds of a round's ratio)")
    args = ap.parse_args()
    if args.res is None:
        args.res = 128 if set(args.bsdfs) <= {"corona-mie"} else 256
    from common import summarise, write
    from bench_render import round_spread
    with tempfile.TemporaryDirectory() as base:
        archive = subprocess.run(["git", "-C", ROOT, "archive", args.base, "src", "benchmarks", "scenes"],
                                 check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", base], input=archive, check=True)
        load_start, loads = os.getloadavg()[0], []
        base_cache = os.path.join(base, ".tables")
        refs = [(n, ROOT, n) for n in ("corona", "roughdielectric") if n not in args.bsdfs]
        runs: dict = {}
        for r in range(args.rounds):
            for name in args.bsdfs:   # each family's two trees back to back, in turn first (A B, B A, ...)
                pair = [(f"{name} (base)", base, name), (name, ROOT, name)]
                for label, root, n in (pair if r % 2 == 0 else pair[::-1]) + (refs if name == args.bsdfs[-1] else []):
                    runs.setdefault(label, []).append(child(root, n, args, base_cache if root == base else None))
                    print(f"round {r + 1}/{args.rounds} {label:24s} {runs[label][-1]['times_s']}", flush=True)
            loads.append(os.getloadavg()[0])
    results = {}
    for label, rs in runs.items():
        results[label] = summarise(rs, "jit_compile_s")
        if all(r.get("bsdf_alone") for r in rs):
            results[label]["bsdf_alone"] = {m: statistics.median(r["bsdf_alone"][m] for r in rs)
                                            for m in rs[0]["bsdf_alone"]}
    for label, res in results.items():
        res["render_over_corona"] = res["median_s"] / results["corona"]["median_s"]
        res["render_over_corona_minima"] = res["min_s"] / results["corona"]["min_s"]
        res["render_over_roughdielectric"] = res["median_s"] / results["roughdielectric"]["median_s"]
        res["over_corona_rounds"] = round_spread(runs[label], runs["corona"])
        res["over_roughdielectric_rounds"] = round_spread(runs[label], runs["roughdielectric"])
        res["jit_over_roughdielectric"] = res["jit_compile_s"] / results["roughdielectric"]["jit_compile_s"]
        spread = res["over_roughdielectric_rounds"]
        print(f"{label:24s} median {res['median_s']:7.3f} s  / corona {res['render_over_corona']:.3f} "
              f"(minima {res['render_over_corona_minima']:.3f})  / roughdielectric "
              f"{res['render_over_roughdielectric']:.3f} (rounds {spread['min']:.3f}-{spread['max']:.3f})  "
              f"JIT {res['jit_compile_s']:6.3f} s "
              f"/ roughdielectric {res['jit_over_roughdielectric']:.3f}")
    over_base = {}
    for name in args.bsdfs:   # this checkout over the base revision, family by family
        new, old = results[name], results[f"{name} (base)"]
        spread = round_spread(runs[name], runs[f"{name} (base)"])
        cpu = [{"times_s": r["cpu_s"]} for r in runs[name]], [{"times_s": r["cpu_s"]} for r in runs[f"{name} (base)"]]
        over_base[name] = {"ratio": new["median_s"] / old["median_s"], "ratio_of_minima": new["min_s"] / old["min_s"],
                           "rounds": spread, "base_median_s": old["median_s"], "median_s": new["median_s"],
                           "cpu_rounds": round_spread(*cpu), "within_goal": bool(spread["median"] <= args.goal)}
        print(f"{name:24s} / base: medians {over_base[name]['ratio']:.3f}, minima "
              f"{over_base[name]['ratio_of_minima']:.3f}, rounds {spread['min']:.3f} {spread['median']:.3f} "
              f"{spread['max']:.3f} (min, median, max); CPU time rounds {over_base[name]['cpu_rounds']['median']:.3f}")
    write(args.name, {"argv": sys.argv, "threads": args.threads, "base": args.base, "over_base": over_base, "goal_over_base": args.goal,
                      "load_average_1min_rounds": loads, "scene": "street_light_scene", "resolution": args.res, "spp": args.spp,
                      "rounds": args.rounds, "repeats": args.repeats, "variant": args.variant, "results": results,
                      "load_average_1min": {"start": load_start, "end": os.getloadavg()[0]}})


if __name__ == "__main__":
    main()
