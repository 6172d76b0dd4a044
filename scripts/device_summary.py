"""The summary of a ``pytest -v`` log as JSON: what scripts/device_check.sh writes after its tests.

    python scripts/device_summary.py LOG --variant cuda_ad_spectral --rc 0 --seconds 312 \\
        --machine gpu="NVIDIA H200" driver=580.159.04 --selection "tests -m ..." --out device_check.json

The JSON (``benchmarks/results/device_check.json`` once copied back from the device): ``machine``
(``date``, UTC, and what was given: GPU, driver, versions), ``variant``, ``selection``, ``rc``
(pytest's exit status; 124: stopped at the time cap), ``complete`` (pytest printed its final
line), ``seconds``, ``passed``, ``failed`` (failures and errors), ``skipped``, ``failing`` (the
test ids, sorted).  Reads the one-line-a-test output of ``-v -o console_output_style=classic``,
with or without pytest-xdist (``[gw3] PASSED tests/...``), and the ``-ra`` summary lines, so a log
cut off by the time cap still counts every test that finished.
"""
from __future__ import annotations

import argparse
import datetime
import json
import re
import sys

STATUSES = ("PASSED", "FAILED", "ERROR", "SKIPPED", "XFAIL", "XPASS")
_STATUS = "|".join(STATUSES)
#: ``[gw0] PASSED tests/a.py::t[x y]`` (xdist) or ``FAILED tests/a.py::t - message`` (-ra summary)
_FIRST = re.compile(rf"^(?:\[gw\d+\]\s+)?(?:\[\s*\d+%\]\s+)?({_STATUS})\s+(\S.*?)(?:\s+-\s+.*)?\s*$")
#: ``tests/a.py::t[x y] PASSED`` (-v without xdist), a percentage after it or not
_LAST = re.compile(rf"^(\S+?::.+?)\s+({_STATUS})\b")
_FINAL = re.compile(r"^=+ .*\b(passed|failed|error|errors|skipped|deselected|no tests ran)\b.* in [\d.]+s")


def parse(lines) -> dict:
    """Per test id its status (a failure or error wins over anything else seen for the id), and
    whether the log holds pytest's final line."""
    status: dict[str, str] = {}
    complete = False
    for line in lines:
        line = line.rstrip("\n")
        if _FINAL.match(line):
            complete = True
            continue
        m = _FIRST.match(line)
        if m:
            st, tid = m.group(1), m.group(2).strip()
        else:
            m = _LAST.match(line)
            if not m:
                continue
            tid, st = m.group(1).strip(), m.group(2)
        if not (tid.startswith("tests/") or "::" in tid):
            continue
        if status.get(tid) in ("FAILED", "ERROR"):
            continue
        status[tid] = st
    return {"status": status, "complete": complete}


def summary(lines, *, variant: str, selection: str, rc: int, seconds: float, machine: dict) -> dict:
    parsed = parse(lines)
    st = parsed["status"]
    count = lambda *names: sum(1 for s in st.values() if s in names)
    return {
        "machine": {"date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"), **machine},
        "variant": variant,
        "selection": selection,
        "rc": int(rc),
        "complete": bool(parsed["complete"]),
        "seconds": float(seconds),
        "passed": count("PASSED", "XPASS"),
        "failed": count("FAILED", "ERROR"),
        "skipped": count("SKIPPED", "XFAIL"),
        "failing": sorted(t for t, s in st.items() if s in ("FAILED", "ERROR")),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("--variant", required=True)
    ap.add_argument("--selection", default="")
    ap.add_argument("--rc", type=int, default=0)
    ap.add_argument("--seconds", type=float, default=0.0)
    ap.add_argument("--machine", nargs="*", default=[], help="key=value pairs (gpu=..., driver=...)")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    machine = dict(kv.split("=", 1) for kv in args.machine if "=" in kv)
    with open(args.log, encoding="utf-8", errors="replace") as f:
        out = summary(f, variant=args.variant, selection=args.selection, rc=args.rc, seconds=args.seconds,
                      machine=machine)
    with open(args.out, "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1)
        f.write("\n")
    print(f"{out['passed']} passed, {out['failed']} failed, {out['skipped']} skipped"
          f"{'' if out['complete'] else ' (cut off: rc ' + str(out['rc']) + ')'}")
    for t in out["failing"]:
        print("FAILING", t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
