"""MLS-MPM substep kernels in Warp (Hu et al. 2018), built for 2D or 3D.

One substep is: clear the grid, particle-to-grid transfer of APIC momentum and
stress (P2G), grid velocity update with gravity, walls and obstacles, and
grid-to-particle transfer with advection (G2P). Quadratic B-spline weights, so
every particle touches a 3^d stencil of nodes.

Importing this module imports Warp: only a running simulator does.

Reproducibility: P2G scatters with atomic adds. Warp runs CPU kernels serially,
so their order is fixed; on CUDA the kernels are compiled in Warp's
deterministic mode (sort-and-reduce of the atomics), so a seed gives the same
bits run after run on the same device. Its record buffers hold the 3^d adds
of every particle thread into each grid array (``deterministic_max_records``).
"""

from dataclasses import dataclass
from functools import cache
from typing import Any

import warp as wp

wp.config.log_level = wp.LOG_WARNING  # no greeting or per-module compile lines

SAND = wp.constant(0)
FLUID = wp.constant(1)
GOOP = wp.constant(2)
"""Constitutive-model ids of MPM particles (kinematic bodies are grid boundaries, not particles)."""

BOX = wp.constant(0)
ELLIPSOID = wp.constant(1)
POLYGON = wp.constant(2)
PLANE = wp.constant(3)
"""Obstacle shape ids."""

_OPTIONS = {"enable_backward": False, "deterministic": wp.DeterministicMode.RUN_TO_RUN, "max_unroll": 27}
"""Unrolling the 3^d stencil loop lets the compiler fold every offset into a constant."""


@dataclass(frozen=True)
class Kernels:
    """The kernels of one spatial dimension, and the Warp types they take."""

    dim: int
    vec: Any
    mat: Any
    ivec: Any
    p2g: Any
    grid_update: Any
    g2p: Any


@wp.func
def coulomb_contact(v_rel: Any, normal: Any, mu: float):
    """Velocity relative to a rigid surface after a contact with Coulomb friction.

    Separating motion is free; approaching motion loses its normal part, and the
    tangential part loses ``mu`` times the removed normal speed (sticking when
    that exceeds it).
    """
    vn = wp.dot(v_rel, normal)
    if vn >= 0.0:
        return v_rel
    vt = v_rel - vn * normal
    vt_norm = wp.length(vt)
    if vt_norm <= -mu * vn:
        return vt * 0.0
    return vt * (1.0 + mu * vn / vt_norm)


@wp.func
def no_slip_contact(v_rel: Any, normal: Any):
    """Velocity relative to a no-slip surface: no tangential motion, and only separating normal motion."""
    return wp.max(wp.dot(v_rel, normal), 0.0) * normal


@wp.func
def polygon_distance(p: wp.vec2, vertices: wp.array(dtype=wp.vec2), start: int, count: int):
    """Signed distance from ``p`` to a counter-clockwise polygon (negative inside), and the outward
    normal of its nearest edge. Inside by the even-odd crossing rule."""
    best = float(1.0e30)
    normal = wp.vec2(0.0, 1.0)
    crossings = int(0)
    for i in range(count):
        a = vertices[start + i]
        b = vertices[start + (i + 1) % count]
        edge = b - a
        t = wp.clamp(wp.dot(p - a, edge) / wp.dot(edge, edge), 0.0, 1.0)
        gap = wp.length(p - (a + t * edge))
        if gap < best:
            best = gap
            normal = wp.normalize(wp.vec2(edge[1], -edge[0]))
        above_a = a[1] > p[1]
        above_b = b[1] > p[1]
        if above_a != above_b and p[0] < a[0] + (p[1] - a[1]) / (b[1] - a[1]) * edge[0]:
            crossings += 1
    if crossings % 2 == 1:
        best = -best
    return best, normal


