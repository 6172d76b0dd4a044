"""Dr.Jit parts every ``corona`` BSDF shares (opaque scatterers and Mie spheres).

What the plugin's scatterer families have in common lives here once, like a
header that Mitsuba's plugins include: the constants, reading and checking
the parameters, texture ranges, arrays and gathers that also work in scalar
variants, the guide-table CDFs of piecewise-linear radial densities and their
Newton inversion, the lane's wavelengths (one-sample mixture over them), the
RGB / mono folding of per-wavelength values, and the components' selection.
The thin glass pane's Fresnel weights live with the substrates,
:mod:`corona.mitsuba.substrate` (docs/physics.md#the-layer-on-glass-substrateglass).

This module imports no plugin module (:mod:`corona.mitsuba.bsdf`,
:mod:`corona.mitsuba.sphere`): they import it.
"""
from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi
import numpy as np

from corona.model import tabulated
from corona._validation import CoronaError, short_repr
from corona.parameters import SPEC
from corona.model.rows import row_slopes

#: Wavelengths per RGB / mono channel (equal-weight quantiles of its response).
N_RESPONSE = 8
#: Safeguarded Newton steps inverting a bin's cubic CDF from a linear first guess (the sphere layer).
NEWTON_STEPS = 5
#: Safeguarded Newton steps of :func:`invert_radial_bin` after its quadratic first guess.
RADIAL_NEWTON_STEPS = 1
#: Parameters that take a Mitsuba texture as well as a float (a float becomes a
#: ``uniform`` texture, so ``mi.traverse`` shows ``area_fraction.value`` etc.).
TEXTURED = ("area_fraction", "radius", "albedo")
#: Parameters a process reads that may also be a texture (the plugin's own rows over them).
PROCESS_TEXTURED = ("breath_time", "dry_time")


# --------------------------------------------------------------------------
# parameters and textures (load time, Python)
# --------------------------------------------------------------------------
def read_props(props) -> tuple[dict, dict]:
    """Named parameters from a ``mi.Properties``, checked against :data:`corona.parameters.SPEC`
    (unknown names are an error), and the textures of :data:`TEXTURED`.

    Returns
    -------
    params : dict
        name -> checked Python value (floats as float, choices as str).
    textures : dict
        name -> ``mi.Texture`` for the :data:`TEXTURED` parameters given as a texture.
    """
    out, textures = {}, {}
    for name in props.keys():
        if name not in SPEC:
            raise CoronaError(f"corona BSDF: unknown parameter '{name}'; known: {', '.join(sorted(SPEC))}")
        value = props.get(name)
        if name in ("shape", "process") and not isinstance(value, str):
            out[name] = instance_of(name, value)          # corona.scatterer(...)
            continue
        if (name in TEXTURED or name in PROCESS_TEXTURED) and isinstance(value, mi.Texture):
            textures[name] = value
            continue
        if name == "mirror_reflectance" and all(hasattr(value, a) for a in ("wavelengths", "values", "is_uniform")):
            # a <spectrum> given in the scene: its wavelength:value pairs, unresolved (every variant)
            lam, val = np.asarray(value.wavelengths, dtype=np.float64), np.asarray(value.values, dtype=np.float64)
            uniform_ = value.is_uniform() if callable(value.is_uniform) else value.is_uniform
            value = float(val.ravel()[0]) if uniform_ or lam.size < 2 else (lam, val)
        if name == "mirror_reflectance" and isinstance(value, (str, tuple, mi.Texture)):
            out[name] = spectrum_samples(value) if isinstance(value, mi.Texture) else value   # Mirror checks it
            continue
        if SPEC[name].kind in ("float", "int"):
            if isinstance(value, bool):   # <boolean name="radius" value="true"/> is no size
                raise CoronaError(f"corona BSDF: {name}={value!r} is not a number; allowed {SPEC[name].allowed}")
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise CoronaError(f"corona BSDF: {name}={value!r} is not a number; "
                                  f"allowed {SPEC[name].allowed}") from None
        else:
            value = str(value)
        out[name] = SPEC[name].check(value)
    return out, textures


class ScattererObject(mi.Object):
    """A :class:`corona.Shape` or :class:`corona.Process` instance as a Mitsuba property
    (:func:`scatterer`)."""

    def __init__(self, value):
        super().__init__()
        self.value = value

    def to_string(self):
        return f"ScattererObject[{self.value!r}]"


