"""Scatterers measured from a micrograph (docs/physics.md: pores, droplets, spores).

:func:`from_micrograph` segments a binary or grey image into scatterers
(Otsu threshold, connected components, region properties — scikit-image)
and returns their centres as a :class:`~corona.model.processes.PointSet`, their
equivalent radii and a matching shape, ready for
:class:`corona.model.material.Material`.

Coordinates: pixel ``(row, col)`` has its centre at
``x = (col + 0.5)·p``, ``y = (H - row - 0.5)·p`` [µm] (``p`` the pixel size,
``H`` the image height in pixels), so the image appears upright with y up;
the observation window is ``[0, W p] × [0, H p]``.
"""
from __future__ import annotations

import os

import numpy as np

from corona.model import shapes as _shapes
from corona._validation import CoronaError, check_positive, check_range
from corona.model.processes import PointSet


class Micrograph:
    """Result of :func:`from_micrograph`.

    Attributes
    ----------
    points : PointSet
        Centroids [µm] of all kept regions in the image window.
    radii : numpy.ndarray
        Equivalent radius ``sqrt(area/π)`` [µm] of each region (same order).
    on_border : numpy.ndarray of bool
        Regions cut by the image border (their radii are excluded from the
        size statistics).
    shape : corona.model.shapes.Shape
        ``Circle`` of the mean equivalent radius of the interior regions, or a
        ``SizeDistribution`` of it with the measured relative spread of radii
        (when that spread is at least ``min_spread``).
    area_fraction : float
        Fraction of the image covered by the kept regions (measured ``F_a``).
    threshold : float or None
        The grey level used (None for a boolean image).
    labels : numpy.ndarray of int
        Label image of the kept regions (0 = background).
    pixel_size : float
        µm per pixel.
    """

    def __init__(self, points, radii, on_border, shape, area_fraction, threshold, labels,
                 pixel_size):
        self.points = points
        self.radii = radii
        self.on_border = on_border
        self.shape = shape
        self.area_fraction = area_fraction
        self.threshold = threshold
        self.labels = labels
        self.pixel_size = pixel_size

    def __repr__(self):
        return (f"Micrograph({len(self.radii)} scatterers, mean radius "
                f"{self.mean_radius:.4g} µm, area_fraction={self.area_fraction:.4g}, "
                f"shape={self.shape!r})")

    @property
    def count(self) -> int:
        return int(len(self.radii))

    @property
    def mean_radius(self) -> float:
        r = self.radii[~self.on_border] if np.any(~self.on_border) else self.radii
        return float(np.mean(r))

    @property
    def radius_spread(self) -> float:
        """Relative standard deviation of the interior regions' radii."""
        r = self.radii[~self.on_border] if np.any(~self.on_border) else self.radii
        return float(np.std(r) / np.mean(r)) if len(r) > 1 else 0.0

    def material(self, mode: str = "aperture", **kwargs):
        """``corona.model.material.Material(self.shape, self.points, mode, **kwargs)``."""
        from corona.model.material import Material
        return Material(self.shape, self.points, mode=mode, **kwargs)


def _load_image(image):
    if isinstance(image, (str, os.PathLike)):
        path = os.fspath(image)
        if not os.path.exists(path):
            raise CoronaError(f"micrograph file {path!r} does not exist")
        try:
            import imageio.v3 as iio
            img = iio.imread(path)
        except Exception as e:  # noqa: BLE001
            raise CoronaError(f"cannot read micrograph {path!r}: {e}") from None
    else:
        img = image
    try:
        img = np.asarray(img)
    except Exception:  # noqa: BLE001
        raise CoronaError("image must be an array or an image file path") from None
    if img.ndim == 3 and img.shape[-1] in (3, 4):
        rgb = img[..., :3].astype(np.float64)
        img = rgb @ np.array([0.2126, 0.7152, 0.0722])  # luminance (Rec. 709)
    elif img.ndim == 3 and img.shape[-1] == 1:
        img = img[..., 0]
    if img.ndim != 2:
        raise CoronaError(f"image must be 2-D grey, RGB or RGBA, got shape {img.shape}")
    if img.shape[0] < 2 or img.shape[1] < 2:
        raise CoronaError(f"image of shape {img.shape} is too small")
    if img.dtype != bool and not np.issubdtype(img.dtype, np.number):
        raise CoronaError(f"image has non-numeric dtype {img.dtype}")
    return img


