"""A corona pass for any linear HDR image: a uniform layer at the camera (numpy/scipy).

A thin uniform layer parallel to the sensor of a pinhole camera, at the camera
(or anywhere in front of it: only directions matter), turns the scene radiance
``L`` seen in the direction ``v`` into

.. math::

    L_\\mathrm{out}(v) = T_c \\, L(v) + \\int \\mathrm{lobe}(p' - p) \\, L(v') \\, d^2 p',
    \\qquad p = v_{xy}, \\; p' = v'_{xy},

with ``T_c`` the coherent transmittance (``F_a²`` for apertures, ``(1 - F_a)²``
for particles) and ``lobe(d) = F_a T_a(d) T_s(d)`` the diffraction lobe per
unit ``d²d`` (docs/physics.md#the-lobe).  This is the BSDF itself: the plugin
returns ``f |cos θo|`` and ``f |cos θo| dω_o = lobe(d) d²d`` with
``d = (ω_o + ω_i)_xy = p' - p`` (the camera ray is ``-ω_i``).  Since the lobe
depends on ``d`` only, the pass is a **convolution in the plane of the direction
cosines** ``p = v_xy``; and since ``lobe(d) = lobe(-d)`` (``|Â(-q)| = |Â(q)|``
for a real profile, ``S(-q) = S(q)``) correlation and convolution coincide.

How the pinhole is handled (exact for any field of view below 180°)
-------------------------------------------------------------------
A pinhole image is uniform in the tangent plane ``t = v_xy / v_z``, not in
``p = t / sqrt(1 + |t|²)``.  So the image is moved to a grid uniform in ``p``
(step ``Δp`` = the pixel pitch at the image centre, nodes on the pixel centres
there) by **splatting**: each pixel
puts its energy ``L_j ΔA_j`` on the four nodes around its centre ``p_j``
(bilinear weights), with ``ΔA_j = s² / (1 + |t_j|²)²`` its area in the ``p``
plane (pixel pitch ``s`` in ``t``; the Jacobian of ``t -> p``, equal to the
pixel's solid angle times ``cos θ``; for pixels wider than 0.01 in ``t`` the
exact area of the footprint, by Hottel's corner formula).  The sum over the grid is then exactly
the quadrature ``Σ_j lobe(p_j - p) L_j ΔA_j`` of the integral above, whatever
the field of view, and no bright pixel is lost where the grid is coarser than
the image (at the edges of wide fields).  Pixels wider than 0.01 in ``t`` (about
0.6°: small images of wide fields) are first cut into ``k x k`` sub-pixels of the
same radiance (at most 4 M sub-pixels in all), and the lobe part is averaged
back over each pixel.  The grid is convolved with the
per-channel kernels and read back at each pixel's ``p`` by bilinear
interpolation (the adjoint of the splat).  The coherent part multiplies the
image itself, untouched by any resampling.

What is dropped, what is assumed
--------------------------------
- **Evanescent part**: only directions that exist (``|p'| < 1``) are
  integrated, as in the BSDF; the grid never leaves the image, which lies
  inside the unit disk for fields below 180°.
- **Outside the frame**: the scene beyond the image is black (light from
  outside the frame that the layer would scatter into it is not known).
- Normal incidence of the optical axis on the layer, ``substrate=none`` (a
  pane's Fresnel factors depend on the angle: not a shift-invariant kernel);
  ``shape=sphere`` (Mie droplets: the lobe depends on the scattering angle, not
  on ``d`` alone) is refused.  ``albedo`` only adds light reflected from behind
  the camera, which the image does not hold: ignored.

Colour
------
The image's channels are a colour space's linear primaries (``"srgb"``: linear
Rec. 709/sRGB by Mitsuba's XYZ matrix, the default; ``"acescg"``: the ACES AP1
primaries of ACEScg, S-2014-004; mono images: luminance ``ȳ``).  Each channel's
kernel is the lobe averaged over that channel's spectral response
``w_c(λ) = max(0, (M x̄ȳz̄(λ))_c)`` (``M`` the XYZ -> RGB matrix), normalised
to ``∫ w_c dλ = 1``: a wavelength-independent layer gives equal kernels and a
channel keeps its energy.  This is the RGB variants' rule for the plugin
(exactly, for the linear sRGB default), so a render through the layer in an RGB
variant and ``apply`` on the render without it agree up to the renders' noise.

The kernel
----------
The pixels are area averages (a box-filtered render), so a node's kernel value is
the lobe's energy weighted by the pixel-to-pixel tent
``Λ(x, y) = (1 - |x|)(1 - |y|)`` (``x, y`` in steps ``Δp``; a box seen through the
lobe and averaged over a box): ``K[k] = ∫ lobe(d) Λ(d/Δp - k) d²d``, which sums to the
lobe's energy and averages rings finer than a pixel instead of aliasing them.
Radial lobes (isotropic shape and process): from the channel-integrated
cumulative energy ``E_c(ρ) = Σ_λ w_c(λ) F_a W(2πRρ/λ)``, with the
wavelength-free ``W(u) = (1/2π) ∫_0^u v(u') u' du'`` of the exact dimensionless
lobe ``v`` (docs/physics.md#dimensionless-tables), the tent taken radially
(half-width ``Δp``); the nodes within 4 steps of the centre as the energy of thin
rings (``E_c`` on a grid finer than both the pixel and the lobe) times the tent
averaged over each ring, so their energy is exact even where one pixel holds the
whole lobe (fields near 180°, scatterers of a millimetre).  The kernel's spectrum is a
type-I DCT of one quadrant (the kernel is even in x and y).  Other lobes: the
renderer's lobe (:meth:`corona.Material.lobe_tabulated`) at each node, at 8
wavelengths per channel (equal-weight quantiles of ``w_c``), tent-weighted
``8 x 8`` samples near the centre, and a full real FFT.

Convolution: ``scipy.fft.rfft2`` / ``irfft2`` (``workers``) on a grid padded to
an even fast length ``>= 2N - 1`` per axis, so that no output node receives
light wrapped around the grid.

Examples
--------
A white image through a layer of 5 µm droplets: the centre keeps ``T_c`` and
gains the lobe's energy that lands there from the frame.

>>> import numpy as np, corona.apps.post as post
>>> img = np.ones((48, 64, 3), dtype=np.float32)
>>> out = post.apply(img, fov=40.0, radius=5.0, area_fraction=0.3, mode="particle", progress=False)
>>> m = post.layer(radius=5.0, area_fraction=0.3, mode="particle")
>>> round(m.coherent_transmittance, 2)
0.49
>>> bool(np.all(out[24, 32] > m.coherent_transmittance)) and bool(np.all(out <= 1.0))
True
"""
from __future__ import annotations

