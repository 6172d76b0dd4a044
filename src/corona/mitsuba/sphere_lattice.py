"""Dr.Jit pieces of spheres on a fixed lattice (docs/physics.md#spheres-on-a-lattice).

Each piece reads the sphere's Mie rows through the public interface of the sphere plugin's rows
lobe (:class:`corona.mitsuba.sphere.MieRowsLobe`: ``states``, ``pattern``, ``spectrum``,
``eval_pdf``, ``sample``), called ``rows`` below.
:class:`LatticeS` (below), :class:`LatticeLobe` (``P S`` from the Mie rows),
:class:`OrderSampler` (the Bragg orders), :class:`LatticeSampler` (the orders mixed with the
sphere's own sampler), :class:`LatticeCap` (the cap per lane) and :class:`LatticeLayer` (the lobe
component the sphere plugin holds for ``process=lattice-*``).
:class:`LatticeS` evaluates a fixed :class:`corona.Lattice`'s structure factor per lane in closed
form, as :meth:`corona.Lattice.structure_factor_at` does in numpy:

    S(q) = 1 - e^{-q²δ²} + Σ_{G ≠ 0, near q} (2π)² n e^{-G²δ²} e^{-|q - G|²/2w²} / (2π w²)

over the ``(2m + 1)²`` reciprocal lattice vectors about the one nearest ``q`` in fractional
coordinates (``f = q · a_i / 2π`` rounded; ``m = ⌈1/2 + 6 w a / 2π⌉``, 1 for the default
crystallite of 20 spacings: the nearest 3 × 3 peaks), ``w`` the peaks' rms width.  It is what the
renderer's lattice lobe ``F_s w P S`` needs besides the sphere plugin's Mie rows and the cap.
:class:`LatticeCap` is the cap's energy per lane in closed form, and :class:`LatticeLayer` the
assembled layer (coherent beam and lattice lobe) that the sphere plugin chooses at load for
``process=lattice-*`` and calls for its eval, pdf and sample (docs/physics.md#spheres-on-a-lattice).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from corona.mitsuba.common import array as _array, gather as _gather, logical_not as _not

__all__ = ["LatticeCap", "LatticeLayer", "LatticeLobe", "LatticeS", "LatticeSampler", "OrderSampler",
           "lattice_layer_params"]

#: The most Bragg orders the per-lane cap (:class:`LatticeCap`) may hold: each costs every lane a
#: Mie lookup per wavelength (a sample's cost grows with them: benchmarks/sphere_lattice_cost.py);
#: a wider lattice is refused at load (:func:`lattice_layer_params`).
LATTICE_ORDERS_MAX = 20_000
#: The Bragg orders' share of the lattice lobe's samples (:class:`LatticeSampler`) ...
ORDER_SHARE = 0.5
#: ... scaled by ``e^{-G₁²δ²} / ORDER_SHARE_DW`` where the first order's Debye–Waller factor is
#: below this (a jitter of about a fifth of the spacing: the orders fade into the diffuse part) ...
ORDER_SHARE_DW = 0.1
#: ... and no order branch below this share (the orders' weight is then below ~1e-6 of the
#: diffuse part's near them, which the sphere's sampler covers).
ORDER_SHARE_MIN = 1e-6


class LatticeS:
    """A fixed lattice's ``S(q)`` in Dr.Jit (module docstring).

    Parameters
    ----------
    lattice : corona.Lattice
        With ``orientation="fixed"``.
    """

    def __init__(self, lattice):
        A = np.asarray(lattice.lattice_vectors, dtype=np.float64)
        B = np.asarray(lattice.reciprocal_vectors, dtype=np.float64)
        w = float(lattice.peak_width)
        # Python floats (numpy scalars would make numpy masks in scalar variants)
        self.A = (A / (2.0 * np.pi)).tolist()            # f = q · a_i / 2π
        self.B = B.tolist()
        self.jitter2 = float(lattice.jitter) ** 2
        self.inv_2w2 = 0.5 / (w * w)
        self.amp = (2.0 * np.pi) ** 2 * float(lattice.number_density) / (2.0 * np.pi * w * w)
        self.m = max(1, int(math.ceil(0.5 + 6.0 * w * lattice.spacing / (2.0 * np.pi))))

    def __call__(self, qx, qy):
        """``S`` at the in-plane momentum transfer ``(qx, qy)`` [rad/µm] (mi.Float each)."""
        out = 1.0 - dr.exp(-(qx * qx + qy * qy) * self.jitter2) if self.jitter2 > 0 else mi.Float(0.0)
        return self.peaks(qx, qy, self.amp, out)

    def peaks(self, qx, qy, amp, out, g_max2=None):
        """``out + amp Σ_{G ≠ 0} e^{-G²δ²} e^{-|q - G|²/2w²}`` over the ``(2m + 1)²`` peaks nearest
        ``q`` (those with ``|G|² ≤ g_max2`` where given)."""
        A, B = self.A, self.B
        f1 = dr.round(qx * A[0][0] + qy * A[0][1])
        f2 = dr.round(qx * A[1][0] + qy * A[1][1])
        for dh in range(-self.m, self.m + 1):
            for dk in range(-self.m, self.m + 1):
                h, k = f1 + dh, f2 + dk
                gx = h * B[0][0] + k * B[1][0]
                gy = h * B[0][1] + k * B[1][1]
                g2 = gx * gx + gy * gy
                dx, dy = qx - gx, qy - gy
                e = -(dx * dx + dy * dy) * self.inv_2w2
                if self.jitter2 > 0:
                    e = e - g2 * self.jitter2
                keep = (h != 0) | (k != 0)
                if g_max2 is not None:
                    keep = keep & (g2 <= g_max2)
                out = out + dr.select(keep, amp * dr.exp(e), 0.0)
        return out


class OrderSampler:
    """Samples the Bragg orders of a fixed lattice: an order ``G`` with probability
    ``π_G = W_G / Σ W`` over the orders ``0 < |G| ≤ G_max`` (``W_G = (2π)² n e^{-G²δ²}``, a
    :class:`mitsuba.DiscreteDistribution`), then ``q = G + w ξ`` (``ξ`` a standard normal pair:
    the broadened peak ``g_G``), ``wo_xy = q/k - wi_xy`` (the grating equation), and the side of
    the layer with the caller's probabilities.  A sample past the horizon (``|wo_xy| ≥ 1``) fails.
    In solid angle (``d²q = k² |cos θo| dΩ``) the density of ``wo`` on the side it is on is

        pdf(wo) = p_side(wo) · k² |cos θo| · Σ_{|G| ≤ G_max} π_G g_G(k (wo + wi)_xy),

    the sum closed-form over the ``(2m + 1)²`` peaks nearest ``q`` (as :class:`LatticeS`): it
    integrates to the share of samples that do not fail.

    Parameters
    ----------
    lattice : corona.Lattice
        With ``orientation="fixed"``.
    g_max : float
        The largest ``|G|`` sampled [rad/µm] (``2 k`` of the shortest wavelength reaches every
        order that can leave the layer).
    """

    def __init__(self, lattice, g_max: float):
        G, W = lattice.bragg_peaks(float(g_max))
        self.structure = LatticeS(lattice)
        self.g_max2 = float(g_max) ** 2
        self.w = float(lattice.peak_width)
        #: the first order's Debye–Waller factor ``e^{-G₁²δ²}`` (0 without an order)
        self.first_dw = float(W[0] / ((2.0 * np.pi) ** 2 * lattice.number_density)) if W.size else 0.0
        # the orders whose weight float32 holds (a jitter of microns leaves none: e^{-G²δ²} underflows)
        keep = np.asarray(W, dtype=np.float32) > 0
        G, W = G[keep], W[keep]
        self.total = float(np.sum(W))
        self.count = int(G.shape[0])
        if self.count == 0:                # nothing to sample: density 0 (LatticeSampler skips it)
            self.Gx = self.Gy = self.orders = None
            return
        self.Gx, self.Gy = _array(mi.Float, G[:, 0]), _array(mi.Float, G[:, 1])
        self.orders = mi.DiscreteDistribution(_array(mi.Float, W))

    def sample(self, wi, k, u_order, u_peak, active=True):
        """``(wo_x, wo_y, valid)``: an order's direction in the plane (the side is the caller's)."""
        idx = self.orders.sample(u_order, active)
        gx = _gather(mi.Float, self.Gx, idx, active)
        gy = _gather(mi.Float, self.Gy, idx, active)
        xi = mi.warp.square_to_std_normal(u_peak)
        px = (gx + self.w * xi.x) / k - wi.x
        py = (gy + self.w * xi.y) / k - wi.y
        valid = mi.Bool(active) & (px * px + py * py < 1.0)
        return px, py, valid

    def density_q(self, qx, qy):
        """``Σ_{|G| ≤ G_max} π_G g_G(q)`` [µm²]: the sampled orders' density in q (0 without one)."""
        if self.count == 0:
            return dr.zeros(mi.Float, dr.width(qx))
        amp = self.structure.amp / self.total               # (2π)² n / (2π w² Σ W)
        return self.structure.peaks(qx, qy, amp, mi.Float(0.0), self.g_max2 * (1 + 1e-6))

    def pdf(self, wi, wo, k, p_side):
        """The density of ``wo`` in solid angle, ``p_side`` the probability of its side."""
        qx, qy = k * (wo.x + wi.x), k * (wo.y + wi.y)
        return p_side * k * k * dr.abs(wo.z) * self.density_q(qx, qy)


