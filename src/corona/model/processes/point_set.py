"""Measured centres: S(q) estimated by a tapered periodogram."""
from __future__ import annotations

import os

import numpy as np

from corona._validation import CoronaError, check_range
from corona.model import registry
from corona.model.processes.base import Process


#: Largest |coordinate| of a point file [µm] (1 km): beyond, the window and the
#: periodogram's phases lose their meaning in float64.
COORDINATE_MAX = 1e9


#: The angle-averaged periodogram costs points × directions × wave numbers
#: complex multiply-adds (wave numbers: 1.25 q_max L / π); above this it is refused
#: (about a minute here), and points × directions is bounded by the memory of its
#: two complex arrays (16 B each).
PERIODOGRAM_MAX_WORK = 2e10
PERIODOGRAM_MAX_TERMS = 1.6e7


def _hann_ft(k, L):
    """Fourier transform of the Hann window ``sin²(π x/L)`` on ``[-L/2, L/2]``
    shifted to be centred at 0: ``∫ w(x) e^{-ikx} dx`` (real)."""
    a = 0.5 * np.asarray(k, dtype=np.float64) * L / np.pi      # np.sinc(x) = sin(πx)/(πx)
    return L * (0.5 * np.sinc(a) + 0.25 * (np.sinc(a - 1.0) + np.sinc(a + 1.0)))


def _windowed_sk(px, py, w, sumw2, nbar, Lx, Ly, qx, qy, chunk=2048):
    """``|Σ_j w_j e^{-i q·s_j} - n̄ Ŵ(q)|² / Σ_j w_j²`` at each ``(qx, qy)``;
    positions are relative to the window centre (a dense sum, in chunks of q)."""
    out = np.empty(qx.shape[0])
    for a in range(0, qx.shape[0], chunk):
        b = a + chunk
        phase = np.outer(qx[a:b], px) + np.outer(qy[a:b], py)          # (chunk, N)
        amp = np.exp(-1j * phase) @ w
        amp -= nbar * _hann_ft(qx[a:b], Lx) * _hann_ft(qy[a:b], Ly)
        out[a:b] = (amp.real**2 + amp.imag**2) / sumw2
    return out


def _radial_periodogram(px, py, w, sumw2, nbar, Lx, Ly, dq, nq, n_ang):
    """Tapered periodogram on the polar grid ``|q| = k dq`` (k < nq),
    ``θ_a = π (a + 1/2) / n_ang``; returns (n_ang, nq).  Along each ray the
    phases advance by the recurrence ``z_j ← z_j e^{-i dq p_j}`` (a progress
    bar on stderr when it takes more than 2 s)."""
    from tqdm import tqdm
    th = np.pi * (np.arange(n_ang) + 0.5) / n_ang
    c, s = np.cos(th), np.sin(th)
    step = np.exp(-1j * dq * (np.outer(c, px) + np.outer(s, py)))       # (n_ang, N)
    z = np.broadcast_to(w.astype(np.complex128), step.shape).copy()
    acc = np.empty((n_ang, nq), dtype=np.complex128)
    for k in tqdm(range(nq), desc="corona: point-set structure factor", unit="q", leave=False, delay=2.0):
        acc[:, k] = z.sum(axis=1)
        z *= step
    q = np.arange(nq) * dq
    acc -= nbar * _hann_ft(np.outer(c, q), Lx) * _hann_ft(np.outer(s, q), Ly)
    return (acc.real**2 + acc.imag**2) / sumw2


def _parse_box(box):
    try:
        b = np.asarray(box, dtype=np.float64)
    except (TypeError, ValueError):
        raise CoronaError(f"box={box!r} is not (Lx, Ly) or ((x0, x1), (y0, y1))") from None
    if b.shape == (2,):
        b = np.array([[0.0, b[0]], [0.0, b[1]]])
    if b.shape != (2, 2) or not np.all(np.isfinite(b)) or np.any(b[:, 1] <= b[:, 0]):
        raise CoronaError(f"box={box!r} is out of range; expected (Lx, Ly) > 0 or "
                          "((x0, x1), (y0, y1)) with x1 > x0, y1 > y0 [µm]")
    return b


