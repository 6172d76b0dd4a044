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

How the pinhole is handled (fields of view up to 176°)
------------------------------------------------------
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
the image (at the edges of wide fields).  The grid's step is the pitch at the
centre, which near 180° is not small against the lobe where the frame reaches
the edge of the unit disk: the field is bounded to :data:`FOV_MAX` (176°: the lobe
part within about 3 % per pixel; 11-17 % at 179°).  Pixels wider than 0.01 in ``t`` (about
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
#: Step in u = 2πR d/λ of the table an anisotropic lobe is read from (bilinear error ~1e-3 of
#: the peak for the sinc-like outlines, whose features are ~1 wide in u).
TABLE_STEP_U = 0.05
#: Lobe evaluations per numpy call (bounds the temporaries: ~0.5 GB).
LOBE_CHUNK = 1 << 20
#: Largest number of lobe evaluations an anisotropic kernel may take (about a minute on one core):
#: beyond it (a very large image whose pixels are coarse against the lobe), one line.
ANISOTROPIC_EVALUATIONS_MAX = 100_000_000
#: Nodes within this many steps of the centre are averaged from point samples.
CENTRE_NODES = 4
CENTRE_SAMPLES = 32
CENTRE_SAMPLES_2D = 4
#: Pixels wider than this in the tangent plane (about 0.6°) are cut into sub-pixels ...
PIXEL_PITCH_MAX = 0.01
#: ... up to this many in all.
SUBPIXELS_MAX = 1 << 22
#: Largest |pixel value|: the output is float32 (3.4e38); the pass's sums stay below twice the peak.
IMAGE_MAX = 1e38
#: Largest field of view [degree].  The grid step is the (sub-)pixel pitch at the image centre,
#: and the sub-pixels are capped (SUBPIXELS_MAX), so near 180° the step is not small against the
#: lobe where the frame reaches the edge of the unit disk: a 31x21 white image's lobe part is off by
#: up to 2.8 % per pixel at 176°, 5.5-7 % at 178° and 11-17 % at 179° (9 % of the energy lost)
#: against the frame integral (tests/apps/test_post.py, issue 47 item 13).
FOV_MAX = 176.0


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
    from corona.model.mie.material import SphereMaterial
    if isinstance(material, SphereMaterial):
        from corona.model import registry
        flat = ", ".join(f.name for f in registry.SHAPE_FAMILIES.values() if f.material is None)
        raise CoronaError("shape='sphere' is out of range for corona post: the Mie lobe depends on the "
                          f"scattering angle, not on d alone (render it); allowed {flat}")
    sub = getattr(material, "substrate", None)
    if sub is not None:
        from corona.model.substrate import Mirror
        name = params.get("substrate") or ("mirror" if isinstance(sub, Mirror) else "glass")
        raise CoronaError(f"substrate={name!r} is out of range for corona post: the pane's Fresnel factors "
                          "depend on the angle (render it); allowed substrate='none'")
    return material


def xyz_to_rgb_matrix(colorspace: str) -> np.ndarray:
    """The 3x3 CIE XYZ -> linear RGB matrix of ``colorspace`` ("srgb" or "acescg")."""
    from corona.color import XYZ_TO_SRGB
    from corona._validation import check_choice
    colorspace = check_choice("colorspace", colorspace, COLORSPACES)
    if colorspace == "srgb":
        return XYZ_TO_SRGB
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


def _lobe_v(m, u):
    """The renderer's dimensionless lobe ``v(u)`` at ``u`` (n, 2), in chunks (bounded memory)."""
    out = np.empty(u.shape[0], dtype=np.float64)
    for a in range(0, u.shape[0], LOBE_CHUNK):
        out[a:a + LOBE_CHUNK] = m.render_lobe.eval(u[a:a + LOBE_CHUNK])
    return out


def _interp_matrix(x, nodes_start, step, n_nodes):
    """Sparse (len(x), n_nodes) matrix of linear interpolation at ``x`` between uniform nodes."""
    import scipy.sparse
    f = np.clip((np.asarray(x, dtype=np.float64) - nodes_start) / step, 0.0, n_nodes - 1.0)
    i0 = np.minimum(f.astype(np.int64), n_nodes - 2)
    w = f - i0
    rows = np.repeat(np.arange(x.size), 2)
    cols = np.stack([i0, i0 + 1], -1).ravel()
    data = np.stack([1.0 - w, w], -1).ravel().astype(np.float32)
    return scipy.sparse.csr_matrix((data, (rows, cols)), shape=(x.size, n_nodes))


def _table_nodes(n, h_max):
    """Nodes (step :data:`TABLE_STEP_U`, symmetric about 0) covering ``|u| <= (n - 1) h_max``."""
    half = math.ceil((n - 1) * h_max / TABLE_STEP_U)
    return (np.arange(2 * half + 2) - (half + 0.5)) * TABLE_STEP_U


def _evaluation_weight(m) -> float:
    """Cost of one evaluation of the renderer's lobe in units of a hexagon's (the slowest
    single outline, ~0.7 µs): closed-form outlines cost by their edges (a polygon its vertices,
    the other outlines 2), a mixture the sum over its components; tables cost at most one."""
    if m.render_kind != "analytic":
        return 1.0
    edges = sum(len(t.params["vertices"]) if t.kind == "polygon" else 2 for t in m.analytic_terms)
    return max(1.0, edges / 6.0)


def anisotropic_cost(m, response, nx, ny, step):
    """``(evaluations of the lobe, "table" or "direct")`` the anisotropic kernel of a grid of
    ``ny x nx`` nodes of step ``step`` needs (see :func:`_anisotropic_kernel`), in units of a
    hexagon's evaluation (:func:`_evaluation_weight`)."""
    lams = _quantile_wavelengths(response, N_PER_CHANNEL_2D)
    h_max = 2 * np.pi * m.length_scale * step / (lams.min() * 1e-3)      # u per node at λ_min
    table = _table_nodes(nx, h_max).size * _table_nodes(ny, h_max).size
    direct = len(np.unique(lams)) * (2 * nx - 1) * ny                  # half the grid: v(-u) = v(u)
    weight = _evaluation_weight(m)
    return (table * weight, "table") if table <= direct else (direct * weight, "direct")


def _anisotropic_kernel(m, response, ly, lx, ny, nx, step):
    """Each channel's kernel on the full padded grid (offsets stored circularly): the renderer's
    lobe at each node, tent-weighted samples for the centre nodes.

    A channel's kernel is ``Σ_k w_k F_a (R/λ_k)² v(2πR d/λ_k)``: copies of the one wavelength-free
    lobe ``v(u)`` scaled by ``1/λ_k``.  Where the grid is fine against the lobe (the usual case:
    large images), ``v`` is evaluated once on a table of step :data:`TABLE_STEP_U` in ``u`` that
    covers the grid at the shortest wavelength, and each wavelength's nodes are read from it by
    separable linear interpolation (two sparse products); else ``v`` is evaluated at every node
    of one half of the grid (the other by ``v(-u) = v(u)``) and wavelength.  The cheaper of the
    two is taken (:func:`anisotropic_cost`); beyond :data:`ANISOTROPIC_EVALUATIONS_MAX` the pass
    is refused."""
    weights = response[1]
    lams = _quantile_wavelengths(response, N_PER_CHANNEL_2D)     # (C, n)
    ky = np.arange(-(ny - 1), ny)
    kx = np.arange(-(nx - 1), nx)
    out = np.zeros((weights.shape[0], ly, lx), dtype=np.float32)
    _, how = anisotropic_cost(m, response, nx, ny, step)
    scale = 2 * np.pi * m.length_scale * step                   # u per node = scale / λ [µm]
    if how == "table":
        ux, uy = _table_nodes(nx, scale / (lams.min() * 1e-3)), _table_nodes(ny, scale / (lams.min() * 1e-3))
        V = np.empty((uy.size, ux.size), dtype=np.float32)       # V[iy, ix], built in blocks of rows
        rows = max(1, LOBE_CHUNK // ux.size)
        for a in range(0, uy.size, rows):
            UX, UY = np.meshgrid(ux, uy[a:a + rows])
            V[a:a + rows] = _lobe_v(m, np.stack([UX.ravel(), UY.ravel()], -1)).reshape(UX.shape)
        del UX, UY
    values = {}

    def copy_at(lam):                                            # v(2πR d/λ) on the grid, rows ky
        if lam not in values:
            h = scale / (lam * 1e-3)
            if how == "table":
                ax = _interp_matrix(kx * h, ux[0], TABLE_STEP_U, ux.size)
                ay = _interp_matrix(-ky * h, uy[0], TABLE_STEP_U, uy.size)   # grid rows go down: -y
                values.clear()                                   # keep one copy in memory
                values[lam] = np.asarray(ay @ (ax @ V.T).T, dtype=np.float32)
            else:                                                # rows ky >= 0, the rest by v(-u) = v(u)
                KX, KY = np.meshgrid(kx * h, -ky[ny - 1:] * h)
                half = _lobe_v(m, np.stack([KX.ravel(), KY.ravel()], -1)).reshape(KX.shape).astype(np.float32)
                del KX, KY
                values.clear()
                values[lam] = np.concatenate([half[:0:-1, ::-1], half], axis=0)
        return values[lam]

    x, w = _tent_samples(CENTRE_SAMPLES_2D)
    ww = (w[:, None] * w[None, :]).ravel()
    n = CENTRE_NODES
    for c in range(weights.shape[0]):
        k = np.zeros((ky.size, kx.size), dtype=np.float32)
        for lam in lams[c]:
            k += np.float32(m.lobe_weight * (m.length_scale / (lam * 1e-3)) ** 2) * copy_at(float(lam))
        cy, cx = ny - 1, nx - 1
        for iy in range(-n, n + 1):
            for ix in range(-n, n + 1):
                if abs(iy) >= ny or abs(ix) >= nx:
                    continue
                XX, YY = np.meshgrid((ix + x) * step, -(iy + x) * step)
                dd = np.stack([XX.ravel(), YY.ravel()], -1)
                k[cy + iy, cx + ix] = sum(float(m.lobe_tabulated(dd, float(lam)) @ ww) for lam in lams[c])
        k *= np.float32(step * step / lams.shape[1])
        out[c][np.ix_(np.mod(ky, ly), np.mod(kx, lx))] = k
        del k
    return out


# ----------------------------------------------------------------------
# the pass
# ----------------------------------------------------------------------
def _checked_image(image) -> tuple:
    """``image`` as a float (H, W, C) array with C in {1, 3}, and its peak |value|; a CoronaError
    for any other shape or dtype, a non-finite value or a peak above IMAGE_MAX."""
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
    peak = float(np.max(np.abs(img))) if img.size else 0.0
    if peak > IMAGE_MAX:
        raise CoronaError(f"image has values up to {peak:.3g}; allowed |values| <= {IMAGE_MAX:g} "
                          "(the output is float32)")
    return img, peak


def _kernel_spectra(m, response, grid, shape: tuple, C: int, what: str, workers: int) -> list:
    """The DFT of the lobe kernel of each of the ``C`` channels on the padded ``shape`` = (ly, lx)
    grid: of the even radial quadrant (isotropic lobes) or of the whole kernel; a CoronaError if an
    anisotropic kernel for ``what`` (the image) would take too many lobe evaluations."""
    import scipy.fft
    ly, lx = shape
    if m.isotropic:
        q = _radial_quadrant(m, response, ly // 2 + 1, lx // 2 + 1, grid.ny, grid.nx, grid.step)
        spectra = []
        for c in range(C):
            k = scipy.fft.dctn(q[c], type=1, workers=workers)          # the even kernel's DFT
            spectra.append(np.concatenate([k, k[-2:0:-1]], axis=0))    # rows 0..ly-1
        return spectra
    cost, _ = anisotropic_cost(m, response, grid.nx, grid.ny, grid.step)
    if cost > ANISOTROPIC_EVALUATIONS_MAX:
        raise CoronaError(f"an anisotropic lobe on {what} needs {cost:.3g} lobe "
                          f"evaluations; allowed at most {ANISOTROPIC_EVALUATIONS_MAX:.3g} (about a minute): "
                          "downsample the image or narrow the field of view")
    full = _anisotropic_kernel(m, response, ly, lx, grid.ny, grid.nx, grid.step)
    return [scipy.fft.rfft2(full[c], workers=workers) for c in range(C)]


def _convolved(g, spectra: list, grid, shape: tuple, workers: int, bar) -> np.ndarray:
    """Each channel of the splatted image ``g`` (ny, nx, C) convolved with its kernel (``spectra``,
    zero-padded to ``shape``), one progress step a channel."""
    import scipy.fft
    ly, lx = shape
    conv = np.empty((grid.ny, grid.nx, g.shape[2]), dtype=np.float32)
    for c in range(g.shape[2]):
        f = scipy.fft.rfft2(g[..., c], s=(ly, lx), workers=workers)
        f *= spectra[c]
        conv[..., c] = scipy.fft.irfft2(f, s=(ly, lx), workers=workers)[:grid.ny, :grid.nx]
        del f
        bar.update(1)
    return conv


def apply(image, fov: float, material=None, *, colorspace: str = "srgb", response=None,
          workers: int | None = None, progress: bool = True, **params) -> np.ndarray:
    """The image seen through a uniform layer at the camera (see the module docstring).

    Parameters
    ----------
    image : array (H, W) or (H, W, C), C in {1, 3}
        Linear scene radiance (an HDR render or a linearised photograph) of a
        pinhole camera with square pixels; finite values.
    fov : float
        Horizontal field of view [degree], in (0, 176] (:data:`FOV_MAX`).
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
    from corona._validation import check_range
    m = layer(material, **params)
    fov = check_range("fov", fov, 0.0, FOV_MAX, lo_open=True, unit="degree")
    img, peak = _checked_image(image)
    if workers is None:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    # the pass runs on the image scaled by a power of two to a peak in (1/2, 1] (exact: only
    # the exponents change), so no sum or FFT of huge finite pixels overflows float32
    scale = 2.0 ** math.ceil(math.log2(peak)) if peak > 0 else 1.0
    img = (img / scale).astype(np.float32) if scale != 1.0 else img.astype(np.float32, copy=False)
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
        spectra = _kernel_spectra(m, response, grid, (ly, lx), C, f"a {W}x{H} image at fov={fov:g}", workers)
        bar.update(1)
        tc = np.float32(m.coherent_transmittance)
        g = grid.splat(src)                                                # (ny, nx, C)
        bar.update(1)
        conv = _convolved(g, spectra, grid, (ly, lx), workers, bar)
        del g
        out = grid.gather(conv)
        if k_sub > 1:
            out = out.reshape(H, k_sub, W, k_sub, C).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)
        out += tc * img
        if scale != 1.0:
            out *= np.float32(scale)
        bar.update(1)
    if not np.all(np.isfinite(out)):     # never written: a bug, not an input, if it ever happens
        raise CoronaError("corona post produced non-finite values; nothing written (please report it)")
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
    if bmp.pixel_format() == mi.Bitmap.PixelFormat.MultiChannel:
        bmp = _main_layer(bmp, path)
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


def _main_layer(bmp, path):
    """The main layer of a multichannel image (an EXR with AOVs: ``R, G, B, A, albedo.R, ...``):
    its unnamed layer of colour (``R, G, B`` or ``Y``), or one line naming the layers found."""
    import mitsuba as mi
    try:
        layers = dict(bmp.split())
    except Exception:  # noqa: BLE001 - Mitsuba raises RuntimeError for channel names it cannot group
        layers = {}
    colour = (mi.Bitmap.PixelFormat.RGB, mi.Bitmap.PixelFormat.RGBA, mi.Bitmap.PixelFormat.Y,
              mi.Bitmap.PixelFormat.YA)
    main = layers.get("<root>")
    if main is not None and main.pixel_format() in colour:
        return main
    struct = bmp.struct_()
    names = ", ".join(struct[i].name for i in range(len(struct)))
    raise CoronaError(f"image {path!r} has channels {names} and no main R, G, B (or Y) layer; allowed an "
                      "image whose unnamed channels are R, G, B or Y (other layers, e.g. AOVs, are ignored)")


def write_image(path: str, image: np.ndarray, exposure: float | None = None) -> str:
    """Write ``image`` (linear, (H, W, C)): ``.exr`` as float32 linear values,
    ``.png`` as 8-bit sRGB by :func:`corona.apps.pictures.display_srgb` (``exposure`` scales the
    linear values; None: the glow around the lamps maps to 1, as ``corona render``)."""
    import mitsuba as mi
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".exr", ".png"):
        raise CoronaError(f"--out {path!r} has extension {ext or '(none)'!r}; allowed .exr, .png")
    arr = np.ascontiguousarray(image, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    fmt = mi.Bitmap.PixelFormat.Y if arr.shape[2] == 1 else mi.Bitmap.PixelFormat.RGB
    if not np.all(np.isfinite(arr)):
        raise CoronaError(f"--out {path!r}: the image holds non-finite values; nothing written")
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    bmp = mi.Bitmap(arr, fmt)
    if ext == ".exr":
        bmp.write(path)
    else:
        from corona.apps.pictures import display_srgb
        mi.Bitmap(np.ascontiguousarray(display_srgb(arr, exposure)), fmt).write(path)
    return path


def check_writable(path: str) -> None:
    """One line, before any work, if ``path`` cannot be written: its folder (or the nearest
    existing folder above it, where it would be created) must accept a new file, and an
    existing file must be writable.  A folder is probed by creating and removing a temporary
    file in it (permission bits do not stop root; a read-only mount or sysfs does)."""
    import tempfile
    target = os.path.abspath(path)
    folder = os.path.dirname(target)
    probe = folder
    while not os.path.exists(probe):
        probe = os.path.dirname(probe)
    if not os.path.isdir(probe):
        raise CoronaError(f"--out {path!r}: {probe!r} is not a folder")
    why = None
    if os.path.exists(target) and not os.access(target, os.W_OK):
        why = "the file is read-only"
    elif not os.access(probe, os.W_OK | os.X_OK):
        why = "the folder is not writable"
    else:
        try:
            fd, name = tempfile.mkstemp(prefix=".corona-post-", dir=probe)
            os.close(fd)
            os.unlink(name)
        except OSError as err:
            why = f"the folder is not writable ({err.strerror or err})"
    if why:
        where = folder if probe == folder else f"{probe} (to create {folder})"
        raise CoronaError(f"--out {path!r} cannot be written: {why}: {where}; allowed a path in a writable folder")


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
    check_writable(out_path)
    m = layer(**(params or {}))
    img, kind = read_image(image_path, srgb_input=srgb_input)
    out = apply(img, fov, m, colorspace=colorspace, workers=workers, progress=progress)
    try:
        write_image(out_path, out, exposure=exposure)
    except (OSError, RuntimeError) as err:    # Mitsuba raises RuntimeError with a traceback text
        text = str(err).strip().splitlines()
        why = err.strerror if isinstance(err, OSError) and err.strerror else (text[-1] if text else repr(err))
        raise CoronaError(f"--out {out_path!r} cannot be written: {why}") from None
    return {"out": out_path, "seconds": time.perf_counter() - t0, "input": kind,
            "coherent_transmittance": float(m.coherent_transmittance), "shape": list(out.shape)}
