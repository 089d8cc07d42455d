"""The MLS-MPM kernels: contact laws, transfers that conserve mass and momentum, APIC, return maps, obstacles.

The contact functions are called from Python; the rest through one launch of a kernel
on a hand-made grid (dx = 0.1, origin 0) on Warp's CPU device, with dt = 0 where a
check must not see the stress or gravity. Values are float32 on the device, so
comparisons allow a few float32 epsilons of the magnitudes involved (~1).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import warp as wp

from gns_builtins.simulators._mpm import kernels as mpm
from gns_builtins.simulators._mpm.models import MODELS
from gns_builtins.simulators._mpm.solver import init_warp

FLOAT32 = 1e-5
"""Tolerance for float32 values of order 1 after a few dozen operations (~100 epsilons)."""

DX = 0.1


@pytest.fixture(scope="module", autouse=True)
def warp_on_cpu():
    init_warp(cuda_wanted=False)


def arrays(values, dtype):
    return wp.array(np.ascontiguousarray(values), dtype=dtype, device="cpu")


def test_coulomb_contact_frees_separation_stops_approach_and_rubs_the_tangent():
    up = wp.vec2(0.0, 1.0)
    # Separating: untouched.
    assert list(mpm.coulomb_contact(wp.vec2(1.0, 2.0), up, 0.3)) == [1.0, 2.0]
    # Approaching at 2 with tangential speed 1: friction removes 0.3 * 2 of it, leaving 0.4.
    assert list(mpm.coulomb_contact(wp.vec2(1.0, -2.0), up, 0.3)) == pytest.approx([0.4, 0.0], abs=FLOAT32)
    # Friction 0.6 * 2 exceeds the tangential speed: it sticks.
    assert list(mpm.coulomb_contact(wp.vec2(1.0, -2.0), up, 0.6)) == [0.0, 0.0]
    # Without friction only the normal part goes.
    assert list(mpm.coulomb_contact(wp.vec2(1.0, -2.0), up, 0.0)) == [1.0, 0.0]


def test_no_slip_contact_keeps_only_separating_normal_motion():
    up = wp.vec2(0.0, 1.0)
    assert list(mpm.no_slip_contact(wp.vec2(1.0, -2.0), up)) == [0.0, 0.0]
    assert list(mpm.no_slip_contact(wp.vec2(1.0, 2.0), up)) == [0.0, 2.0]


def test_the_model_ids_are_the_kernels():
    # A material picks its kernel branch by this id: sand, fluid, and von Mises for goop and clay alike.
    assert {name: model.kernel_id for name, model in MODELS.items()} == {
        "drucker_prager": mpm.SAND,
        "weakly_compressible": mpm.FLUID,
        "von_mises": mpm.GOOP,
        "tresca": mpm.GOOP,
    }


# --- particle to grid and back --------------------------------------------------------------------------------


def p2g(dim, position, velocity, C=None, F=None, model=0, params=(1e5, 1e5, 0.3, 0.0), dt=0.0, mass=2.0, nodes=8):
    """One particle scattered to a grid of ``nodes``^dim nodes: (k, node masses, node momenta, F and J after).

    ``params`` are the kernel's (mu, lam, param_a, param_b); the default is a sand of real moduli (a zero
    shear modulus divides by zero in the return map of the few-ulp strains svd3 finds in F = I).
    """
    k = mpm.kernels(dim)
    res = (nodes,) * dim
    eye = np.eye(dim, dtype=np.float32)
    F_array = arrays(np.asarray([eye if F is None else F], np.float32), k.mat)
    J_array = arrays(np.ones(1, np.float32), float)
    grid_momentum = wp.zeros(nodes**dim, dtype=k.vec, device="cpu")
    grid_mass = wp.zeros(nodes**dim, dtype=float, device="cpu")
    mu, lam, param_a, param_b = (arrays(np.array([p], np.float32), float) for p in params)
    wp.launch(
        k.p2g,
        dim=1,
        inputs=[
            arrays(np.asarray([position], np.float32), k.vec),
            arrays(np.asarray([velocity], np.float32), k.vec),
            arrays(np.asarray([np.zeros((dim, dim)) if C is None else C], np.float32), k.mat),
            F_array,
            J_array,
            arrays(np.array([model], np.int32), int),
            arrays(np.array([mass], np.float32), float),
            arrays(np.array([1e-3], np.float32), float),
            mu,
            lam,
            param_a,
            param_b,
            k.vec(*([0.0] * dim)),
            1.0 / DX,
            dt,
            k.ivec(*res),
            grid_momentum,
            grid_mass,
        ],
        device="cpu",
    )
    return (
        k,
        grid_mass.numpy().reshape(res),
        grid_momentum.numpy().reshape(*res, dim),
        F_array.numpy()[0],
        J_array.numpy()[0],
    )


@pytest.mark.parametrize("dim", [2, 3])
def test_a_particle_on_a_node_spreads_its_mass_by_the_quadratic_b_spline(dim):
    # At a node the B-spline weights along an axis are 1/8, 3/4, 1/8 on the node and its two neighbours.
    position = [0.3, 0.4, 0.5][:dim]
    _, mass, _, _, _ = p2g(dim, position, [0.0] * dim)
    expected = np.zeros((8,) * dim)
    weights = {-1: 1 / 8, 0: 3 / 4, 1: 1 / 8}
    for offsets in itertools.product((-1, 0, 1), repeat=dim):
        node = tuple(round(p / DX) + o for p, o in zip(position, offsets, strict=True))
        expected[node] = 2.0 * np.prod([weights[o] for o in offsets])
    np.testing.assert_allclose(mass, expected, rtol=0, atol=FLOAT32)


@pytest.mark.parametrize("dim", [2, 3])
def test_the_transfer_conserves_mass_and_momentum_wherever_the_particle_is(dim):
    # Partition of unity and a zero first moment of the weights: the affine part m C (x_i - x_p) adds no momentum.
    rng = np.random.default_rng(dim)
    velocity = rng.normal(size=dim)
    C = rng.normal(size=(dim, dim))
    for position in rng.uniform(0.25, 0.45, size=(5, dim)):
        _, mass, momentum, _, _ = p2g(dim, position, velocity, C)
        assert mass.sum() == pytest.approx(2.0, abs=FLOAT32)
        np.testing.assert_allclose(momentum.reshape(-1, dim).sum(0), 2.0 * velocity, rtol=0, atol=FLOAT32)


def grid_update(k, mass, momentum, dt=0.0, gravity=None, walls=None, obstacles=(), time=0.0):
    """One grid update of ``mass`` (res) and ``momentum`` (res, d): the node velocities, and the grid it leaves."""
    res = mass.shape
    dim = len(res)
    lower, upper, friction, no_slip = walls or ((-1,) * dim, res, [0.0] * 2 * dim, [0] * 2 * dim)
    grid_mass = arrays(mass.reshape(-1).astype(np.float32), float)
    grid_momentum = arrays(momentum.reshape(-1, dim).astype(np.float32), k.vec)
    velocity = arrays(np.ones((mass.size, dim), np.float32), k.vec)  # stale values the update must overwrite
    shape, centre, half, rotation, body_velocity, body_friction, vertices = (
        zip(*obstacles, strict=True) if obstacles else ((), (), (), (), (), (), ())
    )
    polygons = [v for v in vertices if v is not None]
    counts = [0 if v is None else len(v) for v in vertices]
    wp.launch(
        k.grid_update,
        dim=mass.size,
        inputs=[
            grid_momentum,
            grid_mass,
            k.vec(*([0.0] * dim)),
            DX,
            k.ivec(*res),
            dt,
            time,
            k.vec(*(gravity or [0.0] * dim)),
            k.ivec(*lower),
            k.ivec(*upper),
            arrays(np.array(friction, np.float32), float),
            arrays(np.array(no_slip, np.int32), int),
            arrays(np.array(shape, np.int32), int),
            arrays(np.array(centre, np.float32).reshape(-1, dim), k.vec),
            arrays(np.array(half, np.float32).reshape(-1, dim), k.vec),
            arrays(np.array(rotation, np.float32).reshape(-1, 2), wp.vec2),
            arrays(np.array(body_velocity, np.float32).reshape(-1, dim), k.vec),
            arrays(np.array(body_friction, np.float32), float),
            arrays(np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)[: len(counts)], int),
            arrays(np.array(counts, np.int32), int),
            arrays(np.concatenate([*polygons, np.zeros((1, 2))]).astype(np.float32), wp.vec2),
            velocity,
        ],
        device="cpu",
    )
    return velocity.numpy().reshape(*res, dim), grid_mass.numpy(), grid_momentum.numpy()


def g2p(k, grid_velocity, position, dt=0.0, lower=-10.0, upper=10.0):
    """One particle gathered from ``grid_velocity`` (res, d): its velocity, C and position after."""
    res = grid_velocity.shape[:-1]
    dim = len(res)
    x = arrays(np.asarray([position], np.float32), k.vec)
    v = wp.zeros(1, dtype=k.vec, device="cpu")
    C = wp.zeros(1, dtype=k.mat, device="cpu")
    wp.launch(
        k.g2p,
        dim=1,
        inputs=[
            arrays(grid_velocity.reshape(-1, dim).astype(np.float32), k.vec),
            k.vec(*([0.0] * dim)),
            1.0 / DX,
            k.ivec(*res),
            dt,
            k.vec(*([lower] * dim)),
            k.vec(*([upper] * dim)),
            x,
            v,
            C,
        ],
        device="cpu",
    )
    return v.numpy()[0], C.numpy()[0], x.numpy()[0]


@pytest.mark.parametrize("dim", [2, 3])
def test_apic_carries_an_affine_velocity_field_to_the_grid_and_back_exactly(dim):
    # Node velocities v + C (x_i - x_p); gathering them gives back v, and (4 / dx^2) sum w v_i (x_i - x_p)^T gives
    # back C because the quadratic B-spline's second moment is dx^2 / 4.
    rng = np.random.default_rng(10 + dim)
    velocity, C = rng.normal(size=dim), rng.normal(size=(dim, dim))
    for position in rng.uniform(0.25, 0.45, size=(3, dim)):
        k, mass, momentum, _, _ = p2g(dim, position, velocity, C)
        grid_velocity, _, _ = grid_update(k, mass, momentum)
        v, C_back, x = g2p(k, grid_velocity, position)
        np.testing.assert_allclose(v, velocity, rtol=0, atol=FLOAT32 * 10)
        np.testing.assert_allclose(C_back, C, rtol=0, atol=FLOAT32 * 10 / DX)
        np.testing.assert_allclose(x, position, rtol=0, atol=FLOAT32)


def test_g2p_advects_with_the_gathered_velocity_and_clamps_to_the_domain():
    k = mpm.kernels(2)
    uniform = np.broadcast_to(np.array([1.0, 0.5], np.float32), (8, 8, 2))
    v, C, x = g2p(k, uniform, [0.33, 0.36], dt=0.02)
    np.testing.assert_allclose(v, [1.0, 0.5], rtol=0, atol=FLOAT32)
    np.testing.assert_allclose(C, np.zeros((2, 2)), rtol=0, atol=FLOAT32 / DX)
    np.testing.assert_allclose(x, [0.35, 0.37], rtol=0, atol=FLOAT32)
    # A step that would leave the domain [0, 0.36] stops at its wall.
    _, _, x = g2p(k, uniform, [0.33, 0.36], dt=0.1, lower=0.0, upper=0.36)
    np.testing.assert_allclose(x, [0.36, 0.36], rtol=0, atol=FLOAT32)


# --- stresses and return maps (seen through the elastic F that P2G stores) -----------------------------------


def test_sand_cannot_hold_tension():
    # A stretched sand particle returns to the cone tip: no elastic strain is kept.
    _, _, _, F, _ = p2g(2, [0.3, 0.3], [0.0, 0.0], F=np.diag([1.1, 1.05]), params=(1e5, 1e5, 0.3, 0.0))
    np.testing.assert_allclose(F, np.eye(2), rtol=0, atol=FLOAT32)


def test_sand_keeps_a_purely_volumetric_compression():
    # No deviatoric strain: inside the cone whatever its slope.
    _, _, _, F, _ = p2g(2, [0.3, 0.3], [0.0, 0.0], F=np.diag([0.9, 0.9]), params=(1e5, 1e5, 0.3, 0.0))
    np.testing.assert_allclose(F, np.diag([0.9, 0.9]), rtol=0, atol=FLOAT32)


def test_von_mises_scales_the_deviatoric_strain_back_to_the_yield_radius_and_keeps_the_volume():
    # Hencky strain (ln 1.2, -ln 1.2): traceless, norm sqrt(2) ln 1.2 = 0.258 > 0.1, so it shrinks to norm 0.1.
    F = np.diag([1.2, 1 / 1.2])
    _, _, _, F_elastic, _ = p2g(2, [0.3, 0.3], [0.0, 0.0], F=F, model=int(mpm.GOOP), params=(1e5, 1e5, 0.1, 0.0))
    strain = 0.1 / np.sqrt(2)
    np.testing.assert_allclose(F_elastic, np.diag([np.exp(strain), np.exp(-strain)]), rtol=0, atol=FLOAT32)
    # Below the radius nothing changes.
    _, _, _, F_elastic, _ = p2g(2, [0.3, 0.3], [0.0, 0.0], F=F, model=int(mpm.GOOP), params=(1e5, 1e5, 0.3, 0.0))
    np.testing.assert_allclose(F_elastic, F, rtol=0, atol=FLOAT32)


def test_a_fluid_particle_updates_its_volume_ratio_and_pulls_on_nothing_in_tension():
    # J' = J (1 + dt tr C) = 1 + 0.5 * 0.2 = 1.1; the Tait pressure is clipped at 0 in tension, and without
    # viscosity the fluid has no stress: the momentum is m v (the affine part m C adds none).
    C = np.diag([0.1, 0.1])
    _, _, momentum, _, J = p2g(
        2, [0.3, 0.3], [0.5, -0.25], C=C, model=int(mpm.FLUID), params=(0.0, 0.0, 2e5, 7.0), dt=0.5
    )
    assert J == pytest.approx(1.1, abs=FLOAT32)  # noqa: SIM300 - J is the volume ratio, not a constant
    np.testing.assert_allclose(momentum.reshape(-1, 2).sum(0), [1.0, -0.5], rtol=0, atol=FLOAT32)


def test_a_compressed_fluid_pushes_its_neighbour_nodes_outwards():
    # J = 1 - 0.5 * 0.2 = 0.9 < 1: positive pressure, a stress impulse -dt V (4/dx^2) tau (x_i - x_p) pointing away.
    _, _, momentum, _, J = p2g(
        2, [0.3, 0.3], [0.0, 0.0], C=np.diag([-0.1, -0.1]), model=int(mpm.FLUID), params=(0.0, 0.0, 2e5, 7.0), dt=0.5
    )
    assert J == pytest.approx(0.9, abs=FLOAT32)  # noqa: SIM300 - J is the volume ratio, not a constant
    # The nodes to the right of and above the particle at (0.3, 0.3) (node 3, 3) gain outward momentum.
    assert momentum[4, 3, 0] > 0 and momentum[2, 3, 0] < 0 and momentum[3, 4, 1] > 0 and momentum[3, 2, 1] < 0


# --- the grid update: gravity, walls and obstacles ------------------------------------------------------------


def one_node(velocity, node=(3, 3), mass=2.0, res=(6, 6)):
    """A grid with mass only at ``node``, moving at ``velocity``."""
    masses = np.zeros(res)
    masses[node] = mass
    momentum = np.zeros((*res, 2))
    momentum[node] = mass * np.asarray(velocity)
    return masses, momentum


def test_node_velocity_is_momentum_over_mass_plus_gravity_and_the_grid_is_cleared():
    k = mpm.kernels(2)
    mass, momentum = one_node([1.0, 0.0])
    velocity, mass_after, momentum_after = grid_update(k, mass, momentum, dt=0.5, gravity=[0.0, -1.0])
    np.testing.assert_allclose(velocity[3, 3], [1.0, -0.5], rtol=0, atol=FLOAT32)
    # Nodes without mass are at rest (the stale ones were overwritten), and the grid is ready for the next P2G.
    assert np.abs(np.delete(velocity.reshape(-1, 2), 3 * 6 + 3, axis=0)).max() == 0.0
    assert not mass_after.any() and not momentum_after.any()


WALLS = ((0, 1), (5, 5))
"""Wall nodes: x index <= 0 or >= 5 and y index <= 1 or >= 5; faces 0, 1 (x) and 2, 3 (y)."""


@pytest.mark.parametrize(
    "velocity, friction, no_slip, expected",
    [
        ([1.0, -2.0], 0.3, 0, [0.4, 0.0]),  # into the floor: Coulomb friction of the floor's own coefficient
        ([1.0, 2.0], 0.3, 0, [1.0, 2.0]),  # leaving the floor: free
        ([1.0, -2.0], 0.0, 1, [0.0, 0.0]),  # a no-slip floor stops it
        ([1.0, 2.0], 0.0, 1, [0.0, 2.0]),  # and lets it leave only along the normal
    ],
)
def test_a_node_on_the_floor_meets_the_floors_condition(velocity, friction, no_slip, expected):
    k = mpm.kernels(2)
    floor_node = (3, 1)
    walls = (*WALLS, [0.9, 0.9, friction, 0.9], [0, 0, no_slip, 0])
    velocity_after, _, _ = grid_update(k, *one_node(velocity, node=floor_node), walls=walls)
    np.testing.assert_allclose(velocity_after[floor_node], expected, rtol=0, atol=FLOAT32)
    # One node above the floor, nothing acts.
    velocity_after, _, _ = grid_update(k, *one_node(velocity, node=(3, 2)), walls=walls)
    np.testing.assert_allclose(velocity_after[3, 2], velocity, rtol=0, atol=FLOAT32)


def test_a_node_on_an_upper_wall_meets_that_walls_condition():
    # x index 5 is the x-upper wall (face 1): moving in +x is moving into it.
    k = mpm.kernels(2)
    walls = (*WALLS, [0.0, 0.25, 0.0, 0.0], [0, 0, 0, 0])
    velocity, _, _ = grid_update(k, *one_node([2.0, 1.0], node=(5, 3)), walls=walls)
    np.testing.assert_allclose(velocity[5, 3], [0.0, 0.5], rtol=0, atol=FLOAT32)


def obstacle(shape, centre, half=(0.0, 0.0), angle=0.0, velocity=(0.0, 0.0), friction=0.0, vertices=None):
    return (int(shape), centre, half, (np.cos(angle), np.sin(angle)), velocity, friction, vertices)


@pytest.mark.parametrize(
    "body, node, velocity, expected",
    [
        # Box 0.2 x 0.2 around (0.4, 0.45): node (4, 5) at (0.4, 0.5) is inside, nearest the top face.
        (obstacle(mpm.BOX, (0.4, 0.45), (0.1, 0.1)), (4, 5), [1.0, -2.0], [1.0, 0.0]),
        # Circle of radius 0.1 around (0.3, 0.25): node (3, 3) at (0.3, 0.3) is inside; normal +y.
        (obstacle(mpm.ELLIPSOID, (0.3, 0.25), (0.1, 0.1)), (3, 3), [1.0, -2.0], [1.0, 0.0]),
        # A square polygon from y = 0.28 up: node (3, 3) at (0.3, 0.3) is 0.02 inside its bottom edge, normal -y.
        (
            obstacle(mpm.POLYGON, (0.0, 0.0), vertices=np.array([[0.15, 0.28], [0.5, 0.28], [0.5, 0.6], [0.15, 0.6]])),
            (3, 3),
            [1.0, 2.0],
            [1.0, 0.0],
        ),
        # The plane y < 0 turned by 90 degrees is the half-space x > 0.25 with outward normal -x.
        (obstacle(mpm.PLANE, (0.25, 0.0), angle=np.pi / 2), (4, 3), [2.0, 1.0], [0.0, 1.0]),
        # Outside each of them nothing acts.
        (obstacle(mpm.BOX, (0.4, 0.45), (0.1, 0.1)), (2, 3), [1.0, -2.0], [1.0, -2.0]),
        (obstacle(mpm.PLANE, (0.25, 0.0), angle=np.pi / 2), (2, 3), [-2.0, 1.0], [-2.0, 1.0]),
    ],
)
def test_obstacles_stop_the_normal_motion_of_the_nodes_inside_them(body, node, velocity, expected):
    k = mpm.kernels(2)
    velocity_after, _, _ = grid_update(k, *one_node(velocity, node=node), obstacles=[body])
    np.testing.assert_allclose(velocity_after[node], expected, rtol=0, atol=FLOAT32)


def test_a_moving_obstacle_is_where_its_velocity_has_taken_it_and_contact_is_relative_to_it():
    # The +x-facing wall of the turned plane starts at x = 0.25 and moves at 0.5 in +x.
    k = mpm.kernels(2)
    wall = obstacle(mpm.PLANE, (0.25, 0.0), angle=np.pi / 2, velocity=(0.5, 0.0))
    # At t = 0.2 it is at 0.35: node (4, 3) at x = 0.4 is inside; its velocity relative to the wall is (1.5, 1),
    # which loses its normal part: (0, 1) relative, (0.5, 1) absolute.
    velocity, _, _ = grid_update(k, *one_node([2.0, 1.0], node=(4, 3)), obstacles=[wall], time=0.2)
    np.testing.assert_allclose(velocity[4, 3], [0.5, 1.0], rtol=0, atol=FLOAT32)
    # At t = 0.4 it is at 0.45, past the node: nothing acts.
    velocity, _, _ = grid_update(k, *one_node([2.0, 1.0], node=(4, 3)), obstacles=[wall], time=0.4)
    np.testing.assert_allclose(velocity[4, 3], [2.0, 1.0], rtol=0, atol=FLOAT32)