def _kinds():
    from corona.model.processes.base import Process
    from corona.model.shapes.base import Shape
    return {"shape": Shape, "process": Process}


def scatterer(value) -> ScattererObject:
    """``value`` (any :class:`corona.Shape` or :class:`corona.Process`, a user's subclass too) as
    the value of the plugin's ``shape`` or ``process`` property:
    ``mi.load_dict({'type': 'corona', 'shape': corona.scatterer(my_shape),
    'process': corona.scatterer(my_process)})``.

    Mitsuba 3.9's properties hold only its own (nanobind) types, so a plain Python object is
    refused by ``mi.load_dict`` before any plugin sees it; this wraps it in an ``mi.Object``.
    The instance is complete as given.  A shape keeps its own size, soft edge, orientation and
    size spread (the layer adds the process, the mode, the albedo and the substrate); without a
    kernel term the plugin tabulates its numpy form factor, as it tabulates a mask.  A process
    keeps its own area fraction and lengths: the plugin neither textures nor differentiates
    them (``area_fraction`` and ``radius`` are plain values there, as with a point file).
    """
    if not isinstance(value, tuple(_kinds().values())):
        raise CoronaError(f"corona.scatterer: {short_repr(value)} is neither a corona.Shape nor a "
                          "corona.Process instance (a subclass of either: corona.Shape implementing area, "
                          "length_scale and amplitude; corona.Process implementing structure_factor_at and "
                          "area_fraction)")
    return ScattererObject(value)


def instance_of(name: str, value):
    """The instance a ``shape`` / ``process`` property holds (:func:`scatterer`), checked to be of
    that kind; anything else that is not a name is one :class:`CoronaError`.

    A process instance is held fixed: its area fraction is its own (no rows over F_a, no
    texture, not differentiated), so the plugin uses a shallow copy with
    ``varying_area_fraction = False`` (the model's physics unchanged, ``Material.lobe`` the same).
    """
    import copy
    kind = _kinds()[name]
    held = value.value if isinstance(value, ScattererObject) else None
    if not isinstance(held, kind):
        what = (f"corona.scatterer({short_repr(held)})" if isinstance(value, ScattererObject)
                else f"a {type(value).__name__}")
        raise CoronaError(f"corona BSDF: {name}={what} is out of range; allowed a registered {name} name "
                          f"({', '.join(SPEC[name].choices)}) or corona.scatterer(<a corona.{kind.__name__} "
                          "instance>)")
    if name == "process" and held.varying_area_fraction:
        held = copy.copy(held)
        held.varying_area_fraction = False
    return held


def spectrum_samples(texture, wavelengths=None):
    """A Mitsuba spectrum (texture) sampled at ``wavelengths`` [nm] (default
    :data:`corona.model.substrate.SPECTRUM_GRID`): (wavelengths, values), spectral variants only (RGB
    and mono variants have turned a spectrum into a colour when they loaded it)."""
    from corona.model.substrate import SPECTRUM_GRID
    if not mi.is_spectral:
        raise CoronaError("corona BSDF: mirror_reflectance as a spectrum object needs a spectral variant "
                          f"({mi.variant()} turns spectra into colours); give it as 'nm:value, ...' text, "
                          "a metal (silver, aluminium, gold, copper) or a number")
    lam = np.asarray(SPECTRUM_GRID if wavelengths is None else wavelengths, dtype=np.float64)
    vals = []
    for x in lam:
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wavelengths = mi.Spectrum(float(x))
        vals.append(float(np.array(texture.eval(si)).ravel()[0]))
    return lam, np.array(vals)


def uniform(value: float):
    """A ``uniform`` Mitsuba texture of ``value`` (its key in ``mi.traverse``: ``value``), made by
    the plugin manager, not the scene parser.

    The BSDF is built while Mitsuba loads a scene, on one of its loader threads.  Mitsuba's
    parser (``mi.load_dict``, ``load_string``, ``load_file``) replaces the process-wide
    ``FileResolver`` for the duration of a load and frees its copy at the end, while the other
    loader threads read that resolver (resolving plugin libraries, ``data/srgb.coeff``, bitmap
    file names): a nested load from here left them reading freed memory
    (``basic_string::_M_create``, ``std::bad_alloc`` in the next emitter).
    ``PluginManager.create_object`` only reads the resolver.
    """
    props = mi.Properties("uniform")
    props["value"] = float(value)
    return mi.PluginManager.instance().create_object(props)