def from_micrograph(image, pixel_size: float, threshold: float | None = None,
                    invert: bool = False, *, min_size: int = 4, min_spread: float = 0.03,
                    connectivity: int = 1) -> Micrograph:
    """Scatterers (centres, radii, shape) segmented from a micrograph.

    Parameters
    ----------
    image : array_like or path
        2-D grey, RGB(A) (converted to luminance) or boolean image, or a file
        readable by ``imageio``.
    pixel_size : float
        Size of one pixel [µm].
    threshold : float or None
        Grey level separating scatterers from background; None uses Otsu's
        method (``skimage.filters.threshold_otsu``).  Ignored for boolean
        images.
    invert : bool, default False
        False: scatterers are the bright pixels (``> threshold``, or True in
        a boolean image) — e.g. pores against back-light.  True: the dark
        ones (spores on a bright-field slide).
    min_size : int, default 4
        Regions smaller than this many pixels are dropped as noise.
    min_spread : float, default 0.03
        Relative spread of radii below which the shape is a plain ``Circle``
        (smaller spreads are dominated by pixelisation).
    connectivity : {1, 2}
        Pixel connectivity of a region (1: edge neighbours, 2: also corners).

    Returns
    -------
    Micrograph
        With ``.points`` (a :class:`~corona.model.processes.PointSet`), ``.radii``,
        ``.shape``, ``.area_fraction`` and ``.material(mode)``.

    Raises
    ------
    CoronaError
        For an unreadable image, a bad parameter, or "image has no
        scatterers".
    """
    from skimage import filters, measure

    px = check_positive("pixel_size", pixel_size, "µm")
    min_size = int(check_range("min_size", min_size, 1, np.inf, hi_open=True))
    min_spread = check_range("min_spread", min_spread, 0.0, 1.0)
    if connectivity not in (1, 2):
        raise CoronaError(f"connectivity={connectivity!r} is not one of 1, 2")
    img = _load_image(image)
    if img.dtype == bool:
        fg = img.copy()
        thr = None
    else:
        g = img.astype(np.float64)
        if not np.all(np.isfinite(g)):
            raise CoronaError("image contains non-finite values")
        if threshold is None:
            if g.min() == g.max():
                raise CoronaError("image has no scatterers: it is uniform "
                                  f"(all pixels = {g.min():g}), nothing to segment")
            thr = float(filters.threshold_otsu(g))
        else:
            thr = check_range("threshold", threshold, -np.inf, np.inf, lo_open=True, hi_open=True)
        fg = g > thr
    if invert:
        fg = ~fg
    labels = measure.label(fg, connectivity=connectivity)
    props = [p for p in measure.regionprops(labels) if p.area >= min_size]
    if not props:
        raise CoronaError("image has no scatterers: no foreground region of at least "
                          f"{min_size} pixels (threshold={thr}, invert={invert}); check "
                          "threshold/invert")
    H, W = fg.shape
    keep = np.zeros(labels.max() + 1, dtype=bool)
    cent = np.empty((len(props), 2))
    area = np.empty(len(props))
    border = np.zeros(len(props), dtype=bool)
    for i, p in enumerate(props):
        keep[p.label] = True
        r, c = p.centroid
        cent[i] = ((c + 0.5) * px, (H - r - 0.5) * px)
        area[i] = p.area
        r0, c0, r1, c1 = p.bbox
        border[i] = r0 == 0 or c0 == 0 or r1 == H or c1 == W
    labels = np.where(keep[labels], labels, 0)
    radii = np.sqrt(area / np.pi) * px
    inner = radii[~border] if np.any(~border) else radii
    rmean = float(np.mean(inner))
    spread = float(np.std(inner) / rmean) if len(inner) > 1 else 0.0
    shape = _shapes.Circle(rmean)
    if spread >= min_spread and hasattr(_shapes, "SizeDistribution"):
        shape = _shapes.SizeDistribution(shape, spread=min(spread, 1.0))
    points = PointSet(cent, ((0.0, W * px), (0.0, H * px)))
    fa = float(np.count_nonzero(labels)) / (H * W)
    return Micrograph(points, radii, border, shape, fa, thr, labels, px)
