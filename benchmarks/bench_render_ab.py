"""Render cost of this checkout against an earlier revision, interleaved in one run.

``bench_render.py``'s children (one scene a process, an empty Dr.Jit kernel
cache, the first render's JIT compile from the kernel history, then timed
renders) run for the BSDFs named by ``--bsdfs`` from both source trees in
turn: the revision ``--base`` (``git archive`` into a temporary folder) and this
checkout; ``corona`` and ``roughdielectric`` from this checkout are the
references.  Interleaving the two trees round by round lets load on a shared
machine hit both alike, so the ratios (render medians and minima over
``corona`` and over ``roughdielectric``, JIT compile over ``roughdielectric``)
compare the revisions; each ratio's spread over the rounds (a round's median over
the reference's in the same round: min, median, max) goes to the JSON file too,
and this checkout's children also time their BSDF alone (``bench_render.py``'s
``--bsdf-lanes``).  Renders are 256² unless only the Mie layer is timed (128²).

    python benchmarks/bench_render_ab.py --base REV [--bsdfs corona-mie] [--rounds 3] [--repeats 2]
        [--res 256] [--spp 64] [--variant llvm_ad_spectral]

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


def child(root: str, name: str, args) -> dict:
    """One ``bench_render.py --child`` process of the tree ``root`` (its own ``src`` first on the path;
    this checkout's also times the BSDF alone)."""
    extra = ["--bsdf-lanes", str(args.bsdf_lanes)] if root == ROOT else []
    with tempfile.TemporaryDirectory() as home:
        env = {**os.environ, "HOME": home, "PYTHONPATH": os.path.join(root, "src")}
        out = subprocess.run([sys.executable, os.path.join(root, "benchmarks", "bench_render.py"), "--child", name,
                              "--res", str(args.res), "--spp", str(args.spp), "--repeats", str(args.repeats),
                              "--variant", args.variant, *extra], env=env, check=True, capture_output=True,
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
    args = ap.parse_args()
    if args.res is None:
        args.res = 128 if set(args.bsdfs) <= {"corona-mie"} else 256
    from common import summarise, write
    from bench_render import round_spread
    with tempfile.TemporaryDirectory() as base:
        archive = subprocess.run(["git", "-C", ROOT, "archive", args.base, "src", "benchmarks", "scenes"],
                                 check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", base], input=archive, check=True)
        load_start = os.getloadavg()[0]
        plan = [(f"{n} (base)", base, n) for n in args.bsdfs] + [(n, ROOT, n) for n in args.bsdfs]
        plan += [(n, ROOT, n) for n in ("corona", "roughdielectric") if n not in args.bsdfs]
        runs: dict = {}
        for r in range(args.rounds):
            for label, root, name in plan:
                runs.setdefault(label, []).append(child(root, name, args))
                print(f"round {r + 1}/{args.rounds} {label:24s} {runs[label][-1]['times_s']}", flush=True)
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
    write(args.name, {"base": args.base, "scene": "street_light_scene", "resolution": args.res, "spp": args.spp,
                      "rounds": args.rounds, "repeats": args.repeats, "variant": args.variant, "results": results,
                      "load_average_1min": {"start": load_start, "end": os.getloadavg()[0]}})


if __name__ == "__main__":
    main()
