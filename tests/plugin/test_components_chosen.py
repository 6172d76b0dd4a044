"""The plugin's representation choices are made once at load (issue 44): eval, pdf and sample
read none of the old flags.  Each layer is evaluated, its flags are then removed from the
instance (and the substrate's class; a time texture the layer evaluates stays), and it is
evaluated again: a traced path that still read
one would raise AttributeError, and the values must be unchanged bit for bit."""
import drjit as dr
import numpy as np
import pytest

#: the flags eval / pdf / sample used to test at trace time (the choice is now a bound function)
FLAT_FLAGS = ("time_tex", "time_name", "fixed_radius", "mode_aperture")
SPHERE_FLAGS = ("fa_textured",)

FA = [[0.2, 0.3], [0.25, 0.35]]
LAYERS = {
    "particle": {"radius": 0.35, "process": "poisson", "area_fraction": 0.3, "albedo": 0.6},
    "aperture": {"radius": 0.35, "process": "poisson", "area_fraction": 0.4, "mode": "aperture", "albedo": 0.6},
    "fa-texture": {"radius": 0.35, "process": "hard-disk", "area_fraction": "tex"},
    "radius-texture": {"radius": [[0.3, 0.4], [0.35, 0.45]], "process": "poisson", "area_fraction": 0.3},
    "breath-time-texture": {"process": "breath-figure", "breath_time": [[8.0, 12.0], [16.0, 24.0]]},
    "dry-time-texture": {"process": "breath-figure", "breath_time": 20.0, "dry_time": [[0.0, 3.0], [6.0, 9.0]]},
    "mask": {"shape": "mask", "pixel_size": 0.03, "process": "poisson", "area_fraction": 0.2},
    "glass": {"radius": 0.35, "process": "hard-disk", "area_fraction": 0.3, "substrate": "glass"},
    "sphere": {"shape": "sphere", "radius": 3.0, "process": "hard-disk", "area_fraction": 0.3},
    "sphere-fa-texture": {"shape": "sphere", "radius": 3.0, "process": "hard-disk", "area_fraction": "tex"},
    "sphere-glass": {"shape": "sphere", "radius": 3.0, "process": "hard-disk", "area_fraction": 0.3,
                     "substrate": "glass"},
}


def _load(mi, params, tmp_path):
    from bsdf_checks import bitmap_texture
    p = {}
    for k, v in params.items():
        p[k] = bitmap_texture(FA) if v == "tex" else bitmap_texture(v) if isinstance(v, list) else v
    if p.get("shape") == "mask":
        import imageio.v3 as iio
        img = np.zeros((24, 24), dtype=np.uint8)
        img[9:15, 3:21] = img[3:21, 9:15] = 255
        iio.imwrite(tmp_path / "cross.png", img)
        p["filename"] = str(tmp_path / "cross.png")
    return mi.load_dict({"type": "corona", **p})


def _run(mi, bsdf):
    """eval, pdf, eval_pdf and sample at four texels, transmitted and reflected, as numpy."""
    from bsdf_checks import uv_interaction
    out = []
    ctx = mi.BSDFContext()
    for k, uv in enumerate([(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)]):
        si = uv_interaction(64, (0.3, -0.2, 0.93), uv)
        rng = np.random.default_rng(k)
        wo = rng.normal(size=(3, 64)).astype(np.float32)
        wo /= np.linalg.norm(wo, axis=0)
        wo = mi.Vector3f(*wo)
        value, pdf = bsdf.eval_pdf(ctx, si, wo)
        bs, weight = bsdf.sample(ctx, si, mi.Float(rng.random(64, np.float32)),
                                 mi.Point2f(*rng.random((2, 64), np.float32)))
        res = [bsdf.eval(ctx, si, wo), bsdf.pdf(ctx, si, wo), value, pdf, weight, bs.wo, bs.pdf]
        dr.eval(res)
        out += [np.asarray(r) for r in res]
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", list(LAYERS))
def test_no_flag_read_in_eval_pdf_sample(mi_variant, name, monkeypatch, tmp_path):
    import mitsuba as mi

    from corona.mitsuba import sphere
    bsdf = _load(mi, LAYERS[name], tmp_path)
    before = _run(mi, bsdf)
    assert all(np.all(np.isfinite(b)) for b in before)
    for flag in FLAT_FLAGS + SPHERE_FLAGS:
        # a time texture the chosen component evaluates stays; as None or a bool it is a flag
        if isinstance(getattr(bsdf, flag, None), (type(None), bool, str)):
            monkeypatch.delattr(bsdf, flag, raising=False)
    for cls in (sphere.SpheresAlone, sphere.SpheresOnPane):
        monkeypatch.delattr(cls, "wavelength_loop", raising=False)
    after = _run(mi, bsdf)
    for b, a in zip(before, after):
        assert np.array_equal(b, a)


@pytest.mark.parametrize("name", ["particle", "breath-time-texture", "radius-texture", "sphere-fa-texture"])
def test_chosen_functions_do_not_keep_a_dropped_plugin(mi_variant, name, tmp_path):
    """The choices are the class's functions, not bound methods: a dropped plugin (and its tables) is
    freed at once, without the garbage collector (a bound method on the instance is a reference cycle)."""
    import gc
    import weakref

    import mitsuba as mi
    bsdf = _load(mi, LAYERS[name], tmp_path)
    alive = weakref.ref(bsdf)
    was = gc.isenabled()
    gc.disable()
    try:
        del bsdf
        assert alive() is None
    finally:
        if was:
            gc.enable()
