"""Pictures of a material's lobe: tables and the far-field corona.

The figures need matplotlib (the ``reference`` extra); they are drawn on a
bare ``matplotlib.figure.Figure``, so no pyplot backend is selected.
"""
from __future__ import annotations

import numpy as np

from corona._validation import CoronaError
from corona.color import blackbody, spectrum_to_linear_srgb, tonemap_srgb


# ----------------------------------------------------------------------
# the PNG convention of every command (render, sweep, post, the gallery)
# ----------------------------------------------------------------------
#: The glow's luminance percentile that the automatic exposure maps to 1.
GLOW_PERCENTILE = 99.5
#: Pixels above this fraction of the peak luminance are lamps (left out of the exposure) ...
LAMP_LEVEL = 0.25
#: ... when they cover less than this share of the frame (else the frame has no lamp to leave out).
LAMP_SHARE_MAX = 0.2
#: Lamps are widened by this many pixels (their antialiased and filtered rims) before they are left out.
LAMP_RIM_PX = 2
_REC709 = np.array([0.2126, 0.7152, 0.0722])


def _luminance(rgb: np.ndarray) -> np.ndarray:
    rgb = np.maximum(np.nan_to_num(np.asarray(rgb, dtype=np.float64)), 0.0)
    if rgb.ndim == 2:
        return rgb
    return rgb[..., 0] if rgb.shape[-1] == 1 else rgb[..., :3] @ _REC709


def dilate_cross(mask: np.ndarray, iterations: int) -> np.ndarray:
    """``scipy.ndimage.binary_dilation(mask, iterations=iterations)`` of a 2-D mask (the
    4-neighbour cross, outside the frame False): the pixels within ``iterations`` steps of
    ``mask`` (city-block).  numpy shifts, since importing scipy.ndimage costs every
    ``corona render`` more CPU than the renders of a preview (its docstring parsing at import)."""
    out = np.asarray(mask, dtype=bool).copy()
    for _ in range(int(iterations)):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown
    return out


def display_exposure(rgb) -> float:
    """The automatic exposure of a picture: the glow around the lamps, not the lamps, maps to 1.

    ``1 / q`` with ``q`` the :data:`GLOW_PERCENTILE` of the luminance (Rec. 709) over the
    pixels that are not lamps.  Lamps are the pixels above :data:`LAMP_LEVEL` × the peak,
    widened by :data:`LAMP_RIM_PX` pixels, when they cover less than :data:`LAMP_SHARE_MAX` of
    the frame (a bright lamp covering 2 % of the frame would otherwise set the exposure and
    leave its corona black).  1 for a black picture.
    """
    lum = _luminance(rgb)
    peak = float(lum.max()) if lum.size else 0.0
    if peak <= 0.0:
        return 1.0
    lamp = lum > LAMP_LEVEL * peak
    if LAMP_RIM_PX and lum.ndim == 2:
        lamp = dilate_cross(lamp, LAMP_RIM_PX)
    glow = lum[~lamp] if 0 < lamp.mean() < LAMP_SHARE_MAX else lum.ravel()
    q = float(np.percentile(glow, GLOW_PERCENTILE)) if glow.size else 0.0
    if q <= 0.0:                       # nothing but lamps on black: the lamps' level
        q = float(np.percentile(lum, GLOW_PERCENTILE))
    return 1.0 / q if q > 0.0 else 1.0


def display_srgb(rgb, exposure: float | None = None) -> np.ndarray:
    """Linear RGB (H, W, 3) or luminance (H, W[, 1]) → 8-bit sRGB: the PNGs of ``corona
    render``, ``corona sweep``, ``corona post`` and the gallery.

    The linear values are scaled by ``exposure`` (default :func:`display_exposure`: the
    glow around the lamps to 1), then the luminance ``x`` rolls off as
    ``y = x (1 + x / W²) / (1 + x)`` with ``W = max(1, max x)`` (Reinhard et al. 2002,
    eq. 4: the brightest pixel just reaches white, the glow at 1 sits at mid-grey, so a
    lamp's rings stay visible beside it), the colour scaled by ``y / x`` (hue kept), and
    encoded with the sRGB curve (IEC 61966-2-1).  NaN and negative values become 0.

    >>> display_srgb(np.array([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1e4, 1e4, 1e4]]]), 1.0)[0, :, 0]
    array([  0, 188, 255], dtype=uint8)
    """
    from corona._validation import check_range
    arr = np.maximum(np.nan_to_num(np.asarray(rgb, dtype=np.float64)), 0.0)
    if exposure is None:
        exposure = display_exposure(arr)
    exposure = check_range("exposure", exposure, 0.0, np.inf, lo_open=True, hi_open=True)
    x = _luminance(arr) * exposure
    white = max(1.0, float(x.max()) if x.size else 1.0)
    y = x * (1.0 + x / white**2) / (1.0 + x)
    scale = np.divide(y, x, out=np.zeros_like(x), where=x > 0)
    out = np.clip(arr * exposure * (scale[..., None] if arr.ndim == 3 else scale), 0.0, 1.0)
    out = np.where(out <= 0.0031308, 12.92 * out, 1.055 * np.power(out, 1 / 2.4) - 0.055)
    return (out * 255 + 0.5).astype(np.uint8)


