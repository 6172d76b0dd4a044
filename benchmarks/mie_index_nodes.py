"""Water's index nodes of a size distribution's Mie rows: accuracy and cost per node spacing and degree.

The rows of 20 µm water droplets with a 10 % lognormal spread (``build_mie_rows``) with the index
nodes ``SIZE_DM`` apart and the rows the Lagrange polynomial of degree ``SIZE_INDEX_ORDER`` through
the nearest nodes, against rows on nodes 0.0005 apart (lines between them).  Per case: the
energy-weighted RMS per row of ``P_b``, ``P_f``, ``C_f`` against the reference (worst row, mean over
the rows; ``layer._lobe_error``), the sizes the plan evaluates (load-free), the index nodes, the
build's CPU seconds (one process, noisy on a shared machine) and the 1-minute load average.

    OPENBLAS_NUM_THREADS=1 python benchmarks/mie_index_nodes.py [--cases 0.002:1,0.004:3] [--name mie_index_nodes]

writes benchmarks/results/<name>.json.  Nothing is asserted.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def build(layer, sizes, dm: float, order: int):
    layer.SIZE_DM, layer.SIZE_INDEX_ORDER = dm, order
    yq, pq = layer._size_quadrature(sizes, layer.SIZE_TAIL_ROWS)
    s_lo, s_hi = math.exp(yq[0]), math.exp(yq[-1])
    r = float(sizes.shape.radius)
    x_rows, _, _ = layer._grid(r, r * min(s_hi, 1.0 + 3.0 * float(sizes.spread)), float(sizes.spread))
    plan = layer._size_plan(sizes.shape, x_rows, 2 * math.pi * r / x_rows * 1e3, yq, pq, s_lo, s_hi)
    c0 = time.process_time()
    rows = layer.build_mie_rows(sizes.shape, sizes=sizes)
    return rows, {"cpu_s": time.process_time() - c0, "index_nodes": len(plan),
                  "sizes_evaluated": int(sum(p[3].size for p in plan)), "load_average_1min": os.getloadavg()[0]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default="0.002:1,0.003:3,0.004:3,0.004:2,0.006:3",
                    help="SIZE_DM:SIZE_INDEX_ORDER pairs, comma-separated")
    ap.add_argument("--radius", type=float, default=20.0)
    ap.add_argument("--spread", type=float, default=0.1)
    ap.add_argument("--name", default="mie_index_nodes")
    args = ap.parse_args()
    import corona
    from corona.model.mie import layer
    from common import write
    kept = (layer.SIZE_DM, layer.SIZE_INDEX_ORDER)
    sizes = corona.SizeDistribution(corona.Sphere(args.radius, ior="water"), args.spread)
    load_start = os.getloadavg()[0]
    ref, ref_info = build(layer, sizes, 0.0005, 1)
    print(f"reference (0.0005, lines): {ref_info}", flush=True)
    ds = float(ref["ds"])
    cases = {}
    for item in args.cases.split(","):
        dm, order = float(item.split(":")[0]), int(item.split(":")[1])
        rows, info = build(layer, sizes, dm, order)
        for key in ("P_b", "P_f", "C_f"):
            e = layer._lobe_error(rows[key], ref[key], ds)
            info[f"{key}_worst_percent"], info[f"{key}_mean_percent"] = 100 * float(e.max()), 100 * float(e.mean())
        tag = f"SIZE_DM={dm:g}, degree {order}" + (" (kept)" if (dm, order) == kept else "")
        cases[tag] = info
        print(f"{tag:34s} nodes {info['index_nodes']:3d} sizes {info['sizes_evaluated']:6d} "
              f"P_b {info['P_b_worst_percent']:.3f} / {info['P_b_mean_percent']:.3f} %  "
              f"P_f {info['P_f_worst_percent']:.3f} %  C_f {info['C_f_worst_percent']:.3f} %  "
              f"CPU {info['cpu_s']:.2f} s  load {info['load_average_1min']:.1f}", flush=True)
    write(args.name, {"radius_um": args.radius, "spread": args.spread, "distribution": "lognormal",
                      "reference": {"SIZE_DM": 0.0005, "degree": 1, **ref_info}, "results": cases,
                      "load_average_1min": [load_start, os.getloadavg()[0]]})


if __name__ == "__main__":
    main()