class LatticeLobe:
    """The lattice layer's lobe per steradian, ``Z = P S`` (one size, ``C = P``), in Dr.Jit.

    ``P`` is the Mie pattern read from a sphere plugin's rows by their own lookup
    (:meth:`corona.mitsuba.sphere.MieRowsLobe.states` and
    :meth:`~corona.mitsuba.sphere.MieRowsLobe.pattern`: the forward rows for ``Θ < 90°`` from
    ``-wi``, the backward rows beyond), ``S`` the lattice's (:class:`LatticeS`) at
    ``q = k (wo + wi)_xy``, on both lobes (a crystal is a strict monolayer).  The cap ``F_s w``
    is not applied here (docs/physics.md#spheres-on-a-lattice).

    Parameters
    ----------
    rows : corona.mitsuba.sphere.MieRowsLobe
        The Mie rows of the same sphere (a plugin of any isotropic process: the rows do not depend
        on it)
    lattice : corona.Lattice (fixed)
    """

    def __init__(self, rows, lattice):
        self.rows = rows
        self.structure = LatticeS(lattice)

    def __call__(self, si, wo, active=True, states=None):
        """Per wavelength of the lane: ``Z`` at ``wo`` (a list of mi.Float); ``states`` the rows'
        (:meth:`corona.mitsuba.sphere.MieRowsLobe.states`), made where not given."""
        active = mi.Bool(active)
        wi = si.wi
        if states is None:
            states, _ = self.rows.states(si, active)
        out = []
        for st in states:
            P, _ = self.rows.pattern(st, wi, wo, active)
            k = (2.0 * dr.pi) / st["lam"]
            S = self.structure(k * (wo.x + wi.x), k * (wo.y + wi.y))
            out.append(dr.select(active, P * S, 0.0))
        return out


