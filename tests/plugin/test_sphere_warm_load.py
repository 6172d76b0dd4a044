"""A sphere layer loaded from a warm table cache: its sampling tables read back, not rebuilt,
and equal to the ones built from the rows."""
import warnings

import numpy as np
import pytest


@pytest.mark.slow     # loads the layer twice per branch: 2 s of CPU warm
def test_warm_load_reads_the_guided_rows_back(mi_variant, upload_branch, monkeypatch, tmp_path):
    import mitsuba as mi

    from corona.model import tabulated
    from corona.mitsuba import sphere
    made = []
    real = sphere.guided_cdfs

    def counting(cdfs):
        made.append(len(cdfs))
        return real(cdfs)
    monkeypatch.setattr(sphere, "guided_cdfs", counting)
    # an empty cache of its own: the first load builds, whatever ran before in this cache
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    spec = {"type": "corona", "shape": "sphere", "radius": 1.3, "area_fraction": 0.2, "process": "poisson"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        first = mi.load_dict(spec)                         # cold
        cold = sum(made)                                   # rows searched (in blocks of rows)
        second = mi.load_dict(spec)
    rows = first.material.rows
    J = rows["x"].size
    assert cold == 2 * J and sum(made) == cold             # built once; the warm load read them back
    ds = float(rows["ds"])
    ref = real([tabulated.RadialTable(ds, r).cdf for r in rows["P_f"]]
               + [tabulated.RadialTable(ds, r).cdf for r in rows["P_b"]])
    for bsdf in (first, second):
        assert (bsdf.G, bsdf.n_bins, bsdf.steps) == (ref["G"], ref["n_bins"], ref["steps"])
        assert np.array_equal(np.asarray(bsdf.cdf), ref["cdf"])
        assert np.array_equal(np.asarray(bsdf.guide), ref["guide"].astype(np.uint32))
    assert np.asarray(first.cdf).size == 2 * J * (ref["n_bins"] + 1)
    # another radius is another table: its guide is built (the cache is keyed by the rows)
    before = sum(made)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        third = mi.load_dict({**spec, "radius": 1.31})
    assert sum(made) == before + 2 * third.material.rows["x"].size
