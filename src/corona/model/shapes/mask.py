"""Image masks: a transmission profile from an image, Fourier transform by FFT."""
from __future__ import annotations

import math
import os

import numpy as np
import scipy   # scipy.fft, scipy.ndimage: loaded on first use (scipy imports its submodules lazily)

from corona._validation import CoronaError, check_positive, check_range
from corona.model import registry
from corona.model.shapes.base import _TWO_PI, Shape, _q_array

_LUMA = np.array([0.2126, 0.7152, 0.0722])

#: Largest side [pixels] of the opening's bounding box: its zero-padded FFT
#: (4 × per axis, complex128) and spline coefficients then take ~0.7 GB.
MASK_MAX_PIXELS = 1024
#: Largest image file [pixels] read at all (the opening may be a small part of it).
IMAGE_MAX_PIXELS = 64_000_000


def _reader_error(exc) -> str:
    """imageio's message on one line: its first line (the rest are install hints)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return lines[0].replace("``", "`") if lines else type(exc).__name__


def _load_image(image) -> tuple[np.ndarray, str | None]:
    """Return a float64 2-D array in [0, 1] and the source path (or None)."""
    source = None
    if isinstance(image, (str, os.PathLike)):
        source = os.fspath(image)
        if os.path.isdir(source):
            raise CoronaError(f"image={source!r} is a directory; expected an image file")
        if not os.path.exists(source):
            raise CoronaError(f"image={source!r}: no such file")
        if not os.path.isfile(source):
            raise CoronaError(f"image={source!r} is not a regular file; expected an image file")
        if os.path.getsize(source) == 0:
            raise CoronaError(f"image={source!r} is an empty file")
        try:
            import warnings

            import imageio.v3 as iio
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                props = iio.improps(source)
                if int(np.prod(props.shape)) > IMAGE_MAX_PIXELS * (4 if len(props.shape) == 3 else 1):
                    raise CoronaError(f"image={source!r} has shape {props.shape}; allowed at most "
                                      f"{IMAGE_MAX_PIXELS:.3g} pixels")
                arr = np.asarray(iio.imread(source))
        except CoronaError:
            raise
        except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file
            raise CoronaError(f"image={source!r} could not be read as an image ({_reader_error(exc)})") \
                from None
        if arr.ndim == 3 and arr.shape[-1] in (1, 2, 3, 4):
            arr = _normalise_levels(arr, source)
            if arr.shape[-1] >= 3:        # RGB(A): Rec. 709 luminance, alpha ignored
                arr = arr[..., :3] @ _LUMA
            else:                         # L or LA
                arr = arr[..., 0]
        elif arr.ndim == 2:
            arr = _normalise_levels(arr, source)
        else:
            raise CoronaError(f"image={source!r} has shape {arr.shape}; expected a single "
                              "2-D grey or RGB(A) image")
    else:
        try:
            arr = np.asarray(image)
        except Exception:  # noqa: BLE001
            raise CoronaError("image must be a 2-D array or a path to an image file") from None
        if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number)
                                       or arr.dtype == np.bool_):
            raise CoronaError(f"image has dtype {arr.dtype}; expected a numeric 2-D array "
                              "with values in [0, 1] or a path to an image file")
        if arr.ndim != 2:
            raise CoronaError(f"image has shape {arr.shape}; expected a 2-D array "
                              "(rows, columns) with values in [0, 1]")
        arr = arr.astype(np.float64)
        if not np.all(np.isfinite(arr)) or (arr.size and (arr.min() < 0.0 or arr.max() > 1.0)):
            raise CoronaError("image values are out of range; expected finite values in [0, 1] "
                              "(1 = transmitting)")
    if arr.size == 0:
        raise CoronaError(f"image has shape {arr.shape}; expected a non-empty 2-D array")
    return np.array(arr, dtype=np.float64, order="C"), source


def _normalise_levels(arr: np.ndarray, source) -> np.ndarray:
    if arr.dtype == np.bool_:
        return arr.astype(np.float64)
    if np.issubdtype(arr.dtype, np.integer):
        out = arr.astype(np.float64) / float(np.iinfo(arr.dtype).max)
    else:
        out = arr.astype(np.float64)
    if out.size and (not np.all(np.isfinite(out)) or out.min() < 0.0 or out.max() > 1.0):
        raise CoronaError(f"image={source!r} has values outside [0, 1] after normalisation")
    return out


class Mask(Shape):
    """A transmission profile given as an image (binary or grey levels).

    The profile is the band-limited (sinc-interpolated) function through the
    pixel values ``a_ij ∈ [0, 1]`` at the pixel centres
    ``x = (j - c_j) p``, ``y = (c_i - i) p`` (row 0 at the top, y up, centred on
    the intensity-weighted centroid ``c``), so

        ``Â(q) = p² Σ_ij a_ij e^{-i q·x_ij}``  for ``|q_x|, |q_y| ≤ π/p``, 0 outside,

    and ``∫ T_a = Σ a² / Σ a`` exactly (1 for binary masks).  Â is computed by
    a zero-padded FFT (``scipy.fft``) of the opening's bounding box: each axis
    of n pixels is padded to ``next_fast_len(max(4n, min(8n, 2048)))``, a
    padding factor between 4 and 8, with the centroid pixel moved to the
    origin so that Â is smooth on the FFT grid; the residual sub-pixel shift is
    applied as an exact phase.  Â at arbitrary q is interpolated with periodic
    cubic splines (real and imaginary parts; the DTFT is periodic), and
    ``form_factor = |Â|²/|A|``, so ``coherent_form_factor == form_factor``
    exactly for this deterministic shape.  Interpolating Â (half the
    bandwidth of ``|Â|²``) is more accurate than interpolating ``|Â|²``.

    Parameters
    ----------
    image : array_like (rows, columns) or str / os.PathLike
        Values in [0, 1], 1 = transmitting; or a path to an image file read
        with ``imageio`` (RGB(A) converted to Rec. 709 luminance, alpha
        ignored; integer levels divided by the dtype's maximum).
    pixel_size : float
        Pixel pitch p > 0 [µm].
    threshold : float in (0, 1), optional
        If given, the image is binarised as ``image >= threshold``.

    Notes
    -----
    ``length_scale`` is the largest distance from the centroid to a
    transmitting pixel centre plus half a pixel diagonal (``p/√2``).

    The opening's bounding box may span at most ``MASK_MAX_PIXELS`` (1024)
    pixels per side (its padded FFT then needs ~0.7 GB), and an image file at
    most ``IMAGE_MAX_PIXELS``; larger ones are refused before any allocation
    (downsample the image and scale ``pixel_size`` by the same factor).

    References
    ----------
    Goodman, *Introduction to Fourier Optics*, §2.4 and §4.2 (sampling and
    FFT evaluation of Fraunhofer patterns).
    """

    _cost = 8.0   # two cubic-spline lookups

    def __init__(self, image, pixel_size: float, threshold: float | None = None):
        self.pixel_size = check_positive("pixel_size", pixel_size, "µm")
        if threshold is not None:
            threshold = check_range("threshold", threshold, 0.0, 1.0, lo_open=True, hi_open=True)
        self.threshold = threshold
        img, self._source = _load_image(image)
        if threshold is not None:
            img = (img >= threshold).astype(np.float64)
        total = float(img.sum())
        if not total > 0.0:
            raise CoronaError(("image" if self._source is None else f"image={self._source!r}")
                              + " has no transmitting pixel (all values are 0"
                              + (f" below threshold={threshold:g}" if threshold is not None
                                 else "") + "); expected at least one opening")
        img.setflags(write=False)
        self.image = img
        self._prepare()

    def _prepare(self):
        img, p = self.image, self.pixel_size
        rows = np.nonzero(img.any(axis=1))[0]
        cols = np.nonzero(img.any(axis=0))[0]
        crop = img[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
        ny, nx = crop.shape
        if max(ny, nx) > MASK_MAX_PIXELS:
            src = "image" if self._source is None else f"image={self._source!r}"
            raise CoronaError(f"{src}: the opening spans {nx} x {ny} pixels; allowed at most "
                              f"{MASK_MAX_PIXELS} per side (the FFT would need "
                              f"{16 * 4 * nx * 4 * ny / 2**30:.1f} GiB): downsample the image and scale "
                              "pixel_size by the same factor")
        total = float(crop.sum())
        ii, jj = np.indices(crop.shape)
        ci = float(np.sum(ii * crop)) / total
        cj = float(np.sum(jj * crop)) / total
        self._area = p * p * total
        self._overlap = float(np.sum(crop * crop)) / total
        nzr = crop > 0
        self._radius = p * float(np.max(np.hypot(ii[nzr] - ci, jj[nzr] - cj))) + p / math.sqrt(2.0)
        i0, j0 = int(round(ci)), int(round(cj))
        self._shift = (ci - i0, cj - j0)
        self._P = tuple(scipy.fft.next_fast_len(max(4 * n, min(8 * n, 2048))) for n in (ny, nx))
        self._crop_info = (crop, i0, j0)
        F = self._fft()
        self._coef_re = scipy.ndimage.spline_filter(F.real, order=3, mode="grid-wrap")
        self._coef_im = scipy.ndimage.spline_filter(F.imag, order=3, mode="grid-wrap")

    def _fft(self) -> np.ndarray:
        crop, i0, j0 = self._crop_info
        Py, Px = self._P
        arr = np.zeros((Py, Px))
        arr[:crop.shape[0], :crop.shape[1]] = crop
        arr = np.roll(arr, (-i0, -j0), axis=(0, 1))
        return scipy.fft.fft2(arr, workers=1)

    def __repr__(self):
        ny, nx = self.image.shape
        src = f"{self._source!r}" if self._source else f"<array {ny}x{nx}>"
        th = "" if self.threshold is None else f", threshold={self.threshold:g}"
        return f"Mask({src}, pixel_size={self.pixel_size:g}{th})"

    @property
    def area(self) -> float:
        return self._area

    @property
    def length_scale(self) -> float:
        return self._radius

    @property
    def self_overlap(self) -> float:
        """``Σ a² / Σ a`` (1 for a binary mask)."""
        return self._overlap

    @property
    def band_limit(self) -> float:
        """``π / pixel_size`` [rad/µm]: Â is 0 for ``|q_x|`` or ``|q_y|`` beyond it."""
        return np.pi / self.pixel_size

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        shape = q.shape[:-1]
        qf = q.reshape(-1, 2)
        p = self.pixel_size
        Py, Px = self._P
        out = np.zeros(qf.shape[0], dtype=np.complex128)
        inb = (np.abs(qf[:, 0]) * p <= np.pi) & (np.abs(qf[:, 1]) * p <= np.pi)
        if np.any(inb):
            qx, qy = qf[inb, 0], qf[inb, 1]
            coords = np.stack([-qy * p * Py / _TWO_PI, qx * p * Px / _TWO_PI])
            re = scipy.ndimage.map_coordinates(self._coef_re, coords, order=3, mode="grid-wrap",
                                         prefilter=False)
            im = scipy.ndimage.map_coordinates(self._coef_im, coords, order=3, mode="grid-wrap",
                                         prefilter=False)
            di, dj = self._shift
            out[inb] = p * p * (re + 1j * im) * np.exp(1j * p * (qx * dj - qy * di))
        return out.reshape(shape)

    def _overlap_sum(self, widths, coeffs) -> float:
        # Parseval on the FFT grid: p² Σ |F|² e^{-q² w²} / (P_x P_y)
        p = self.pixel_size
        Py, Px = self._P
        power = None
        total = 0.0
        for w, c in zip(np.ravel(widths), np.ravel(coeffs)):
            if w <= 0.0:
                total += c * self._overlap * self._area
                continue
            if power is None:
                power = np.abs(self._fft()) ** 2
                qy2 = (_TWO_PI * scipy.fft.fftfreq(Py, d=p)) ** 2
                qx2 = (_TWO_PI * scipy.fft.fftfreq(Px, d=p)) ** 2
            g = np.exp(-qy2 * w * w)[:, None] * np.exp(-qx2 * w * w)[None, :]
            total += c * float(p * p * np.sum(power * g) / (Px * Py))
        return total




def _mask_from(p: dict) -> Mask:
    if not p.get("filename"):
        raise CoronaError("shape='mask' needs filename=<image file>")
    if p.get("pixel_size") is None:
        raise CoronaError("shape='mask' needs pixel_size=<µm per pixel>")
    return Mask(p["filename"], p["pixel_size"])


# --- the family (corona.model.registry): shape=mask ----------------------------------------------
registry.add_shape(registry.ShapeFamily("mask", _mask_from, ("filename", "pixel_size") + registry.FLAT
                                        + registry.ROTATABLE, cls=Mask))
