"""Shared helpers of the benchmark scripts: machine description and JSON output."""
from __future__ import annotations

import datetime
import json
import os
import platform

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


def write(name: str, payload: dict) -> str:
    os.makedirs(RESULTS, exist_ok=True)
    path = os.path.join(RESULTS, f"{name}.json")
    with open(path, "w") as f:
        json.dump({"machine": machine(), **payload}, f, indent=2)
    print(f"wrote {path}")
    return path