class LatticeSampler:
    """The lattice lobe's sampler: a mixture of the Bragg orders (:class:`OrderSampler`, with
    probability ``alpha``) and the sphere plugin's own sampler of its Mie lobes (the diffuse part
    ``P (1 - e^{-q²δ²})`` and the orders' Mie envelope: the rows lobe's ``sample`` and ``eval_pdf``
    with its coherent beam off), one-sample balance heuristic.

    The order branch picks one of the lane's wavelengths uniformly, an order for it, and the side
    of the layer in the ratio of ``Σ_λ P`` at the two candidate directions; so

        pdf(wo) = alpha · p_side(wo) · mean_λ [k² |cos θo| Σ π_G g_G(k (wo + wi)_xy)]
                  + (1 - alpha) · pdf_sphere(wo)

    with ``pdf_sphere`` the sphere plugin's pdf of its lobes alone (its coherent beam off).

    Parameters
    ----------
    rows : corona.mitsuba.sphere.MieRowsLobe
        The Mie rows of the same sphere (bare: no pane)
    lattice : corona.Lattice (fixed)
    alpha : float, optional
        The order branch's share; by default :data:`ORDER_SHARE`, scaled down with the first
        order's Debye–Waller factor ``e^{-G₁²δ²}`` below :data:`ORDER_SHARE_DW` (the orders carry
        that share of the energy near them: a jitter of a spacing leaves the diffuse part) and 0
        below :data:`ORDER_SHARE_MIN`.  0 where no order's weight is left (then the sphere's
        sampler alone, ``pdf = pdf_sphere``).
    """

    def __init__(self, rows, lattice, alpha: float | None = None):
        from corona.model import tabulated
        self.rows = rows
        self.lobe = LatticeLobe(rows, lattice)
        self.orders = OrderSampler(lattice, 2.0 * 2.0 * np.pi / (tabulated.WAVELENGTH_MIN * 1e-3))
        if alpha is None:
            alpha = ORDER_SHARE * min(1.0, self.orders.first_dw / ORDER_SHARE_DW)
            alpha = alpha if alpha >= ORDER_SHARE_MIN else 0.0
        self.alpha = float(alpha) if self.orders.count else 0.0
        #: the rows lobe's own sampler: its lobes alone (the coherent beam off)
        self.ctx = mi.BSDFContext()
        self.ctx.type_mask = +(mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection)

    def _mie(self, si, wo, active, states=None):
        """``Σ_λ P`` at ``wo`` over the lane's wavelengths, and the lane's states (the rows',
        made where not given)."""
        if states is None:
            states, _ = self.rows.states(si, active)
        total = mi.Float(0.0)
        for st in states:
            total += self.rows.pattern(st, si.wi, wo, active)[0]
        return total, states

    def _side(self, si, px, py, active, states):
        cz = dr.safe_sqrt(1.0 - px * px - py * py)
        up, down = mi.Vector3f(px, py, cz), mi.Vector3f(px, py, -cz)
        a, _ = self._mie(si, up, active, states)
        b, _ = self._mie(si, down, active, states)
        return up, down, dr.select(a + b > 0, a / dr.maximum(a + b, 1e-30), 0.5)

    def _order_pdf(self, si, wo, active, states):
        dens = mi.Float(0.0)
        for st in states:
            dens += self.orders.pdf(si.wi, wo, (2.0 * dr.pi) / st["lam"], 1.0)
        _, _, p_up = self._side(si, wo.x, wo.y, active, states)
        return dr.select(wo.z > 0, p_up, 1.0 - p_up) * dens / len(states)

    def sample(self, si, u1, u2, active=True):
        """``(wo, pdf)``; pdf 0 where the sample failed (an order past the horizon)."""
        active = mi.Bool(active)
        if self.alpha == 0.0:              # no order branch: the sphere's sampler alone
            bs, _ = self.rows.sample(self.ctx, si, u1, u2, active)
            return bs.wo, dr.select(active & (bs.pdf > 0), self.pdf(si, bs.wo, active), 0.0)
        pick_order = u1 < self.alpha
        u = dr.select(pick_order, u1 / self.alpha, (u1 - self.alpha) / (1.0 - self.alpha))
        states, _ = self.rows.states(si, active)
        n = len(states)
        # the order branch: a wavelength, an order (the rest of u), the side (what is left of it)
        g = u * n
        i = dr.minimum(mi.UInt32(dr.floor(g)), n - 1)
        u_order = g - mi.Float(i)
        lam = states[0]["lam"]
        for m in range(1, n):
            lam = dr.select(i == m, states[m]["lam"], lam)
        _, u_side = self.orders.orders.sample_reuse(u_order, active & pick_order)
        px, py, valid = self.orders.sample(si.wi, (2.0 * dr.pi) / lam, u_order, u2, active & pick_order)
        up, down, p_up = self._side(si, px, py, active & pick_order & valid, states)
        wo_order = dr.select(u_side < p_up, up, down)
        bs, _ = self.rows.sample(self.ctx, si, u, u2, active & _not(pick_order))
        wo = dr.select(pick_order, wo_order, bs.wo)
        ok = dr.select(pick_order, valid, bs.pdf > 0) & active
        return wo, dr.select(ok, self.pdf(si, wo, active, states), 0.0)

    def pdf(self, si, wo, active=True, states=None):
        """The mixture's density of ``wo`` in solid angle (``states``: the rows', made where not
        given)."""
        active = mi.Bool(active)
        if states is None:
            states, _ = self.rows.states(si, active)
        p_sphere = self.rows.eval_pdf(self.ctx, si, wo, active)[1]
        if self.alpha == 0.0:
            return dr.select(active, p_sphere, 0.0)
        return dr.select(active, self.alpha * self._order_pdf(si, wo, active, states)
                         + (1.0 - self.alpha) * p_sphere, 0.0)