@cache
def kernels(dim: int) -> Kernels:
    """Compile-once kernels for ``dim`` = 2 or 3."""
    vec = wp.types.vector(dim, float)
    mat = wp.types.matrix((dim, dim), float)
    ivec = wp.types.vector(dim, int)
    stencil = 3**dim

    @wp.func
    def drucker_prager_projection(eps: Any, mu: float, lam: float, alpha: float):
        """Drucker-Prager return mapping of Hencky strain ``eps`` = log(singular values) (Klar et al. 2016).

        Tension returns to the cone tip (no cohesion); a deviatoric strain outside
        the cone of slope ``alpha`` shrinks back onto it.
        """
        tr = float(0.0)
        for a in range(wp.static(dim)):
            tr += eps[a]
        if tr > 0.0:
            return eps * 0.0
        dev = eps - vec(tr / float(dim))
        dev_norm = wp.length(dev)
        if dev_norm <= 0.0:
            return eps
        plastic = dev_norm + (float(dim) * lam + 2.0 * mu) / (2.0 * mu) * tr * alpha
        if plastic <= 0.0:
            return eps
        return eps - plastic / dev_norm * dev

    @wp.func
    def svd(F: Any):
        if wp.static(dim == 2):
            return wp.svd2(F)
        else:
            return wp.svd3(F)

    @wp.func
    def von_mises_projection(eps: Any, yield_strain: float):
        """Scale the deviatoric Hencky strain back to the von Mises radius; volume is untouched."""
        tr = float(0.0)
        for a in range(wp.static(dim)):
            tr += eps[a]
        mean = vec(tr / float(dim))
        dev = eps - mean
        dev_norm = wp.length(dev)
        if dev_norm <= yield_strain:
            return eps
        return mean + dev * (yield_strain / dev_norm)

    @wp.func
    def hencky_stress(
        F: Any, mu: float, lam: float, plastic: int, yield_param: float, F_out: wp.array(dtype=mat), p: int
    ):
        """Kirchhoff stress of Hencky elasticity after the plastic return mapping; stores the elastic F.

        ``plastic`` picks the yield surface: Drucker-Prager (sand, ``yield_param`` =
        cone slope alpha) or von Mises (goop, ``yield_param`` = yield strain).
        """
        U, sig, V = svd(F)
        eps = vec()
        for a in range(wp.static(dim)):
            eps[a] = wp.log(wp.max(sig[a], 1.0e-6))
        if plastic == SAND:
            eps = drucker_prager_projection(eps, mu, lam, yield_param)
        else:
            eps = von_mises_projection(eps, yield_param)
        sig_new = vec()
        tr = float(0.0)
        for a in range(wp.static(dim)):
            sig_new[a] = wp.exp(eps[a])
            tr += eps[a]
        F_out[p] = U @ wp.diag(sig_new) @ wp.transpose(V)
        return U @ wp.diag(2.0 * mu * eps + vec(lam * tr)) @ wp.transpose(U)

    @wp.func
    def stencil_offset(n: int):
        offset = ivec()
        r = n
        for a in range(wp.static(dim)):
            offset[a] = r % 3
            r = r // 3
        return offset

    @wp.func
    def flat_index(node: Any, res: Any):
        """Row-major index of a grid node; ``res`` holds nodes per axis."""
        idx = int(0)
        for a in range(wp.static(dim)):
            idx = idx * res[a] + node[a]
        return idx

    weights_t = wp.types.matrix((3, dim), float)

    @wp.func
    def bspline_weights(fx: Any):
        """Quadratic B-spline weights of the 3 nodes along each axis; ``fx`` is in [0.5, 1.5) cells."""
        w = weights_t()
        for a in range(wp.static(dim)):
            f = fx[a]
            w[0, a] = 0.5 * (1.5 - f) * (1.5 - f)
            w[1, a] = 0.75 - (f - 1.0) * (f - 1.0)
            w[2, a] = 0.5 * (f - 0.5) * (f - 0.5)
        return w

    @wp.func
    def stencil_weight(w: Any, offset: Any):
        weight = float(1.0)
        for a in range(wp.static(dim)):
            weight *= w[offset[a], a]
        return weight

    # Each thread adds exactly once per stencil node into each grid array: the deterministic mode's
    # record buffers are sized for that, not for a bound inferred from the code.
    @wp.kernel(module="unique", module_options={**_OPTIONS, "deterministic_max_records": stencil})
    def p2g(
        x: wp.array(dtype=vec),
        v: wp.array(dtype=vec),
        C: wp.array(dtype=mat),
        F: wp.array(dtype=mat),
        J: wp.array(dtype=float),
        model: wp.array(dtype=int),
        mass: wp.array(dtype=float),
        volume: wp.array(dtype=float),
        mu: wp.array(dtype=float),
        lam: wp.array(dtype=float),
        param_a: wp.array(dtype=float),
        param_b: wp.array(dtype=float),
        origin: vec,
        inv_dx: float,
        dt: float,
        res: ivec,
        grid_momentum: wp.array(dtype=vec),
        grid_mass: wp.array(dtype=float),
    ):
        """Scatter APIC momentum and the stress impulse -dt V0 (4/dx^2) tau of each particle to its stencil.

        Per-model parameters: sand (param_a = Drucker-Prager alpha), fluid
        (mu = dynamic viscosity eta, param_a = bulk modulus K, param_b = Tait
        exponent gamma), goop (param_a = von Mises yield strain).
        """
        p = wp.tid()
        rel = (x[p] - origin) * inv_dx
        base = ivec()
        fx = vec()
        for a in range(wp.static(dim)):
            base[a] = int(wp.floor(rel[a] - 0.5))
            fx[a] = rel[a] - float(base[a])
        Cp = C[p]
        grad = wp.identity(n=wp.static(dim), dtype=float) + dt * Cp
        kind = model[p]
        tau = mat()
        if kind == FLUID:
            Jp = J[p] * (1.0 + dt * wp.trace(Cp))
            J[p] = Jp
            # Tait equation of state; a free surface cannot pull, so no tension.
            pressure = wp.max(param_a[p] / param_b[p] * (wp.pow(Jp, -param_b[p]) - 1.0), 0.0)
            # Newtonian viscous stress 2 eta dev(D), D = sym(C) the velocity gradient, on the rest volume:
            # J ~ 1 in the weakly compressible bulk, and where a free surface tears (J > 1, no pressure)
            # a Kirchhoff factor J would shrink the explicit viscous limit rho dx^2 / (2 d eta) by J.
            strain_rate = 0.5 * (Cp + wp.transpose(Cp))
            shear = strain_rate - wp.identity(n=wp.static(dim), dtype=float) * (wp.trace(Cp) / float(dim))
            tau = wp.identity(n=wp.static(dim), dtype=float) * (-pressure * Jp) + (2.0 * mu[p]) * shear
        else:
            tau = hencky_stress(grad @ F[p], mu[p], lam[p], kind, param_a[p], F, p)
        affine = (-dt * volume[p] * 4.0 * inv_dx * inv_dx) * tau + mass[p] * Cp
        momentum = mass[p] * v[p]
        weights = bspline_weights(fx)
        for n in range(wp.static(stencil)):
            offset = stencil_offset(n)
            w = stencil_weight(weights, offset)
            dpos = vec()
            for a in range(wp.static(dim)):
                dpos[a] = (float(offset[a]) - fx[a]) / inv_dx
            idx = flat_index(base + offset, res)
            wp.atomic_add(grid_momentum, idx, w * (momentum + affine @ dpos))
            wp.atomic_add(grid_mass, idx, w * mass[p])

    @wp.kernel(module="unique", module_options=_OPTIONS)
    def grid_update(
        grid_momentum: wp.array(dtype=vec),
        grid_mass: wp.array(dtype=float),
        origin: vec,
        dx: float,
        res: ivec,
        dt: float,
        time: float,
        gravity: vec,
        wall_lower: ivec,
        wall_upper: ivec,
        wall_friction: wp.array(dtype=float),
        wall_no_slip: wp.array(dtype=int),
        obstacle_shape: wp.array(dtype=int),
        obstacle_centre: wp.array(dtype=vec),
        obstacle_half: wp.array(dtype=vec),
        obstacle_rotation: wp.array(dtype=wp.vec2),
        obstacle_velocity: wp.array(dtype=vec),
        obstacle_friction: wp.array(dtype=float),
        obstacle_first_vertex: wp.array(dtype=int),
        obstacle_vertex_count: wp.array(dtype=int),
        polygon_vertices: wp.array(dtype=wp.vec2),
        grid_velocity: wp.array(dtype=vec),
    ):
        """Node velocity = momentum / mass + dt g, then frictional contact with walls and obstacles at ``time``.

        Wall nodes are decided by integer index (``wall_lower`` / ``wall_upper``:
        per axis, the node on or first beyond each wall): comparing float32
        node positions with the bounds moves a wall by a cell when rounding
        puts the node on it just outside. Face ``2 a`` (lower) and ``2 a + 1``
        (upper) of axis ``a`` has its own Coulomb coefficient ``wall_friction``
        or is no-slip (``wall_no_slip`` 1).

        Obstacle ``k`` is a signed-distance shape in its own frame: centre at
        t = 0, half extents, rotation (cos, sin) in the x-y plane. A box, an
        ellipsoid, a plane (the half-space below local y = 0) or a polygon
        (vertices in the domain frame; centre 0, no rotation). Nodes inside
        (distance < 0) get Coulomb contact against the surface normal.
        Clears momentum and mass behind itself, ready for the next P2G.
        """
        n = wp.tid()
        m = grid_mass[n]
        momentum = grid_momentum[n]
        grid_mass[n] = 0.0
        grid_momentum[n] = vec()
        if m <= 0.0:
            grid_velocity[n] = vec()
            return
        vel = momentum / m + dt * gravity
        node = ivec()
        r = n
        for k in range(wp.static(dim)):
            a = wp.static(dim) - 1 - k
            node[a] = r % res[a]
            r = r // res[a]
        pos = vec()
        for a in range(wp.static(dim)):
            pos[a] = origin[a] + float(node[a]) * dx
        for a in range(wp.static(dim)):
            normal = vec()
            face = int(-1)
            if node[a] <= wall_lower[a]:
                normal[a] = 1.0
                face = 2 * a
            elif node[a] >= wall_upper[a]:
                normal[a] = -1.0
                face = 2 * a + 1
            if face >= 0:
                if wall_no_slip[face] != 0:
                    vel = no_slip_contact(vel, normal)
                else:
                    vel = coulomb_contact(vel, normal, wall_friction[face])
        for k in range(obstacle_shape.shape[0]):
            half = obstacle_half[k]
            body_velocity = obstacle_velocity[k]
            rel = pos - (obstacle_centre[k] + time * body_velocity)
            cs = obstacle_rotation[k]
            local = vec()
            for a in range(wp.static(dim)):
                local[a] = rel[a]
            local[0] = cs[0] * rel[0] + cs[1] * rel[1]
            local[1] = -cs[1] * rel[0] + cs[0] * rel[1]
            distance = float(0.0)
            local_normal = vec()
            shape = obstacle_shape[k]
            if shape == BOX:
                # Signed distance to a box; inside, the nearest face gives the normal.
                q = vec()
                for a in range(wp.static(dim)):
                    q[a] = wp.abs(local[a]) - half[a]
                distance = q[0]
                face = int(0)
                for a in range(wp.static(dim)):
                    if q[a] > distance:
                        distance = q[a]
                        face = a
                local_normal[face] = wp.sign(local[face])
            elif shape == ELLIPSOID:
                # Distance to an ellipsoid, first order: scale to the unit sphere (exact for a sphere).
                scaled = vec()
                smallest = half[0]
                for a in range(wp.static(dim)):
                    scaled[a] = local[a] / half[a]
                    smallest = wp.min(smallest, half[a])
                distance = (wp.length(scaled) - 1.0) * smallest
                for a in range(wp.static(dim)):
                    local_normal[a] = scaled[a] / half[a]
                local_normal = wp.normalize(local_normal)
            elif shape == PLANE:
                distance = local[1]
                local_normal[1] = 1.0
            else:
                gap, edge_normal = polygon_distance(
                    wp.vec2(local[0], local[1]), polygon_vertices, obstacle_first_vertex[k], obstacle_vertex_count[k]
                )
                distance = gap
                local_normal[0] = edge_normal[0]
                local_normal[1] = edge_normal[1]
            if distance < 0.0:
                normal = vec()
                for a in range(wp.static(dim)):
                    normal[a] = local_normal[a]
                normal[0] = cs[0] * local_normal[0] - cs[1] * local_normal[1]
                normal[1] = cs[1] * local_normal[0] + cs[0] * local_normal[1]
                vel = body_velocity + coulomb_contact(vel - body_velocity, normal, obstacle_friction[k])
        grid_velocity[n] = vel

    @wp.kernel(module="unique", module_options=_OPTIONS)
    def g2p(
        grid_velocity: wp.array(dtype=vec),
        origin: vec,
        inv_dx: float,
        res: ivec,
        dt: float,
        lower: vec,
        upper: vec,
        x: wp.array(dtype=vec),
        v: wp.array(dtype=vec),
        C: wp.array(dtype=mat),
    ):
        """Gather velocity and its affine part C = (4/dx^2) sum w v (x_i - x_p)^T, then advect; clamp to the domain."""
        p = wp.tid()
        rel = (x[p] - origin) * inv_dx
        base = ivec()
        fx = vec()
        for a in range(wp.static(dim)):
            base[a] = int(wp.floor(rel[a] - 0.5))
            fx[a] = rel[a] - float(base[a])
        new_v = vec()
        new_C = mat()
        weights = bspline_weights(fx)
        for n in range(wp.static(stencil)):
            offset = stencil_offset(n)
            w = stencil_weight(weights, offset)
            dpos = vec()
            for a in range(wp.static(dim)):
                dpos[a] = float(offset[a]) - fx[a]
            g = grid_velocity[flat_index(base + offset, res)]
            new_v += w * g
            new_C += (4.0 * inv_dx * w) * wp.outer(g, dpos)
        v[p] = new_v
        C[p] = new_C
        moved = x[p] + dt * new_v
        for a in range(wp.static(dim)):
            moved[a] = wp.clamp(moved[a], lower[a], upper[a])
        x[p] = moved

    return Kernels(dim, vec, mat, ivec, p2g, grid_update, g2p)
