"""From a photograph of a corona to a material: ``corona fit`` (the inverse problem).

A bright light seen through a layer of scatterers (a fogged window, a dusted
slide, thin cloud) is surrounded by coloured rings whose angular radii scale
as ``λ / R``.  :func:`fit_photograph` reads the scatterer radius, size spread
and area fraction (and the light's colour temperature) off such a photograph:

1. **Image.**  8-/16-bit sRGB images (PNG, JPEG, TIFF ...) are decoded to
   linear values with the sRGB transfer curve (IEC 61966-2-1); EXR/HDR/PFM
   files are taken as linear sRGB.  Pixels with a clipped channel are
   *saturated* and never used.
2. **Camera.**  A pinhole camera with the principal point at the image centre
   and the horizontal field of view ``fov_deg`` (or ``deg_per_pixel`` at the
   centre): pixel ``(x, y)`` looks along ``r ∝ ((x - c_x)/f, (y - c_y)/f, 1)``.
3. **Source.**  The light is the largest blob of saturated pixels (the
   centroid of the blob: sub-pixel, and the clipped core cannot bias it), or,
   when nothing is clipped, the luminance-weighted centroid of the region above
   half the (lightly smoothed) peak.
4. **Profile.**  With the layer parallel to the sensor (a window facing the
   camera), the lobe depends on ``ρ = |d| = |(w_o + w_i).xy| = |r.xy - s.xy|``
   exactly (``s`` the unit vector toward the source; docs/physics.md, the
   projected offset), whatever the pixel's position in the frame.  Pixels are
   binned in ``ρ`` (one pixel wide) and in azimuthal sectors, with the
   saturated pixels (dilated by a pixel) and the source's own disk masked.
   The mean over all sectors is the profile; the scatter between sectors
   gives each bin's uncertainty.
5. **Model.**  For a point source of spectrum ``B(λ, T)`` (Planck) the image
   is ``I_c(ρ) = a Σ_λ M_c(λ) B(λ, T) F_a (R/λ)² v(2π R ρ / λ) + b_c`` with
   ``v(u) = [P + C (S - 1)] / R²`` the material's dimensionless radial lobe
   (:meth:`corona.Material.lobe_dimensionless_radial`), ``M_c`` the CIE 1931 →
   linear sRGB weights (:func:`corona.color.spectrum_to_linear_srgb`), ``a``
   the exposure and ``b_c`` a background.  ``v`` does not depend on ``R``, so
   it is computed once per (size spread, area fraction) and scaled; a source
   of angular diameter ``source_diameter_deg`` is a uniform disk in ``d``
   convolved with the profile.  For 8-/16-bit images the model is clipped at
   0 like the data.
6. **Fit.**  A coarse search over the radius (2.5 % steps), a few spreads and
   temperatures picks the ring branch; :func:`scipy.optimize.least_squares`
   refines (ln R, spread, F_a, 1000/T) from the best few starts, with the
   exposure and backgrounds solved linearly (non-negative) at every step
   (variable projection).  Uncertainties are the covariance
   ``(JᵀJ)⁻¹ · max(1, χ²/ν)`` of the weighted residuals, or with
   ``bootstrap=N`` the spread of N refits to profiles resampled over the
   azimuthal sectors.

The area fraction acts on the profile only through the structure factor
(the overall brightness is the unknown exposure), i.e. near the aureole and
the first dark ring; where that part is saturated or masked it is poorly
constrained, and the result says so (``area_fraction_constrained``).

Only circular scatterers (``shape="circle"``) are fitted today; the layer
models are looked up in :data:`FIT_SHAPES`, where transparent spheres (Mie)
will be added.

References
----------
L. Cowley, *Atmospheric Optics*, "Corona — effects of droplet sizes"
(atoptics.co.uk/droplets/cordrsz.htm): droplet diameter [µm] ≈ 250 / (the
red first ring's diameter in moon diameters) — the rule of thumb reported as
``rule_of_thumb_diameter``.
P. Laven, "Simulation of rainbows, coronas and glories using Mie theory and
the Debye series", J. Quant. Spectrosc. Radiat. Transfer 89, 257 (2004).
G. H. Golub, V. Pereyra, "Separable nonlinear least squares: the variable
projection method and its applications", Inverse Problems 19, R1 (2003).
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
import warnings

import numpy as np

from corona._validation import CoronaError, check_choice, check_range
from corona.model.layer import decoupled_lobe

#: The moon's mean angular diameter [degree] (the unit of Cowley's rule of thumb).
MOON_DIAMETER_DEG = 0.52
#: Cowley's rule of thumb: droplet diameter [µm] × red first ring diameter [moon diameters].
RED_RING_RULE = 250.0
#: Azimuthal sectors of the profile (noise estimate, bootstrap).
N_SECTORS = 16
#: Processes whose structure factor is radial (the ones a profile can fit).
FIT_PROCESSES = ("hard-disk", "rsa", "poisson")
#: Modes of the layer (the lobe is the same by Babinet's principle; only the XML differs).
FIT_MODES = ("particle", "aperture")
#: Largest area fraction tried per process (hard-disk table limit, RSA jamming).
AREA_FRACTION_MAX = {"hard-disk": 0.6, "rsa": 0.53, "poisson": 0.95}
#: A refined start with χ²/ν below this ends the search over ring branches.
GOOD_FIT_CHI2 = 2.0
#: The fitted area fraction is reported as constrained when its error is below this.
AREA_FRACTION_CONSTRAINED_ERR = 0.1
TEMPERATURE_RANGE = (1500.0, 20000.0)
SIZE_SPREAD_MAX = 0.5
#: Largest photograph fitted [pixels] (width × height; the designer's upload limit too): the fit
#: holds a few float64 copies of the image, about 100 bytes a pixel at its peak.
MAX_PIXELS = 40_000_000


# ----------------------------------------------------------------------
# the image
# ----------------------------------------------------------------------
@dataclasses.dataclass
class Photograph:
    """An image in linear values.

    Attributes
    ----------
    linear : ndarray (H, W, C)
        Linear sRGB (C = 3) or linear luminance (C = 1), float64.
    saturated : ndarray (H, W) of bool
        Pixels with a clipped (or non-finite) channel.
    encoding : {"srgb", "linear"}
        "srgb": integer data decoded with the sRGB curve (clipped at 0 and at
        the top code); "linear": floating-point data.
    name : str
        The file name, or "array".
    black : ndarray (H, W, C) of bool, optional
        Channels clipped at black (code 0 of integer data).
    """

    linear: np.ndarray
    saturated: np.ndarray
    encoding: str
    name: str = "array"
    black: np.ndarray | None = None

    @property
    def shape(self):
        return self.linear.shape[:2]


def srgb_to_linear(v) -> np.ndarray:
    """Inverse sRGB transfer curve (IEC 61966-2-1) of encoded values in [0, 1]."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _check_pixels(name: str, w: int, h: int) -> None:
    """One line when a ``w`` × ``h`` image is above :data:`MAX_PIXELS`."""
    if w * h > MAX_PIXELS:
        raise CoronaError(f"image {name!r} is {w}x{h} pixels ({w * h / 1e6:.0f} Mpixel); the fit takes at "
                          f"most {MAX_PIXELS} pixels ({MAX_PIXELS / 1e6:.0f} Mpixel): downsample it first "
                          "(the rings need a few pixels each, not the full resolution)")