class LatticeCap:
    """The lattice layer's energy ``e(λ, wi)`` per lane (per unit ``F_s w``) and its cap
    ``w = min(1, (1 - |t|²) / (ENERGY_MARGIN F_s e))`` (docs/physics.md#spheres-on-a-lattice).

        e = D + Σ_G e_G,   e_G = W_G / (k² ε^½) Σ_i w_i(u) [P(wo↑) + P(wo↓)](r_i) / (1 + r_i)^½

    over the orders that reach the layer's directions (``ρ_G = |G/k - wi_xy| < 1 + 8 ε``), ``ε =
    w/k``, ``u = (ρ_G - 1)/ε``, the radial Gauss rule ``(t_i, w_i)`` of
    :func:`corona.model.mie.lattice_cap.rim_rules` (``r_i = 1 - ε t_i²``) near the horizon and the
    peak's centre (``P/c (1 + 3/8u²)``) for ``u < -RIM_U``; one Dr.Jit loop over the orders
    (sorted by ``|G|``, each lane stopping past ``k_max (1 + |wi_xy|) + 8 w``; per wavelength
    an order is a branch taken where it reaches the layer, ``u < 8``, and the rule's other nodes
    a branch taken near the horizon), ``P`` read from the
    sphere's Mie rows by their own lookup (:meth:`corona.mitsuba.sphere.MieRowsLobe.pattern`) at
    both sides' directions.  ``D`` is the jittered
    lattice's diffuse part per row of x and ``μ_i``
    (:func:`corona.model.mie.lattice_cap.diffuse_rows_mu`, read bilinearly; 0 for a perfect
    crystal).

    Parameters
    ----------
    rows : corona.mitsuba.sphere.MieRowsLobe
        The sphere's Mie rows
    lattice : corona.Lattice (fixed)
    """

    def __init__(self, rows, lattice):
        from corona.model import tabulated
        from corona.model.mie import lattice_cap
        self.rows = rows
        w = float(lattice.peak_width)
        self.w = w
        k_max = 2.0 * np.pi / (tabulated.WAVELENGTH_MIN * 1e-3)
        G, W = lattice.bragg_peaks(2.0 * k_max + lattice_cap.RIM_REACH * w)
        keep = np.asarray(W, dtype=np.float32) > 0        # a jitter's e^{-G²δ²} below float32: no energy
        G, W = G[keep], W[keep]
        Gn = np.hypot(G[:, 0], G[:, 1])
        order = np.argsort(Gn, kind="stable")
        G, W, Gn = G[order], W[order], Gn[order]
        self.count = int(G.shape[0])
        # one Vector4f an order: (G_x, G_y, W_G, |G|) (without an order one unread zero entry)
        self.orders = _array(mi.Float, np.stack([G[:, 0], G[:, 1], W, Gn], axis=-1).ravel() if self.count
                             else np.zeros(4))
        us, tn, tw = lattice_cap.rim_rules()
        self.n_rule = int(tn.shape[1])
        self.rule_u0, self.rule_du, self.rule_n = float(us[0]), float(us[1] - us[0]), int(us.size)
        self.rule = _array(mi.Float, np.concatenate([tn, tw], axis=1).ravel())
        self.rim_u = float(lattice_cap.RIM_U)
        self.reach = float(lattice_cap.RIM_REACH)
        material = rows.material
        rows, radius, jitter = material.rows, float(material.length_scale), float(lattice.jitter)
        if jitter > 0.0:     # seconds of quadrature: kept in the table cache beside the rows
            def make():
                return {"D": lattice_cap.diffuse_rows_mu(rows, radius, jitter)}
            key = {**material.table_params(), "lattice_jitter": jitter,
                   "lattice_diffuse": [tabulated.code_key(lattice_cap.diffuse_rows_mu, make),
                                       lattice_cap.DIFFUSE_MU_NODES, lattice_cap.DIFFUSE_PHI]}
            D = np.asarray(tabulated.cached(key, make, use_cache=material.use_cache)["D"])
        else:
            D = lattice_cap.diffuse_rows_mu(rows, radius, jitter)
        self.has_diffuse = bool(np.any(D > 0))
        self.n_mu = int(D.shape[1])
        self.D = _array(mi.Float, D.ravel())

    def _psum(self, st, wi, px, py, active):
        """(forward, backward) ``P`` at ``wo = (p, ±c)``: each side's ``P`` by its chord's lobe."""
        cz = dr.safe_sqrt(1.0 - px * px - py * py)
        e_f, e_b = mi.Float(0.0), mi.Float(0.0)
        for side in (1.0, -1.0):
            P, forward = self.rows.pattern(st, wi, mi.Vector3f(px, py, side * cz), active)
            e_f += dr.select(forward, P, 0.0)
            e_b += dr.select(forward, 0.0, P)
        return e_f, e_b

    def energies(self, si, states, active=True):
        """Per state (wavelength) of the lane: ``(e_f, e_b)``, the orders' energy split by the lobe
        (forward or backward chord) with the diffuse part in ``e_f`` (per unit ``F_s w``)."""
        from corona.mitsuba.common import gather4
        active = mi.Bool(active)
        wi = si.wi
        n = len(states)
        ks = [(2.0 * dr.pi) / st["lam"] for st in states]
        k_max = ks[0]
        for k in ks[1:]:
            k_max = dr.maximum(k_max, k)
        g_stop = k_max * (1.0 + dr.sqrt(wi.x * wi.x + wi.y * wi.y)) + self.reach * self.w
        R = self.n_rule

        def cond(i, *e):
            o = gather4(self.orders, i, active & (i < self.count))
            return active & (i < self.count) & (o.w <= g_stop)

        def body(i, *e):
            e = list(e)
            o = gather4(self.orders, i, active)
            for m, (st, k) in enumerate(zip(states, ks)):
                eps = self.w / k
                px, py = o.x / k - wi.x, o.y / k - wi.y
                rho = dr.sqrt(px * px + py * py)
                u = (rho - 1.0) / eps
                reach = active & (u < self.reach)
                far = u < -self.rim_u
                scale = o.z / (k * k)
                # the rim rule near the horizon (read linearly in u); node 0 is the peak's centre
                # far from it (P/c (1 + 3/8u²))
                near = reach & _not(far)
                g = dr.clip((u - self.rule_u0) * (1.0 / self.rule_du), 0.0, self.rule_n - 1.001)
                j = mi.UInt32(dr.floor(g))
                t = g - mi.Float(j)
                inv_r = 1.0 / dr.maximum(rho, 1e-12)
                c2 = dr.maximum(1.0 - rho * rho, 1e-12)
                def node(q, on, ef, eb):
                    t0 = _gather(mi.Float, self.rule, j * (2 * R) + q, on)
                    t1 = _gather(mi.Float, self.rule, (j + 1) * (2 * R) + q, on)
                    w0 = _gather(mi.Float, self.rule, j * (2 * R) + R + q, on)
                    w1 = _gather(mi.Float, self.rule, (j + 1) * (2 * R) + R + q, on)
                    tq, wq = dr.lerp(t0, t1, t), dr.lerp(w0, w1, t)
                    r = 1.0 - eps * tq * tq
                    wt = scale * wq / dr.sqrt(eps * (1.0 + r))
                    if q == 0:
                        r = dr.select(far, rho, r)
                        wt = dr.select(far, scale * (1.0 + 0.375 / (u * u)) / dr.sqrt(c2), wt)
                    fq, bq = self._psum(st, wi, px * inv_r * r, py * inv_r * r, on)
                    return ef + dr.select(on, fq * wt, 0.0), eb + dr.select(on, bq * wt, 0.0)

                def rim(ef, eb):
                    for q in range(1, R):
                        ef, eb = node(q, near, ef, eb)
                    return ef, eb

                def order(ef, eb):
                    ef, eb = node(0, reach, ef, eb)
                    # the rule's other nodes only where the order is near the horizon (a branch)
                    return dr.if_stmt(args=(ef, eb), cond=near, true_fn=rim, false_fn=lambda ef, eb: (ef, eb))

                # only the orders that reach the layer's directions at this wavelength (a branch)
                ef, eb = dr.if_stmt(args=(mi.Float(0.0), mi.Float(0.0)), cond=reach, true_fn=order,
                                    false_fn=lambda ef, eb: (ef, eb))
                e[2 * m] = e[2 * m] + ef
                e[2 * m + 1] = e[2 * m + 1] + eb
            return (i + 1, *e)

        zero = [mi.Float(0.0) for _ in range(2 * n)]
        out = dr.while_loop(state=(mi.UInt32(0), *zero), cond=cond, body=body)[1:] if self.count else zero
        res = []
        for m, st in enumerate(states):
            e_f, e_b = out[2 * m], out[2 * m + 1]
            if self.has_diffuse:     # bilinear in (row, μ_i)
                g = dr.clip(dr.abs(wi.z), 0.0, 1.0) * (self.n_mu - 1)
                b = dr.minimum(mi.UInt32(dr.floor(g)), self.n_mu - 2)
                f = g - mi.Float(b)
                k0 = st["j"] * self.n_mu + b
                d = [_gather(mi.Float, self.D, k0 + o, active) for o in (0, 1, self.n_mu, self.n_mu + 1)]
                e_f = e_f + dr.lerp(dr.lerp(d[0], d[1], f), dr.lerp(d[2], d[3], f), st["t"])
            res.append((e_f, e_b))
        return res

    def capped(self, si, states, active=True):
        """The states with the lattice layer's cap: ``w`` and ``e_f``, ``e_b`` (the lobes' energies
        times ``F_s w``) replaced (new dicts)."""
        from corona.model.mie.layer import ENERGY_MARGIN
        out = []
        for st, (e_f, e_b) in zip(states, self.energies(si, states, active)):
            scattered = st["fs"] * (e_f + e_b) * ENERGY_MARGIN
            w = dr.minimum(1.0, dr.maximum(1.0 - st["coherent"], 0.0) / dr.maximum(scattered, 1e-30))
            out.append({**st, "w": w, "e_f": st["fs"] * w * e_f, "e_b": st["fs"] * w * e_b,
                        "e_lattice": e_f + e_b})
        return out