def far_field_corona(material, half_angle_deg: float = 10.0, size: int = 256,
                     temperature: float = 3000.0, n_wavelengths: int = 48) -> np.ndarray:
    """The corona around a point light seen through the layer at normal incidence.

    Returns linear sRGB (size, size, 3): the lobe ``F_a T_a T_s`` at each
    direction ``wo`` (d = wo.xy), times a black-body spectrum, integrated
    against the CIE 1931 colour matching functions.
    """
    d, lams, spd = _corona_view(half_angle_deg, size, temperature, n_wavelengths)
    spectra = np.stack([material.lobe_tabulated(d, lam) * s for lam, s in zip(lams, spd)], -1)
    return spectrum_to_linear_srgb(spectra, lams)


def _corona_view(half_angle_deg: float, size: int, temperature: float, n_wavelengths: int):
    """The view of a corona picture: ``d = (sin θx cos θy, sin θy)`` at the pixel centres (size, size, 2),
    the wavelengths [nm] of the visible range and the black body at ``temperature`` on them (peak 1)."""
    from corona.model import tabulated
    t = np.radians(np.linspace(-half_angle_deg, half_angle_deg, size))
    tx, ty = np.meshgrid(t, t[::-1], indexing="xy")
    d = np.stack([np.sin(tx) * np.cos(ty), np.sin(ty)], -1)
    lams = np.linspace(max(380.0, tabulated.WAVELENGTH_MIN), 780.0, n_wavelengths)
    spd = blackbody(lams, temperature)
    return d, lams, spd / spd.max()


def _u_extent(material, u_cap: float = 40.0) -> float:
    """Largest |u| to plot: the table's reach, at most ``u_cap``."""
    t = material.table
    reach = t.u_max if hasattr(t, "u_max") else t.reach
    return float(min(reach, u_cap))


def lobe_maps(material, u_extent: float, n: int = 201) -> dict:
    """The dimensionless tables on an n×n grid of ``u = (u_x, u_y)`` in [-u_extent, u_extent]².

    Returns ``u`` (n,) and maps (n, n), index [iy, ix]: ``form_factor`` =
    ``P(u/R)/R²`` (T_a = (R/λ)² × this), ``structure_factor`` = S (for fixed
    lattices the mean over each grid cell, so that Bragg peaks narrower than a
    cell keep their weight, as in the renderer's tables), and ``lobe`` =
    ``v(u) = [P + C (S - 1)]/R²`` (:meth:`corona.Material.lobe_terms`; = T_a T_s
    for identical scatterers; F_a (R/λ)² × this is the BSDF's lobe).
    """
    R = material.length_scale
    u = np.linspace(-u_extent, u_extent, n)
    ux, uy = np.meshgrid(u, u[::-1], indexing="xy")
    if material.isotropic:
        terms = material.lobe_terms(np.hypot(ux, uy), radial=True)
    else:
        terms = material.lobe_terms(np.stack([ux, uy], -1), cell=u[1] - u[0])
    return {"u": u, "form_factor": terms["P"] / R**2, "structure_factor": terms["S"], "lobe": terms["v"]}