def _check_saturation(saturation) -> float | None:
    """``saturation``: None or a finite linear value > 0."""
    if saturation is None:
        return None
    if isinstance(saturation, (bool, np.bool_)):
        raise CoronaError(f"saturation={saturation!r} is not a number")
    try:
        v = float(saturation)
    except (TypeError, ValueError):
        raise CoronaError(f"saturation={saturation!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise CoronaError(f"saturation={saturation!r} is out of range; allowed a finite linear value > 0")
    return v


def _header_size(path: str) -> tuple[int, int] | None:
    """(width, height) from an image file's header (Pillow reads no pixels), None if Pillow
    cannot tell; a header past Pillow's decompression-bomb limit is refused as too large."""
    try:
        from PIL import Image
    except ImportError:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")       # DecompressionBombWarning: we decide below
            with Image.open(path) as im:
                return int(im.size[0]), int(im.size[1])
    except Image.DecompressionBombError as err:
        raise CoronaError(f"image {path!r} is larger than {MAX_PIXELS} pixels ({' '.join(str(err).split())[:80]}); "
                          "downsample it first") from None
    except Exception:  # noqa: BLE001 - not for Pillow: the reader below decides
        return None


def _from_array(a, name: str, jpeg: bool = False, saturation: float | None = None) -> Photograph:
    a = np.asarray(a)
    if a.ndim in (2, 3):
        _check_pixels(name, int(a.shape[1]), int(a.shape[0]))
    if a.ndim == 3 and a.shape[2] in (2, 4):        # drop alpha
        a = a[..., :-1]
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3):
        raise CoronaError(f"image {name!r} has shape {a.shape}; expected (height, width), "
                          "(height, width, 3) or with an alpha channel")
    h, w = a.shape[:2]
    if min(h, w) < 16:
        raise CoronaError(f"image {name!r} is {w}x{h} pixels; the fit needs at least 16x16")
    if a.dtype.kind in "ui":
        top = 255 if a.dtype.itemsize == 1 else 65535
        if a.max() > top:
            top = int(np.iinfo(a.dtype).max)
        # clipped codes: the top code (JPEG blurs it: a few codes below too)
        clip = top * (1.0 - (5.0 if jpeg else 1.0) / 255.0)
        sat = np.any(a >= clip, axis=-1)
        lut = srgb_to_linear(np.arange(top + 1) / top)          # decode by table lookup
        return Photograph(lut[np.clip(a, 0, top)], sat, "srgb", name, black=(a <= 0))
    if a.dtype.kind != "f":
        raise CoronaError(f"image {name!r} has pixel type {a.dtype}; expected integers or floats")
    lin = a.astype(np.float64)
    sat = ~np.all(np.isfinite(lin), axis=-1)
    lin = np.where(np.isfinite(lin), lin, 0.0)
    if saturation is not None:
        sat |= np.any(lin >= saturation, axis=-1)
    else:
        # a clipped linear image: the channel maximum shared by several pixels
        for c in range(lin.shape[2]):
            top = lin[..., c].max()
            at_top = lin[..., c] >= top
            if top > 0 and at_top.sum() >= max(3, 1e-4 * h * w):
                sat |= at_top
    return Photograph(lin, sat, "linear", name)


def read_photograph(image, saturation: float | None = None) -> Photograph:
    """The photograph ``image`` (a file name or an array) in linear values.

    Parameters
    ----------
    image : str, os.PathLike or ndarray
        A file (``.exr``, ``.hdr``, ``.pfm``: linear sRGB, read by Mitsuba's
        ``Bitmap``; anything else through imageio, integer data taken as sRGB)
        or an array: integers = sRGB-encoded, floats = linear.
    saturation : float, optional
        Linear value at and above which a floating-point image is clipped
        (default: a channel's maximum shared by several pixels); finite, > 0.

    An image of more than :data:`MAX_PIXELS` pixels is refused with one line
    (for files, from the header, before the pixels are decoded).
    """
    if isinstance(image, Photograph):
        return image
    saturation = _check_saturation(saturation)
    if isinstance(image, (str, os.PathLike)):
        path = os.fspath(image)
        if not os.path.isfile(path):
            raise CoronaError(f"image {path!r} does not exist")
        ext = os.path.splitext(path)[1].lower()
        if ext not in (".exr", ".hdr", ".pfm", ".rgbe"):
            size = _header_size(path)
            if size is not None:
                _check_pixels(path, *size)
        try:
            if ext in (".exr", ".hdr", ".pfm", ".rgbe"):
                import mitsuba as mi
                bmp = mi.Bitmap(path)
                if bmp.channel_count() not in (1, 2, 3, 4):
                    raise ValueError(f"{bmp.channel_count()} channels")
                # width()/height(), not size(): size() returns a variant-specific vector
                # that Mitsuba cannot hand to Python before a variant is set (the CLI)
                w, h = int(bmp.width()), int(bmp.height())
                if w * h > MAX_PIXELS:
                    del bmp
                    _check_pixels(path, w, h)
                data = np.array(bmp, dtype=np.float32)
            else:
                import imageio.v3 as iio
                with warnings.catch_warnings():   # imageio's legacy plugins warn while probing
                    warnings.simplefilter("ignore")
                    data = iio.imread(path)
        except CoronaError:
            raise
        except Exception as err:   # imageio / Mitsuba raise many kinds of errors
            msg = " ".join(str(err).split())[:120]
            raise CoronaError(f"image {path!r} is not an image file that can be read ({msg})") from None
        if data.ndim == 4:   # animated formats: the first frame
            data = data[0]
        return _from_array(data, path, jpeg=ext in (".jpg", ".jpeg"), saturation=saturation)
    try:
        arr = np.asarray(image)
    except Exception:
        arr = None
    if arr is None or arr.dtype.kind not in "uif":
        raise CoronaError(f"image={type(image).__name__} is not an image (a file name or a numeric array)")
    return _from_array(arr, "array", saturation=saturation)


def luminance(photo: Photograph) -> np.ndarray:
    """Linear luminance (Rec. 709 / sRGB weights) of the photograph."""
    lin = photo.linear
    if lin.shape[2] == 1:
        return lin[..., 0]
    return lin @ np.array([0.2126, 0.7152, 0.0722])


# ----------------------------------------------------------------------
# the camera
# ----------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera: principal point at the image centre, square pixels.

    Pixel ``(x, y)`` (pixel centres at ``i + 0.5``) looks along
    ``((x - c_x)/f, (y - c_y)/f, 1)`` normalised, with ``f`` the focal length
    in pixels: ``f = (W/2) / tan(fov/2)`` for a horizontal field of view, or
    ``f = 1 / tan(deg_per_pixel)`` (the angle of one pixel at the centre).
    """

    width: int
    height: int
    focal: float

    @classmethod
    def from_field_of_view(cls, width: int, height: int, fov_deg: float | None = None,
                           deg_per_pixel: float | None = None) -> "PinholeCamera":
        if (fov_deg is None) == (deg_per_pixel is None):
            raise CoronaError("give the camera's horizontal field of view (fov_deg, --fov DEG) "
                              "or its scale (deg_per_pixel, --deg-per-pixel DEG), exactly one")
        if fov_deg is not None:
            fov = check_range("fov", fov_deg, 0.0, 180.0, lo_open=True, hi_open=True, unit="degree")
            return cls(width, height, 0.5 * width / math.tan(math.radians(0.5 * fov)))
        hi = 180.0 / width
        dpp = check_range("deg_per_pixel", deg_per_pixel, 0.0, hi, lo_open=True, hi_open=True,
                          unit=f"degree (the {width}-pixel width must span less than 180 degree)")
        return cls(width, height, 1.0 / math.tan(math.radians(dpp)))

    @property
    def centre(self):
        return 0.5 * self.width, 0.5 * self.height

    @property
    def fov_deg(self) -> float:
        return 2.0 * math.degrees(math.atan(0.5 * self.width / self.focal))

    @property
    def deg_per_pixel(self) -> float:
        return math.degrees(math.atan(1.0 / self.focal))

    def directions(self, x, y) -> np.ndarray:
        """Unit view vectors (..., 3) of image points ``(x, y)`` [pixels]."""
        cx, cy = self.centre
        v = np.stack(np.broadcast_arrays((np.asarray(x, float) - cx) / self.focal,
                                         (np.asarray(y, float) - cy) / self.focal, 1.0), -1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def pixels(self, directions) -> tuple[np.ndarray, np.ndarray]:
        """Image points (x, y) of view vectors (..., 3) with z > 0."""
        d = np.asarray(directions, dtype=np.float64)
        cx, cy = self.centre
        return cx + self.focal * d[..., 0] / d[..., 2], cy + self.focal * d[..., 1] / d[..., 2]


# ----------------------------------------------------------------------
# the light source
# ----------------------------------------------------------------------
@dataclasses.dataclass
class LightSource:
    """Where the light is: centroid (x, y) [pixels], its core's pixels, whether it is clipped."""

    x: float
    y: float
    core: np.ndarray          # (H, W) bool: the blob that locates the source
    saturated: bool
    peak: float               # linear luminance at the peak (of the clipped values when clipped)


