"""The sphere layer's packed tables read what the plain ones do, and an update re-uses the kernel.

The plugin reads its lobes' rows as packed Catmull–Rom intervals (one Vector4f a
row) while the packed arrays fit ``LOBE_PACKING_BYTES``, else the plain rows
with four scalar gathers; a layer with one area fraction reads ``S`` and the
forward energies centred on that value (value + slope) instead of the cubic
Hermite between its F_a rows.  Both pairs are compared here on the same
directions (eval, pdf, and the sample weights and pdfs of the same samples),
and an update of the area fraction inside the rows must neither change the
traced kernel (a kernel-cache hit) nor the agreement.
"""
import warnings

import drjit as dr
import numpy as np
import pytest

from bsdf_checks import interaction

LAYERS = {
    "hard-disk": {"type": "corona", "shape": "sphere", "radius": 2.0, "area_fraction": 0.3,
                  "process": "hard-disk"},
    "spread": {"type": "corona", "shape": "sphere", "radius": 1.5, "area_fraction": 0.2,
               "process": "hard-disk", "size_spread": 0.1},
    "poisson": {"type": "corona", "shape": "sphere", "radius": 5.0, "area_fraction": 0.05,
                "process": "poisson"},
}


def _load(props):
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return mi.load_dict(props)


def _directions(wi, n=3000, seed=4):
    """Random directions plus many near the forward (-wi) and backward (wi) peaks and 90° from them."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    fwd = -wi + rng.normal(0.0, 0.05, (n, 3))
    back = wi + rng.normal(0.0, 0.3, (n, 3))
    out = np.concatenate([v, fwd, back])
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _figures(bsdf, deg, n_samples=4000):
    import mitsuba as mi
    wi = np.array([np.sin(np.radians(deg)), 0.0, np.cos(np.radians(deg))])
    wo = _directions(wi)
    ctx = mi.BSDFContext()
    si = interaction(len(wo), wi)
    v, p = bsdf.eval_pdf(ctx, si, mi.Vector3f(wo.T.astype(np.float32)))
    rng = np.random.default_rng(5)
    si_s = interaction(n_samples, wi)
    bs, w = bsdf.sample(ctx, si_s, mi.Float(rng.random(n_samples).astype(np.float32)),
                        mi.Point2f(rng.random((2, n_samples)).astype(np.float32)))
    return [np.asarray(x, dtype=np.float64) for x in (v, p, w, bs.pdf, bs.wo)]


def _assert_close(a, b, what):
    for x, y, name in zip(a, b, ("eval", "pdf", "sample weight", "sample pdf", "sampled wo")):
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(y)), (what, name)
        scale = max(float(np.max(np.abs(y))), 1e-12)
        err = float(np.max(np.abs(x - y)))
        assert err <= 2e-5 * scale, f"{what}: {name} differs by {err:.3g} (scale {scale:.3g})"


@pytest.mark.slow     # 3 s of CPU warm, 3 s cold per layer
@pytest.mark.parametrize("name", list(LAYERS))
def test_packed_lobe_rows_read_the_plain_rows(mi_variant, monkeypatch, name):
    import mitsuba as mi
    if not dr.is_array_v(mi.Float):
        pytest.skip("the vectorised variants pack the rows")
    from corona.mitsuba import sphere
    packed = _load(LAYERS[name])
    assert isinstance(packed.chords, sphere.PackedChordRows)
    monkeypatch.setattr(sphere, "LOBE_PACKING_BYTES", 0)
    plain = _load(LAYERS[name])
    assert isinstance(plain.chords, sphere.PlainChordRows)
    for deg in (0.0, 35.0, 75.0):
        _assert_close(_figures(packed, deg), _figures(plain, deg), f"{name} at {deg}°")
    # a negative control: a lobe row shifted by one node is seen
    rows = packed.material.rows
    shifted = np.roll(np.concatenate([rows["P_f"], rows["P_b"]]), 1, axis=1)
    plain.chords.P = sphere._array(mi.Float, shifted.ravel())
    with pytest.raises(AssertionError):
        _assert_close(_figures(packed, 0.0), _figures(plain, 0.0), "shifted")


def test_one_area_fraction_centred_matches_the_rows_and_updates_without_recompiling(mi_variant, upload_branch):
    import mitsuba as mi
    if not dr.is_array_v(mi.Float):
        pytest.skip("kernels: vectorised variants")
    from corona.mitsuba.lobes import CentredFaTables
    bsdf = _load(LAYERS["hard-disk"])
    assert isinstance(bsdf.fa_tables, CentredFaTables)
    # the Hermite between the F_a rows (as for a texture) at the same value
    rows_only = _load(LAYERS["hard-disk"])
    rows_only.fa_tables = rows_only.fa_tables.grid     # the Hermite between the rows
    _assert_close(_figures(bsdf, 20.0), _figures(rows_only, 20.0), "centred vs rows")
    params = mi.traverse(bsdf)
    key = "area_fraction.value"
    _figures(bsdf, 20.0)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        params[key] = 0.32                     # inside the rows (0.25 .. 0.35): no rebuild
        params.update()
        moved = _figures(bsdf, 20.0)
        history = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert bsdf.fa_cover[0] < 0.32 < bsdf.fa_cover[1]
    assert history and all(k.get("cache_hit") for k in history), \
        [(k.get("cache_hit"), k.get("operation_count")) for k in history]
    # the same update of the layer that reads the Hermite between its F_a rows
    p2 = mi.traverse(rows_only)
    p2[key] = 0.32
    p2.update()
    _assert_close(moved, _figures(rows_only, 20.0), "centred vs rows after an update")


def test_guide_tables_are_the_last_bin_at_or_below_each_mark(mi_variant):
    """:func:`corona.mitsuba.common.guided_cdfs` (all rows at once) against its definition, row by row:
    ``guide[j]`` is the last bin whose normalised float32 CDF is <= ``float32(j / G)`` (clipped to
    the bins), on rows with empty stretches, a zero row, a row of denormal-small values and random
    peaked rows."""
    from corona.model import tabulated
    from corona.mitsuba.common import guided_cdfs
    rng = np.random.default_rng(7)
    for n in (3, 17, 200, 833):
        v = rng.random((12, n)) ** 8
        v[1] = 0.0
        v[2, n // 2:] = 0.0
        v[3] = 1e-38
        v[4, :n // 3] = 0.0
        cdfs = tabulated.radial_cdfs(0.01, v)
        g = guided_cdfs(cdfs)
        G, n_bins = g["G"], g["n_bins"]
        assert n_bins == n - 1
        marks = (np.arange(G + 1) / G).astype(np.float32)
        guide = g["guide"].reshape(len(v), G + 1)
        cdf = g["cdf"].reshape(len(v), n)
        width = 1
        for row, c64 in enumerate(cdfs):
            c32 = (c64 / (c64[-1] if c64[-1] > 0 else 1.0)).astype(np.float32)
            assert np.array_equal(cdf[row], c32)
            for j, mark in enumerate(marks):
                below = np.nonzero(c32 <= mark)[0]
                want = min(max(int(below[-1]) if below.size else 0, 0), n_bins - 1)
                assert guide[row, j] == want, (n, row, j)
            width = max(width, int(np.max(np.diff(guide[row]))) + 1)
        assert g["steps"] == max(1, int(np.ceil(np.log2(width + 1))))


def test_catmull_rom_intervals_are_the_cubic_through_the_rows(mi_variant):
    """The packed intervals (:func:`corona.mitsuba.sphere._catmull_rom_intervals`), node-major, against the
    Catmull–Rom cubic written out from four nodes (end nodes repeated): its value at the nodes and
    at the interval's middle, for two lobes of different widths."""
    from corona.mitsuba import sphere
    rng = np.random.default_rng(3)
    lobes = [rng.random((5, 9)) * 10.0, rng.random((5, 9))]
    packed = np.asarray(sphere._catmull_rom_intervals(*lobes), dtype=np.float64).reshape(-1, 4)
    start = 0
    for rows in lobes:
        J, K = rows.shape
        q = packed[start:start + rows.size].reshape(K, J, 4)
        for j in range(J):
            P = rows[j]
            for i in range(K):
                p0, p1 = P[max(i - 1, 0)], P[i]
                p2, p3 = P[min(i + 1, K - 1)], P[min(i + 2, K - 1)]
                a, d, c1, c2 = q[i, j]
                c3 = d - c1 - c2
                cubic = lambda f: a + f * (c1 + f * (c2 + f * c3))
                ref = lambda f: 0.5 * ((2 * p1) + (-p0 + p2) * f + (2 * p0 - 5 * p1 + 4 * p2 - p3) * f * f
                                       + (-p0 + 3 * p1 - 3 * p2 + p3) * f ** 3)
                for f in (0.0, 0.5, 1.0):
                    assert abs(cubic(f) - ref(f)) <= 1e-5 * max(1.0, abs(ref(f))), (j, i, f)
        start += rows.size


