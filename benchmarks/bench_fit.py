"""`corona fit` on a one-megapixel photograph: time and accuracy.

A 1024² corona (droplets of 8 µm radius, 6 % size spread, F_a 0.35, hard
disks; a 3200 K lamp 0.2° across, off-centre, 40° field of view) is rendered
with the plugin, given noise and a saturated core, and saved as an 8-bit sRGB
PNG; :func:`corona.apps.fit.fit_photograph` then reads it and fits it, timed in
the process (imports done) and as the command ``corona fit --json`` (a fresh
process, imports included).  Writes benchmarks/results/fit.json.  Goal (issue
13): a one-megapixel image fits in <= 5 s on 2 cores.

    python benchmarks/bench_fit.py [--res 1024] [--repeats 3]
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

import corona  # noqa: E402
from common import write  # noqa: E402

TRUTH = dict(radius=8.0, size_spread=0.06, area_fraction=0.35, temperature=3200.0)
FOV, LAMP_DIAMETER, OFFSET = 40.0, 0.2, (2.0, -1.5)


def render_photograph(path: str, res: int, spp: int = 4) -> float:
    import imageio.v3 as iio
    import mitsuba as mi
    import numpy as np

    from corona.color import tonemap_srgb
    from corona.apps.scenes import lamp_photograph_scene
    mi.set_variant(corona.default_variant(prefer_gpu=False))
    corona.register()
    bsdf = {"type": "corona", "radius": TRUTH["radius"], "size_spread": TRUTH["size_spread"],
            "area_fraction": TRUTH["area_fraction"], "process": "hard-disk", "mode": "particle"}
    t0 = time.perf_counter()
    scene = mi.load_dict(lamp_photograph_scene(res, bsdf, fov=FOV, source_deg=OFFSET,
                                               source_radius_deg=LAMP_DIAMETER / 2,
                                               temperature=TRUTH["temperature"]))
    img = np.array(mi.render(scene, spp=spp), dtype=np.float64)
    seconds = time.perf_counter() - t0
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    noisy = img / np.percentile(lum, 99.5) + np.random.default_rng(0).normal(0.0, 0.002, img.shape)
    iio.imwrite(path, tonemap_srgb(noisy, exposure=1.0))
    return seconds


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--res", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    from corona.apps.fit import fit_photograph
    tmp = tempfile.mkdtemp(prefix="corona-bench-fit-")
    os.environ.setdefault("CORONA_CACHE_DIR", os.path.join(tmp, "cache"))
    png = os.path.join(tmp, "corona.png")
    render_s = render_photograph(png, args.res)
    times, cpu, res = [], [], None
    for _ in range(args.repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        res = fit_photograph(png, FOV, source_diameter_deg=LAMP_DIAMETER)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)

    def cli(*extra):
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-m", "corona.apps.cli", "fit", png, "--fov", str(FOV),
                              "--source-diameter", str(LAMP_DIAMETER), "--json", "--out",
                              os.path.join(tmp, "out"), *extra], check=True, capture_output=True, text=True)
        return time.perf_counter() - t0, json.loads(out.stdout)
    cli_s, cli_out = cli()
    cli_plain_s, _ = cli("--no-diagnostic")
    pixels = args.res * args.res
    results = {
        f"{args.res}² 8-bit PNG": {
            "megapixels": pixels / 1e6,
            "fit_median_s": statistics.median(times), "fit_min_s": min(times),
            "fit_cpu_median_s": statistics.median(cpu),
            "cli_s": cli_plain_s, "cli_with_diagnostic_s": cli_s,
            "radius_true": TRUTH["radius"], "radius_fit": res.radius, "radius_err": res.radius_err,
            "radius_error_percent": 100 * (res.radius / TRUTH["radius"] - 1),
            "size_spread_true": TRUTH["size_spread"], "size_spread_fit": res.size_spread,
            "area_fraction_true": TRUTH["area_fraction"], "area_fraction_fit": res.area_fraction,
            "temperature_true": TRUTH["temperature"], "temperature_fit": res.temperature,
            "chi2_reduced": res.chi2_reduced, "profile_bins": res.n_bins,
            "meets_goal": statistics.median(times) <= 5.0,
        }
    }
    print(json.dumps(results, indent=1))
    write("fit", {"goal": "a one-megapixel image fits in <= 5 s on 2 cores (issue 13)",
                  "results": results, "render_seconds": render_s, "fit_seconds": times,
                  "fit_cpu_seconds": cpu, "cli_radius": cli_out["radius"],
                  "note": "fit_*: fit_photograph in a warm process (reading the PNG included); cli_*: "
                          "`corona fit --json` in a fresh process (Python, numpy, scipy, corona imports; "
                          "with the diagnostic: matplotlib too)"})


if __name__ == "__main__":
    main()