import math
import os

import numpy as np

from corona._validation import CoronaError

#: Colour spaces of the image (linear primaries).
COLORSPACES = ("srgb", "acescg")

#: ACES AP1 (ACEScg) -> CIE XYZ, from SMPTE ST 2065-1 / Academy S-2014-004.
AP1_TO_XYZ = np.array([[0.6624541811, 0.1340042065, 0.1561876870],
                       [0.2722287168, 0.6740817658, 0.0536895174],
                       [-0.0055746495, 0.0040607335, 1.0103391003]])

#: Wavelengths of the spectral quadrature of the channel responses [nm].
WAVELENGTHS = np.arange(360.0, 830.1, 2.5)
#: Wavelengths per channel of anisotropic kernels (equal-weight quantiles of the response).
N_PER_CHANNEL_2D = 8
#: Nodes within this many steps of the centre are averaged from point samples.
CENTRE_NODES = 4
CENTRE_SAMPLES = 32
CENTRE_SAMPLES_2D = 4
#: Pixels wider than this in the tangent plane (about 0.6°) are cut into sub-pixels ...
PIXEL_PITCH_MAX = 0.01
#: ... up to this many in all.
SUBPIXELS_MAX = 1 << 22
#: Largest field of view [degree] (a pinhole covers less than a hemisphere).
FOV_MAX = 179.0


def _progress(total, enabled, desc="corona post"):
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, disable=not enabled, leave=False, unit="step")


def layer(material=None, **params):
    """The :class:`corona.Material` of the pass: ``material`` itself, or one
    built by :func:`corona.parameters.material_from_parameters` from ``params``
    (the plugin's parameter specification: same names, ranges and errors).
    Layers the pass cannot model exactly are refused with one line."""
    if material is None:
        from corona.parameters import material_from_parameters
        material = material_from_parameters(**params)
    elif params:
        raise CoronaError(f"give either a material or parameters, not both (got {', '.join(sorted(params))})")
    from corona.model.mie.layer import SphereMaterial
    if isinstance(material, SphereMaterial):
        from corona.model import registry
        flat = ", ".join(f.name for f in registry.SHAPE_FAMILIES.values() if f.material is None)
        raise CoronaError("shape='sphere' is out of range for corona post: the Mie lobe depends on the "
                          f"scattering angle, not on d alone (render it); allowed {flat}")
    sub = getattr(material, "substrate", None)
    if sub is not None:
        raise CoronaError("substrate='glass' is out of range for corona post: the pane's Fresnel factors "
                          "depend on the angle (render it); allowed substrate='none'")
    return material


