"""Shared helpers of the benchmark scripts: machine description, run summaries and JSON output."""
from __future__ import annotations

import datetime
import json
import os
import platform
import statistics

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def machine() -> dict:
    info = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "python": platform.python_version(), "platform": platform.platform(),
            "cores": os.cpu_count()}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import corona  # before drjit: it points Dr.Jit at a usable libLLVM
    try:
        import drjit as dr
        import mitsuba as mi
        info.update(mitsuba=mi.__version__, drjit=dr.__version__, variant=mi.variant())
    except Exception:
        pass
    info["corona"] = corona.__version__
    return info


def write(name: str, payload: dict, path: str | None = None) -> str:
    """``{"machine": machine(), **payload}`` as JSON into ``path`` (default ``results/<name>.json``)."""
    path = path or os.path.join(RESULTS, f"{name}.json")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump({"machine": machine(), **payload}, f, indent=2)
    print(f"wrote {path}")
    return path


def summarise(rounds, *medians: str) -> dict:
    """One entry's summary over its rounds (each a dict with ``times_s``, a list of seconds):
    the median, minimum and every time, and the median over the rounds of each key in ``medians``."""
    times = [t for r in rounds for t in r["times_s"]]
    out = {"median_s": statistics.median(times), "min_s": min(times), "times_s": times}
    out.update({key: statistics.median(r[key] for r in rounds) for key in medians})
    return out