class PointSet(Process):
    """Measured scatterer centres in a rectangular window.

    ``S(q)`` is the tapered periodogram of the one realisation,

        S(q) = |Σ_j w(s_j) e^{-i q·s_j} - n̄ Ŵ(q)|² / Σ_j w(s_j)²,

    with the separable Hann window ``w(x, y) = sin²(π x'/L_x) sin²(π y'/L_y)``
    (``x', y'`` measured from the box corner), its Fourier transform ``Ŵ``
    (analytic) and ``n̄ = N / box area``.  The taper suppresses the box-edge
    leakage of the plain ``|Σ e^{-iq·s}|²/N``; subtracting ``n̄ Ŵ(q)`` removes
    the forward (mean-density) peak.  The estimate is ``S`` convolved with
    ``|Ŵ|²/∫w²`` (resolution ≈ 4π/L), so values at ``|q| ≲ 4π/L`` are not
    meaningful; see Percival & Walden, *Spectral analysis for physical
    applications* (1993), ch. 6, and T. Rajala, S. Olhede, J. Grainger,
    D. Murrell, "What is the Fourier transform of a spatial point process?",
    IEEE Trans. Inf. Theory (2023), arXiv:2009.01474 (tapering, isotropic
    averages).

    With ``isotropic=True`` (default) ``S`` is the average over ``n_angles``
    directions of ``q`` (default 256, on a half circle since ``S(-q) = S(q)``),
    computed once on a radial grid of step ``π/L`` (``L`` the longer box
    side), smoothed with weights (1/4, 1/2, 1/4) and interpolated linearly;
    cost ``∝ N · n_angles · q_max L``.  With ``isotropic=False`` the raw
    periodogram is evaluated at each ``q`` (anisotropic, and noisy: one
    realisation's periodogram has ~100 % scatter at each ``q``).

    Parameters
    ----------
    points : array_like (N, 2)
        Centres [µm], inside the box.
    box : (Lx, Ly) or ((x0, x1), (y0, y1))
        Observation window [µm].
    isotropic : bool, default True
        Angular average (radial ``S``) or the raw anisotropic estimate.
    n_angles : int or None
        Directions of the angular average (None: 256).
    """

    def __init__(self, points, box, isotropic: bool = True, n_angles: int | None = None):
        try:
            p = np.array(points, dtype=np.float64)
        except (TypeError, ValueError):
            raise CoronaError("points must be a numeric array of shape (N, 2)") from None
        if p.ndim != 2 or p.shape[1] != 2:
            raise CoronaError(f"points must have shape (N, 2), got {p.shape}")
        if p.shape[0] < 1:
            raise CoronaError("points is empty; a PointSet needs at least one centre")
        if not np.all(np.isfinite(p)):
            raise CoronaError("points contains non-finite values")
        b = _parse_box(box)
        tol = 1e-9 * float(np.max(b[:, 1] - b[:, 0]))
        outside = ((p[:, 0] < b[0, 0] - tol) | (p[:, 0] > b[0, 1] + tol)
                   | (p[:, 1] < b[1, 0] - tol) | (p[:, 1] > b[1, 1] + tol))
        if np.any(outside):
            k = int(np.argmax(outside))
            raise CoronaError(f"points[{k}] = {tuple(p[k])} lies outside box "
                              f"x in [{b[0, 0]:g}, {b[0, 1]:g}], y in [{b[1, 0]:g}, {b[1, 1]:g}] µm")
        p.setflags(write=False)
        self.points = p
        self.box = (tuple(b[0]), tuple(b[1]))
        self.isotropic = bool(isotropic)
        if n_angles is not None:
            n_angles = int(check_range("n_angles", n_angles, 1, 1e6))
        self.n_angles = n_angles
        self._radial = None  # (q grid, S grid)

    def __repr__(self):
        return (f"PointSet(<{len(self.points)} points>, box={self.box}, "
                f"isotropic={self.isotropic})")

    # --- construction -----------------------------------------------------
    @classmethod
    def from_file(cls, path, box=None, **kwargs) -> "PointSet":
        """Read centres [µm] from a text file (CSV, semicolon-, tab- or
        whitespace-separated; ``#`` comments and one header line allowed; the
        first two columns are x, y) or a ``.npy`` array (N, ≥2).

        ``box=None`` estimates the window from the points: per axis the
        unbiased range of N uniform points, ``(max - min)(N + 1)/(N - 1)``,
        centred on the points.
        """
        path = os.fspath(path)
        if os.path.isdir(path):
            raise CoronaError(f"point file {path!r} is a directory")
        if not os.path.exists(path):
            raise CoronaError(f"point file {path!r} does not exist")
        if not os.path.isfile(path):     # a device (/dev/zero), a FIFO, a socket ...
            raise CoronaError(f"point file {path!r} is not a regular file")
        if path.lower().endswith(".npy"):
            try:
                arr = np.load(path, allow_pickle=False)
            except Exception as e:  # noqa: BLE001
                first = (str(e).strip().splitlines() or [type(e).__name__])[0]
                raise CoronaError(f"point file {path!r} is not a readable .npy array: {first}") from None
            if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
                raise CoronaError(f"point file {path!r} holds {arr.dtype} values; expected real numbers "
                                  "(integer or floating point)")
            arr = np.asarray(arr, dtype=np.float64)
            if arr.size == 0:
                raise CoronaError(f"point file {path!r} contains no points")
            if arr.ndim != 2 or arr.shape[1] < 2:
                raise CoronaError(f"point file {path!r} holds an array of shape {arr.shape}; "
                                  "expected (N, 2) or more columns")
            pts = arr[:, :2]
        else:
            pts = _read_point_text(path)
        if not np.all(np.isfinite(pts)):
            raise CoronaError(f"point file {path!r} contains non-finite coordinates")
        big = np.abs(pts) > COORDINATE_MAX
        if np.any(big):
            k = int(np.argmax(big.any(axis=1)))
            raise CoronaError(f"point file {path!r}: point {k + 1} has a coordinate of "
                              f"{float(pts[k][np.argmax(big[k])]):g} µm; allowed |x|, |y| <= {COORDINATE_MAX:g} µm")
        if box is None:
            n = len(pts)
            if n < 2:
                raise CoronaError(f"point file {path!r} has {n} point; give box= explicitly")
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            if np.any(hi <= lo):
                raise CoronaError(f"point file {path!r}: the points do not span an area; give box=")
            half = 0.5 * (hi - lo) * (n + 1) / (n - 1)
            mid = 0.5 * (hi + lo)
            box = ((mid[0] - half[0], mid[0] + half[0]), (mid[1] - half[1], mid[1] + half[1]))
        return cls(pts, box, **kwargs)

    # --- geometry -----------------------------------------------------------
    @property
    def box_size(self):
        """``(Lx, Ly)`` [µm]."""
        return (self.box[0][1] - self.box[0][0], self.box[1][1] - self.box[1][0])

    @property
    def box_area(self) -> float:
        Lx, Ly = self.box_size
        return Lx * Ly

    @property
    def number_density(self) -> float:
        """``n = N / box area`` [µm⁻²]."""
        return len(self.points) / self.box_area

    def area_fraction(self, shape) -> float:
        return len(self.points) * shape.area / self.box_area

    def validate(self, shape) -> None:
        fa = self.area_fraction(shape)
        if fa >= 1.0:
            raise CoronaError(f"PointSet: area fraction N|A|/box area = {fa:.4g} is out of range; "
                              "expected < 1 (shape too large for these centres)")

    @property
    def q_step(self) -> float:
        """Step [rad/µm] of the q grid on which the radial ``S`` is tabulated
        (linear in between): ``π / max(Lx, Ly)``."""
        return np.pi / max(self.box_size)

    # --- structure factor ----------------------------------------------------
    def _window(self):
        (x0, x1), (y0, y1) = self.box
        Lx, Ly = x1 - x0, y1 - y0
        px = self.points[:, 0] - 0.5 * (x0 + x1)
        py = self.points[:, 1] - 0.5 * (y0 + y1)
        w = np.cos(np.pi * px / Lx) ** 2 * np.cos(np.pi * py / Ly) ** 2
        return px, py, w, Lx, Ly

    def periodogram(self, q) -> np.ndarray:
        """The tapered periodogram at ``q`` [rad/µm] of shape (..., 2) (no averaging)."""
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 0 or q.shape[-1] != 2:
            raise CoronaError(f"q must have shape (..., 2), got {q.shape}")
        px, py, w, Lx, Ly = self._window()
        sw2 = float(np.sum(w * w))
        if sw2 <= 0.0:
            return np.ones(q.shape[:-1])
        flat = q.reshape(-1, 2)
        out = _windowed_sk(px, py, w, sw2, self.number_density, Lx, Ly,
                           np.ascontiguousarray(flat[:, 0]), np.ascontiguousarray(flat[:, 1]))
        return out.reshape(q.shape[:-1])

    def _radial_table(self, q_max):
        if self._radial is not None and self._radial[0][-1] >= q_max:
            return self._radial
        px, py, w, Lx, Ly = self._window()
        L = max(Lx, Ly)
        dq = np.pi / L
        nq = int(np.ceil(1.25 * q_max / dq)) + 3
        n_ang = 256 if self.n_angles is None else self.n_angles
        n = len(self.points)
        if n * n_ang > PERIODOGRAM_MAX_TERMS or float(n) * n_ang * nq > PERIODOGRAM_MAX_WORK:
            raise CoronaError(
                f"PointSet: {n} points in a {Lx:.4g} x {Ly:.4g} µm window need {n} x {n_ang} directions x "
                f"{nq} wave numbers = {float(n) * n_ang * nq:.3g} terms for S(q) up to {q_max:.3g} rad/µm; "
                f"allowed at most {PERIODOGRAM_MAX_WORK:.3g} (and points x directions <= "
                f"{PERIODOGRAM_MAX_TERMS:.3g}): use fewer points or a smaller window")
        sw2 = float(np.sum(w * w))
        P = _radial_periodogram(px, py, w, sw2, self.number_density, Lx, Ly, dq, nq, n_ang)
        S = P.mean(axis=0)
        # light radial smoothing (1/4, 1/2, 1/4): width ≈ 2π/L, below the taper's resolution
        Ss = S.copy()
        Ss[1:-1] = 0.25 * S[:-2] + 0.5 * S[1:-1] + 0.25 * S[2:]
        self._radial = (np.arange(nq) * dq, Ss)
        return self._radial

    def structure_factor_radial(self, q_abs, shape=None) -> np.ndarray:
        """Angle-averaged estimate of ``S(|q|)`` (``q_abs`` in rad/µm)."""
        q = np.abs(np.asarray(q_abs, dtype=np.float64))
        if q.size == 0:
            return np.zeros(q.shape)
        qg, S = self._radial_table(float(q.max()))
        return np.interp(q, qg, S)

    def structure_factor_at(self, q, shape=None) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        if q.ndim == 0 or q.shape[-1] != 2:
            raise CoronaError(f"q must have shape (..., 2), got {q.shape}")
        if self.isotropic:
            return self.structure_factor_radial(np.hypot(q[..., 0], q[..., 1]), shape)
        return self.periodogram(q)