def xyz_to_rgb_matrix(colorspace: str) -> np.ndarray:
    """The 3x3 CIE XYZ -> linear RGB matrix of ``colorspace`` ("srgb" or "acescg")."""
    from corona.color import _xyz_to_srgb
    from corona._validation import check_choice
    colorspace = check_choice("colorspace", colorspace, COLORSPACES)
    if colorspace == "srgb":
        return _xyz_to_srgb()
    return np.linalg.inv(AP1_TO_XYZ)


def channel_responses(colorspace: str = "srgb", channels: int = 3,
                      wavelengths=WAVELENGTHS) -> np.ndarray:
    """Quadrature weights ``w_c(λ_k) Δλ`` (channels, n_λ) of each channel's
    spectral response, each row summing to 1.

    RGB: ``max(0, (M x̄ȳz̄)_c)`` with ``M`` the XYZ -> RGB matrix of the colour
    space (negative lobes clipped, as the plugin's RGB variants do); one
    channel: ``ȳ``.
    """
    from corona.color import cie1931_xyz
    lam = np.asarray(wavelengths, dtype=np.float64)
    cmf = cie1931_xyz(lam).T                                  # (3, n)
    if channels == 1:
        resp = cmf[1:2]
    else:
        resp = np.maximum(xyz_to_rgb_matrix(colorspace) @ cmf, 0.0)
    w = resp * np.gradient(lam)[None, :]
    return w / w.sum(axis=1, keepdims=True)


def plugin_response() -> tuple[np.ndarray, np.ndarray]:
    """The spectral quadrature of the plugin in the active RGB (or mono) Mitsuba
    variant as a ``response`` for :func:`apply`: its ``N_RESPONSE`` wavelengths per
    channel at equal weights (:func:`corona.mitsuba.common.channel_response`), so that
    ``apply`` and a render through the plugin integrate the same wavelengths."""
    from corona.mitsuba.common import channel_response
    chans, w = channel_response()                              # (C, n) each
    lams = chans.ravel()
    weights = np.zeros((chans.shape[0], lams.size))
    for c in range(chans.shape[0]):
        weights[c, c * chans.shape[1]:(c + 1) * chans.shape[1]] = w[c]
    order = np.argsort(lams, kind="stable")
    return lams[order], weights[:, order]


def _check_response(response, channels):
    lams, weights = (np.asarray(x, dtype=np.float64) for x in response)
    from corona.model.tabulated import WAVELENGTH_MAX, WAVELENGTH_MIN
    if weights.shape != (channels, lams.size) or lams.ndim != 1:
        raise CoronaError(f"response of shapes {lams.shape}, {weights.shape} is out of range; allowed "
                          f"wavelengths (n,) and weights ({channels}, n)")
    if not (np.all(np.isfinite(lams)) and lams.min() >= WAVELENGTH_MIN and lams.max() <= WAVELENGTH_MAX):
        raise CoronaError(f"response wavelengths are out of range; allowed [{WAVELENGTH_MIN:g}, "
                          f"{WAVELENGTH_MAX:g}] nm")
    if not (np.all(weights >= 0) and np.allclose(weights.sum(axis=1), 1.0, atol=1e-6)):
        raise CoronaError("response weights are out of range; allowed >= 0, each channel summing to 1")
    order = np.argsort(lams)
    return lams[order], weights[:, order]


