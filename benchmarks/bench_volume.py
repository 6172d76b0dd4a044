"""Volume render cost: the corona_mie phase function against Mitsuba's hg (same σ_t, g matched).

A slab of optical depth 1 (5 µm water droplets, gamma, v_eff 0.01, albedo 1) seen against a
distant light (corona.mitsuba.volume.slab_scene), volpath with up to 32 bounces.  Per variant the
three scenes (isotropic, hg, corona_mie) are loaded and rendered once to compile the kernels,
then rendered in turn ``--repeat`` times (interleaved, new seeds), so every round's ratio
corona_mie / hg is measured under the same load; the median and the spread of the per-round
ratios are reported, with the machine's load average.  Besides the wall-clock time the CPU
time of the process (all its threads) is recorded: on a shared, loaded machine its ratio is
the steadier measure of the work each phase function costs.  Goal: corona_mie <= 1.3x hg.

    python benchmarks/bench_volume.py [--size 96] [--spp 32] [--repeat 9]

Writes benchmarks/results/volume.json.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import common  # noqa: F401  (imports corona before drjit)

NAMES = ("isotropic", "hg", "corona_mie")


def run(variant: str, size: int, spp: int, repeat: int) -> dict:
    import corona  # noqa: I001  (before drjit)
    import drjit as dr
    import mitsuba as mi

    from corona.mitsuba import volume
    from corona.model.mie.volume import MieVolume
    mi.set_variant(variant)
    corona.register()
    kw = dict(distribution="gamma", variance=0.01)
    v = MieVolume(5.0, **kw)
    h, tau = 0.01, 1.0
    sigma_t = tau / h
    g = float(v.cross_sections(550.0)["g"])
    phases = {"isotropic": {"type": "isotropic"}, "hg": {"type": "hg", "g": g},
              "corona_mie": {"type": "corona_mie", "radius": 5.0, **kw}}
    scenes = {}
    for name in NAMES:
        med = {"type": "homogeneous", "sigma_t": sigma_t, "albedo": 1.0, "phase": phases[name]}
        scenes[name] = mi.load_dict(volume.slab_scene(med, thickness=h, fov=24.0, size=size, spp=spp,
                                                      max_depth=32))
        dr.eval(mi.render(scenes[name], seed=0))
        dr.sync_thread()
    times = {name: [] for name in NAMES}
    cpu = {name: [] for name in NAMES}
    load = [os.getloadavg()[0]]
    for k in range(repeat):
        for name in NAMES:
            t, c = time.perf_counter(), time.process_time()
            img = mi.render(scenes[name], seed=k + 1)
            dr.eval(img)
            dr.sync_thread()
            times[name].append(time.perf_counter() - t)
            cpu[name].append(time.process_time() - c)
    load.append(os.getloadavg()[0])
    ratios = [m / h for m, h in zip(times["corona_mie"], times["hg"])]
    cpu_ratios = [m / h for m, h in zip(cpu["corona_mie"], cpu["hg"])]
    out = {"g": g, "load_average_1min": load}
    for name in NAMES:
        out[name] = {"min_s": min(times[name]), "median_s": statistics.median(times[name]),
                     "times_s": times[name], "cpu_s": cpu[name]}
    out["ratio_per_round"] = ratios
    out["cpu_ratio_per_round"] = cpu_ratios
    out["cpu_ratio"] = statistics.median(cpu_ratios)
    out["ratio"] = statistics.median(ratios)
    out["ratio_of_minima"] = out["corona_mie"]["min_s"] / out["hg"]["min_s"]
    q = sorted(ratios)
    print(f"{variant}: median times isotropic {out['isotropic']['median_s']:.3f} s, hg "
          f"{out['hg']['median_s']:.3f} s, corona_mie {out['corona_mie']['median_s']:.3f} s; "
          f"corona_mie / hg per round: median {out['ratio']:.2f} (range {q[0]:.2f}-{q[-1]:.2f}), "
          f"of the minima {out['ratio_of_minima']:.2f}; CPU time ratio {out['cpu_ratio']:.2f} "
          f"(range {min(cpu_ratios):.2f}-{max(cpu_ratios):.2f}); load {load[0]:.1f}-{load[1]:.1f}")
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--variants", default="llvm_ad_rgb,llvm_ad_spectral")
    ap.add_argument("--no-write", action="store_true")
    a = ap.parse_args()
    res = {v: run(v, a.size, a.spp, a.repeat) for v in a.variants.split(",")}
    if not a.no_write:
        common.write("volume", {"size": a.size, "spp": a.spp, "repeat": a.repeat, "goal_ratio": 1.3,
                                "interleaved": True, "results": res})


if __name__ == "__main__":
    main()
