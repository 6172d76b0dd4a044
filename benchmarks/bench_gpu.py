"""The render benchmark on the GPU (`cuda_ad_spectral`), when a CUDA device exists.

Runs ``bench_render.py --variant cuda_ad_spectral --name render_cuda``; on a
machine without a usable CUDA backend it writes
benchmarks/results/gpu.json saying it was skipped and why (never an error).

    python benchmarks/bench_gpu.py [bench_render options]
"""
from __future__ import annotations

import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def main():
    from corona import _environment
    from common import write
    if not _environment.has_cuda():
        write("gpu", {"skipped": True, "reason": "no usable CUDA device / cuda variant on this machine"})
        print("no CUDA device: GPU benchmark skipped")
        return
    subprocess.run([sys.executable, os.path.join(HERE, "bench_render.py"), "--variant", "cuda_ad_spectral",
                    "--name", "render_cuda", *sys.argv[1:]], check=True)
    write("gpu", {"skipped": False, "see": "render_cuda.json"})


if __name__ == "__main__":
    main()