# ----------------------------------------------------------------------
# the pinhole and the grid in p = v.xy
# ----------------------------------------------------------------------
def pixel_tangents(width: int, height: int, fov: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Tangent-plane coordinates ``t = v_xy / v_z`` of the pixel centres of a pinhole
    image (``fov`` the horizontal field of view [degree], square pixels, x to the
    right, y up, row 0 at the top) and the pixel pitch ``s`` in ``t``."""
    s = 2.0 * math.tan(math.radians(fov) / 2.0) / width
    tx = (np.arange(width) + 0.5 - width / 2.0) * s
    ty = (height / 2.0 - np.arange(height) - 0.5) * s
    return tx, ty, s


def _pinhole_pixel_areas(tx, ty, s) -> np.ndarray:
    """Exact areas in the ``p`` plane of the pixels ``[t - s/2, t + s/2]²`` of a pinhole:
    ``∫∫ (1 + x² + y²)⁻² dx dy`` (a rectangle's view factor, Hottel's corner formula
    ``F(x, y) = [x/√(1+x²) atan(y/√(1+x²)) + y/√(1+y²) atan(x/√(1+y²))] / 2``,
    odd in x and y, taken at the four corners)."""
    x = np.concatenate([tx - s / 2, [tx[-1] + s / 2]])[None, :]
    y = np.concatenate([ty + s / 2, [ty[-1] - s / 2]])[:, None]       # rows top-down: y falls
    ax, ay = np.sqrt(1 + x * x), np.sqrt(1 + y * y)
    F = 0.5 * (x / ax * np.arctan(y / ax) + y / ay * np.arctan(x / ay))
    return -(F[1:, 1:] - F[:-1, 1:] - F[1:, :-1] + F[:-1, :-1])


class _Grid:
    """The grid uniform in ``p`` and the bilinear splat / gather of the image's pixels.

    The nodes sit on the pixel centres at the image centre (``p ≈ t`` there), so
    near the optical axis splat and gather are the identity, and they spread a
    pixel over its neighbours only where the pinhole moves its centre off a node.
    """

    def __init__(self, width, height, fov):
        tx, ty, s = pixel_tangents(width, height, fov)
        self.step = s                                          # Δp: the pixel pitch at the centre
        ex, ey = width / 2.0 * s, height / 2.0 * s            # image edges in t
        self.ax = int(math.ceil(ex / math.sqrt(1 + ex * ex) / s)) + 1
        self.ay = int(math.ceil(ey / math.sqrt(1 + ey * ey) / s)) + 1
        self.nx, self.ny = 2 * self.ax + 1, 2 * self.ay + 1
        ox, oy = 0.5 * (width % 2 == 0), 0.5 * (height % 2 == 0)   # node a at p = (a - ax + ox) Δp
        tx32, ty32 = tx.astype(np.float32), ty.astype(np.float32)
        r2 = tx32[None, :] ** 2 + ty32[:, None] ** 2
        inv = 1.0 / np.sqrt(1.0 + r2)                          # cos θ of each pixel
        del r2
        fx = tx32[None, :] * inv * np.float32(1.0 / s) + np.float32(self.ax - ox)   # node coordinates
        fy = np.float32(self.ay - oy) - ty32[:, None] * inv * np.float32(1.0 / s)   # rows top-down
        if s <= 0.01:   # the midpoint rule: ΔA_j = s² cos⁴θ, relative error below 1e-5
            inv2 = inv * inv
            self.area = np.float32(s * s) * inv2 * inv2
            del inv2
        else:           # large pixels (very wide fields of small images): the exact area
            self.area = _pinhole_pixel_areas(tx, ty, s).astype(np.float32)
        del inv
        x0 = fx.astype(np.int32)                               # fx, fy > 0: truncation is floor
        y0 = fy.astype(np.int32)
        wx = np.clip(fx - x0, 0.0, 1.0).ravel()
        wy = np.clip(fy - y0, 0.0, 1.0).ravel()
        del fx, fy
        base = (y0 * np.int32(self.nx) + x0).ravel()
        del x0, y0
        # the splat as a sparse matrix (nodes x pixels), four nodes per pixel: column j holds
        # pixel j's bilinear weights, so splat = M @ e and gather = M.T @ grid
        import scipy.sparse
        n = self.nx
        npix = base.size
        rows = np.empty((npix, 4), dtype=np.int32)
        rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3] = base, base + 1, base + n, base + (n + 1)
        data = np.empty((npix, 4), dtype=np.float32)
        data[:, 0] = (1 - wx) * (1 - wy)
        data[:, 1] = wx * (1 - wy)
        data[:, 2] = (1 - wx) * wy
        data[:, 3] = wx * wy
        self.matrix = scipy.sparse.csc_matrix(
            (data.ravel(), rows.ravel(), np.arange(0, 4 * npix + 1, 4, dtype=np.int64)),
            shape=(self.ny * self.nx, npix))
        self.shape = (height, width)

    def splat(self, image: np.ndarray) -> np.ndarray:
        """Radiance density on the grid, (ny, nx, C): ``Σ_j L_j ΔA_j w_j(node) / Δp²``."""
        e = image.reshape(-1, image.shape[-1]) * self.area.reshape(-1, 1)
        out = self.matrix @ e
        return (out * np.float32(1.0 / (self.step * self.step))).reshape(self.ny, self.nx, -1)

    def gather(self, grid: np.ndarray) -> np.ndarray:
        """The grid (ny, nx, C) read at each pixel's ``p`` (bilinear), (H, W, C)."""
        g = grid.reshape(self.ny * self.nx, -1)
        return (self.matrix.T @ g).reshape(*self.shape, -1)


def _even_fast_length(n: int) -> int:
    import scipy.fft
    m = scipy.fft.next_fast_len(n, real=True)
    while m % 2:
        m = scipy.fft.next_fast_len(m + 1, real=True)
    return m


# ----------------------------------------------------------------------
# kernels: K[k] = ∫ lobe(d) Λ(d/Δp - k) d²d, Λ(x, y) = (1 - |x|)(1 - |y|) the pixel-to-pixel
# tent (a box-filtered pixel seen through the lobe, averaged over a box-filtered pixel)
# ----------------------------------------------------------------------
def _tent_samples(n):
    """Offsets in [-1, 1] (units of Δp) and tent weights of ``2n`` midpoint samples."""
    x = (np.arange(2 * n) + 0.5) / n - 1.0
    w = 1.0 - np.abs(x)
    return x, w / w.sum()


def _radial_profiles(m, response, rho_top, step):
    """Channel-integrated ``(ρ grid, G = ∫ E dρ on it, fine ρ grid near the centre, E on it)``
    of a radial lobe (``E_c`` its cumulative energy within ``ρ``)."""
    lams, weights = response
    R = m.length_scale
    lam_um = np.asarray(lams, dtype=np.float64) * 1e-3
    fa = float(m.lobe_weight)
    u_top = 2 * np.pi * R * (rho_top + 2 * step) / lam_um.min() * 1.001
    n_u = int(min(1 << 21, max(4096, math.ceil(u_top / 0.02) + 1)))
    u = np.linspace(0.0, u_top, n_u)
    v = np.maximum(m.lobe_dimensionless_radial(u), 0.0)
    # W(u) = (1/2π) ∫ v u du  (E_λ(ρ) = F_a W(2πRρ/λ))
    g = v * u
    W = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(u))]) / (2 * np.pi)
    rho = np.arange(0.0, rho_top + 3 * step, step / 8.0)
    E = np.zeros((weights.shape[0], rho.size))
    for k, lam in enumerate(lam_um):
        E += weights[:, k:k + 1] * (fa * np.interp(2 * np.pi * R * rho / lam, u, W))[None, :]
    G = np.concatenate([np.zeros((E.shape[0], 1)),
                        np.cumsum(0.5 * (E[:, 1:] + E[:, :-1]) * np.diff(rho)[None, :], axis=1)], axis=1)
    # the centre nodes' radii on a grid that resolves the lobe as well as the pixel:
    # the cumulative energy on it, bin by bin, is exact whatever their ratio
    rho_c = (CENTRE_NODES + 1.5) * math.sqrt(2) * step
    fine = min(step / 64.0, 0.25 * lam_um.min() / (2 * np.pi * R))
    rf = np.linspace(0.0, rho_c, int(min(1 << 17, max(2048, math.ceil(rho_c / fine) + 1))))
    Ef = np.zeros((weights.shape[0], rf.size))
    for k, lam in enumerate(lam_um):
        Ef += weights[:, k:k + 1] * (fa * np.interp(2 * np.pi * R * rf / lam, u, W))[None, :]
    return rho, G, rf, Ef