def texture_range(texture) -> tuple[float | None, float]:
    """(min, max) of a scalar texture's values.

    Evaluated at the texel centres of a bitmap (``texture.resolution()``) or
    on a 64×64 grid of uv for procedural textures (scalar variants: every
    k-th of these points, at most 256×256); where the texture cannot
    be evaluated without a mesh (``mesh_attribute``) the minimum is unknown
    (None) and the maximum is ``texture.max()``.  A NaN texel makes both NaN,
    an infinite one the end it lies on (the caller refuses them by name).
    """
    if not texture.is_spatially_varying():
        v = float(np.asarray(dr.detach(texture.mean())).ravel()[0])
        return v, v
    res = [int(x) for x in texture.resolution()]
    nx, ny = min(max(res[0], 64), 4096), min(max(res[1], 64), 4096)
    uu, vv = np.meshgrid((np.arange(nx) + 0.5) / nx, (np.arange(ny) + 0.5) / ny)
    try:
        if dr.is_array_v(mi.Float):
            si = dr.zeros(mi.SurfaceInteraction3f, uu.size)
            si.uv = mi.Point2f(uu.ravel().astype(np.float32), vv.ravel().astype(np.float32))
            vals = np.asarray(dr.detach(texture.eval_1(si)), dtype=np.float64).ravel()
        else:   # scalar variants: one point at a time, on at most 256×256 of the points
            si = dr.zeros(mi.SurfaceInteraction3f)
            step = max(1, -(-max(nx, ny) // 256))
            vals = []
            for u, v in zip(uu[::step, ::step].ravel(), vv[::step, ::step].ravel()):
                si.uv = mi.Point2f(float(u), float(v))
                vals.append(float(texture.eval_1(si)))
            vals = np.asarray(vals)
        if vals.size:          # NaN / ±inf texels come out as such: the caller names them
            return float(np.min(vals)), float(np.max(vals))
    except Exception:  # noqa: BLE001 - textures that need a mesh
        pass
    return None, float(texture.max())


_VARIANT_CLASSES: dict = {}


def variant_class(mixin: type, base_name: str, name: str) -> type:
    """The subclass ``name`` of the active variant's ``mi.<base_name>`` (``"BSDF"``,
    ``"PhaseFunction"``) holding ``mixin``'s methods, made once per variant.

    Each Mitsuba variant has its own base classes and nanobind types take a single base, so the
    plugins keep their methods in plain mixins (with their plain bases', e.g.
    :class:`corona.mitsuba.core.PluginCore`) and copy them into one subclass per variant.
    """
    key = (mi.variant(), mixin, base_name)
    if key not in _VARIANT_CLASSES:
        methods = {}
        for klass in reversed(mixin.__mro__[:-1]):     # a shared shell's methods, then the family's own
            methods.update({k: v for k, v in vars(klass).items() if k not in ("__dict__", "__weakref__")})
        _VARIANT_CLASSES[key] = type(name, (getattr(mi, base_name),), methods)
    return _VARIANT_CLASSES[key]


# --------------------------------------------------------------------------
# arrays (scalar variants too)
# --------------------------------------------------------------------------
def array(dtype, values):
    """A Dr.Jit array of ``values`` (``mi.Float``: float32, ``mi.UInt32``, ``mi.Int32``);
    a numpy array in scalar variants.

    The array is written by a Dr.Jit kernel (a copy), not taken over from numpy: Dr.Jit 1.x's
    LLVM backend turns a ``Vector4f`` gather (:func:`gather4`) into one packet load per lane
    only from arrays it allocated itself, and into four gathers from one made of a numpy array.
    """
    if dtype is mi.UInt32:
        a = np.asarray(values, dtype=np.uint32)
    elif dtype is mi.Int32:
        a = np.asarray(values, dtype=np.int32)
    else:
        a = np.asarray(values, dtype=np.float32)
    if dr.is_array_v(dtype) is False:
        return a
    out = dtype(a) + dr.opaque(dtype, 0)
    dr.eval(out)
    return out


#: The CUDA branch on every backend: :func:`host_buffer` hands out a numpy array to upload (as on
#: CUDA and in scalar variants) instead of a view of an LLVM array's memory, so that the CPU tests
#: run that branch too.  Set from the environment variable ``CORONA_UPLOAD_BRANCH`` (``1``) when
#: the module loads; the tests switch it per test (tests/conftest.py, fixture ``upload_branch``).
#: Every place the plugin branches on the Dr.Jit backend goes through :func:`upload_branch`.
UPLOAD_BRANCH = os.environ.get("CORONA_UPLOAD_BRANCH", "").strip() not in ("", "0")


def upload_branch() -> bool:
    """Whether the plugin takes the branch of a backend whose arrays live off the host (CUDA):
    on CUDA, or everywhere while :data:`UPLOAD_BRANCH` is set."""
    if UPLOAD_BRANCH or not dr.is_array_v(mi.Float):
        return True
    return dr.backend_v(mi.Float) != dr.JitBackend.LLVM


def host_buffer(dtype, n):
    """An array of ``n`` float32 values to fill in place: ``(array, view)``, ``view`` a writable
    numpy view of the Dr.Jit ``array``'s own memory where the backend keeps it on the host (LLVM):
    a large table is then written once, not built in numpy and copied (:func:`array`).  Elsewhere
    (CUDA, scalar variants, a backend that hands numpy a copy, or :data:`UPLOAD_BRANCH` set)
    ``(None, view)``, ``view`` a numpy array: upload it with :func:`array` once filled."""
    n = int(n)
    if dtype is mi.Float and not upload_branch() and n > 0:
        out = dr.empty(dtype, n)
        dr.eval(out)
        view = np.asarray(out)
        if view.dtype == np.float32 and view.flags.writeable and view.size == n:
            view[0] = 1.0                           # the view is the array's memory, not a copy
            if dr.slice(out, 0) == 1.0:
                view[0] = -1.0
                if dr.slice(out, 0) == -1.0:
                    return out, view
    return None, np.empty(n, dtype=np.float32)


def gather(dtype, source, index, active=True):
    """``dr.gather`` that also works in scalar variants (Python scalars there)."""
    if dr.is_array_v(dtype):
        return dr.gather(dtype, source, index, active)
    return dtype(source[int(index)]) if active else dtype(0)


def gather4(source, index, active=True):
    """``mi.Vector4f`` of ``source[4 index : 4 index + 4]`` (one packet gather; scalar variants too)."""
    if dr.is_array_v(mi.Float):
        return dr.gather(mi.Vector4f, source, index, active)
    if not active:
        return mi.Vector4f(0.0)
    k = 4 * int(index)
    return mi.Vector4f(*[float(source[k + c]) for c in range(4)])


# --------------------------------------------------------------------------
# trigonometry that is the same on every backend
# --------------------------------------------------------------------------
#: 2π as three float32 parts (Cody & Waite): ``x - k·2π`` in three fused multiply-adds, the first exact.
TWO_PI_PARTS = (float(np.float32(2.0 * np.pi)),
                float(np.float32(2.0 * np.pi - float(np.float32(2.0 * np.pi)))),
                float(np.float32(2.0 * np.pi - float(np.float32(2.0 * np.pi))
                                 - float(np.float32(2.0 * np.pi - float(np.float32(2.0 * np.pi)))))))


def reduce_angle(x):
    """``x - 2π k``, ``k = round(x / 2π)``: the angle in ``[-π, π]`` (a rounding beyond at most) with
    the sine and cosine of ``x`` itself (float32 ``x`` taken as exact).

    The three parts of :data:`TWO_PI_PARTS` (Cody & Waite): ``x - k c1`` is exact (a multiple of
    ``ulp(c1)`` below 4 for ``|x|`` below 10⁷), so the result is off by about one ulp of itself plus
    ``|k| · 3e-16`` (the parts sum to float64's 2π); Dr.Jit's own reduction (Cephes' π/4 in three
    float32 parts) loses precision above about 10⁴ (errors 5e-7 at 3·10⁴, 1e-6 at 10⁵)."""
    c1, c2, c3 = TWO_PI_PARTS
    k = dr.round(x * (0.5 / np.pi))
    return dr.fma(k, -c3, dr.fma(k, -c2, dr.fma(k, -c1, x)))


def sincos(x):
    """``(sin x, cos x)`` to float precision on every backend: :func:`reduce_angle`, then Dr.Jit's
    polynomial ``dr.sincos``.

    ``dr.sin`` and ``dr.cos`` of float32 on CUDA are the GPU's ``sin.approx.ftz.f32`` /
    ``cos.approx.ftz.f32`` (drjit-extra's ``jit_var_sin``: ``jit_var_sin_intrinsic`` on GPU
    backends): an *absolute* error of about 2^-21.4 within ``[-π, π]`` and more beyond, which is
    a relative error of 1e-4 on ``sin x`` at ``x = 2e-3`` (a sinc near its peak).  ``dr.sincos``
    is the same polynomial on every backend (LLVM, CUDA, scalar); the plugin's kernels call this
    instead of ``dr.sin`` / ``dr.cos`` (tests/plugin/test_trig.py holds them to it)."""
    return dr.sincos(reduce_angle(x))


def sin(x):
    """``sin x`` (:func:`sincos`; the unused cosine is not traced into a kernel)."""
    return sincos(x)[0]


def cos(x):
    """``cos x`` (:func:`sincos`)."""
    return sincos(x)[1]


def hermite_rows(x, rows, at):
    """Cubic Hermite interpolation of ``rows`` (n, ...) over ``x`` (n,) at ``at`` (numpy, float64),
    the tangents :func:`corona.model.rows.row_slopes`: (value, derivative in x) at ``at``.

    ``at`` outside ``[x[0], x[-1]]`` is clamped to the nearer end (derivative there: the end row's).
    """
    x = np.asarray(x, dtype=np.float64)
    rows = np.asarray(rows, dtype=np.float64)
    if x.size < 2:
        return rows[0], np.zeros_like(rows[0])
    j = int(np.clip(np.searchsorted(x, at, side="right") - 1, 0, x.size - 2))
    h = x[j + 1] - x[j]
    t = float(np.clip((at - x[j]) / h, 0.0, 1.0))
    # the slopes at rows j and j + 1 read rows j - 1 … j + 2 only (the ends' one-sided ones the
    # first or last three rows, which the window then holds): the same values as row_slopes over
    # every row, without its cost in each update (an update recentres a uniform layer's rows)
    lo = max(j - 1, 0)
    m = row_slopes(x[lo:j + 3], rows[lo:j + 3])[j - lo:]
    a, b, ma, mb = rows[j], rows[j + 1], m[0] * h, m[1] * h
    t2, t3 = t * t, t * t * t
    v = (2 * t3 - 3 * t2 + 1) * a + (t3 - 2 * t2 + t) * ma + (3 * t2 - 2 * t3) * b + (t3 - t2) * mb
    dv = ((6 * t2 - 6 * t) * a + (3 * t2 - 4 * t + 1) * ma + (6 * t - 6 * t2) * b + (3 * t2 - 2 * t) * mb) / h
    return v, dv


def hermite_weights(t):
    """The cubic Hermite basis at ``t`` in [0, 1] of an interval of unit width: the weights of (value at
    0, slope at 0, value at 1, slope at 1); slopes in the interval's units (scale them by its width)."""
    t2 = t * t
    t3 = t2 * t
    return (2.0 * t3 - 3.0 * t2 + 1.0, t3 - 2.0 * t2 + t, 3.0 * t2 - 2.0 * t3, t3 - t2)


def centre_rows(x, at, *tables):
    """A uniform layer's rows centred at one area fraction ``at`` (the flat and the sphere plugin's
    ``F_a`` rows): ``(centre, [(value, slope), ...])``, ``centre`` ``at`` as an opaque Dr.Jit scalar (an
    update moves it without recompiling: lanes read value + slope × (F_a - centre)) and per table of
    rows over ``x`` its cubic Hermite value and slope in F_a at ``at`` (:func:`hermite_rows`)."""
    centre = dr.opaque(mi.Float, at) if dr.is_array_v(mi.Float) else mi.Float(at)
    return centre, [hermite_rows(x, rows, at) for rows in tables]


def positive(x):
    """``x`` where it is > 0, else 1: a divisor safe in scalar variants too, where
    ``dr.select`` evaluates both branches (``value / pdf`` raised ZeroDivisionError)."""
    return dr.select(x > 0, x, 1.0)


def clip(x, lo, hi):
    """``x`` clipped to ``[lo, hi]``, with the derivative of ``x`` where it lies on a bound: Dr.Jit's
    ``clip`` (and ``maximum``) pass the bound's derivative, 0, where ``x`` equals it, so a texel
    holding its texture's least value (the end of the rows' cover) had no derivative."""
    return dr.select((x < lo) | (x > hi), dr.clip(x, lo, hi), x)


def logical_not(x):
    """Logical not of a mask (a Dr.Jit Bool, or a Python bool in scalar variants, where ``~`` is wrong)."""
    return ~x if dr.is_array_v(x) else (not x)


# --------------------------------------------------------------------------
# piecewise-linear radial densities: guide tables, search, Newton
# --------------------------------------------------------------------------
def guided_cdfs(cdfs) -> dict:
    """Normalised float32 CDFs of rows of a radial table plus guide tables that narrow each search.

    Parameters
    ----------
    cdfs : sequence of ndarray
        Each row's CDF (float64, ``n_bins + 1`` values from 0, all rows the same
        length), e.g. :attr:`corona.model.tabulated.RadialTable.cdf`; a row of total 0 stays 0.

    Returns
    -------
    dict
        ``cdf`` (rows concatenated, float32 numpy), ``guide`` (uint32 numpy,
        ``G + 1`` a row), ``G`` (guide cells a row), ``n_bins`` and ``steps``
        (bisection steps, enough for the widest guide cell).  ``guide[j]`` is the
        last bin whose CDF is <= j/G, so a target in [j/G, (j+1)/G) lies in
        bins ``guide[j] .. guide[j+1]``; :func:`guided_search` then finds the bin
        in ``steps`` bisection steps.
    """
    C = np.asarray(cdfs, dtype=np.float64)
    if C.ndim == 1:
        C = C[None, :]
    n_rows, n_bins = C.shape[0], C.shape[1] - 1
    G = int(min(max(n_bins, 16), 1 << 16))
    marks = (np.arange(G + 1) / G).astype(np.float32)
    cdf32 = np.empty(C.shape, dtype=np.float32)
    guide = np.empty((n_rows, G + 1), dtype=np.uint32)
    width = 1
    # every row's search at once: guide[j] + 1 counts a row's CDF values <= marks[j]; a value c counts
    # for the marks from pos(c) = searchsorted(marks, c) on, so the counts are the cumulated
    # histogram of those positions.  pos(c) is ceil(c G) up to the marks' float32 rounding: one
    # step down or up where the neighbouring mark says so makes it exact.  In blocks of rows
    # that stay in the caches.
    step = max(1, (1 << 18) // (n_bins + 1))
    for a in range(0, n_rows, step):
        b = min(a + step, n_rows)
        total = np.where(C[a:b, -1] > 0, C[a:b, -1], 1.0)
        c32 = cdf32[a:b]
        np.divide(C[a:b], total[:, None], out=c32, casting="same_kind")
        pos = np.minimum(np.ceil(c32 * np.float64(G)).astype(np.int64), G + 1)
        pos -= (pos > 0) & (marks[np.maximum(pos - 1, 0)] >= c32)
        pos += (pos <= G) & (marks[np.minimum(pos, G)] < c32)
        pos += (np.arange(b - a, dtype=np.int64) * (G + 2))[:, None]
        hist = np.bincount(pos.ravel(), minlength=(b - a) * (G + 2)).reshape(b - a, G + 2)
        # the block's guide (counts - 1, clipped to the bins) in int64, stored as uint32
        gb = np.cumsum(hist[:, :G + 1], axis=1)
        gb -= 1
        np.clip(gb, 0, n_bins - 1, out=gb)
        width = max(width, int(np.max(gb[:, 1:] - gb[:, :-1])) + 1)
        guide[a:b] = gb
    return dict(cdf=cdf32.ravel(), guide=guide.ravel(), G=G, n_bins=n_bins,
                steps=max(1, int(np.ceil(np.log2(max(width, 1) + 1)))))


def guided_search(cdf, guide, G, n_bins, steps, row, xi, active, guide_offset=0, cdf_offset=0):
    """The bin of ``xi`` in row ``row`` of a :func:`guided_cdfs` table (Dr.Jit).

    ``cdf``, ``guide`` are the tables as ``mi.Float`` / ``mi.UInt32``;
    ``guide_offset`` / ``cdf_offset`` (UInt32 or int) move into a second table
    concatenated behind the first (e.g. a forward and a backward lobe).

    Returns
    -------
    idx, c0, c1
        The bin (UInt32, ``cdf[idx] <= xi < cdf[idx + 1]``) and the CDF at its ends.
    """
    base_c = row * (n_bins + 1) + cdf_offset
    g = mi.UInt32(dr.minimum(xi * G, G - 1))
    base_g = row * (G + 1) + guide_offset
    lo = gather(mi.UInt32, guide, base_g + g, active)
    hi = dr.minimum(gather(mi.UInt32, guide, base_g + g + 1, active) + 1, n_bins)

    def bisect(lo, hi):
        mid = (lo + hi) >> 1
        go_right = gather(mi.Float, cdf, base_c + mid, active) <= xi
        return dr.select(go_right, mid, lo), dr.select(go_right, hi, mid)
    if dr.is_array_v(mi.Float) and steps > 1:
        # most guide cells hold one or two bins (a lane needs one step) and the widest ones lie
        # where the density is small: a loop that stops once every lane of a packet is done
        lo, hi = dr.while_loop((lo, hi), lambda lo, hi: active & (hi - lo > 1), bisect,
                               label="corona guided search")
    else:
        for _ in range(steps):
            lo, hi = bisect(lo, hi)
    idx = dr.minimum(lo, n_bins - 1)
    c0 = gather(mi.Float, cdf, base_c + idx, active)
    c1 = gather(mi.Float, cdf, base_c + idx + 1, active)
    return idx, c0, c1


def invert_radial_bin(rest, c0, c1, x0, dx, a, b, total, steps=None):
    """Position ``t`` in [0, 1] inside a bin of a radial density ``2π x v(x)``, ``v`` linear (Dr.Jit).

    In the bin ``[x0, x0 + dx]`` with ``v = a + b t`` the normalised CDF past
    its start is the cubic ``C(t) = k1 t + k2 t² + k3 t³``
    (``k1 = N x0 a``, ``k2 = N (x0 b + dx a) / 2``, ``k3 = N dx b / 3``,
    ``N = 2π dx / total``).  ``C(t) = rest`` starts from the root of the
    quadratic without ``k3`` (exact where ``v`` is constant in the bin),
    ``t₀ = 2 rest / (k1 + √(k1² + 4 k2 rest))`` (monotone on [0, 1] since
    ``k1 + 2 k2 >= 0``), then takes ``steps`` (default :data:`RADIAL_NEWTON_STEPS`)
    safeguarded Newton steps (bisection where a step leaves the bracket; a step that
    does not move keeps its point).  On the tables' bins one step leaves |Δt| < 4e-6
    of the bin (float32; five Newton steps from the linear guess ``rest / (c1 - c0)``
    left up to 6e-3).  The point is ``x0 + t dx``; ``c0``, ``c1`` (the CDF at the bin's
    ends) are kept for the callers' signature.
    """
    steps = RADIAL_NEWTON_STEPS if steps is None else steps
    norm = 2.0 * dr.pi * dx / dr.maximum(total, 1e-30)
    k1 = norm * x0 * a
    k2 = norm * (x0 * b + dx * a) * 0.5
    k3 = norm * dx * b * (1.0 / 3.0)
    disc = dr.safe_sqrt(dr.fma(4.0 * k2, rest, k1 * k1))
    t = dr.clip(2.0 * rest / dr.maximum(k1 + disc, 1e-30), 0.0, 1.0)
    lo = mi.Float(0.0)
    hi = mi.Float(1.0)
    for _ in range(steps):
        f = dr.fma(dr.fma(k3, t, k2), t, k1) * t - rest
        lo = dr.select(f < 0, t, lo)
        hi = dr.select(f >= 0, t, hi)
        df = dr.fma(dr.fma(3.0 * k3, t, 2.0 * k2), t, k1)
        t_new = t - f / dr.maximum(df, 1e-30)            # df = density >= 0
        bad = (t_new < lo) | (t_new > hi)
        t = dr.select(bad, 0.5 * (lo + hi), t_new)
    return dr.clip(t, 0.0, 1.0)


# --------------------------------------------------------------------------
# wavelengths: the lane's mixture, the RGB / mono channels
# --------------------------------------------------------------------------
def lambda_um(lam_nm):
    """Wavelength [nm] clamped to the tables' range [360, 830] nm, in µm (a zero stays finite)."""
    return dr.clip(lam_nm, tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX) * 1e-3


def channel_curves():
    """(wavelengths [nm] (n,), responses (channels, n)) of the RGB / mono channels
    (CIE 1931 → linear sRGB, negative lobes clipped; ȳ for mono)."""
    from corona.color import XYZ_TO_SRGB, cie1931_xyz
    lam = np.linspace(tabulated.WAVELENGTH_MIN, tabulated.WAVELENGTH_MAX, 2048)
    xyz = cie1931_xyz(lam).T                                     # (3, n)
    return lam, (xyz[1:2] if mi.is_monochromatic else np.maximum(XYZ_TO_SRGB @ xyz, 0.0))


def channel_response():
    """(wavelengths [nm], weights) of the RGB / mono channels, each (channels, N_RESPONSE).

    Each channel's response (:func:`channel_curves`) is represented by ``N_RESPONSE``
    wavelengths at equal-weight quantiles of the response, so the channel value is their mean.
    """
    lam, resp = channel_curves()
    chans = []
    for r in resp:
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * np.diff(lam))])
        qs = (np.arange(N_RESPONSE) + 0.5) / N_RESPONSE * cdf[-1]
        chans.append(np.interp(qs, cdf, lam))
    chans = np.array(chans)
    return chans, np.full(chans.shape, 1.0 / N_RESPONSE)


