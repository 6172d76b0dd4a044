"""`make bench`: every benchmark at its default size, then the markdown report."""
import glob
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))

for script in sorted(glob.glob(os.path.join(HERE, "bench_*.py"))):
    print(f"== {os.path.basename(script)}", flush=True)
    subprocess.run([sys.executable, script], check=True)
subprocess.run([sys.executable, os.path.join(HERE, "report.py")], check=True)