def lattice_layer_params(params: dict, textures: dict):
    """``(lattice, params)`` for a sphere layer with ``process=lattice-*``: the fixed lattice the
    parameters make (:func:`corona.parameters.material_from_parameters`, its checks and errors) and
    the parameters of the sphere plugin's Mie rows (the same sphere, ``process=poisson`` at the
    lattice's area fraction).  One-line errors for what the lattice path does not take: a glass
    substrate, area_fraction or radius textures that vary, and a lattice wider than
    :data:`LATTICE_ORDERS_MAX` Bragg orders."""
    from corona.model import tabulated
    from corona._validation import CoronaError
    from corona.parameters import material_from_parameters
    import warnings
    process = params["process"]
    for name in ("area_fraction", "radius"):
        tex = textures.get(name)
        if tex is not None and tex.is_spatially_varying():
            raise CoronaError(f"a {name} texture is out of range for shape='sphere' with process={process!r}; "
                              "allowed a uniform value (the lattice's spacing and its Bragg orders are one "
                              "for the whole layer)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        material = material_from_parameters(**params)
    lattice = material.lattice
    # the cap's orders, |G| <= 2 k_max: about π (2 k_max)² A_c / (2π)² for a cell of area A_c
    g_max = 2.0 * 2.0 * np.pi / (tabulated.WAVELENGTH_MIN * 1e-3)
    cell_max = LATTICE_ORDERS_MAX * 4.0 * np.pi / (g_max * g_max)
    spacing_max = math.sqrt(cell_max * lattice.spacing ** 2 / lattice.cell_area)
    if lattice.spacing > spacing_max * (1 + 1e-9):
        raise CoronaError(f"the lattice spacing {lattice.spacing:.4g} µm (radius={float(material.sphere.radius):g}, "
                          f"area_fraction={float(material.area_fraction):.4g}) is out of range for shape='sphere' "
                          f"with process={process!r} in the renderer; allowed at most {spacing_max:.4g} µm "
                          f"(area_fraction at least π radius² / {cell_max:.4g} µm²: each of its Bragg orders, "
                          f"at most {LATTICE_ORDERS_MAX}, costs every sample a Mie lookup)")
    if material.substrate is not None:
        raise CoronaError(f"substrate={params.get('substrate')!r} is out of range for shape='sphere' with "
                          f"process={process!r} in the renderer; allowed none (the sphere plugin's pane "
                          "composes the isotropic lobes only; the numpy model takes a lattice on glass)")
    rows = {k: v for k, v in params.items() if k != "jitter"}
    rows["process"] = "poisson"
    rows["area_fraction"] = float(material.area_fraction)
    return lattice, rows


class LatticeLayer:
    """The lobe component of the sphere plugin on a fixed lattice (chosen at load for
    ``process=lattice-*``, in place of the disordered :class:`corona.mitsuba.sphere.MieRowsLobe`,
    whose rows it reads): the coherent beam ``C = |1 - F_s s₀|²`` along
    ``-wi`` and the lattice lobe ``F_s w P S`` (:class:`LatticeLobe`) with the per-lane cap
    (:class:`LatticeCap`); the coherent beam picked with the probability of its weight ``C`` (the
    lane's mean), the lobe otherwise (its capped energy is at most ``1 - C``: the pdf needs no
    cap), sampled by :class:`LatticeSampler`.
    The sphere plugin calls its :meth:`eval_pdf` and :meth:`sample` (its ``lobe``).

    Parameters
    ----------
    rows : corona.mitsuba.sphere.MieRowsLobe
        The sphere's Mie rows (a plugin of ``process=poisson``, no pane)
    lattice : corona.Lattice (fixed)
    """

    def __init__(self, rows, lattice):
        self.rows = rows
        self.lattice = lattice
        self.cap = LatticeCap(rows, lattice)
        self.sampler = LatticeSampler(rows, lattice)
        self.lobe = self.sampler.lobe

    def _states(self, si, active):
        states, m = self.rows.states(si, active)
        return self.cap.capped(si, states, active), m

    def _selection(self, ctx, states):
        """``(p_coherent, p_lobe)``: the coherent beam with the probability of its weight (the
        lane's mean ``C``), the lobe with the rest (whose capped energy is at most ``1 - C``), so
        that the pdf needs no cap; honouring the context."""
        on_coh = ctx.is_enabled(mi.BSDFFlags.DeltaTransmission, 0)
        on_lobe = ctx.is_enabled(mi.BSDFFlags.GlossyTransmission, 1) or ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 2)
        if not on_coh:
            return mi.Float(0.0), mi.Float(1.0 if on_lobe else 0.0)
        if not on_lobe:
            return mi.Float(1.0), mi.Float(0.0)
        c = mi.Float(0.0)
        for st in states:
            c = c + st["coherent"]
        p_coh = dr.clip(c / len(states), 0.0, 1.0)
        return p_coh, 1.0 - p_coh

    def eval_pdf(self, ctx, si, wo, active, cached=None):
        """``(f |cos θo|, pdf)`` of the lattice lobe (the coherent beam is a delta)."""
        active = mi.Bool(active)
        if cached is None:     # the pdf needs no cap (:meth:`_selection`), eval does
            states, m = self._states(si, active)
        else:
            states, m = cached
        _, p_lobe = self._selection(ctx, states)
        on_f = ctx.is_enabled(mi.BSDFFlags.GlossyTransmission, 1)
        on_b = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 2)
        forward = dr.norm(wo + si.wi) <= dr.norm(wo - si.wi)
        on = active & dr.select(forward, on_f, on_b)
        Z = self.lobe(si, wo, active, states)
        values = [dr.select(on, z * (st["fs"] * st["w"]), 0.0) for st, z in zip(states, Z)]
        pdf = p_lobe * self.sampler.pdf(si, wo, active)
        return self.rows.spectrum(values), dr.select(active, pdf, 0.0)

    def sample(self, ctx, si, sample1, sample2, active=True):
        """``(BSDFSample3f, weight)``: the coherent beam or the lattice lobe (:class:`LatticeSampler`)."""
        wi = si.wi
        cos_i = mi.Frame3f.cos_theta(wi)
        active = mi.Bool(active) & (cos_i != 0)
        states, m = self._states(si, active)
        p_coh, p_lobe = self._selection(ctx, states)
        pick_coh = active & (sample1 < p_coh)
        pick_lobe = active & _not(pick_coh) & (p_lobe > 0)
        u = dr.clip((sample1 - p_coh) / dr.maximum(p_lobe, 1e-30), 0.0, 0.99999994)
        wo_lobe, pdf_lobe = self.sampler.sample(si, u, sample2, pick_lobe)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.eta = 1.0
        bs.wo = dr.select(pick_coh, -wi, wo_lobe)
        forward = dr.norm(bs.wo + wi) <= dr.norm(bs.wo - wi)
        bs.sampled_component = dr.select(pick_coh, mi.UInt32(0), dr.select(forward, mi.UInt32(1), mi.UInt32(2)))
        same_side = cos_i * mi.Frame3f.cos_theta(bs.wo) > 0
        bs.sampled_type = dr.select(pick_coh, mi.UInt32(+mi.BSDFFlags.DeltaTransmission),
                                    dr.select(same_side, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                              mi.UInt32(+mi.BSDFFlags.GlossyTransmission)))
        lobe_ok = pick_lobe & (pdf_lobe > 0)
        value, pdf = self.eval_pdf(ctx, si, bs.wo, lobe_ok, (states, m))
        bs.pdf = dr.select(pick_coh, p_coh, pdf)
        weight = dr.select(pdf > 0, value / dr.maximum(pdf, 1e-30), 0.0)
        coh = self.rows.spectrum([st["coherent"] for st in states])
        weight = dr.select(pick_coh, coh / dr.maximum(p_coh, 1e-30), weight)
        ok = pick_coh | (lobe_ok & (bs.pdf > 0))
        return bs, dr.select(ok, mi.Spectrum(weight), 0.0)