def wavelength_mixture(wavelengths, channel_lambdas=None):
    """The wavelengths [nm] a lane evaluates and their (equal) mixture weights.

    Spectral variants: the lane's own wavelengths (``si.wavelengths``); RGB and
    mono: the channels' response wavelengths ``channel_lambdas``
    (:func:`channel_response`), flattened channel by channel.  Sampling picks
    one of them with its weight (:func:`pick_wavelength`) and the pdf is the
    weighted mean of theirs: a one-sample balance-heuristic mixture
    (docs/physics.md#hero-wavelength-and-the-mixture-pdf).
    """
    if mi.is_spectral:
        lams = [wavelengths[k] for k in range(dr.size_v(mi.Spectrum))]
    else:
        lams = [mi.Float(float(lam)) for lam in np.asarray(channel_lambdas).ravel()]
    return lams, [1.0 / len(lams)] * len(lams)


def pick_wavelength(s, lams):
    """One of ``lams`` picked by ``s`` in [0, 1) with equal probability (Dr.Jit).

    Returns ``(pick, lam, rest)``: the index (UInt32), its wavelength and what is
    left of ``s`` (``s n - pick``, in [0, 1)), free for a further choice.
    """
    n = len(lams)
    s = dr.clip(s, 0.0, 0.99999994) * n
    pick = dr.minimum(mi.UInt32(s), n - 1)
    return pick, picked(pick, lams), s - mi.Float(pick)


