"""`make bench`: every benchmark at its default size (<= 10 minutes on 2 cores), then the report.

    python benchmarks/run_all.py [--full] [--only NAME ...]

``--full`` runs the bigger versions (more rounds, larger images, more
realisations); ``--only render sampling`` runs just those scripts
(``bench_<name>.py``).  The report docs/benchmarks.md is regenerated from
every JSON file in benchmarks/results/.
"""
import argparse
import glob
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
FULL = {   # bigger runs: extra arguments per script
    "designer": ["--steps", "40"],
    "render": ["--rounds", "5", "--repeats", "5"],
    "sampling": ["--res", "512", "--ref-spp", "8192"],
    "scaling": ["--repeats", "5"],
    "sweep": ["--rounds", "4", "--res", "256", "--spp", "64"],
    "tables": ["--repeats", "20"],
    "wave": ["--max-m", "512"],
    "fit": ["--repeats", "7"],
    "mie": ["--repeats", "5", "--rounds", "5"],
}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="bigger runs (tens of minutes)")
    ap.add_argument("--only", nargs="*", default=None, help="names of benchmarks to run")
    args = ap.parse_args()
    t_all = time.perf_counter()
    for script in sorted(glob.glob(os.path.join(HERE, "bench_*.py"))):
        name = os.path.basename(script)[len("bench_"):-len(".py")]
        if args.only is not None and name not in args.only:
            continue
        extra = FULL.get(name, []) if args.full else []
        print(f"== {name} {' '.join(extra)}", flush=True)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, script, *extra], check=True)
        print(f"== {name}: {time.perf_counter() - t0:.0f} s", flush=True)
    subprocess.run([sys.executable, os.path.join(HERE, "report.py")], check=True)
    print(f"all benchmarks: {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
