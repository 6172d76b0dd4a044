"""Pictures of a material's lobe: tables and the far-field corona (matplotlib)."""
from __future__ import annotations

import numpy as np

from .color import blackbody, spectrum_to_linear_srgb, tonemap_srgb


def far_field_corona(material, half_angle_deg: float = 10.0, size: int = 256,
                     temperature: float = 3000.0, n_wavelengths: int = 48) -> np.ndarray:
    """The corona around a point light seen through the layer at normal incidence.

    Returns linear sRGB (size, size, 3): the lobe ``F_a T_a T_s`` at each
    direction ``wo`` (d = wo.xy), times a black-body spectrum, integrated
    against the CIE 1931 colour matching functions.
    """
    from . import tables
    t = np.radians(np.linspace(-half_angle_deg, half_angle_deg, size))
    tx, ty = np.meshgrid(t, t[::-1], indexing="xy")
    d = np.stack([np.sin(tx) * np.cos(ty), np.sin(ty)], -1)
    lams = np.linspace(max(380.0, tables.WAVELENGTH_MIN), 780.0, n_wavelengths)
    spd = blackbody(lams, temperature)
    spd = spd / spd.max()
    spectra = np.stack([material.lobe_tabulated(d, lam) * s for lam, s in zip(lams, spd)], -1)
    return spectrum_to_linear_srgb(spectra, lams)


def lobe_figure(material, path: str, wavelength: float = 550.0, half_angle_deg: float | None = None):
    """Save a 4-panel figure: form factor, structure factor, their product, the corona."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    R = material.length_scale
    u_plot = min(material.table.u_max, 40.0)
    u = np.linspace(1e-6, u_plot, 2000)
    q = u / R
    pts = np.stack([q, 0 * q], -1)
    P = material.shape.form_factor(pts) / R**2
    S = material.process.structure_factor_at(pts, material.shape)
    v = material.lobe_dimensionless(np.stack([u, 0 * u], -1))
    if half_angle_deg is None:
        # show the first few rings: u ≈ 14 at 550 nm
        half_angle_deg = float(np.degrees(np.arcsin(min(1.0, 14 * 0.55 / (2 * np.pi * R)))))
    img = far_field_corona(material, half_angle_deg)

    fig, ax = plt.subplots(1, 4, figsize=(17, 4))
    ax[0].semilogy(u, P / P[0])
    ax[0].set(title=f"form factor T_a ({type(material.shape).__name__})", xlabel="u = 2πR|d|/λ",
              ylabel="relative")
    ax[1].plot(u, S)
    ax[1].axhline(1, color="0.7", lw=0.8)
    ax[1].set(title=f"structure factor T_s ({type(material.process).__name__})", xlabel="u", ylabel="S")
    ax[2].semilogy(u, v / v[0])
    ax[2].set(title="lobe T_a·T_s", xlabel="u", ylabel="relative")
    ax[3].imshow(tonemap_srgb(img, percentile=99.0), extent=[-half_angle_deg, half_angle_deg] * 2)
    ax[3].set(title="far-field corona (3000 K light)", xlabel="degree", ylabel="degree")
    fig.suptitle(repr(material), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