def test_packed_rows_written_in_place_are_the_intervals(mi_variant, upload_branch):
    """The plugin writes its packed intervals straight into its Dr.Jit arrays where the backend keeps
    them on the host (:func:`corona.mitsuba.common.host_buffer`): they are, value for value, the
    intervals :func:`corona.mitsuba.sphere._catmull_rom_intervals` builds in numpy; and the buffer's
    numpy view is the array's memory (a write through it is read back by Dr.Jit), where elsewhere
    it is a plain numpy array to upload (CUDA, scalar variants, or the upload branch forced:
    ``CORONA_UPLOAD_BRANCH``, fixture ``upload_branch``), the intervals the same."""
    import mitsuba as mi
    from corona.mitsuba import common, sphere
    bsdf = _load(LAYERS["hard-disk"])
    if not isinstance(bsdf.chords, sphere.PackedChordRows):
        pytest.skip("the vectorised variants pack the rows")
    rows = bsdf.material.rows
    want = sphere._catmull_rom_intervals(rows["P_f"], rows["P_b"]).ravel()
    np.testing.assert_array_equal(np.asarray(bsdf.chords.P), want)
    buf, view = common.host_buffer(mi.Float, 8)
    assert (buf is None) == (upload_branch or not mi_variant.startswith("llvm")), (upload_branch, mi_variant)
    if buf is None:                                 # CUDA (or the upload branch): filled in numpy, uploaded
        assert isinstance(view, np.ndarray) and view.dtype == np.float32 and view.size == 8
        return
    view[:] = np.arange(8, dtype=np.float32)
    np.testing.assert_array_equal(np.asarray(buf + 0.0), np.arange(8, dtype=np.float32))