def lobe_figure(material, path: str, wavelength: float = 550.0, half_angle_deg: float | None = None):
    """Save the material's pictures: the single-scatterer (form factor) table, the
    structure-factor table, their product (the lobe), and the far-field corona.

    Top row: 2-D maps over ``u = 2πR d/λ`` (log scale for the form factor and
    the lobe); bottom row: cuts along u_x (and u_y for anisotropic
    materials), and the corona as a person would see it around a 3000 K point
    light (spectrally integrated to sRGB).
    """
    try:
        from matplotlib.colors import LogNorm
        from matplotlib.figure import Figure
    except ImportError:
        raise CoronaError("lobe pictures need matplotlib: pip install 'corona-bsdf[reference]' "
                          "(or use `corona lobe --json` for the numbers)") from None

    R = material.length_scale
    U = _u_extent(material)
    maps = lobe_maps(material, U)
    u = maps["u"]
    mid = u.size // 2
    if half_angle_deg is None:
        # show the first few rings: u ≈ 14 at 550 nm
        half_angle_deg = float(np.degrees(np.arcsin(min(1.0, 14 * 0.55 / (2 * np.pi * R)))))
    img = far_field_corona(material, half_angle_deg)

    # a bare Figure (no pyplot): no backend is selected, no global state changes
    fig = Figure(figsize=(18, 8.6))
    ax = fig.subplots(2, 4, gridspec_kw={"height_ratios": [1.15, 1]})
    ext = [-U, U, -U, U]
    names = [("form_factor", f"single scatterer: T_a table ({type(material.shape).__name__})", True),
             ("structure_factor", f"structure factor: T_s table ({type(material.process).__name__})", False),
             ("lobe", "product: lobe T_a·T_s", True)]
    for k, (key, title, log) in enumerate(names):
        m = maps[key]
        if log:
            top = float(np.max(m)) if np.max(m) > 0 else 1.0
            im = ax[0, k].imshow(np.maximum(m, top * 1e-8), extent=ext, cmap="magma",
                                 norm=LogNorm(vmin=top * 1e-6, vmax=top))
        else:
            hi = max(1.5, float(np.percentile(m, 99.9)))
            im = ax[0, k].imshow(m, extent=ext, cmap="viridis", vmin=0.0, vmax=hi)
        ax[0, k].set(title=title, xlabel="u_x = 2πR d_x/λ", ylabel="u_y")
        fig.colorbar(im, ax=ax[0, k], fraction=0.046, pad=0.03)
        # cuts through the centre (row mid is u_y = 0, column mid is u_x = 0)
        ax[1, k].plot(u[mid:], m[mid, mid:], label="along u_x")
        if not material.isotropic:
            ax[1, k].plot(u[mid:], m[mid::-1, mid], "--", label="along u_y")
            ax[1, k].legend(fontsize=8)
        if log:
            ax[1, k].set_yscale("log")
            ax[1, k].set_ylim(max(np.max(m) * 1e-8, 1e-300), None)
        else:
            ax[1, k].axhline(1, color="0.7", lw=0.8)
        ax[1, k].set(xlabel="u", ylabel="dimensionless table" if k != 1 else "S")
    ax[0, 3].imshow(tonemap_srgb(img, percentile=99.0), extent=[-half_angle_deg, half_angle_deg] * 2)
    ax[0, 3].set(title="far-field corona (3000 K point light, sRGB)", xlabel="degree", ylabel="degree")
    lines = [f"area fraction F_a = {material.area_fraction:.3g}",
             f"length scale R = {R:.3g} µm",
             f"coherent transmittance = {material.coherent_transmittance:.4f}",
             f"diffuse (lobe) transmittance = {material.diffuse_transmittance():.4f}",
             f"reflectance = {material.reflectance:.4f}",
             "",
             f"at {wavelength:g} nm: u = 2πR|d|/λ, |d| = sin θ",
             f"u = 10  ↔  θ = {np.degrees(np.arcsin(min(1.0, 10 * wavelength * 1e-3 / (2 * np.pi * R)))):.3g}°",
             "lobe f = F_a (R/λ)² × table  (no cosine)"]
    ax[1, 3].axis("off")
    ax[1, 3].text(0.02, 0.95, "\n".join(lines), va="top", family="monospace", fontsize=10,
                  transform=ax[1, 3].transAxes)
    fig.suptitle(repr(material), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    return path


def sphere_corona(material, half_angle_deg: float, size: int = 192, temperature: float = 3000.0,
                  n_wavelengths: int = 32) -> np.ndarray:
    """:func:`far_field_corona` of a layer of Mie spheres (:class:`corona.model.mie.material.SphereMaterial`):
    its transmitted lobe (:meth:`~corona.model.mie.material.SphereMaterial.lobe`, which depends on λ beyond
    ``u``) at each pixel and wavelength; radial layers on one profile of 1024 points in ``|d|`` per
    wavelength, interpolated per pixel; a fixed lattice at each pixel (fewer pixels and wavelengths)."""
    if not material.isotropic:
        size, n_wavelengths = min(size, 96), min(n_wavelengths, 12)
    d, lams, spd = _corona_view(half_angle_deg, size, temperature, n_wavelengths)
    if material.isotropic:
        rho = np.hypot(d[..., 0], d[..., 1])
        grid = np.linspace(0.0, float(rho.max()), 1024)
        dg = np.stack([grid, 0 * grid], -1)
        prof = spectrum_to_linear_srgb(np.stack([material.lobe(dg, lam) * s for lam, s in zip(lams, spd)], -1), lams)
        return np.stack([np.interp(rho, grid, prof[:, c]) for c in range(3)], -1)
    spectra = np.stack([material.lobe(d, lam) * s for lam, s in zip(lams, spd)], -1)
    return spectrum_to_linear_srgb(spectra, lams)


def sphere_lobe_figure(material, path: str, wavelength: float = 550.0, half_angle_deg: float | None = None):
    """Save the pictures of a layer of Mie spheres (``corona lobe --shape sphere --out``): the
    transmitted lobe ``F_a T_a T_s`` [1/sr] along θ at 450, 550 and 650 nm (log scale; Mie theory,
    not the Fraunhofer tables of :func:`lobe_figure`), the structure factor ``T_s(q r)``, the
    far-field corona around a 3000 K point light (:func:`sphere_corona`) and the energies at
    ``wavelength`` [nm] (:meth:`corona.Material.directional_albedo`)."""
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise CoronaError("lobe pictures need matplotlib: pip install 'corona-bsdf[reference]' "
                          "(or use `corona lobe --json` for the numbers)") from None
    R = material.length_scale
    if half_angle_deg is None:      # the first few rings: u ≈ 14 at 550 nm, as lobe_figure
        half_angle_deg = float(np.degrees(np.arcsin(min(1.0, 14 * 0.55 / (2 * np.pi * R)))))
    theta = np.radians(np.linspace(0.0, 2.0 * half_angle_deg, 600))
    d = np.stack([np.sin(theta), 0 * theta], -1)
    fig = Figure(figsize=(18, 4.8))
    ax = fig.subplots(1, 4)
    for lam, colour in ((450.0, "tab:blue"), (550.0, "tab:green"), (650.0, "tab:red")):
        ax[0].plot(np.degrees(theta), np.maximum(material.lobe(d, lam), 1e-300), color=colour, label=f"{lam:g} nm")
    ax[0].set_yscale("log")
    ax[0].set(title="lobe F_a T_a T_s along θ (Mie theory)", xlabel="θ [degree]", ylabel="lobe [1/sr]")
    ax[0].legend(fontsize=8)
    u = np.linspace(0.0, 30.0, 400)
    if material.isotropic:
        ax[1].plot(u, material.structure_factor(u))
        ax[1].axhline(1, color="0.7", lw=0.8)
        ax[1].set(title=f"structure factor T_s ({type(material.process).__name__})", xlabel="u = q r", ylabel="S")
    else:
        ax[1].axis("off")
        ax[1].text(0.02, 0.95, f"{type(material.process).__name__}: Bragg peaks and\nDebye–Waller background "
                   "(the corona picture)", va="top", transform=ax[1].transAxes)
    img = sphere_corona(material, half_angle_deg)
    ax[2].imshow(tonemap_srgb(img, percentile=99.0), extent=[-half_angle_deg, half_angle_deg] * 2)
    ax[2].set(title="far-field corona (3000 K point light, sRGB)", xlabel="degree", ylabel="degree")
    e = material.directional_albedo(1.0, wavelength, n_phi=4 if material.isotropic else None)
    lines = [f"area fraction F_a = {material.area_fraction:.3g}", f"sphere radius r = {R:.3g} µm", "",
             f"at {wavelength:g} nm, normal incidence:",
             f"coherent transmittance = {e['coherent']:.4f}",
             f"lobe transmission = {e['lobe_transmission']:.4f}",
             f"lobe reflection (backward) = {e['lobe_reflection']:.4f}"]
    ax[3].axis("off")
    ax[3].text(0.02, 0.95, "\n".join(lines), va="top", family="monospace", fontsize=10, transform=ax[3].transAxes)
    fig.suptitle(repr(material), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    return path