def locate_source(photo: Photograph) -> LightSource:
    """Find the light: the largest saturated blob's centroid, else the half-maximum region's.

    Raises one :class:`corona.CoronaError` when the image is saturated nearly
    everywhere, has no bright compact source, or the source touches the border.
    """
    from scipy import ndimage
    h, w = photo.shape
    sat = photo.saturated
    frac = float(sat.mean())
    if frac > 0.5:
        raise CoronaError(f"image {photo.name!r} is saturated in {100 * frac:.0f} % of its pixels "
                          "(allowed < 50 %); nothing to fit — take it with a shorter exposure")
    lum = luminance(photo)
    if sat.any():
        labels, n = ndimage.label(sat)
        sizes = np.bincount(labels.ravel())[1:]
        core = labels == (1 + int(np.argmax(sizes)))
        peak, clipped = float(lum[core].max()), True
        background = float(np.median(lum[~sat]))
        # a clipped blob is only a light source if it stands out from the rest
        if peak <= 4.0 * max(background, 0.0) or core.mean() > 0.25:
            raise CoronaError(f"image {photo.name!r}: no bright light source found (the clipped "
                              f"region is not a compact spot brighter than the rest of the picture)")
        # centroid of the blob and its rim, each pixel weighted by how close it is
        # to clipping (1 when clipped): the partly bright rim pixels carry the
        # sub-pixel position that the clipped core has lost
        rim = ndimage.binary_dilation(core, iterations=2)
        top = photo.linear.max(-1)
        floor = float(np.median(top[~sat]))
        wgt = np.clip((top - floor) / max(float(top[core].min()) - floor, 1e-300), 0.0, 1.0)
        wgt = np.where(rim, wgt, 0.0)
        yy, xx = np.mgrid[:h, :w]
        x = float((wgt * (xx + 0.5)).sum() / wgt.sum())
        y = float((wgt * (yy + 0.5)).sum() / wgt.sum())
    else:
        smooth = ndimage.gaussian_filter(lum, 1.0)
        iy, ix = np.unravel_index(int(np.argmax(smooth)), smooth.shape)
        peak = float(smooth[iy, ix])
        med = float(np.median(smooth))
        mad = float(np.median(np.abs(smooth - med)))
        if not (peak > 0 and peak > 10.0 * max(med, 0.0) and peak > med + 30.0 * mad):
            raise CoronaError(f"image {photo.name!r}: no bright light source found (peak luminance "
                              f"{peak:.3g} vs. median {med:.3g}; the light must stand out)")
        labels, _ = ndimage.label(smooth >= 0.5 * peak)
        core = labels == labels[iy, ix]
        if core.mean() > 0.25:
            raise CoronaError(f"image {photo.name!r}: no bright light source found (the brightest "
                              "region is not a compact spot)")
        wgt = np.where(core, lum - 0.5 * peak, 0.0)
        wgt = np.maximum(wgt, 0.0)
        if wgt.sum() <= 0:
            wgt = core.astype(float)
        yy, xx = np.mgrid[:h, :w]
        x = float((wgt * (xx + 0.5)).sum() / wgt.sum())
        y = float((wgt * (yy + 0.5)).sum() / wgt.sum())
        clipped = False
    ys, xs = np.nonzero(core)
    if xs.min() == 0 or ys.min() == 0 or xs.max() == w - 1 or ys.max() == h - 1:
        raise CoronaError(f"image {photo.name!r}: the light source at pixel ({x:.0f}, {y:.0f}) touches the "
                          "image border; the fit needs the light inside the frame with the corona around it")
    return LightSource(float(x), float(y), core, clipped, peak)


# ----------------------------------------------------------------------
# the azimuthal profile
# ----------------------------------------------------------------------
@dataclasses.dataclass
class Profile:
    """The azimuthally averaged image around the source, in ``ρ = |d|``.

    Attributes
    ----------
    rho : (n,) mean ``|d|`` of each bin's pixels
    value : (C, n) mean linear value per channel
    sigma : (C, n) uncertainty of ``value``
    usable : (C, n) bool: False where too many of the bin's pixels are clipped
        at black in that channel (the mean would be biased)
    count : (n,) pixels per bin
    sector_sum : (S, C, n), sector_count : (S, n) the same per azimuthal sector
    rho_mask : radius of the masked source disk in ``|d|``
    bin_width : width of a bin in ``|d|`` (one pixel at the image centre)
    """

    rho: np.ndarray
    value: np.ndarray
    sigma: np.ndarray
    usable: np.ndarray
    count: np.ndarray
    sector_sum: np.ndarray
    sector_count: np.ndarray
    rho_mask: float
    bin_width: float

    @property
    def angle_deg(self) -> np.ndarray:
        return np.degrees(np.arcsin(np.minimum(self.rho, 1.0)))

    def resampled(self, sectors) -> np.ndarray:
        """The mean profile (C, n) of the given sectors (indices, repeats allowed)."""
        s = self.sector_sum[sectors].sum(0)
        c = self.sector_count[sectors].sum(0)
        return np.where(c > 0, s / np.maximum(c, 1), self.value)


#: A bin is dropped when more than this fraction of its pixels is saturated (the
#: unsaturated rest would be biased low); a channel of a bin is not used when more
#: than this fraction is clipped at black (its mean would be biased high).
CLIPPED_FRACTION_MAX = 0.02


def _sigma_floor(value, encoding):
    """Model-error floor of a bin's uncertainty: 1 % of the value, and for
    integer images a tenth of a code step at black (1/255 decoded / 12.92)."""
    floor = 0.01 * np.abs(value)
    if encoding == "srgb":
        floor = np.hypot(floor, 0.1 / 255.0 / 12.92)
    return floor