def _ring_tent(iy: int, ix: int, radii: np.ndarray, n_phi: int = 512) -> np.ndarray:
    """The tent ``Λ(x - ix, y - iy)`` averaged over the circle of each radius
    (units of ``Δp``), for the node (iy, ix) and its mirror images in the
    other quadrants (the kernel is even in x and y: they share one value)."""
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    x = radii[:, None] * np.cos(phi)[None, :]
    y = radii[:, None] * np.sin(phi)[None, :]
    return (np.clip(1 - np.abs(x - ix), 0, None) * np.clip(1 - np.abs(y - iy), 0, None)).mean(axis=1)


def _radial_quadrant(m, response, qy, qx, valid_y, valid_x, step):
    """One quadrant (qy, qx) of each channel's kernel, node (0, 0) at offset 0, float32.

    Away from the centre the 2-D tent is replaced by a radial one of the same
    half-width ``Δp``: ``K = Δp² ∫ f Λ_ρ 2πr dr / ∫ Λ_ρ 2πr dr`` with
    ``∫ f Λ_ρ 2πr dr = [G(ρ+h) - 2G(ρ) + G(ρ-h)] / h`` (``G = ∫ E dρ``, ``E`` the
    cumulative energy), so rings finer than a pixel are averaged, never aliased.
    """
    weights = response[1]
    rho_top = math.hypot(valid_x, valid_y) * step
    rho, G, rf, rf_E = _radial_profiles(m, response, rho_top, step)
    h = step
    ky = np.arange(valid_y, dtype=np.float32)
    kx = np.arange(valid_x, dtype=np.float32)
    r = np.sqrt(ky[:, None] ** 2 + kx[None, :] ** 2) * np.float32(step)
    out = np.zeros((weights.shape[0], qy, qx), dtype=np.float32)

    # the tent-averaged profile on the ρ grid, then linear interpolation at every node
    # (it is smooth on the scale Δp; the grid step is Δp/8)
    def second_difference(fun, x):     # [fun(x+h) - 2 fun(x) + fun(x-h)] / h, fun odd below 0
        return (fun(x + h) - 2 * fun(x) + fun(np.abs(x - h)) * np.sign(x - h)) / h
    area = second_difference(lambda x: np.pi * x ** 3 / 3.0, rho)
    area[0] = 1.0
    prof = np.empty((weights.shape[0], rho.size), dtype=np.float32)
    for c in range(weights.shape[0]):
        Gc = G[c]
        prof[c] = second_difference(lambda x: np.interp(x, rho, Gc), rho) / area * step * step
    x = (r * (1.0 / (rho[1] - rho[0]))).astype(np.float32)
    del r
    i = np.minimum(x.astype(np.int32), rho.size - 2)
    frac = x - i
    del x
    for c in range(weights.shape[0]):
        lo = prof[c][i]
        out[c, :valid_y, :valid_x] = lo + (prof[c][i + 1] - lo) * frac
    # centre nodes: K = Σ_bins ΔE Λ̄(ρ), the energy of each thin ring times the
    # ring-averaged tent, exact in energy (Σ_k Λ̄_k = 1) for lobes of any width
    n = CENTRE_NODES
    dE = np.diff(rf_E, axis=1)                                   # (C, bins)
    mid = 0.5 * (rf[1:] + rf[:-1]) / step
    coarse = np.linspace(0.0, mid[-1] + 1e-9, 8 * (n + 3) * 4)
    for iy in range(min(n + 1, valid_y)):
        for ix in range(min(n + 1, valid_x)):
            lam_k = np.interp(mid, coarse, _ring_tent(iy, ix, coarse))
            for c in range(weights.shape[0]):
                out[c, iy, ix] = float(dE[c] @ lam_k)
    return out


