"""examples/fit_window.py, reduced (its ``quick()``): Adam on ``prb`` renders recovers the layer.

The targets are renders at the true values (more samples than each step);
the goals are the issue's: droplet radius within 2 %, area fraction within
5 %, each texel of an area-fraction bitmap within 10 % (a 4×4 bitmap here,
8×8 in the full example).
"""
import os
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir))


def test_fit_window_recovers_radius_area_fraction_and_bitmap(mi_variant):
    sys.path.insert(0, os.path.join(ROOT, "examples"))
    try:
        import fit_window
    finally:
        sys.path.pop(0)
    res = fit_window.quick(log=lambda *a: None)
    u, b = res["uniform"], res["bitmap"]
    assert abs(u["radius_error"]) < 0.02, u
    assert abs(u["area_fraction_error"]) < 0.05, u
    assert b["max_texel_error"] < 0.10, {k: v for k, v in b.items() if k not in ("truth", "fit")}
    # and it did fit: the start was 10 % / 20 % off, the bitmap's start 0.3 everywhere
    assert u["loss_last"] < 0.5 * u["loss_first"] and b["loss_last"] < 0.5 * b["loss_first"]
