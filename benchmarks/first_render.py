"""First use: every scene of scenes/ rendered cold from the command line, and the Mie preview.

Scenes: ``corona render SCENE -D res=RES --spp SPP`` in a fresh process with an empty table
cache (``CORONA_CACHE_DIR`` a new temporary folder per scene): the wall clock from the
process's start to its exit (imports, the variant, the tables, Dr.Jit's kernels, the render
and the files), and the render alone as the command reports it.  Dr.Jit's own kernel cache
is left as it is (warm after the first scene of a kind): what a user meets after the first
day.  The resolution and sample count are scaled down (the tables, not the pixels, are
measured).

Preview: for new sphere radii (hard disks, F_a 0.4, water) the time of
``SphereMaterial.preview()``'s rows and forward energies (what the designer shows first),
in this process, against the exact rows' build of one radius.

Designer: for new sphere radii (hard disks, F_a 0.4, water), the seconds from the request to
the first picture of 256² pixels (the preview, while the exact table builds in the background),
the exact table's build after it, and the exact picture.

Each scene and the whole run record the 1-minute load average (the machine may be shared).

Writes benchmarks/results/first_render.json.

    python benchmarks/first_render.py [--res 64] [--spp 4] [--scenes scenes/a.xml ...] [--timeout 600]
                                      [--radii 5 13.7 25] [--exact-radius 13.7] [--designer-radii 4.3 11.1]
"""
from __future__ import annotations

import argparse
import glob
import os
import re
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)


def one_scene(path: str, res: int, spp: int, timeout: float) -> dict:
    from corona.apps.sweep import scene_parameters
    args = [sys.executable, "-m", "corona.apps.cli", "render", path, "--spp", str(spp)]
    if "res" in scene_parameters(path):
        args += ["-D", f"res={res}"]
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        env = {**os.environ, "CORONA_CACHE_DIR": cache}
        t0 = time.perf_counter()
        try:
            p = subprocess.run(args + ["--out", out], capture_output=True, text=True, timeout=timeout,
                               env=env, cwd=out)
        except subprocess.TimeoutExpired:
            return {"status": "timeout", "wall_s": timeout}
        wall = time.perf_counter() - t0
    m = re.search(r"\(([^,]+), ([0-9.]+) s, (\d+) spp, (\w+)\)", p.stdout)
    entry = {"status": "ok" if p.returncode == 0 else "failed", "wall_s": round(wall, 2),
             "load_avg_1min": round(os.getloadavg()[0], 2)}
    if m:
        entry.update(render_s=float(m.group(2)), spp=int(m.group(3)), variant=m.group(4))
    if p.returncode != 0:
        entry["error"] = (p.stderr.strip().splitlines() or ["?"])[-1][:300]
    return entry


def preview_times(radii) -> dict:
    from corona.parameters import material_from_parameters
    out = {}
    for r in radii:
        m = material_from_parameters(shape="sphere", radius=r, area_fraction=0.4, process="hard-disk")
        m.use_cache = False
        t0 = time.perf_counter()
        p = m.preview()
        _ = p.rows
        t1 = time.perf_counter()
        _ = p._derived
        t2 = time.perf_counter()
        out[f"{r:g}"] = {"rows_s": round(t1 - t0, 3), "forward_energy_s": round(t2 - t1, 3),
                         "total_s": round(t2 - t0, 3), "rows": int(p.rows["x"].size),
                         "chord_nodes": int(p.rows["P_f"].shape[1])}
    return out


def designer_first_picture(radii) -> dict:
    """The designer's answer to a new sphere radius (hard disks, F_a 0.4, water; 256² pixels, the
    page's size): the seconds to its first picture (the preview, :func:`compute.shown_material`),
    and to the exact picture once the background build is done, in this process, after the
    server's warm-up (:func:`corona.apps.designer.warm_up`: the first preset once)."""
    from corona.apps.designer import compute
    pr = next(iter(compute.PRESETS.values()))         # what the server does at its start (warm_up)
    compute.corona_png(pr["material"], {**pr["view"], "size": 64})
    compute.profiles(pr["material"], pr["view"])
    out = {}
    for r in radii:
        params, view, _ = compute.parse({"shape": "sphere", "radius": f"{r:g}", "area_fraction": "0.4",
                                         "process": "hard-disk", "size": "256"})
        t0 = time.perf_counter()
        _, used = compute.corona_png(params, view, preview=True)
        t1 = time.perf_counter()
        while not compute.builds.idle():
            time.sleep(0.05)
        t2 = time.perf_counter()
        _, used2 = compute.corona_png(params, view, preview=True)
        t3 = time.perf_counter()
        out[f"{r:g}"] = {"first_picture_s": round(t1 - t0, 3), "first_is_preview": bool(used["building"]),
                         "exact_table_s": round(t2 - t1, 2), "exact_picture_s": round(t3 - t2, 3),
                         "exact_is_preview": bool(used2["building"]),
                         "load_avg_1min": round(os.getloadavg()[0], 2)}
    return out


def exact_time(radius: float) -> dict:
    from corona.parameters import material_from_parameters
    m = material_from_parameters(shape="sphere", radius=radius, area_fraction=0.4, process="hard-disk")
    m.use_cache = False
    t0 = time.perf_counter()
    _ = m.rows
    t1 = time.perf_counter()
    _ = m._derived
    t2 = time.perf_counter()
    return {"radius_um": radius, "rows_s": round(t1 - t0, 2), "forward_energy_s": round(t2 - t1, 2),
            "rows": int(m.rows["x"].size)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--scenes", nargs="*", default=None)
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--radii", type=float, nargs="*", default=[5.0, 13.7, 25.0])
    ap.add_argument("--exact-radius", type=float, default=13.7)
    ap.add_argument("--designer-radii", type=float, nargs="*", default=[4.3, 11.1])
    a = ap.parse_args()
    load_start = round(os.getloadavg()[0], 2)
    import common
    scenes = ([os.path.abspath(s) for s in a.scenes] if a.scenes
              else sorted(glob.glob(os.path.join(ROOT, "scenes", "*.xml"))))
    results = {}
    for path in scenes:
        name = os.path.basename(path)
        results[name] = one_scene(path, a.res, a.spp, a.timeout)
        print(f"{name}: {results[name]}", flush=True)
    preview = preview_times(a.radii)
    print("preview:", preview, flush=True)
    exact = exact_time(a.exact_radius)
    print("exact:", exact, flush=True)
    designer = designer_first_picture(a.designer_radii)
    print("designer:", designer, flush=True)
    common.write("first_render", {
        "what": "cold first render of every scene from the command line (fresh process, empty table "
                "cache; Dr.Jit's kernel cache as found), the Mie preview against the exact rows, and "
                "the designer's first picture of a new sphere radius",
        "res": a.res, "spp": a.spp, "cpu_affinity": len(os.sched_getaffinity(0)),
        "load_avg_1min": {"start": load_start, "end": round(os.getloadavg()[0], 2)},
        "results": {f"designer, new sphere radius {r} µm": v for r, v in designer.items()},
        "scenes": results, "sphere_preview": preview, "sphere_exact": exact, "argv": sys.argv})


if __name__ == "__main__":
    main()
