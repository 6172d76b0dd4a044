"""The plugin finds each lane's F_a row (guide grid over the rows) as a search of the rows would."""
import drjit as dr
import numpy as np
import pytest


@pytest.mark.parametrize("process,lo,hi", [("hard-disk", 0.005, 0.6), ("rsa", 0.01, 0.5)])
def test_row_of_each_area_fraction(mi_variant, process, lo, hi):
    import mitsuba as mi
    probe = mi.load_dict({"type": "corona", "radius": 5.0, "process": process,
                          "area_fraction": 0.5 * (lo + hi)})
    rng = np.random.default_rng(3)
    # random values, the rows themselves and their float32 neighbours (where rounding bites)
    rows = probe.fa_rows_np.astype(np.float32)
    vals = np.concatenate([[lo, hi], rng.uniform(lo, hi, 3000), rows, np.nextafter(rows, 0),
                           np.nextafter(rows, 1)]).astype(np.float32)
    vals = np.clip(vals, lo, hi)
    n = vals.size
    bsdf = mi.load_dict({"type": "corona", "radius": 5.0, "process": process,
                         "area_fraction": {"type": "bitmap", "bitmap": mi.Bitmap(vals[None, :, None]),
                                           "raw": True, "filter_type": "nearest"}})
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.uv = mi.Point2f(((np.arange(n) + 0.5) / n).astype(np.float32), np.full(n, 0.5, np.float32))
    layer = bsdf._layer(si, True)
    fa, j, t = (np.array(layer[k]) for k in ("fa", "j", "t"))
    rows = np.array(bsdf.fa_rows)
    ref = np.clip(np.searchsorted(rows, fa, side="right") - 1, 0, bsdf.n_rows - 2)
    exact = j == ref
    # elsewhere only float32 rounding at a guide cell's edge: fa one ulp below the next row
    assert np.all(exact | ((j == ref + 1) & (np.abs(t) < 1e-5))), np.where(~exact)
    assert np.mean(exact) > 0.999
    assert np.all((t > -1e-5) & (t <= 1.0))
    np.testing.assert_allclose(rows[j] + t * (rows[j + 1] - rows[j]), fa, atol=1e-6)
