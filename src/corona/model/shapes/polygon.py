"""Polygons: closed-form Fourier transform by the edge sum."""
from __future__ import annotations

import math

import numpy as np

from corona._validation import CoronaError, check_positive
from corona.model import registry
from corona.model.shapes.base import _TWO_PI, Shape, Term, _check_finite, _check_int, _q_array


def _orient(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


def _check_simple(v: np.ndarray) -> None:
    """Raise CoronaError if the closed polygon ``v`` (n, 2) self-intersects.

    Edges are sorted by their smallest x; only pairs whose x and y extents
    overlap get the exact orientation test (vectorised, in bounded chunks).
    """
    n = len(v)
    a = v
    b = np.roll(v, -1, axis=0)
    scale = float(np.max(np.abs(v))) or 1.0
    eps = 1e-12 * scale**2
    e = b - a
    # adjacent edges folding back onto each other
    nxt = np.roll(e, -1, axis=0)
    cr = e[:, 0] * nxt[:, 1] - e[:, 1] * nxt[:, 0]
    dt = e[:, 0] * nxt[:, 0] + e[:, 1] * nxt[:, 1]
    bad = (np.abs(cr) <= eps) & (dt < 0)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise CoronaError(f"vertices: polygon folds back on itself at vertex {(i + 1) % n}; "
                          "expected a simple polygon")
    if n <= 3:
        return
    tol = 1e-12 * scale
    xlo = np.minimum(a[:, 0], b[:, 0]) - tol
    xhi = np.maximum(a[:, 0], b[:, 0]) + tol
    ylo = np.minimum(a[:, 1], b[:, 1]) - tol
    yhi = np.maximum(a[:, 1], b[:, 1]) + tol
    order = np.argsort(xlo, kind="stable")
    xs = xlo[order]
    hi = np.searchsorted(xs, xhi[order], side="right")
    counts = np.maximum(hi - np.arange(n) - 1, 0)
    budget = 4_000_000
    start = 0
    while start < n:
        stop = start + 1
        acc = counts[start]
        while stop < n and acc + counts[stop] <= budget:
            acc += counts[stop]
            stop += 1
        c = counts[start:stop]
        tot = int(c.sum())
        start_i = start
        start = stop
        if tot == 0:
            continue
        pos = np.repeat(np.arange(start_i, stop), c)
        first = np.repeat(np.cumsum(c) - c, c)
        pj = pos + 1 + (np.arange(tot) - first)
        i = order[pos]
        j = order[pj]
        keep = (ylo[i] <= yhi[j]) & (ylo[j] <= yhi[i])
        d = (j - i) % n
        keep &= (d != 1) & (d != n - 1)
        i, j = i[keep], j[keep]
        if not len(i):
            continue
        ax, ay, bx, by = a[i, 0], a[i, 1], b[i, 0], b[i, 1]
        cx, cy, dx, dy = a[j, 0], a[j, 1], b[j, 0], b[j, 1]
        o1 = _orient(ax, ay, bx, by, cx, cy)
        o2 = _orient(ax, ay, bx, by, dx, dy)
        o3 = _orient(cx, cy, dx, dy, ax, ay)
        o4 = _orient(cx, cy, dx, dy, bx, by)
        z1, z2, z3, z4 = (np.abs(o) <= eps for o in (o1, o2, o3, o4))
        s1 = np.where(z1, 0, np.sign(o1))
        s2 = np.where(z2, 0, np.sign(o2))
        s3 = np.where(z3, 0, np.sign(o3))
        s4 = np.where(z4, 0, np.sign(o4))
        cross = (s1 * s2 <= 0) & (s3 * s4 <= 0)
        colin = z1 & z2 & z3 & z4
        if np.any(colin):
            # collinear segments intersect only if their projections overlap
            ex, ey = bx - ax, by - ay
            L2 = ex * ex + ey * ey
            t1 = ((cx - ax) * ex + (cy - ay) * ey) / L2
            t2 = ((dx - ax) * ex + (dy - ay) * ey) / L2
            overlap = (np.maximum(t1, t2) >= 0) & (np.minimum(t1, t2) <= 1)
            cross = np.where(colin, overlap, cross)
        if np.any(cross):
            k = int(np.argmax(cross))
            e1, e2 = sorted((int(i[k]), int(j[k])))
            raise CoronaError(f"vertices: polygon is not simple (edges {e1} and {e2} "
                              "intersect); expected a simple polygon")


#: Polygons with more edges go to the form-factor grid (the edge sum costs one
#: sincos per edge and wavelength in the kernel).
EDGE_MAX = 16


class Polygon(Shape):
    """An arbitrary simple polygon (convex or not), transmitting inside.

    Closed-form Fraunhofer transform by the divergence theorem
    (``e^{-iq·x} = ∇·(i q e^{-iq·x}/|q|²)``): with counter-clockwise edges
    ``e_k = v_{k+1} - v_k`` and midpoints ``m_k``,

        ``Â(q) = (i/|q|²) Σ_k (q × e_k) · sinc(q·e_k/2) · e^{-i q·m_k}``,

    ``q × e = q_x e_y - q_y e_x``, ``sinc(x) = sin(x)/x`` (finite for q
    parallel to an edge).  For ``|q| R < 0.02`` (R the circumradius), where
    the sum cancels to O(q²), the Taylor series ``Σ_n (-i)^n/n! ∫(q·x)^n dx``
    to order 7 is used instead, with the moments of the triangle fan from the
    centroid in closed form (``∫_T (q·x)^n = 2|T| n!/(n+2)! Σ_{i+j=n} α^i β^j``
    for a triangle (0, a, b), α = q·a, β = q·b).  Both branches agree to
    ~1e-13 at the switch, so the result is continuous and never NaN.

    Parameters
    ----------
    vertices : array_like, shape (n, 2)
        Vertices [µm] in either winding; a repeated closing vertex and
        repeated consecutive vertices are dropped.  The polygon is re-centred
        on its area centroid and stored counter-clockwise as ``vertices``.

    Notes
    -----
    ``length_scale`` is the circumradius (largest vertex distance from the
    centroid); ``exclusion_diameter`` twice that.

    References
    ----------
    S.-W. Lee, R. Mittra, "Fourier transform of a polygonal shape function and
    its application in electromagnetics", IEEE Trans. Antennas Propag. 31(1),
    99–103 (1983); J. Wuttke, "Numerically stable form factor of any polygon
    and polyhedron", J. Appl. Cryst. 54, 580–587 (2021).
    """

    _TAYLOR_U = 0.02
    _TAYLOR_ORDER = 7
    _CHUNK = 4_000_000  # q points × edges per vectorised block

    def __init__(self, vertices):
        v = self._validated_vertices(vertices)
        _check_simple(v)
        self._set_vertices(v)

    # --- construction helpers ----------------------------------------------
    @staticmethod
    def _validated_vertices(vertices) -> np.ndarray:
        try:
            v = np.array(vertices, dtype=np.float64)
        except (TypeError, ValueError):
            raise CoronaError("vertices must be a numeric array of shape (n, 2) [µm]") from None
        if v.ndim != 2 or v.shape[1] != 2:
            raise CoronaError(f"vertices must have shape (n, 2) [µm], got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise CoronaError("vertices contain non-finite values; expected finite µm")
        # drop consecutive duplicates (including the closing vertex)
        if len(v) > 1:
            keep = np.any(v != np.roll(v, -1, axis=0), axis=1)
            v = v[keep]
        if len(v) < 3:
            raise CoronaError("vertices: a polygon needs at least 3 distinct vertices, "
                              f"got {len(v)}")
        return v

    def _set_vertices(self, v: np.ndarray) -> None:
        w = np.roll(v, -1, axis=0)
        cr = v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]
        A2 = float(np.sum(cr))
        scale = float(np.max(np.ptp(v, axis=0)))
        if not abs(A2) > 1e-12 * scale**2:
            raise CoronaError("vertices: the polygon has zero area; expected a simple polygon "
                              "with area > 0")
        c = np.sum((v + w) * cr[:, None], axis=0) / (3.0 * A2)
        if A2 < 0:
            v = v[::-1]
        v = np.ascontiguousarray(v - c)
        v.setflags(write=False)
        self.vertices = v
        w = np.roll(v, -1, axis=0)
        self._edges = w - v
        self._mids = 0.5 * (w + v)
        self._cross = v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]
        self._area = 0.5 * float(np.sum(self._cross))
        self._radius = float(np.max(np.hypot(v[:, 0], v[:, 1])))

    def __repr__(self):
        return f"Polygon(n_vertices={len(self.vertices)}, area={self.area:g})"

    @property
    def area(self) -> float:
        return self._area

    @property
    def length_scale(self) -> float:
        return self._radius

    @property
    def _cost(self) -> float:
        return float(len(self.vertices))

    @property
    def perimeter(self) -> float:
        """Perimeter [µm]."""
        return float(np.sum(np.hypot(self._edges[:, 0], self._edges[:, 1])))

    def kernel_terms(self):
        """The edge sum for the render kernel (:mod:`corona.mitsuba.kernels`), up to
        :data:`EDGE_MAX` edges (more: None, the form-factor grid)."""
        if len(self.vertices) > EDGE_MAX:
            return None
        if type(self).amplitude is not Polygon.amplitude:      # a subclass with a form factor of its own
            return None
        return [Term("polygon", {"vertices": np.array(self.vertices)}, 1.0, self.area, shape=self)]

    def signed_distance(self, x, y) -> np.ndarray:
        """Signed distance [µm] of the points (x, y) [µm] to the outline (negative inside; the
        crossing-number rule, so non-convex outlines too)."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        v = self.vertices
        d2 = np.full(x.shape, np.inf)
        inside = np.zeros(x.shape, dtype=bool)
        for (ax, ay), (bx, by) in zip(v, np.roll(v, -1, axis=0)):
            ex, ey = bx - ax, by - ay
            wx, wy = x - ax, y - ay
            t = np.clip((wx * ex + wy * ey) / (ex * ex + ey * ey), 0.0, 1.0)
            np.minimum(d2, (wx - t * ex) ** 2 + (wy - t * ey) ** 2, out=d2)
            with np.errstate(divide="ignore", invalid="ignore"):
                cross = ((ay > y) != (by > y)) & (x < ax + (y - ay) * ex / ey)
            inside ^= cross
        d = np.sqrt(d2)
        return np.where(inside, -d, d)

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        shape = q.shape[:-1]
        qf = q.reshape(-1, 2)
        M = qf.shape[0]
        out = np.empty(M, dtype=np.complex128)
        qq = qf[:, 0] ** 2 + qf[:, 1] ** 2
        small = qq * self._radius**2 < self._TAYLOR_U**2
        big = ~small
        if np.any(big):
            out[big] = self._amplitude_edges(qf[big], qq[big])
        if np.any(small):
            out[small] = self._amplitude_taylor(qf[small])
        return out.reshape(shape)

    def _amplitude_edges(self, q, qq):
        ex, ey = self._edges[:, 0], self._edges[:, 1]
        mx, my = self._mids[:, 0], self._mids[:, 1]
        N = len(ex)
        out = np.empty(len(q), dtype=np.complex128)
        step = max(1, self._CHUNK // N)
        for s in range(0, len(q), step):
            qx = q[s:s + step, 0:1]
            qy = q[s:s + step, 1:2]
            w = (qx * ey - qy * ex) * np.sinc((qx * ex + qy * ey) / _TWO_PI)
            ph = qx * mx + qy * my
            re = np.sum(w * np.cos(ph), axis=1)
            im = -np.sum(w * np.sin(ph), axis=1)
            # i (re + i im) / |q|²
            out[s:s + step] = (-im + 1j * re) / qq[s:s + step]
        return out

    def _amplitude_taylor(self, q):
        step = max(1, self._CHUNK // len(self._cross))
        if len(q) > step:
            return np.concatenate([self._amplitude_taylor(q[s:s + step])
                                   for s in range(0, len(q), step)])
        v = self.vertices
        w = np.roll(v, -1, axis=0)
        alpha = q[:, 0:1] * v[:, 0] + q[:, 1:2] * v[:, 1]   # (M, N)
        beta = q[:, 0:1] * w[:, 0] + q[:, 1:2] * w[:, 1]
        c = self._cross
        h = np.ones_like(alpha)
        apow = np.ones_like(alpha)
        total = np.full(len(q), 0.5 * np.sum(c), dtype=np.complex128)
        for n in range(1, self._TAYLOR_ORDER + 1):
            apow = apow * alpha
            h = beta * h + apow                      # Σ_{i+j=n} α^i β^j
            mom = h @ c / math.factorial(n + 2)       # ∫(q·x)^n dx / n!
            total += (-1j) ** n * mom
        return total


class RegularPolygon(Polygon):
    """A regular polygon with ``sides`` vertices on a circle of radius ``radius``.

    Vertices at ``radius · (cos φ_k, sin φ_k)``, ``φ_k = angle + 2πk/sides``
    (``angle = 0`` puts a vertex on the +x axis).  Transform as for
    :class:`Polygon`; area ``(n/2) r² sin(2π/n)``.

    Parameters
    ----------
    sides : int
        Number of sides, 3 … 100000 (the plugin's ``sides``).
    radius : float
        Circumradius r > 0 [µm] (= ``length_scale``; the plugin's ``radius``).
    angle : float, default 0
        Rotation [degree], counter-clockwise (the plugin's ``angle``).

    Examples
    --------
    ``RegularPolygon(4, r, angle=45)`` is the square of half-width ``r/√2``:

    >>> import numpy as np, corona
    >>> q = np.array([[0.7, 0.2], [1.3, -0.4]])
    >>> a = corona.RegularPolygon(4, 1.0, angle=45.0).form_factor(q)
    >>> bool(np.allclose(a, corona.Square(1.0 / np.sqrt(2.0)).form_factor(q), rtol=1e-12))
    True
    """

    def __init__(self, sides: int, radius: float, *, angle: float = 0.0):
        self.sides = _check_int("sides", sides, 3, 100_000)
        self.radius = check_positive("radius", radius, "µm")
        self.angle = _check_finite("angle", angle, "degree")
        phi = math.radians(self.angle) + _TWO_PI * np.arange(self.sides) / self.sides
        v = self.radius * np.stack([np.cos(phi), np.sin(phi)], axis=-1)
        self._set_vertices(v)
        # the centroid is the centre: keep exact values (no round-off shift)
        v.setflags(write=False)
        self.vertices = v
        w = np.roll(v, -1, axis=0)
        self._edges = w - v
        self._mids = 0.5 * (w + v)
        self._cross = v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]
        self._area = 0.5 * float(np.sum(self._cross))
        self._radius = self.radius
        self._symmetry = self.sides

    def __repr__(self):
        return f"RegularPolygon(sides={self.sides}, radius={self.radius:g}, angle={self.angle:g})"

    def key(self) -> dict:
        return {"type": "RegularPolygon", "sides": self.sides, "radius": self.radius,
                "angle": self.angle}




# --- the family (corona.model.registry): shape=polygon -------------------------------------------
registry.add_shape(registry.ShapeFamily(
    "polygon", lambda p: RegularPolygon(p["sides"], p["radius"], angle=p["angle"]),
    ("radius", "sides", "angle") + registry.FLAT + registry.ROTATABLE, cls=RegularPolygon,
    mixable=True))