def picked(pick, values):
    """``values[pick]`` per lane (Dr.Jit): ``pick`` a UInt32 index into the list ``values``."""
    v = values[-1]
    for q in range(len(values) - 2, -1, -1):
        v = dr.select(pick == q, values[q], v)
    return v


def fold_spectrum(values, channel_lambdas=None, channel_weights=None):
    """Per-wavelength values (list, in :func:`wavelength_mixture`'s order) as a ``mi.Spectrum``.

    Spectral variants: the values themselves; RGB and mono: each channel's
    weighted sum over its response wavelengths (:func:`channel_response`).
    """
    if mi.is_spectral:
        return mi.Spectrum(values)
    nc, per = np.asarray(channel_lambdas).shape
    chans = []
    for c in range(nc):
        acc = mi.Float(0.0)
        for q in range(per):
            acc += float(channel_weights[c, q]) * values[c * per + q]
        chans.append(acc)
    return mi.Spectrum(chans[0]) if nc == 1 else mi.Spectrum(chans)


def selection(energies, enabled):
    """Per-lane probabilities of components ∝ their energies, 0 where a component is disabled
    (``enabled`` a list of Python bools, e.g. ``ctx.is_enabled(flag, index)``); all 0 where none is left."""
    en = [e if on else mi.Float(0.0) for e, on in zip(energies, enabled)]
    total = en[0]
    for e in en[1:]:
        total = total + e
    inv = dr.select(total > 0, 1.0 / dr.maximum(total, 1e-30), 0.0)
    return tuple(e * inv for e in en)
