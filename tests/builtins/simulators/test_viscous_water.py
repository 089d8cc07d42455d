"""Viscosity of the weakly compressible water (issue 19): a physical dynamic viscosity in Pa s.

Gravity-driven plane Poiseuille flow between no-slip walls has the exact steady
profile u(y) = g y (h - y) / (2 nu), mean g h^2 / (12 nu), nu = eta / rho.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from load_script import load_script
from scene_builders import problems

from gns_framework.assembly.ground_truth import build_ground_truth_simulator
from gns_framework.ground_truth.scene_spec import parse_scene

G, H, RHO = 1.0, 0.1, 1000.0


def channel(viscosity: float, substeps: int = 15) -> dict:
    """A 0.4 m water slug filling a 0.1 m channel (no-slip floor and lid) driven along x by g = 1 m/s^2.

    dx = 10 mm; the bulk modulus is lowered to 2e4 Pa (sound speed ~5 m/s, 40 x the flow) for cheap substeps.
    """
    return {
        "name": "poiseuille",
        "dim": 2,
        "domain": {
            "bounds": [[0.0, 0.6], [0.0, H]],
            "grid": 60,
            "walls": {"y_min": "no_slip", "y_max": "no_slip", "x_min": "slip", "x_max": "slip"},
        },
        "time": {"frame_dt": 0.01, "substeps": substeps, "frames": 51},
        "gravity": [G, 0.0],
        "blocks": [
            {
                "material": "water",
                "position": [0.1, 0.0],
                "size": [0.4, H],
                "parameters": {"viscosity": viscosity, "bulk_modulus": 2e4},
            }
        ],
    }


def middle_profile(viscosity: float, registry) -> tuple[np.ndarray, np.ndarray]:
    """(y bin centres, mean x velocity) at t = 0.5 s (5 viscous time scales h^2 / (pi^2 nu)),
    away from the slug ends."""
    scene = parse_scene(channel(viscosity))
    position = build_ground_truth_simulator(scene, registry, "<test>").simulate(scene, 0).position
    u = (position[-1, :, 0] - position[-2, :, 0]) / scene.time.frame_dt
    x, y = position[-1, :, 0], position[-1, :, 1]
    middle = (x > x.min() + 0.15) & (x < x.max() - 0.15)
    edges = np.linspace(0.0, H, 6)
    centres = 0.5 * (edges[:-1] + edges[1:])
    means = np.array([u[middle & (y >= lo) & (y < hi)].mean() for lo, hi in itertools.pairwise(edges)])
    return centres, means


@pytest.mark.parametrize("viscosity", [10.0, 20.0])
def test_poiseuille_flow_has_the_exact_profile_for_the_viscosity(viscosity, sim_registry):
    nu = viscosity / RHO
    y, u = middle_profile(viscosity, sim_registry)
    # Bin means of the parabola: g / (2 nu) * mean over the bin of y (h - y).
    width = y[1] - y[0]
    exact = G / (2 * nu) * (y * (H - y) - width**2 / 12)
    np.testing.assert_allclose(u, exact, rtol=0.1)
    assert u.mean() == pytest.approx(G * H**2 / (12 * nu), rel=0.08)


def test_too_few_substeps_for_the_viscosity_says_how_many(sim_registry):
    found = problems(channel(2000.0), sim_registry)
    assert "viscous limit" in found["time.substeps"] and "use at least" in found["time.substeps"]


@pytest.fixture(scope="module")
def dam_break():
    """benchmarks/dam_break.py: the Martin & Moyce column and Ritter's reservoir."""
    return load_script("benchmarks/dam_break.py")


@pytest.fixture(scope="module")
def martin_moyce_fronts(dam_break, sim_registry):
    """Front Z at Martin & Moyce's times for water (1e-3 Pa s) and a 1000x more viscous liquid, 10 cells across a."""
    return {
        eta: np.interp(dam_break.MARTIN_MOYCE_T, *dam_break.run(eta, 10, "no_slip", sim_registry))
        for eta in (1e-3, 1.0)
    }


def test_water_dam_break_front_follows_martin_and_moyce(dam_break, martin_moyce_fronts):
    """Within 10 % at every tabulated time (at 20 cells across a: -0.6 % on average, see docs/ground_truth.md)."""
    np.testing.assert_allclose(martin_moyce_fronts[1e-3], dam_break.MARTIN_MOYCE_Z, rtol=0.1)


def test_a_viscous_liquid_runs_out_more_slowly(martin_moyce_fronts):
    assert martin_moyce_fronts[1.0][-1] < 0.9 * martin_moyce_fronts[1e-3][-1]


def test_shallow_dam_break_holds_ritters_depth_at_the_dam(dam_break, sim_registry):
    """Ritter: the depth at the dam site stays 4/9 h0 until the rarefaction returns (MPM: 0.48 h0)."""
    _, _, at_dam = dam_break.ritter_run(0.0, sim_registry)
    assert at_dam / dam_break.RITTER_H0 == pytest.approx(4 / 9, rel=0.15)