def _read_point_text(path) -> np.ndarray:
    rows = []
    header_skipped = False
    try:
        with open(path, "r", encoding="utf-8-sig") as fh:
            for lineno, line in enumerate(fh, 1):
                s = line.split("#", 1)[0].strip()
                if not s:
                    continue
                tokens = s.replace(",", " ").replace(";", " ").split()
                try:
                    vals = [float(t) for t in tokens[:2]]
                    if len(tokens) < 2:
                        raise ValueError
                except ValueError:
                    if not rows and not header_skipped and len(tokens) >= 2 and not any(
                            _is_number(t) for t in tokens[:2]):
                        header_skipped = True  # a header line such as "x,y"
                        continue
                    # the line itself is not echoed: the file may be anything (a secret)
                    raise CoronaError(f"point file {path!r}, line {lineno}: cannot read two numbers "
                                      "(x, y)") from None
                rows.append(vals)
    except UnicodeDecodeError:
        raise CoronaError(f"point file {path!r} is not a text file (use .npy for binary arrays)") from None
    if not rows:
        raise CoronaError(f"point file {path!r} contains no points")
    return np.array(rows, dtype=np.float64)


def _is_number(t) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False



def points_file(p: dict) -> str:
    """The point file of process='points': ``points_filename``, else ``filename``
    unless the shape reads that (the mask image of shape='mask')."""
    if p.get("points_filename"):
        return p["points_filename"]
    shape = registry.SHAPE_FAMILIES.get(p.get("shape")) if isinstance(p.get("shape"), str) else None
    if shape is not None and "filename" in shape.parameters:     # the shape's own file (a mask's image)
        raise CoronaError(f"process='points' with shape={shape.name!r} needs points_filename=<point file> "
                          f"(filename is the {shape.name} image)")
    if not p.get("filename"):
        raise CoronaError("process='points' needs filename=<point file> (or points_filename=)")
    return p["filename"]


# --- the family (corona.model.registry): process=points ------------------------------------------
registry.add_process(registry.ProcessFamily("points", lambda p, shape: PointSet.from_file(points_file(p)),
                                            ("filename", "points_filename"), cls=PointSet, absolute=True))
