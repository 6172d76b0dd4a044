"""Inverse rendering of a fogged window with Mitsuba's ``prb`` integrator and ``mi.ad.Adam``.

Two problems, each fitted to a target rendering of the same scene at the
true values (more samples per pixel than each optimisation step):

1. **Droplet radius and area fraction** of a uniform layer (water droplets,
   hard disks, particle mode) on a pane 0.5 m from the camera, a lamp 20 m
   behind it.  The radius sets the size of the corona's rings (∝ λ/R), the
   area fraction its brightness (the lobe weight F_a) and the shape of its
   aureole (the structure factor).  The loss leaves out the pixels that see
   the lamp itself through the coherent beam (found by a render without the
   pane): Mitsuba's ``prb`` differentiates a path by re-evaluating
   ``bsdf.eval`` along it, which is zero along a delta component, so the
   derivative of the coherent weight (1 - F_a)² is not in its gradients.
   The corona around the lamp carries both unknowns.
2. **An 8×8 bitmap of area fraction** (radius known, nearest-neighbour
   lookup) on a pane that fills the view, against a uniformly bright sky,
   so that every texel is seen in front of light.  Each pixel then receives
   the coherent beam (1 - F_a)² and the whole lobe F_a (1 - F_a) of the texel
   it looks through: ``1 - F_a`` in all, a strong and monotonic handle on
   every texel.  The coherent beam's derivative, which ``prb`` leaves out,
   is added to the rendered image as ``(C - detach(C)) B`` (zero, but with
   the derivative ``∂C/∂F_a B``; :class:`CoherentTerm`), with ``C`` looked up
   in a bitmap of the same data at the point each pixel sees and ``B`` the
   sky without the pane.  Adam runs on ln F_a, so that thin texels are
   found to the same relative precision as dense ones.  (A grid of lamps
   behind the texels works too, but the corona's aureole depends on F_a
   through F_a S(q → 0), which is not monotonic: the fit is slower and can
   stall in the wrong branch.)

Adam's learning rates drop to a quarter for the last third of the
iterations, where its state is reset, and the result is the mean of the
iterates over that third (Monte Carlo noise averages out).

The layer's tables cover the values given at load (radius: 1.25× the
largest; area fraction: ± 0.1 around a uniform value, a texture's range);
an update beyond them rebuilds the tables and recompiles the kernels.  The
scenes are therefore loaded at the upper end of what the optimiser may
explore (radius ``R_LOAD``, a bitmap spanning ``FA_BOUNDS``) before the
initial guess is set, and the optimiser's values are clipped to those bounds.

    python examples/fit_window.py [--quick] [--json out.json]

``--quick`` (the test, tests/plugin/test_gradients.py) runs smaller images and
fewer iterations.  Each problem prints the iterations, the time and the
final errors.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

R_TRUE, FA_TRUE = 5.0, 0.35               # µm, -
R_START, FA_START = 4.0, 0.22             # the initial guess of problem 1
R_LOAD = 7.0                              # µm: the tables cover 1.25 × this
FA_BOUNDS = (0.02, 0.6)                   # area fractions the optimiser may visit (problem 2)
LAMP_DISTANCE, PANE_DISTANCE = 20.0, 0.5  # m
LAYER = {"type": "corona", "process": "hard-disk", "mode": "particle"}


def _tensor(values):
    """A ``mi.TensorXf`` of numpy ``values`` in memory Dr.Jit allocated itself.  One made straight
    from numpy maps numpy's memory, whose alignment varies from run to run and is compiled into
    every kernel that reads it (the loss's, the backward render's): each run then missed Dr.Jit's
    kernel cache and compiled those kernels anew."""
    from corona.mitsuba.common import array
    import mitsuba as mi
    a = np.ascontiguousarray(values, np.float32)
    return mi.TensorXf(array(mi.Float, a.ravel()), shape=a.shape)


def _sensor(fov, res, spp):
    import mitsuba as mi
    return {"type": "perspective", "fov": fov, "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at([0, 0, 0], [0, 0, 1], [0, 1, 0]),
            "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp}}


def _lamp(direction_deg, radius=0.1, radiance=100.0):
    """A sphere ``LAMP_DISTANCE`` away in the direction (angle about y, angle about x) [degree]."""
    tx, ty = (np.tan(np.radians(a)) for a in direction_deg)
    return {"type": "sphere", "radius": radius,
            "center": [float(LAMP_DISTANCE * tx), float(LAMP_DISTANCE * ty), LAMP_DISTANCE],
            "emitter": {"type": "area", "radiance": {"type": "uniform", "value": radiance}}}


def window_scene(bsdf, lamps, fov, res, spp, pane=True):
    """Camera at the origin looking along +z, the pane ``PANE_DISTANCE`` away filling the view
    (its uv square maps onto the image), lamps behind it; ``pane=False`` leaves the pane out."""
    import mitsuba as mi
    half = PANE_DISTANCE * np.tan(np.radians(fov / 2))
    scene = {"type": "scene", "integrator": {"type": "prb", "max_depth": 3},
             "sensor": _sensor(fov, res, spp)}
    if pane:
        scene["pane"] = {"type": "rectangle", "bsdf": bsdf,
                         "to_world": mi.ScalarTransform4f().translate([0, 0, PANE_DISTANCE]).scale(
                             [float(half), float(half), 1.0])}
    for i, d in enumerate(lamps):
        scene[f"lamp{i}"] = _lamp(d)
    return scene


def _render(scene, spp, seed=0):
    import mitsuba as mi
    return mi.render(scene, spp=spp, seed=seed)


def _off_lamp_mask(lamps, fov, res):
    """1 where a pixel does not see a lamp directly (a render without the pane), else 0."""
    import mitsuba as mi
    clear = mi.load_dict(window_scene(None, lamps, fov, res, 256, pane=False))
    seen = np.asarray(_render(clear, 256)).max(axis=2) > 0      # enough samples to find every lamp
    # one more pixel around each lamp: the box filter and the lamp's edge
    grown = seen.copy()
    for ax in (0, 1):
        for s in (-1, 1):
            grown |= np.roll(seen, s, axis=ax)
    return _tensor(np.repeat((~grown).astype(np.float32)[..., None], 3, axis=2))


def _optimise(scene, params, opt, keys_to_params, loss_of, iterations, spp, lr_schedule, clip, trace=None):
    """Adam steps: render, loss, backward, step, clip, write into the scene.

    Returns the losses and the mean of each optimised variable over the last
    third of the iterations (where the learning rate is low: averaging the
    iterates averages out the Monte Carlo noise of the gradients).
    """
    import drjit as dr
    import mitsuba as mi
    history, sums, count, rates = [], {}, 0, {}
    for it in range(iterations):
        for key, lr in lr_schedule(it).items():
            if key in rates and rates[key] != lr:
                # a new phase: forget the gradient scale of the first one (Adam's second moment
                # would keep the steps tiny once the gradients have shrunk near the optimum)
                opt.reset(key)
            rates[key] = lr
            opt.set_learning_rate({key: lr})
        keys_to_params(opt, params)
        img = mi.render(scene, params, spp=spp, seed=2 * it + 1, seed_grad=2 * it + 2)
        loss = loss_of(img)
        dr.backward(loss)
        opt.step()
        clip(opt)
        history.append(float(loss.array[0]))
        values = {k: np.asarray(v, dtype=np.float64) for k, v in opt.items()}
        if trace is not None:
            trace.append({k: float(v.ravel()[0]) for k, v in values.items()})
        if it >= iterations - iterations // 3:
            sums = {k: sums.get(k, 0.0) + v for k, v in values.items()}
            count += 1
    keys_to_params(opt, params)
    return history, {k: v / count for k, v in sums.items()}


def fit_uniform(res=48, spp=32, target_spp=1024, iterations=120, fov=24.0, start=(R_START, FA_START),
                log=print) -> dict:
    """Problem 1: recover the droplet radius and the area fraction of a uniform layer."""
    import drjit as dr
    import mitsuba as mi
    lamps = [(0.0, 0.0)]
    t0 = time.perf_counter()
    target = _render(mi.load_dict(window_scene({**LAYER, "radius": R_TRUE, "area_fraction": FA_TRUE},
                                               lamps, fov, res, target_spp)), target_spp, seed=10**6)
    mask = _off_lamp_mask(lamps, fov, res)
    scene = mi.load_dict(window_scene({**LAYER, "radius": R_LOAD, "area_fraction": 0.3}, lamps, fov, res, spp))
    params = mi.traverse(scene)
    kr, kf = "pane.bsdf.radius.value", "pane.bsdf.area_fraction.value"
    opt = mi.ad.Adam(lr=0.02)
    opt["radius"] = mi.Float(start[0])
    opt["area_fraction"] = mi.Float(start[1])
    scale = float(dr.mean(target * mask, axis=None).array[0]) ** 2

    def to_params(o, p):
        p[kr] = o["radius"]
        p[kf] = o["area_fraction"]
        p.update()

    def clip(o):
        o["radius"] = dr.clip(o["radius"], 0.5, 1.25 * R_LOAD)
        o["area_fraction"] = dr.clip(o["area_fraction"], 0.2, 0.4)      # the rows loaded: 0.3 ± 0.1

    def schedule(it):       # steps in µm and in F_a; a quarter of them for the last third
        f = 1.0 if it < 2 * iterations // 3 else 0.25
        return {"radius": 0.05 * f, "area_fraction": 0.008 * f}

    trace = []
    hist, mean = _optimise(scene, params, opt, to_params,
                           lambda img: dr.mean(dr.square((img - target) * mask), axis=None) / scale,
                           iterations, spp, schedule, clip, trace)
    seconds = time.perf_counter() - t0
    r, fa = float(mean["radius"].ravel()[0]), float(mean["area_fraction"].ravel()[0])
    out = {"iterations": iterations, "seconds": seconds, "resolution": res, "spp": spp,
           "radius": r, "radius_true": R_TRUE, "radius_error": r / R_TRUE - 1,
           "area_fraction": fa, "area_fraction_true": FA_TRUE, "area_fraction_error": fa / FA_TRUE - 1,
           "loss_first": hist[0], "loss_last": hist[-1],
           "trajectory": [(t["radius"], t["area_fraction"]) for t in trace]}
    log(f"uniform layer: {iterations} iterations in {seconds:.1f} s ({res}², {spp} spp): "
        f"radius {r:.3f} µm (true {R_TRUE}, {100 * out['radius_error']:+.2f} %), "
        f"area fraction {fa:.4f} (true {FA_TRUE}, {100 * out['area_fraction_error']:+.2f} %)")
    return out


def true_bitmap(n=8, seed=7) -> np.ndarray:
    """The unknown area fraction: fog denser towards the frame, a wiped diagonal streak, noise."""
    rng = np.random.default_rng(seed)
    y, x = (np.mgrid[:n, :n] + 0.5) / n
    edge = np.maximum(np.abs(x - 0.5), np.abs(y - 0.5)) * 2            # 0 centre, 1 frame
    fa = 0.2 + 0.25 * edge**2
    fa = np.where(np.abs(x - y) < 0.2, 0.1, fa)                           # the wiped streak
    return np.clip(fa + rng.normal(0, 0.02, fa.shape), 0.06, 0.5).astype(np.float32)


def sky_scene(bsdf, fov, res, spp, radiance=1.0, pane=True):
    """The pane of :func:`window_scene` against a uniformly bright sky (Mitsuba's ``constant``)."""
    scene = window_scene(bsdf, [], fov, res, spp, pane=pane)
    scene["sky"] = {"type": "constant", "radiance": {"type": "uniform", "value": radiance}}
    return scene


class CoherentTerm:
    """The derivative of the coherent beam, which ``prb`` leaves out, as an image term.

    A pixel that looks through the pane at the sky receives ``C B`` along the
    coherent (delta) path, with ``C = (1 - F_a)²`` (particle mode) at the
    point it sees and ``B`` the sky behind it.  ``term(F_a) = (C - detach(C)) B``
    is zero but carries ``∂C/∂F_a B``: added to ``prb``'s image it completes
    the gradient.  ``F_a`` at each pixel centre comes from a bitmap texture
    with the same data and lookup as the pane's, evaluated where the pixel's
    ray meets the pane (one texel per pixel block, so the centre stands for
    the whole pixel).
    """

    def __init__(self, scene, clear, n, res):
        import drjit as dr
        import mitsuba as mi
        self.res = res
        self.texture = mi.load_dict(_bitmap(np.full((n, n), 0.5, np.float32)))
        self.params = mi.traverse(self.texture)
        k = dr.arange(mi.UInt32, res * res)
        pos = (mi.Point2f(mi.Float(k % res), mi.Float(k // res)) + 0.5) / res
        ray, _ = scene.sensors()[0].sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
        self.si = scene.ray_intersect(ray)
        self.sky = clear                                     # B: the image without the pane

    def __call__(self, area_fraction):
        import drjit as dr
        import mitsuba as mi
        self.params["data"] = area_fraction
        self.params.update()
        c = dr.square(1.0 - self.texture.eval_1(self.si))
        c = mi.TensorXf(dr.repeat(c - dr.detach(c), 3), shape=(self.res, self.res, 3))
        return c * self.sky


def _bitmap(values):
    import mitsuba as mi
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.asarray(values, np.float32)[..., None]),
            "raw": True, "filter_type": "nearest"}


def fit_bitmap(n=8, pixels_per_texel=4, spp=16, target_spp=256, iterations=200, fov=40.0,
               fa_start=0.3, radius=R_TRUE, log=print) -> dict:
    """Problem 2: recover an n×n bitmap of area fraction (radius known) against a bright sky."""
    import drjit as dr
    import mitsuba as mi
    res = n * pixels_per_texel
    truth = true_bitmap(n)
    t0 = time.perf_counter()
    target = _render(mi.load_dict(sky_scene({**LAYER, "radius": radius, "area_fraction": _bitmap(truth)},
                                            fov, res, target_spp)), target_spp, seed=10**6)
    # load with a bitmap spanning FA_BOUNDS, so that the rows cover every value the optimiser visits
    span = np.full((n, n), fa_start, np.float32)
    span[0, 0], span[-1, -1] = FA_BOUNDS
    scene = mi.load_dict(sky_scene({**LAYER, "radius": radius, "area_fraction": _bitmap(span)}, fov, res, spp))
    clear = _render(mi.load_dict(sky_scene(None, fov, res, 4, pane=False)), 4)
    coherent = CoherentTerm(scene, clear, n, res)
    params = mi.traverse(scene)
    key = "pane.bsdf.area_fraction.data"
    # Adam on ln F_a: steps relative to each texel's value, so that a thin texel is found to the
    # same relative precision as a dense one
    opt = mi.ad.Adam(lr=0.05)
    opt["ln_fa"] = _tensor(np.full((n, n, 1), np.log(fa_start)))
    state = {}

    def to_params(o, p):
        state["fa"] = dr.exp(o["ln_fa"])
        p[key] = state["fa"]
        p.update()

    def clip(o):
        o["ln_fa"] = dr.clip(o["ln_fa"], *np.log(FA_BOUNDS))

    def schedule(it):
        return {"ln_fa": 0.08 if it < 2 * iterations // 3 else 0.02}

    # on the sum of the channels: the sky's flat spectrum, sampled at random wavelengths, scatters
    # the colour of each sample (spectral noise) much more than its brightness
    weight = _tensor(np.ones((res, res, 3)))
    grey = dr.sum(target * weight, axis=2)

    def loss(img):
        return dr.mean(dr.square(dr.sum((img + coherent(state["fa"])) * weight, axis=2) - grey), axis=None)

    hist, mean = _optimise(scene, params, opt, to_params, loss, iterations, spp, schedule, clip)
    seconds = time.perf_counter() - t0
    fit = np.exp(mean["ln_fa"][..., 0])
    rel = fit / truth - 1
    out = {"iterations": iterations, "seconds": seconds, "resolution": res, "spp": spp, "texels": n,
           "max_texel_error": float(np.max(np.abs(rel))), "rms_texel_error": float(np.sqrt(np.mean(rel**2))),
           "truth": truth.tolist(), "fit": fit.tolist(), "loss_first": hist[0], "loss_last": hist[-1]}
    log(f"{n}×{n} bitmap: {iterations} iterations in {seconds:.1f} s ({res}², {spp} spp): per texel "
        f"max error {100 * out['max_texel_error']:.2f} %, rms {100 * out['rms_texel_error']:.2f} % "
        f"(true values {truth.min():.2f} to {truth.max():.2f}, start {fa_start})")
    return out


def quick(log=print) -> dict:
    """The reduced version the test runs: smaller images, fewer iterations, a start 10 % (radius)
    and 20 % (area fraction) off, a 4×4 bitmap."""
    return {"uniform": fit_uniform(res=32, spp=16, target_spp=256, iterations=45, start=(4.5, 0.28), log=log),
            "bitmap": fit_bitmap(n=4, pixels_per_texel=4, spp=16, target_spp=256, iterations=45, log=log)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller images, fewer iterations (the test)")
    ap.add_argument("--variant", default=None, help="Mitsuba variant (default: corona's)")
    ap.add_argument("--json", default=None, help="write the results here")
    a = ap.parse_args(argv)
    from corona.apps.render import setup_variant
    setup_variant(a.variant)
    results = quick() if a.quick else {"uniform": fit_uniform(), "bitmap": fit_bitmap()}
    if a.json:
        with open(a.json, "w", encoding="utf-8") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
