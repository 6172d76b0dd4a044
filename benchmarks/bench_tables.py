"""Table build times: every scene of scenes/ cold, and each kind of material.

Scenes: each scene in a fresh process with an empty table cache
(``CORONA_CACHE_DIR`` a new temporary folder per scene), Python, corona,
Mitsuba and scipy imported and Dr.Jit started before the clock runs; then
``mi.load_file(scene)`` is timed.  Reported per scene: the whole load (wall
and CPU), the time spent constructing corona's plugins (``corona`` BSDF,
``corona_mie`` phase function: the tables' build), the part of it in Mie
theory (``sphere_material.build_mie_rows`` for sphere layers,
``MieVolume`` tables for fog), the rest ("lobe"), a second load from the
now warm cache (after the tables written in the background are on disk: ``writes_after_s``; the whole load's wall clock; corona's plugins' wall and CPU time: the goal is
<= 0.5 s beyond Mitsuba's own load), the number and size of the tables written, and the 1-minute
load average (the machine may be shared).  Goal: every scene's tables build
in <= 2 s cold.  On a shared machine the wall clock counts the neighbours
too: the CPU time of the constructing thread (numpy runs there) is reported
beside it.

Materials: the time to build one material's lobe table from scratch and to
load it back from the on-disk cache (``--repeats`` times, medians).

Writes benchmarks/results/tables.json.

    python benchmarks/bench_tables.py [--repeats 5] [--scenes scenes/a.xml ...] [--timeout 300]

With ``--base REV`` the scenes alone (no materials) load cold from two source trees in turn, round by
round (``--rounds``): the revision REV (``git archive`` into a temporary folder, its own
``bench_tables.py --one`` child) and this checkout, so that load on a shared machine hits both
alike; per scene and tree the children's figures and the minimum and median of each; writes
benchmarks/results/<name>.json (default ``tables_ab``).
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

MATERIALS = {
    "circle / poisson": dict(radius=0.5, process="poisson"),
    "circle / hard-disk": dict(radius=0.5, process="hard-disk", area_fraction=0.5),
    "droplets 5 µm / hard-disk": dict(radius=5.0, process="hard-disk", area_fraction=0.4),
    "lycopodium 15 µm / rsa": dict(radius=15.0, process="rsa", area_fraction=0.4),
    "square / lattice-square (2D)": dict(shape="square", radius=0.5, process="lattice-square",
                                         area_fraction=0.3, jitter=0.05),
    "voile 20 µm / lattice-square (2D)": dict(shape="square", radius=20.0, process="lattice-square",
                                              area_fraction=0.25, jitter=4.0, mode="aperture"),
    "hexagon random / hard-disk": dict(shape="polygon", sides=6, radius=0.5, orientation="random",
                                       process="hard-disk", area_fraction=0.3),
    "ellipse (2D) / hard-disk": dict(shape="ellipse", radius=0.5, aspect=1.5, process="hard-disk",
                                     area_fraction=0.3),
}
GOAL_S = 2.0


def one_scene(path: str) -> dict:
    """In this (fresh) process: time the cold load of one scene; return the figures."""
    import corona
    corona.set_default_variant(prefer_gpu=False)
    import mitsuba as mi
    spent = {"corona": 0.0, "mie": 0.0, "corona_cpu": 0.0, "mie_cpu": 0.0}
    depth = {"corona": 0, "mie": 0}

    def timed(key, fn):
        def wrapper(*args, **kwargs):
            depth[key] += 1
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                depth[key] -= 1
                if depth[key] == 0:
                    spent[key] += time.perf_counter() - t0
                    spent[key + "_cpu"] += time.thread_time() - c0   # numpy runs on the calling thread
        return wrapper
    register_bsdf, register_phase = mi.register_bsdf, mi.register_phase
    mi.register_bsdf = lambda name, make: register_bsdf(name, timed("corona", make))
    mi.register_phase = lambda name, make: register_phase(name, timed("corona", make))
    corona.register()
    mi.register_bsdf, mi.register_phase = register_bsdf, register_phase
    # imports and Dr.Jit's start out of the clock
    import scipy.fft
    import scipy.interpolate
    import scipy.ndimage
    import scipy.special  # noqa: F401
    from corona.model import material
    from corona.mitsuba import bsdf as mitsuba_bsdf
    from corona.mitsuba import phase as mitsuba_phase
    from corona.mitsuba import sphere as mitsuba_sphere
    from corona.model import processes
    from corona.model import rows
    from corona.model.mie import material as sphere_material
    from corona.model.mie import volume as droplets
    sphere_material.build_mie_rows = timed("mie", sphere_material.build_mie_rows)
    droplets.MieVolume._build = timed("mie", droplets.MieVolume._build)
    mi.load_dict({"type": "scene", "s": {"type": "sphere", "bsdf": {"type": "diffuse"}}})
    folder = os.environ["CORONA_CACHE_DIR"]
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    mi.load_file(path)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    cold = dict(spent)
    # tables written in the background (corona.model.tabulated.cached(background=True)) on disk before the
    # count and the warm load: the wait past the load, writes_after_s (older trees: none)
    from corona.model import tabulated
    t0 = time.perf_counter()
    getattr(tabulated, "wait_for_writes", lambda: None)()
    writes_after = time.perf_counter() - t0
    files = [f for f in os.listdir(folder) if f.endswith(".npz")]
    size = sum(os.path.getsize(os.path.join(folder, f)) for f in files)
    spent.update(corona=0.0, mie=0.0, corona_cpu=0.0, mie_cpu=0.0)
    t0 = time.perf_counter()
    mi.load_file(path)
    warm = time.perf_counter() - t0
    return {"load_s": wall, "load_cpu_s": cpu, "corona_s": cold["corona"], "mie_s": cold["mie"],
            "lobe_s": cold["corona"] - cold["mie"], "corona_cpu_s": cold["corona_cpu"],
            "mie_cpu_s": cold["mie_cpu"], "lobe_cpu_s": cold["corona_cpu"] - cold["mie_cpu"], "writes_after_s": writes_after, "warm_load_s": warm, "warm_corona_s": spent["corona"], "warm_corona_cpu_s": spent["corona_cpu"],
            "tables": len(files), "bytes": size, "load_average_1min": [load0, os.getloadavg()[0]],
            "meets_goal_wall": cold["corona"] <= GOAL_S, "meets_goal_cpu": cold["corona_cpu"] <= GOAL_S}


def scenes(paths, timeout: float, root: str = ROOT) -> dict:
    """Each scene cold in a fresh ``--one`` child of the source tree ``root`` (its ``src`` first)."""
    out = {}
    for path in paths:
        name = os.path.basename(path)
        cache = tempfile.mkdtemp(prefix="corona-bench-tables-")
        env = {**os.environ, "CORONA_CACHE_DIR": cache,
               "PYTHONPATH": os.pathsep.join([os.path.join(root, "src"), os.environ.get("PYTHONPATH", "")])}
        try:
            res = subprocess.run([sys.executable, os.path.join(root, "benchmarks", "bench_tables.py"), "--one",
                                  os.path.abspath(path)], env=env, capture_output=True, text=True, timeout=timeout,
                                 cwd=root)
            lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
            if res.returncode != 0 or not lines:
                out[name] = {"error": (res.stderr.strip().splitlines() or ["?"])[-1]}
            else:
                out[name] = json.loads(lines[-1])
        except subprocess.TimeoutExpired:
            out[name] = {"error": f"timed out after {timeout:g} s"}
        finally:
            shutil.rmtree(cache, ignore_errors=True)
        r = out[name]
        if "error" in r:
            print(f"{name:28s} error: {r['error']}", flush=True)
        else:
            print(f"{name:28s} corona {r['corona_s']:6.2f} s wall {r['corona_cpu_s']:6.2f} s CPU "
                  f"(Mie {r['mie_cpu_s']:6.2f}, lobe {r['lobe_cpu_s']:5.2f} CPU)  "
                  f"load {r['load_s']:6.2f} s wall {r['load_cpu_s']:6.2f} s CPU  warm {r['warm_load_s']:5.2f} s "
                  f"(corona {r['warm_corona_s']:5.2f} s, CPU {r['warm_corona_cpu_s']:5.2f} s)  "
                  f"{r['tables']} tables  load avg {r['load_average_1min'][0]:.1f}", flush=True)
    return out


def materials(repeats: int) -> dict:
    import corona  # noqa: F401
    from corona.model import tabulated
    from corona.parameters import material_from_parameters
    os.environ["CORONA_CACHE_DIR"] = tempfile.mkdtemp(prefix="corona-bench-")
    material_from_parameters(**MATERIALS["circle / hard-disk"]).table  # warm imports / data load
    tabulated.cache_clear()
    results = {}
    for name, params in MATERIALS.items():
        build, load = [], []
        for _ in range(repeats):
            tabulated.cache_clear()
            m = material_from_parameters(**params)
            t0 = time.perf_counter()
            t = m.table
            build.append(time.perf_counter() - t0)
            m2 = material_from_parameters(**params)
            t0 = time.perf_counter()
            m2.table
            load.append(time.perf_counter() - t0)
        results[name] = {"kind": "radial" if m.isotropic else "2d",
                         "samples": int(t.values.size), "bytes": int(t.values.nbytes),
                         "build_median_s": statistics.median(build),
                         "load_median_s": statistics.median(load)}
        print(f"{name:34s} {results[name]['kind']:6s} {t.values.size:8d} samples  "
              f"build {results[name]['build_median_s'] * 1e3:8.1f} ms  "
              f"load {results[name]['load_median_s'] * 1e3:6.1f} ms", flush=True)
    tabulated.cache_clear()
    return results


def compare(args, paths) -> None:
    """``--base``: the scenes cold from the revision's tree and this checkout's, round by round."""
    from common import write
    keys = ("corona_s", "corona_cpu_s", "mie_cpu_s", "lobe_cpu_s", "load_s", "warm_corona_cpu_s")
    runs: dict = {}
    load_start = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as base:
        archive = subprocess.run(["git", "-C", ROOT, "archive", args.base, "src", "benchmarks", "scenes"],
                                 check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", base], input=archive, check=True)
        for r in range(args.rounds):
            for tree, root in ((f"base {args.base}", base), ("this checkout", ROOT)):
                print(f"round {r + 1}/{args.rounds} {tree}", flush=True)
                for name, res in scenes(paths, args.timeout, root).items():
                    runs.setdefault(name, {}).setdefault(tree, []).append(res)
    summary = {name: {tree: {k: {"min": min(x[k] for x in rs), "median": statistics.median(x[k] for x in rs)}
                             for k in keys if all(k in x for x in rs)}
                      for tree, rs in trees.items()} for name, trees in runs.items()}
    write(args.name or "tables_ab", {"base": args.base, "rounds": args.rounds, "summary": summary, "runs": runs,
                                     "load_average_1min": [load_start, os.getloadavg()[0]],
                                     "goal": f"every scene's tables cold <= {GOAL_S:g} s (corona_s)"})


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--scenes", nargs="*", default=None, help="scene files (default: scenes/*.xml)")
    ap.add_argument("--timeout", type=float, default=300.0, help="longest load of one scene [s]")
    ap.add_argument("--base", help="a git revision: the scenes from it and from this checkout, interleaved")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of the --base comparison")
    ap.add_argument("--name", default=None, help="the JSON file's name (default tables, with --base tables_ab)")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one_scene(args.one)), flush=True)
        return
    from common import write
    paths = args.scenes or sorted(glob.glob(os.path.join(ROOT, "scenes", "*.xml")))
    if args.base:
        compare(args, paths)
        return
    load_start = os.getloadavg()[0]
    per_scene = scenes(paths, args.timeout)
    per_material = materials(args.repeats)
    write(args.name or "tables", {"repeats": args.repeats, "results": per_material, "scenes": per_scene,
                     "load_average_1min": [load_start, os.getloadavg()[0]],
                     "goal": "structure-factor table of a material from shipped data <= 0.2 s; "
                             f"every scene's tables cold <= {GOAL_S:g} s (corona_s)"})


if __name__ == "__main__":
    main()