def _quantile_wavelengths(response, n):
    """``n`` wavelengths per channel at equal-weight quantiles of its response, (C, n)."""
    lams, weights = response
    cdf = np.cumsum(weights, axis=1)
    qs = (np.arange(n) + 0.5) / n
    return np.array([np.interp(qs, c, lams) for c in cdf])


def _anisotropic_kernel(m, response, ly, lx, ny, nx, step):
    """Each channel's kernel on the full padded grid (offsets stored circularly): point
    samples of the renderer's lobe, tent-weighted samples for the centre nodes."""
    weights = response[1]
    lams = _quantile_wavelengths(response, N_PER_CHANNEL_2D)     # (C, n)
    ky = np.arange(-(ny - 1), ny)
    kx = np.arange(-(nx - 1), nx)
    KX, KY = np.meshgrid(kx * step, ky * step)
    d = np.stack([KX, -KY], -1)                                   # grid rows go down: -y
    out = np.zeros((weights.shape[0], ly, lx), dtype=np.float32)
    x, w = _tent_samples(CENTRE_SAMPLES_2D)
    ww = (w[:, None] * w[None, :]).ravel()
    n = CENTRE_NODES
    for c in range(weights.shape[0]):
        k = np.zeros(KX.shape)
        for lam in lams[c]:
            k += m.lobe_tabulated(d, float(lam))
        cy, cx = ny - 1, nx - 1
        for iy in range(-n, n + 1):
            for ix in range(-n, n + 1):
                XX, YY = np.meshgrid((ix + x) * step, -(iy + x) * step)
                dd = np.stack([XX.ravel(), YY.ravel()], -1)
                k[cy + iy, cx + ix] = sum(float(m.lobe_tabulated(dd, float(lam)) @ ww) for lam in lams[c])
        k *= step * step / lams.shape[1]
        out[c][np.ix_(np.mod(ky, ly), np.mod(kx, lx))] = k
    return out