def azimuthal_profile(photo: Photograph, camera: PinholeCamera, source: LightSource,
                      source_radius: float = 0.0, n_sectors: int = N_SECTORS) -> Profile:
    """Bin the unsaturated pixels around ``source`` in ``ρ = |r.xy - s.xy|`` and azimuth.

    ``source_radius`` is the source's angular radius as ``|d|`` (sin of the
    angle); the disk it covers and the source's core blob are masked, and
    every saturated pixel with its neighbours.  Bins where more than
    :data:`CLIPPED_FRACTION_MAX` of the pixels are saturated are dropped, and a
    channel is not used in bins where more than that fraction is clipped at
    black: clipping biases the mean of the rest.
    """
    from scipy import ndimage
    h, w = photo.shape
    s = camera.directions(source.x, source.y)
    yy, xx = np.mgrid[:h, :w]
    r = camera.directions(xx + 0.5, yy + 0.5)
    dx, dy = r[..., 0] - s[0], r[..., 1] - s[1]
    rho = np.hypot(dx, dy)
    bin_width = 1.0 / camera.focal
    rho_core = float(rho[source.core].max()) if source.core.any() else 0.0
    rho_mask = max(rho_core, source_radius) + 1.5 * bin_width
    outside = rho >= rho_mask
    k = np.floor((rho - rho_mask) / bin_width).astype(np.int64)
    bad = ndimage.binary_dilation(photo.saturated, iterations=1) | source.core
    valid = ~bad & outside
    if not valid.any():
        raise CoronaError(f"image {photo.name!r}: no unsaturated pixels around the light source")
    n = int(k[valid].max()) + 1
    ring = outside & (k < n)
    n_all = np.bincount(k[ring], minlength=n)
    n_sat = np.bincount(k[ring & photo.saturated], minlength=n)
    phi = np.arctan2(dy, dx)
    sec = np.minimum(((phi + np.pi) / (2 * np.pi) * n_sectors).astype(np.int64), n_sectors - 1)
    idx = (sec * n + k)[valid]
    size = n_sectors * n
    counts = np.bincount(idx, minlength=size).reshape(n_sectors, n).astype(np.float64)
    lin = photo.linear[valid]
    C = lin.shape[1]
    sums = np.stack([np.bincount(idx, weights=lin[:, c], minlength=size).reshape(n_sectors, n)
                     for c in range(C)], 1)                          # (S, C, n)
    rho_sum = np.bincount(idx, weights=rho[valid], minlength=size).reshape(n_sectors, n).sum(0)
    count = counts.sum(0)
    covered = (counts > 0).sum(0)
    keep = ((count >= 3) & (covered >= max(3, n_sectors // 2))
            & (n_sat <= CLIPPED_FRACTION_MAX * n_all))
    if photo.black is not None:
        kb = k[valid]
        bv = photo.black[valid]
        black = np.stack([np.bincount(kb, weights=bv[:, c], minlength=n) for c in range(C)])
        usable = black <= CLIPPED_FRACTION_MAX * np.maximum(count, 1)
    else:
        usable = np.ones((C, n), dtype=bool)
    keep &= usable.any(0)
    if keep.sum() < 12:
        raise CoronaError(f"image {photo.name!r}: too little of the corona is visible around the light "
                          f"({int(keep.sum())} usable rings of pixels; the fit needs at least 12 that are "
                          "neither saturated nor black)")
    counts, sums, count, covered = counts[:, keep], sums[..., keep], count[keep], covered[keep]
    value = sums.sum(0) / count
    # uncertainty of the mean from the scatter between the sectors (weighted by their pixels)
    with np.errstate(invalid="ignore", divide="ignore"):
        sec_mean = sums / counts[:, None, :]
    dev = np.where(counts[:, None, :] > 0, sec_mean - value[None], 0.0)
    var = (counts[:, None, :] * dev**2).sum(0) / count                # per-pixel-weighted spread
    sigma_sec = np.sqrt(var / np.maximum(covered - 1, 1))
    sigma = np.hypot(sigma_sec, _sigma_floor(value, photo.encoding))
    return Profile(rho_sum[keep] / count, value, sigma, usable[:, keep], count, sums, counts,
                   rho_mask, bin_width)


# ----------------------------------------------------------------------
# the forward model
# ----------------------------------------------------------------------
class CircleLayer:
    """The radial lobe of a layer of circular scatterers (any radial process).

    ``lobe(ρ, λ) = F_a (R/λ)² v(u)``, ``u = 2π R ρ / λ``, with
    ``v(u) = max(P + C (S - 1), 0) / R²`` (:func:`corona.model.layer.decoupled_lobe`) exactly as
    :meth:`corona.Material.lobe_dimensionless_radial` (``P``, ``C`` the form
    factors of the size-distributed circle, :class:`corona.SizeDistribution`;
    ``S`` the structure factor of the process).  ``v`` does not depend on
    ``R``, so it is tabulated on a grid in ``u`` — uniform (step 0.04) where
    rings can be sharp, geometric (ratio 1.01) beyond ``u = max(40, 5/spread)``
    where the size spread has washed them out — and interpolated linearly.

    The size average is the expensive part; while fitting (``exact=False``)
    ``P`` and ``C`` are computed at nodes ``spread = k h`` (``h`` about
    ``0.2/u_max``, at most 0.01) and interpolated between the four nearest by a
    cubic (Lagrange), so that small steps in the spread reuse the nodes.

    This is the extension point of ``--shape``: another layer model (e.g.
    transparent spheres, whose lobe is not a function of ``u`` alone) provides
    the same ``lobe``, ``set_u_max`` and ``parameters``.
    """

    name = "circle"
    R_REF = 10.0   # µm: v(u) does not depend on it
    DU = 0.04
    RATIO = 1.01
    H_FACTOR = 0.5  # spread nodes every H_FACTOR / u_max

    def __init__(self, process: str = "hard-disk"):
        self.process = check_choice("process", process, FIT_PROCESSES)
        self._cache: dict = {}
        self.u_max = 0.0

    def set_u_max(self, u_max: float) -> None:
        """Tabulate ``v`` up to ``u_max`` from now on (clears the tables when it grows)."""
        if u_max > self.u_max or u_max < 0.5 * self.u_max:
            self.u_max = float(u_max)
            self._cache.clear()

    def _shape(self, spread: float):
        from corona.model.shapes import Circle, SizeDistribution
        c = Circle(self.R_REF)
        return SizeDistribution(c, spread) if spread > 0 else c

    def _process(self, area_fraction: float):
        from corona.model.processes import HardDisk, Poisson, SequentialAdsorption
        return {"hard-disk": HardDisk, "rsa": SequentialAdsorption, "poisson": Poisson}[self.process](area_fraction)

    def _grid(self, spread: float) -> np.ndarray:
        u_max = self.u_max
        u1 = u_max if spread <= 0 else min(u_max, max(40.0, 5.0 / spread))
        u = np.arange(0.0, u1 + self.DU, self.DU)
        if u[-1] < u_max:
            m = int(math.ceil(math.log(u_max / u[-1]) / math.log(self.RATIO)))
            u = np.concatenate([u, u[-1] * self.RATIO ** np.arange(1, m + 1)])
        return u

    def _form_factors(self, spread: float, grid_spread: float):
        """P/R², C/R² at spread ``spread`` on the grid of ``grid_spread`` (cached)."""
        key = ("PC", round(spread, 12), round(grid_spread, 12))
        if key not in self._cache:
            q = self._grid(grid_spread) / self.R_REF
            shape = self._shape(spread)
            self._cache[key] = (shape.form_factor_radial(q) / self.R_REF**2,
                                shape.coherent_form_factor_radial(q) / self.R_REF**2)
        return self._cache[key]

    def table(self, spread: float, area_fraction: float, exact: bool = True):
        """(u, v(u)) for ``u <= u_max`` (see :meth:`set_u_max`)."""
        key = (round(spread, 12), round(area_fraction, 12), exact)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        if len(self._cache) > 256:
            self._cache.clear()
        h = min(0.01, self.H_FACTOR / self.u_max)
        k = int(spread / h)
        if exact or abs(spread - k * h) < 1e-12:
            u = self._grid(spread)
            P, C = self._form_factors(spread, spread)
        else:
            nodes = np.arange(max(k - 1, 0), max(k - 1, 0) + 4) * h
            u = self._grid(nodes[0])                          # one grid for the four nodes
            P = C = 0.0
            for j, sj in enumerate(nodes):
                lj = np.prod([(spread - nodes[i]) / (sj - nodes[i]) for i in range(4) if i != j])
                Pj, Cj = self._form_factors(sj, nodes[0])
                P = P + lj * Pj
                C = C + lj * Cj
        shape = self._shape(spread)
        proc = self._process(area_fraction)
        proc.validate(shape)
        S = proc.structure_factor_radial(u / self.R_REF, shape)
        v = decoupled_lobe(P, C, S)     # P, C already divided by R²
        self._cache[key] = (u, v)
        return u, v

    def lobe(self, rho, wavelengths, radius: float, spread: float, area_fraction: float,
             exact: bool = True) -> np.ndarray:
        """``F_a (R/λ)² v(2π R ρ/λ)`` at ``rho`` (n,) and ``wavelengths`` (m,) [nm]: (m, n)."""
        lam = np.asarray(wavelengths, dtype=np.float64)[:, None] * 1e-3
        rho = np.asarray(rho, dtype=np.float64)[None, :]
        u = 2.0 * np.pi * radius * rho / lam
        if u.max() > self.u_max:
            self.set_u_max(1.25 * float(u.max()))
        ug, vg = self.table(spread, area_fraction, exact)
        return area_fraction * (radius / lam) ** 2 * np.interp(u, ug, vg)

    def parameters(self, radius, spread, area_fraction, mode) -> dict:
        """The layer as :func:`corona.parameters.material_from_parameters` arguments."""
        return {"shape": "circle", "radius": float(radius), "size_spread": float(spread),
                "area_fraction": float(area_fraction), "process": self.process, "mode": mode}


#: Layer models by ``--shape``; the value for a planned shape is the reason it is missing.
FIT_SHAPES = {"circle": CircleLayer,
              "sphere": "transparent spheres (water droplets, Mie theory) are not available yet; "
                        "fit them as shape='circle' (the diffraction of opaque disks of the same radius)"}


def layer_model(shape: str, process: str):
    """The layer model for ``shape`` (see :data:`FIT_SHAPES`)."""
    shape = check_choice("shape", shape, tuple(FIT_SHAPES))
    model = FIT_SHAPES[shape]
    if isinstance(model, str):
        raise CoronaError(f"shape={shape!r}: {model}")
    return model(process)


class Spectrum:
    """Wavelength samples (uniform in wavenumber, so that ``u ∝ 1/λ`` is
    sampled evenly) and each one's weight in the image's channels."""

    def __init__(self, n: int, channels: int):
        from corona.model import tabulated
        from corona.color import spectrum_to_linear_srgb
        k = np.linspace(1.0 / tabulated.WAVELENGTH_MAX, 1.0 / tabulated.WAVELENGTH_MIN, n)
        self.wavelengths = 1.0 / k[::-1]
        rgb = spectrum_to_linear_srgb(np.eye(n), self.wavelengths).T       # (3, n), dλ included
        if channels == 1:
            rgb = np.array([[0.2126, 0.7152, 0.0722]]) @ rgb
        self.response = rgb

    def weights(self, temperature: float) -> np.ndarray:
        """(C, n): channel response × Planck's spectrum at ``temperature`` [K]."""
        from corona.color import blackbody
        b = blackbody(self.wavelengths, temperature)
        return self.response * (b / b.max())


def _disk_nodes(n_r: int = 5, n_phi: int = 10):
    """Quadrature of the unit disk (uniform weight): Gauss–Legendre in r², midpoints
    in φ over [0, π] (the profile is even in φ)."""
    x, wt = np.polynomial.legendre.leggauss(n_r)
    r = np.sqrt(0.5 * (x + 1.0))
    phi = (np.arange(n_phi) + 0.5) * np.pi / n_phi
    pts = np.stack([np.outer(r, np.cos(phi)).ravel(), np.outer(r, np.sin(phi)).ravel()], -1)
    return pts, np.repeat(0.5 * wt, n_phi) / n_phi


class _Problem:
    """The weighted least-squares problem: profile data vs. the spectral model."""

    def __init__(self, profile: Profile, layer, channels: int, encoding: str,
                 source_radius: float, background: bool):
        self.profile = profile
        self.layer = layer
        self.encoding = encoding
        self.source_radius = source_radius
        self.background = background
        self.channels = channels
        self.exact = True
        self.set_data(profile.value)
        self.spectrum = Spectrum(48, channels)
        self._disk = _disk_nodes() if source_radius > 0.25 * profile.bin_width else None

    def set_data(self, value):
        self.data = np.asarray(value)
        # a bin whose pixels are all equal (a noise-free image) has sigma 0: floor it at 1e-6 of the
        # data's scale, so that its weight is large but finite
        floor = 1e-6 * max(float(np.max(np.abs(self.data), initial=0.0)), 1e-30)
        self.w = np.where(self.profile.usable, 1.0 / np.maximum(self.profile.sigma, floor), 0.0)

    def set_wavelengths(self, n: int):
        self.spectrum = Spectrum(int(n), self.channels)

    def shape_model(self, radius, spread, fa, temperature, rho=None) -> np.ndarray:
        """Channel profiles (C, n) before exposure and background."""
        rho = self.profile.rho if rho is None else rho
        W = self.spectrum.weights(temperature)
        lam = self.spectrum.wavelengths
        if self._disk is None:
            return W @ self.layer.lobe(rho, lam, radius, spread, fa, exact=self.exact)
        a = self.source_radius
        pts, wts = self._disk
        grid = np.arange(max(0.0, rho.min() - a), rho.max() + a + self.profile.bin_width,
                         0.5 * self.profile.bin_width)
        prof = W @ self.layer.lobe(grid, lam, radius, spread, fa, exact=self.exact)
        shifted = np.hypot(rho[:, None] + a * pts[None, :, 0], a * pts[None, :, 1])   # (n, k)
        return np.stack([np.interp(shifted, grid, p) @ wts for p in prof])

    def linear_solve(self, m) -> tuple[float, np.ndarray]:
        """Exposure a >= 0 and backgrounds b_c >= 0 minimising the weighted misfit."""
        from scipy.optimize import nnls
        C, n = m.shape
        cols = [(m * self.w).ravel()]
        if self.background:
            for c in range(C):
                e = np.zeros((C, n))
                e[c] = self.w[c]
                cols.append(e.ravel())
        A = np.stack(cols, 1)
        scale = np.maximum(np.abs(A).max(0), 1e-300)
        x, _ = nnls(A / scale, (self.data * self.w).ravel(), maxiter=50 * A.shape[1])
        x = x / scale
        b = x[1:] if self.background else np.zeros(C)
        return float(x[0]), np.asarray(b)

    def predict(self, m, a, b):
        pred = a * m + b[:, None]
        return np.maximum(pred, 0.0) if self.encoding == "srgb" else pred

    def residuals(self, params) -> np.ndarray:
        m = self.shape_model(*params)
        a, b = self.linear_solve(m)
        return ((self.data - self.predict(m, a, b)) * self.w).ravel()

    def cost(self, m) -> float:
        a, b = self.linear_solve(m)
        r = (self.data - self.predict(m, a, b)) * self.w
        return float(np.sum(r * r))


# ----------------------------------------------------------------------
# the result
# ----------------------------------------------------------------------
@dataclasses.dataclass
class FitResult:
    """The fitted layer and light, with uncertainties (1σ) and diagnostics.

    Lengths in µm, angles in degree, temperature in K.  ``*_err`` is None for
    a parameter that was held fixed.
    """

    radius: float
    radius_err: float
    size_spread: float
    size_spread_err: float | None
    area_fraction: float
    area_fraction_err: float | None
    area_fraction_constrained: bool
    temperature: float
    temperature_err: float | None
    residual: float
    chi2_reduced: float
    exposure: float
    background: list
    source_xy: tuple
    source_mask_deg: float
    fov_deg: float
    deg_per_pixel: float
    shape: str
    process: str
    mode: str
    source_diameter_deg: float
    uncertainty: str
    fixed: list
    aureole_edge_deg: float | None
    red_rings_deg: list
    red_ring_diameter_deg: float | None
    rule_of_thumb_diameter: float | None
    n_bins: int
    seconds: float
    warnings: list
    diagnostic: str | None = None
    diagnostic_note: str | None = None
    profile: Profile | None = dataclasses.field(default=None, repr=False)
    model_profile: np.ndarray | None = dataclasses.field(default=None, repr=False)
    photo: Photograph | None = dataclasses.field(default=None, repr=False)
    camera: PinholeCamera | None = dataclasses.field(default=None, repr=False)

    def parameters(self) -> dict:
        """The fitted material as :func:`corona.parameters.material_from_parameters` arguments."""
        return {"shape": self.shape, "radius": self.radius, "size_spread": self.size_spread,
                "area_fraction": self.area_fraction, "process": self.process, "mode": self.mode}

    def material(self):
        """The fitted :class:`corona.Material`."""
        from corona.parameters import material_from_parameters
        return material_from_parameters(**self.parameters())

    def xml(self) -> str:
        """The Mitsuba XML of the fitted material (``<bsdf type="corona">``)."""
        p = self.parameters()
        lines = [f'<!-- corona fit: radius {self.radius:.4g} ± {self.radius_err:.2g} um, '
                 f'light {self.temperature:.0f} K -->', '<bsdf type="corona">']
        for k in ("shape", "radius", "size_spread", "area_fraction", "process", "mode"):
            v = p[k]
            if isinstance(v, str):
                lines.append(f'    <string name="{k}" value="{v}"/>')
            else:
                lines.append(f'    <float name="{k}" value="{v:.5g}"/>')
        lines.append("</bsdf>")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-ready numbers (no arrays)."""
        skip = {"profile", "model_profile", "photo", "camera"}
        out = {}
        for f in dataclasses.fields(self):
            if f.name in skip:
                continue
            v = getattr(self, f.name)
            if isinstance(v, tuple):
                v = list(v)
            if isinstance(v, (np.floating, np.integer)):
                v = v.item()
            if isinstance(v, float) and not math.isfinite(v):
                v = None
            out[f.name] = v
        out["xml"] = self.xml()
        return out

    def summary(self) -> str:
        """A few lines for people."""
        def pm(v, e, fmt, unit=""):
            return f"{v:{fmt}}{unit} (fixed)" if e is None else f"{v:{fmt}} ± {e:{fmt}}{unit}"
        lines = [f"radius        {pm(self.radius, self.radius_err, '.4g', ' µm')}",
                 f"size_spread   {pm(self.size_spread, self.size_spread_err, '.3f')}",
                 f"area_fraction {pm(self.area_fraction, self.area_fraction_err, '.3f')}"
                 + ("" if self.area_fraction_constrained else "  (not constrained by this image)"),
                 f"temperature   {pm(self.temperature, self.temperature_err, '.0f', ' K')}",
                 f"residual      {self.residual:.3g} (rms, relative to the profile), χ²/ν = {self.chi2_reduced:.3g}",
                 f"source        pixel ({self.source_xy[0]:.2f}, {self.source_xy[1]:.2f}), masked to "
                 f"{self.source_mask_deg:.3g}°; {self.deg_per_pixel:.4g}°/pixel"]
        if self.red_ring_diameter_deg:
            lines.append(f"red 1st ring  {self.red_ring_diameter_deg:.3g}° across; rule of thumb "
                         f"(Cowley): droplet diameter ≈ {self.rule_of_thumb_diameter:.3g} µm "
                         f"(fit: {2 * self.radius:.3g} µm)")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


# ----------------------------------------------------------------------
# the fit
# ----------------------------------------------------------------------
def _local_minima(cost: np.ndarray) -> np.ndarray:
    c = np.concatenate([[np.inf], cost, [np.inf]])
    return np.nonzero((c[1:-1] <= c[:-2]) & (c[1:-1] <= c[2:]))[0]


def _u_needed(radius: float, rho_max: float) -> float:
    """The largest ``u = 2π R ρ / λ`` the model evaluates (shortest wavelength)."""
    from corona.model import tabulated
    return 2 * np.pi * radius * rho_max / (tabulated.WAVELENGTH_MIN * 1e-3)


def _n_wavelengths(radius: float, rho_max: float) -> int:
    """Wavelength samples so that the phase u = 2πRρ/λ moves < 0.3 rad between samples."""
    from corona.model import tabulated
    u_span = 2 * np.pi * radius * rho_max * 1e3 * (1 / tabulated.WAVELENGTH_MIN - 1 / tabulated.WAVELENGTH_MAX)
    return int(np.clip(math.ceil(u_span / 0.3), 48, 320))


def _ring_radii(problem: _Problem, x, rho_max) -> tuple:
    """Angular radii [deg] of the model's red-chromaticity maxima (point source):
    the aureole's red edge and the red rings, from the noise-free model (for a
    one-channel image: (None, the luminance maxima))."""
    radius, spread, fa, temp = x
    rho = np.linspace(0.02 * problem.profile.bin_width, rho_max, 4000)
    W = problem.spectrum.weights(temp)
    prof = W @ problem.layer.lobe(rho, problem.spectrum.wavelengths, radius, spread, fa)
    if prof.shape[0] == 3:
        curve = prof[0] / np.maximum(prof.sum(0), 1e-300)
    else:
        curve = prof[0]
    idx = _local_minima(-curve)
    idx = idx[(idx > 0) & (idx < rho.size - 1)]
    deg = np.degrees(np.arcsin(np.minimum(rho[idx], 1.0)))
    if prof.shape[0] == 1:
        return None, deg.tolist()
    return (float(deg[0]) if deg.size else None), deg[1:].tolist()


def _measured_red_ring(profile: Profile, predicted_deg: float | None) -> float | None:
    """The first red ring's angular radius [deg] read from the data: the maximum of
    the (3-bin smoothed) red chromaticity R/(R+G+B) within ±25 % of the model's
    ring, refined by a parabola."""
    if predicted_deg is None or profile.value.shape[0] != 3:
        return None
    deg = profile.angle_deg
    lo, hi = 0.75 * predicted_deg, 1.25 * predicted_deg
    if deg[0] > lo or deg[-1] < hi:
        return None
    v = np.maximum(profile.value, 0.0)
    chroma = v[0] / np.maximum(v.sum(0), 1e-300)
    chroma = np.convolve(chroma, np.ones(3) / 3, mode="same")
    win = np.nonzero((deg >= lo) & (deg <= hi))[0]
    if win.size < 3:
        return None
    i = win[int(np.argmax(chroma[win]))]
    if i in (win[0], win[-1]):
        return None
    y0, y1, y2 = chroma[i - 1:i + 2]
    den = y0 - 2 * y1 + y2
    shift = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    return float(np.interp(i + shift, np.arange(deg.size), deg))


#: The refinement moves the radius at most this factor from its coarse start.
RADIUS_WINDOW = 1.3


@dataclasses.dataclass
class _FitSpace:
    """What a fit varies: the log radius always; the size spread, the area fraction and the
    temperature (as 1000 / T) where they are not held fixed (``None`` here)."""
    size_spread: float | None
    temperature: float | None
    fa0: float       # the area fraction's start, or its fixed value
    fit_fa: bool
    fa_max: float

    @property
    def names(self) -> list:
        return ["ln_radius"] + (["size_spread"] if self.size_spread is None else []) \
            + (["area_fraction"] if self.fit_fa else []) + (["kilo_inverse_T"] if self.temperature is None else [])

    def start(self, R0: float, spread: float, temperature: float) -> list:
        return [math.log(R0)] + ([spread] if self.size_spread is None else []) \
            + ([self.fa0] if self.fit_fa else []) + ([1e3 / temperature] if self.temperature is None else [])

    def unpack(self, x) -> tuple:
        """(radius, spread, area fraction, temperature) of the fit vector ``x``."""
        it = iter(x)
        R = math.exp(next(it))
        sp = next(it) if self.size_spread is None else self.size_spread
        fa = next(it) if self.fit_fa else self.fa0
        T = 1e3 / next(it) if self.temperature is None else self.temperature
        return R, sp, fa, T

    def bounds(self, R0: float) -> tuple:
        lo, hi = [math.log(R0 / RADIUS_WINDOW)], [math.log(R0 * RADIUS_WINDOW)]
        if self.size_spread is None:
            lo.append(0.0)
            hi.append(SIZE_SPREAD_MAX)
        if self.fit_fa:
            lo.append(0.02)
            hi.append(self.fa_max)
        if self.temperature is None:
            lo.append(1e3 / TEMPERATURE_RANGE[1])
            hi.append(1e3 / TEMPERATURE_RANGE[0])
        return np.array(lo), np.array(hi)

    def refine(self, problem: _Problem, x0, R0: float, max_nfev: int):
        """Least squares from ``x0`` within :meth:`bounds` of ``R0``."""
        from scipy.optimize import least_squares
        lo, hi = self.bounds(R0)
        x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
        return least_squares(lambda x: problem.residuals(self.unpack(x)), x0, bounds=(lo, hi), method="trf",
                             diff_step=1e-3, x_scale="jac", max_nfev=max_nfev)


def _check_fit_inputs(process, mode, shape, source_diameter_deg, temperature, area_fraction, size_spread,
                      bootstrap, radius_range) -> tuple:
    """The checked arguments of :func:`fit_photograph`: (process, mode, layer model, source diameter
    [degree], :class:`_FitSpace`, bootstrap refits, (lowest, highest radius) [µm])."""
    process = check_choice("process", process, FIT_PROCESSES)
    mode = check_choice("mode", mode, FIT_MODES)
    layer = layer_model(shape, process)
    src_diam = check_range("source_diameter", source_diameter_deg, 0.0, 30.0, unit="degree")
    if temperature is not None:
        temperature = check_range("temperature", temperature, *TEMPERATURE_RANGE, unit="K")
    fa_max = AREA_FRACTION_MAX[process]
    if area_fraction is not None:
        area_fraction = check_range("area_fraction", area_fraction, 0.0, fa_max, lo_open=True)
    if size_spread is not None:
        size_spread = check_range("size_spread", size_spread, 0.0, SIZE_SPREAD_MAX)
    nboot = int(check_range("bootstrap", bootstrap, 0, 10000))
    if nboot == 1:
        raise CoronaError("bootstrap=1 is out of range; allowed 0 (covariance) or >= 2 refits")
    try:
        r_lo, r_hi = (float(v) for v in radius_range)
    except (TypeError, ValueError):
        raise CoronaError(f"radius_range={radius_range!r} is not two numbers (µm)") from None
    if not (0 < r_lo < r_hi):
        raise CoronaError(f"radius_range={radius_range!r} is out of range; expected 0 < low < high µm")
    space = _FitSpace(size_spread=size_spread, temperature=temperature,
                      fa0=area_fraction if area_fraction is not None else 0.3,
                      fit_fa=area_fraction is None and process != "poisson", fa_max=fa_max)
    return process, mode, layer, src_diam, space, nboot, (r_lo, r_hi)


def _coarse_starts(problem: _Problem, layer, space: _FitSpace, radius_range, r_lo: float, r_hi: float,
                   rho_edge: float) -> tuple:
    """The coarse search, radius (2.5 % steps) × spread × temperature: the radii, spreads and
    temperatures tried and up to three starts (indices into them) at the best local minima in radius
    (``rho_edge``: the profile's last rho plus the source's radius and two bins)."""
    profile = problem.profile
    R_min = max(r_lo, 4.5 * 0.7 / (2 * np.pi * float(profile.rho[-1])))   # the first red ring in view
    R_max = min(r_hi, 0.45 / (2 * 3 * profile.bin_width))                  # rings >= 3 pixels apart
    if R_max <= R_min * 1.05:
        raise CoronaError(f"radius_range={radius_range!r}: no radius there gives rings this image "
                          f"resolves (about {R_min:.3g}–{R_max:.3g} µm for this field of view)")
    radii = np.exp(np.arange(math.log(R_min), math.log(R_max), math.log(1.025)))
    spreads = [space.size_spread] if space.size_spread is not None else [0.0, 0.08, 0.16]
    temps = [space.temperature] if space.temperature is not None else [2700.0, 4000.0, 6500.0]
    problem.set_wavelengths(64)
    layer.set_u_max(_u_needed(R_max, rho_edge))
    weights = {T: problem.spectrum.weights(T) for T in temps}
    costs = np.full((len(radii), len(spreads), len(temps)), np.inf)
    for j, sp in enumerate(spreads):
        for i, R in enumerate(radii):
            V = layer.lobe(profile.rho, problem.spectrum.wavelengths, R, sp, space.fa0)
            for k, T in enumerate(temps):
                costs[i, j, k] = problem.cost(weights[T] @ V)
    best_per_R = costs.reshape(len(radii), -1).min(1)
    order = sorted(_local_minima(best_per_R), key=lambda i: best_per_R[i])
    starts = []
    for i in order:
        if best_per_R[i] > 4.0 * best_per_R[order[0]]:
            break
        if all(abs(math.log(radii[i] / radii[s[0]])) > 0.08 for s in starts):
            j, k = np.unravel_index(int(np.argmin(costs[i])), costs[i].shape)
            starts.append((i, j, k))
        if len(starts) == 3:
            break
    return radii, spreads, temps, starts


def _refine_best(problem: _Problem, layer, space: _FitSpace, coarse: tuple, rho_edge: float, nu: int) -> tuple:
    """Least squares from each coarse start (:func:`_coarse_starts`), best first, until one explains
    the data within its noise: the best solution and its start radius (``problem`` keeps its
    wavelengths)."""
    radii, spreads, temps, starts = coarse
    rho_hi = float(problem.profile.rho[-1])
    problem.exact = False
    layer.set_u_max(_u_needed(max(radii[i] for i, _, _ in starts) * RADIUS_WINDOW, rho_edge))
    best = None
    for i, j, k in starts:
        R0 = radii[i]
        problem.set_wavelengths(_n_wavelengths(R0 * RADIUS_WINDOW, rho_hi))
        sol = space.refine(problem, space.start(R0, spreads[j], temps[k]), R0, 60)
        if best is None or sol.cost < best[0].cost:
            best = (sol, problem.spectrum, R0)
        if 2.0 * best[0].cost / nu < GOOD_FIT_CHI2:
            break   # explains the data within its noise: no other branch can do much better
    sol, problem.spectrum, R0 = best
    return sol, R0


def _uncertainties(problem: _Problem, space: _FitSpace, sol, R0: float, nu: int, nboot: int, seed: int) -> tuple:
    """(reduced chi², 1σ error per fitted name, how they were found): the fit covariance, or the
    spread of ``nboot`` refits to profiles resampled over the azimuthal sectors."""
    profile = problem.profile
    chi2 = 2.0 * sol.cost / nu
    J = sol.jac
    cov = np.linalg.pinv(J.T @ J) * max(1.0, chi2)
    err = np.sqrt(np.maximum(np.diag(cov), 0.0))
    how = "covariance"
    if nboot > 1:
        rng = np.random.default_rng(seed)
        S = profile.sector_sum.shape[0]
        samples = []
        for _ in range(nboot):
            problem.set_data(profile.resampled(rng.integers(0, S, S)))
            samples.append(space.refine(problem, sol.x, R0, 20).x)
        problem.set_data(profile.value)
        err = np.std(np.asarray(samples), axis=0, ddof=1)
        how = f"bootstrap over {S} azimuthal sectors ({nboot} refits)"
    return chi2, dict(zip(space.names, err)), how


def _fit_result(problem: _Problem, space: _FitSpace, x: tuple, R0: float, fit: dict, **fields) -> FitResult:
    """The :class:`FitResult` of the fitted ``x`` = (radius, spread, area fraction, temperature) with
    ``fit`` = {"chi2", "errors", "how"} (:func:`_uncertainties`): errors in the parameters' units,
    warnings, residual, model profile and ring radii; ``fields``: the rest of its fields."""
    R, sp, fa, T = x
    profile, errs, warnings = problem.profile, fit["errors"], []
    R_err = R * errs["ln_radius"]
    sp_err = errs.get("size_spread")
    fa_err = errs.get("area_fraction")
    T_err = errs["kilo_inverse_T"] * T * T / 1e3 if "kilo_inverse_T" in errs else None
    fa_ok = space.fit_fa and fa_err is not None and fa_err < AREA_FRACTION_CONSTRAINED_ERR
    if space.fit_fa and not fa_ok:
        warnings.append(f"area_fraction is not constrained by this image (± {fa_err:.2g}); "
                        "the aureole and first dark ring are saturated, masked or too faint")
    if T_err is not None and T_err > 0.25 * T:
        warnings.append(f"temperature is not constrained by this image (± {T_err:.0f} K); "
                        "give --temperature if the light is known")
    if abs(math.log(R / R0)) > math.log(RADIUS_WINDOW) - 1e-3:
        warnings.append("the radius ran to the edge of its search window; check the field of view")

    m = problem.shape_model(R, sp, fa, T)
    a, b = problem.linear_solve(m)
    model = problem.predict(m, a, b)
    use = profile.usable
    resid = float(np.sqrt(np.mean((profile.value - model)[use] ** 2) / np.mean(profile.value[use] ** 2)))
    aureole, rings = _ring_radii(problem, (R, sp, fa, T), float(profile.rho[-1]))
    red_ring = _measured_red_ring(profile, rings[0] if rings else None)
    red_dia = 2 * red_ring if red_ring else None
    rule = RED_RING_RULE * MOON_DIAMETER_DEG / red_dia if red_dia else None
    fixed = [n for n, v in (("size_spread", space.size_spread), ("temperature", space.temperature))
             if v is not None] + ([] if space.fit_fa else ["area_fraction"])
    return FitResult(
        radius=R, radius_err=float(R_err), size_spread=sp,
        size_spread_err=None if sp_err is None else float(sp_err),
        area_fraction=fa, area_fraction_err=None if fa_err is None else float(fa_err),
        area_fraction_constrained=bool(fa_ok), temperature=T,
        temperature_err=None if T_err is None else float(T_err),
        residual=resid, chi2_reduced=float(fit["chi2"]), exposure=a, background=b.tolist(),
        source_mask_deg=math.degrees(math.asin(min(profile.rho_mask, 1.0))), shape=problem.layer.name,
        uncertainty=fit["how"], fixed=fixed, aureole_edge_deg=aureole, red_rings_deg=rings[:5],
        red_ring_diameter_deg=red_dia, rule_of_thumb_diameter=rule, n_bins=int(profile.rho.size), seconds=0.0,
        warnings=warnings, profile=profile, model_profile=model, **fields)


def fit_photograph(image, fov_deg: float | None = None, *, deg_per_pixel: float | None = None,
                   temperature: float | None = None, area_fraction: float | None = None,
                   size_spread: float | None = None, process: str = "hard-disk",
                   mode: str = "particle", shape: str = "circle",
                   source_diameter_deg: float = 0.0, background: bool = True,
                   bootstrap: int = 0, radius_range=(0.5, 200.0), saturation: float | None = None,
                   diagnostic: str | None = None, seed: int = 0) -> FitResult:
    """Fit a layer of scatterers to a photograph of its corona around a light.

    Parameters
    ----------
    image : str, os.PathLike, ndarray or Photograph
        The photograph (see :func:`read_photograph`): 8-/16-bit sRGB or linear EXR.
    fov_deg : float in (0, 180)
        Horizontal field of view of the (pinhole) image [degree].
    deg_per_pixel : float, optional
        Instead of ``fov_deg``: the angle one pixel spans at the centre [degree].
    temperature : float, optional
        Colour temperature of the light [K] (black body); fitted when None.
    area_fraction, size_spread : float, optional
        Hold these fixed instead of fitting them.  With ``process="poisson"``
        the area fraction does not change the profile's shape and is always fixed
        (default 0.3).
    process : {"hard-disk", "rsa", "poisson"}
        Point process of the scatterers' centres.
    mode : {"particle", "aperture"}
        Written to the material; the lobe is the same (Babinet).
    shape : {"circle"}
        The scatterer model (:data:`FIT_SHAPES`; "sphere" is planned).
    source_diameter_deg : float, default 0
        Angular diameter of the light (the moon: 0.52°); 0 for a point.
    background : bool, default True
        Fit a constant background per channel (sky, dark level).
    bootstrap : int, default 0
        Number of refits to profiles resampled over the azimuthal sectors for
        the uncertainties (0: the fit covariance).
    radius_range : (float, float)
        Radii searched [µm] (further limited to rings the image can resolve).
    saturation : float, optional
        Clipping level of a linear (float) image.
    diagnostic : str, optional
        Write the diagnostic PNG there (profiles vs. model; the image with the
        fitted rings).
    seed : int
        Seed of the bootstrap.

    Returns
    -------
    FitResult
        Radius [µm], size spread, area fraction, temperature [K] with 1σ errors,
        the residual, ring radii, the XML snippet (:meth:`FitResult.xml`) ...
    """
    t0 = time.perf_counter()
    process, mode, layer, src_diam, space, nboot, (r_lo, r_hi) = _check_fit_inputs(
        process, mode, shape, source_diameter_deg, temperature, area_fraction, size_spread, bootstrap, radius_range)
    photo = read_photograph(image, saturation=saturation)
    h, w = photo.shape
    camera = PinholeCamera.from_field_of_view(w, h, fov_deg, deg_per_pixel)
    source = locate_source(photo)
    src_r = math.sin(math.radians(0.5 * src_diam))
    profile = azimuthal_profile(photo, camera, source, src_r)
    problem = _Problem(profile, layer, photo.linear.shape[2], photo.encoding, src_r, background)
    rho_edge = float(profile.rho[-1]) + src_r + 2 * profile.bin_width

    coarse = _coarse_starts(problem, layer, space, radius_range, r_lo, r_hi, rho_edge)
    nu = max(1, int(problem.w.astype(bool).sum()) - len(space.names) - (1 + problem.channels * background))
    sol, R0 = _refine_best(problem, layer, space, coarse, rho_edge, nu)
    chi2, errors, how = _uncertainties(problem, space, sol, R0, nu, nboot, seed)
    result = _fit_result(problem, space, space.unpack(sol.x), R0, {"chi2": chi2, "errors": errors, "how": how},
                         source_xy=(source.x, source.y), fov_deg=camera.fov_deg,
                         deg_per_pixel=camera.deg_per_pixel, process=process, mode=mode,
                         source_diameter_deg=src_diam, photo=photo, camera=camera)
    if diagnostic:
        result.diagnostic, result.diagnostic_note = write_diagnostic(result, diagnostic)
    result.seconds = time.perf_counter() - t0
    return result


# ----------------------------------------------------------------------
# the diagnostic picture
# ----------------------------------------------------------------------
def _ring_outline(camera: PinholeCamera, source_xy, rho: float, n: int = 180):
    """Image points of the ring ``|r.xy - s.xy| = rho`` around the source."""
    s = camera.directions(*source_xy)
    phi = np.linspace(0, 2 * np.pi, n)
    rx, ry = s[0] + rho * np.cos(phi), s[1] + rho * np.sin(phi)
    rz = np.sqrt(np.maximum(1.0 - rx * rx - ry * ry, 1e-12))
    return camera.pixels(np.stack([rx, ry, rz], -1))


def _overlay(result: FitResult) -> np.ndarray:
    """The photograph around the source (sRGB 8-bit, cropped to the fitted
    region) with the fitted red rings (red), the aureole's red edge (orange)
    and the masked source disk (grey) drawn on it."""
    from PIL import Image, ImageDraw

    from corona.color import tonemap_srgb
    photo, cam = result.photo, result.camera
    h, w = photo.shape
    sx, sy = result.source_xy
    half = 1.1 * cam.focal * float(result.profile.rho[-1]) + 4
    x0, x1 = int(max(0, sx - half)), int(min(w, sx + half + 1))
    y0, y1 = int(max(0, sy - half)), int(min(h, sy + half + 1))
    lin = photo.linear[y0:y1, x0:x1]
    if lin.shape[2] == 1:
        lin = np.repeat(lin, 3, axis=2)
    if photo.encoding == "srgb":
        img = tonemap_srgb(lin, exposure=1.0)
    else:
        lum = luminance(photo)
        ref = np.percentile(lum[~photo.saturated], 99.0) if (~photo.saturated).any() else 1.0
        img = tonemap_srgb(lin, exposure=1.0 / ref if ref > 0 else 1.0)
    im = Image.fromarray(img)
    scale = max(1, int(math.ceil(480 / max(im.size))))
    if scale > 1:
        im = im.resize((im.size[0] * scale, im.size[1] * scale), Image.NEAREST)
    elif max(im.size) > 1024:
        scale = 1024 / max(im.size)
        im = im.resize((max(1, round(im.size[0] * scale)), max(1, round(im.size[1] * scale))), Image.BILINEAR)
    draw = ImageDraw.Draw(im)
    width = max(1, round(scale / 2))

    def ring(deg, colour):
        x, y = _ring_outline(cam, result.source_xy, math.sin(math.radians(deg)))
        draw.line(list(zip(((x - x0) * scale).tolist(), ((y - y0) * scale).tolist())), fill=colour, width=width)

    ring(result.source_mask_deg, (160, 160, 160))
    if result.aureole_edge_deg:
        ring(result.aureole_edge_deg, (255, 160, 0))
    for deg in result.red_rings_deg[:3]:
        ring(deg, (255, 40, 40))
    return np.asarray(im)


def write_diagnostic(result: FitResult, path: str) -> tuple[str, str | None]:
    """Write the diagnostic PNG; returns (path, note).

    With matplotlib (the ``reference`` extra): the profiles per channel (data
    with error bars, the fitted model) next to the image with the fitted rings.
    Without it: only the image with the rings (Pillow), and the note says so.
    """
    import imageio.v3 as iio
    overlay = _overlay(result)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    try:
        import matplotlib
    except ImportError:
        iio.imwrite(path, overlay)
        return path, ("matplotlib is not installed (pip install 'corona-bsdf[reference]'): the diagnostic "
                      "shows the image with the fitted rings only, without the profile plot")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    prof = result.profile
    deg = prof.angle_deg
    colours = ["tab:red", "tab:green", "tab:blue"] if prof.value.shape[0] == 3 else ["k"]
    labels = ["R", "G", "B"] if prof.value.shape[0] == 3 else ["luminance"]
    fig, ax = plt.subplots(1, 2, figsize=(13, 5.4), gridspec_kw={"width_ratios": [1, 1.35]})
    ax[0].imshow(overlay)
    ax[0].set(title="the light and its corona; fitted rings: red 1st/2nd/3rd (red),\n"
                    "aureole's red edge (orange), masked disk (grey)",
              xticks=[], yticks=[])
    ax[0].title.set_fontsize(8)
    for c in range(prof.value.shape[0]):
        use = prof.usable[c]
        ax[1].errorbar(deg[use], prof.value[c, use], yerr=prof.sigma[c, use], fmt=".", ms=2.5, lw=0.6,
                       color=colours[c], alpha=0.55, label=f"{labels[c]} data")
        if not use.all():
            ax[1].plot(deg[~use], np.maximum(prof.value[c, ~use], 1e-12), "x", ms=3, color=colours[c], alpha=0.4,
                       label=f"{labels[c]}: clipped at black, not used")
        ax[1].plot(deg, result.model_profile[c], "-", color=colours[c], lw=1.2, label=f"{labels[c]} model")
    for d in result.red_rings_deg[:3]:
        ax[1].axvline(d, color="tab:red", lw=0.6, ls=":")
    top = float(np.max(result.model_profile))
    ax[1].set_yscale("log")
    ax[1].set_ylim(max(top * 1e-4, 1e-6), top * 2)
    ax[1].set(xlabel="angle from the light [degree]", ylabel="linear value (azimuthal mean)")
    fe = "" if result.size_spread_err is None else f" ± {result.size_spread_err:.3f}"
    ax[1].set_title(f"R = {result.radius:.4g} ± {result.radius_err:.2g} µm, spread {result.size_spread:.3f}{fe}, "
                    f"F_a {result.area_fraction:.2f}, {result.temperature:.0f} K; residual {result.residual:.3f}",
                    fontsize=9)
    ax[1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path, None
