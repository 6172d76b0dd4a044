#!/usr/bin/env python
"""Regenerate ``src/corona/data/breath_figure.npz``, the table of ``process=breath-figure``.

Simulations of :func:`corona.reference.breath_figure.simulate_breath_figure` (defaults: θ = 90°,
flux 0.1 µm/s, nucleation 0.05 µm⁻² s⁻¹ on the free area, nuclei 0.25 µm), two seeds in a 400 µm box,
measured at the times of :data:`corona.reference.breath_figure_optics.TABLE_TIMES` by
:func:`corona.reference.breath_figure_optics.breath_figure_table`; and the fading phase, runs that
evaporate from :data:`~corona.reference.breath_figure_optics.EVAPORATION_STARTS` (5, 20, 80 s), measured
at :data:`~corona.reference.breath_figure_optics.EVAPORATION_FRACTIONS` of the water gone, by
:func:`corona.reference.breath_figure_optics.evaporation_rows` (the ``dry_*`` arrays).  The table is shipped (under 600 kB), so
nothing is simulated at run time; rebuilding it takes about 50 s of CPU here (the two simulations
about 5 s each, the structure factors and partials the rest; the wall time is in the table's
metadata).

Usage: PYTHONPATH=src .venv/bin/python scripts/make_breath_figure_table.py
"""
from __future__ import annotations

import datetime
import json
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "src"))

from corona.reference import breath_figure_optics as bfo  # noqa: E402


def main() -> None:
    t = bfo.breath_figure_table()
    t.update(bfo.evaporation_rows(t["x_edges"], t["class_edges"]))
    meta = {"format_version": 2, "date": datetime.date.today().isoformat(),
            "seeds": list(bfo.TABLE_SEEDS), "box_um": bfo.TABLE_BOX, "contact_angle": 90.0,
            "flux_um_per_s": 0.1, "nucleation_rate": 0.05, "nucleus_radius_um": 0.25,
            "evaporation_rate_um_per_s": bfo.TABLE_EVAPORATION_RATE,
            "seconds": round(float(t.pop("seconds")), 1)}
    path = os.path.join(ROOT, "src", "corona", "data", "breath_figure.npz")
    np.savez_compressed(path, **{k: np.asarray(v, dtype=np.float32 if k in ("partial", "dry_partial") else np.float64)
                                 for k, v in t.items()},
                        metadata=json.dumps(meta))
    print(f"wrote {path} ({os.path.getsize(path)} bytes) in {meta['seconds']} s")


if __name__ == "__main__":
    main()