# ----------------------------------------------------------------------
# the pass
# ----------------------------------------------------------------------
def apply(image, fov: float, material=None, *, colorspace: str = "srgb", response=None,
          workers: int | None = None, progress: bool = True, **params) -> np.ndarray:
    """The image seen through a uniform layer at the camera (see the module docstring).

    Parameters
    ----------
    image : array (H, W) or (H, W, C), C in {1, 3}
        Linear scene radiance (an HDR render or a linearised photograph) of a
        pinhole camera with square pixels; finite values.
    fov : float
        Horizontal field of view [degree], in (0, 179].
    material : corona.Material, optional
        The layer; or give its parameters by name (``radius=5.0, area_fraction=0.3``:
        :data:`corona.parameters.PARAMETERS`).
    colorspace : {"srgb", "acescg"}
        The linear primaries of the image's channels (default linear sRGB).
    response : (wavelengths (n,), weights (C, n)), optional
        Instead of ``colorspace``: each channel's spectral quadrature, rows
        summing to 1 (e.g. a camera's measured responses, or the plugin's
        RGB-variant wavelengths, :func:`plugin_response`).
    workers : int, optional
        Threads of ``scipy.fft`` (default: the CPUs this process may use).
    progress : bool
        A tqdm progress bar on stderr.

    Returns
    -------
    ndarray, float32, the shape of ``image``:
        ``T_c · image + (lobe ⊛ image)`` in the direction-cosine plane.
    """
    import scipy.fft
    from corona._validation import check_range
    m = layer(material, **params)
    fov = check_range("fov", fov, 0.0, FOV_MAX, lo_open=True, unit="degree")
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 3) or img.shape[0] < 1 or img.shape[1] < 1:
        raise CoronaError(f"image of shape {np.shape(image)} is out of range; allowed (H, W), (H, W, 1) "
                          "or (H, W, 3)")
    if not np.issubdtype(img.dtype, np.floating):
        raise CoronaError(f"image of dtype {img.dtype} is not linear HDR; allowed float arrays of linear "
                          "radiance (linearise 8-bit sRGB first)")
    bad = int(np.count_nonzero(~np.isfinite(img)))
    if bad:
        raise CoronaError(f"image has {bad} non-finite value(s) (NaN or inf); allowed finite values")
    if workers is None:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    img = img.astype(np.float32, copy=False)
    H, W, C = img.shape
    steps = 3 + C
    # large pixels (small images of wide fields) are cut into k x k sub-pixels of the same
    # radiance, so that each is small against the lobe and the grid; the lobe part is
    # averaged back over each pixel (a box filter in the film plane)
    pitch = 2.0 * math.tan(math.radians(fov) / 2.0) / W
    k_sub = 1
    if pitch > PIXEL_PITCH_MAX:
        k_sub = max(1, min(math.ceil(pitch / PIXEL_PITCH_MAX), math.isqrt(SUBPIXELS_MAX // (W * H))))
    src = img if k_sub == 1 else np.repeat(np.repeat(img, k_sub, axis=0), k_sub, axis=1)
    with _progress(steps, progress) as bar:
        grid = _Grid(W * k_sub, H * k_sub, fov)
        ly, lx = _even_fast_length(2 * grid.ny - 1), _even_fast_length(2 * grid.nx - 1)
        if response is None:
            response = (WAVELENGTHS, channel_responses(colorspace, C))
        response = _check_response(response, C)
        if m.isotropic:
            q = _radial_quadrant(m, response, ly // 2 + 1, lx // 2 + 1, grid.ny, grid.nx, grid.step)
            spectra = []
            for c in range(C):
                k = scipy.fft.dctn(q[c], type=1, workers=workers)          # the even kernel's DFT
                spectra.append(np.concatenate([k, k[-2:0:-1]], axis=0))    # rows 0..ly-1
        else:
            full = _anisotropic_kernel(m, response, ly, lx, grid.ny, grid.nx, grid.step)
            spectra = [scipy.fft.rfft2(full[c], workers=workers) for c in range(C)]
        bar.update(1)
        tc = np.float32(m.coherent_transmittance)
        g = grid.splat(src)                                                # (ny, nx, C)
        bar.update(1)
        conv = np.empty((grid.ny, grid.nx, C), dtype=np.float32)
        for c in range(C):
            f = scipy.fft.rfft2(g[..., c], s=(ly, lx), workers=workers)
            f *= spectra[c]
            conv[..., c] = scipy.fft.irfft2(f, s=(ly, lx), workers=workers)[:grid.ny, :grid.nx]
            del f
            bar.update(1)
        del g
        out = grid.gather(conv)
        if k_sub > 1:
            out = out.reshape(H, k_sub, W, k_sub, C).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)
        out += tc * img
        bar.update(1)
    return out.reshape(np.shape(image)) if np.ndim(image) == 2 else out


# ----------------------------------------------------------------------
# files
# ----------------------------------------------------------------------
def read_image(path: str, srgb_input: bool = False) -> tuple[np.ndarray, str]:
    """``(linear float32 (H, W, C), kind)`` of an EXR/HDR/PFM (linear) or, with
    ``srgb_input``, an 8-/16-bit sRGB PNG/JPEG decoded to linear values (its
    clipped highlights stay clipped: the corona of a clipped light is too faint).
    Without ``srgb_input`` a non-float image is refused: it is display-referred,
    not linear HDR.  An alpha channel is dropped."""
    import mitsuba as mi
    if not os.path.isfile(path):
        raise CoronaError(f"image {path!r} does not exist")
    try:
        bmp = mi.Bitmap(path)
    except Exception as err:  # noqa: BLE001 - Mitsuba raises RuntimeError with a traceback text
        first = str(err).strip().splitlines()[-1] if str(err).strip() else type(err).__name__
        raise CoronaError(f"image {path!r} cannot be read: {first}") from None
    fmt = bmp.pixel_format()
    floating = bmp.component_format() in (mi.Struct.Type.Float16, mi.Struct.Type.Float32,
                                          mi.Struct.Type.Float64)
    if not floating and not srgb_input:
        raise CoronaError(f"image {path!r} has {bmp.component_format().name} values, not linear HDR; "
                          "give a float EXR (linear radiance), or pass --srgb-input (srgb_input=True) to "
                          "decode an sRGB-encoded image to linear values")
    mono = fmt in (mi.Bitmap.PixelFormat.Y, mi.Bitmap.PixelFormat.YA)
    target = mi.Bitmap.PixelFormat.Y if mono else mi.Bitmap.PixelFormat.RGB
    lin = bmp.convert(target, mi.Struct.Type.Float32, srgb_gamma=False)
    arr = np.array(lin, dtype=np.float32, copy=True)
    if arr.ndim == 2:
        arr = arr[..., None]
    return arr, ("hdr" if floating else "srgb")


def write_image(path: str, image: np.ndarray, exposure: float = 1.0) -> str:
    """Write ``image`` (linear, (H, W, C)): ``.exr`` as float32 linear values,
    ``.png`` as 8-bit sRGB of ``exposure × image`` (clipped to [0, 1])."""
    import mitsuba as mi
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".exr", ".png"):
        raise CoronaError(f"--out {path!r} has extension {ext or '(none)'!r}; allowed .exr, .png")
    arr = np.ascontiguousarray(image, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    fmt = mi.Bitmap.PixelFormat.Y if arr.shape[2] == 1 else mi.Bitmap.PixelFormat.RGB
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    bmp = mi.Bitmap(arr, fmt)
    if ext == ".exr":
        bmp.write(path)
    else:
        scaled = mi.Bitmap(np.ascontiguousarray(np.clip(arr * exposure, 0.0, 1.0)), fmt)
        scaled.convert(fmt, mi.Struct.Type.UInt8, srgb_gamma=True).write(path)
    return path


def apply_file(image_path: str, out_path: str, fov: float, params: dict | None = None, *,
               colorspace: str = "srgb", srgb_input: bool = False, exposure: float | None = None,
               workers: int | None = None, progress: bool = True) -> dict:
    """``corona post``: read ``image_path``, :func:`apply`, write ``out_path``.

    Returns a dict: ``out``, ``seconds``, ``coherent_transmittance``, ``shape``.
    """
    import time
    import mitsuba  # noqa: F401 - import corona first (the package does) for DRJIT_LIBLLVM_PATH
    t0 = time.perf_counter()
    ext = os.path.splitext(out_path)[1].lower()
    if ext not in (".exr", ".png"):
        raise CoronaError(f"--out {out_path!r} has extension {ext or '(none)'!r}; allowed .exr, .png")
    if os.path.isdir(out_path):
        raise CoronaError(f"--out {out_path!r} is a folder; expected a file path ending in .exr or .png")
    m = layer(**(params or {}))
    img, kind = read_image(image_path, srgb_input=srgb_input)
    out = apply(img, fov, m, colorspace=colorspace, workers=workers, progress=progress)
    write_image(out_path, out, exposure=1.0 if exposure is None else exposure)
    return {"out": out_path, "seconds": time.perf_counter() - t0, "input": kind,
            "coherent_transmittance": float(m.coherent_transmittance), "shape": list(out.shape)}
