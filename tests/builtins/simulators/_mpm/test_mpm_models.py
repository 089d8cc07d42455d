"""The MPM constitutive models: their kernel inputs, wave speeds and substep limits, by hand.

E = 1.3 MPa and nu = 0.3 are used throughout because their Lame parameters are round:
mu = E / (2 (1 + nu)) = 0.5 MPa and lam = E nu / ((1 + nu)(1 - 2 nu)) = 0.75 MPa.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from gns_builtins.simulators._mpm.models import (
    MODELS,
    DruckerPragerSand,
    UndrainedClay,
    VonMisesGoop,
    WeaklyCompressibleFluid,
)

ELASTIC = {"youngs_modulus": np.array([1.3e6]), "poisson_ratio": np.array([0.3])}
MU, LAM = 5e5, 7.5e5


def test_undrained_clay_yields_at_its_cohesion_in_the_von_mises_return_map():
    """tresca: sigma_y = sqrt(3) c_u (kPa -> Pa), so the yield strain is sqrt(2/3) sigma_y / (2 mu) = c_u / (sqrt(2)
    mu)."""
    model = MODELS["tresca"]
    assert model.kernel_id == VonMisesGoop.kernel_id
    values = {"youngs_modulus": np.array([1.3e6]), "poisson_ratio": np.array([0.3]), "cohesion": np.array([0.5])}
    arrays = model.kernel_parameters(values)
    mu = 1.3e6 / (2 * 1.3)
    np.testing.assert_allclose(arrays["mu"], mu)
    np.testing.assert_allclose(arrays["param_a"], 500.0 / (np.sqrt(2) * mu), rtol=1e-12)


def test_sand_takes_the_lame_parameters_and_the_cone_slope_of_its_friction_angle():
    # tan(30 deg) gives sin(phi) = 1/2: alpha = sqrt(2/3) * 2 * (1/2) / (3 - 1/2) = 0.4 sqrt(2/3).
    arrays = DruckerPragerSand.kernel_parameters({**ELASTIC, "friction": np.array([math.tan(math.radians(30))])})
    np.testing.assert_allclose(arrays["mu"], [MU], rtol=1e-12)
    np.testing.assert_allclose(arrays["lam"], [LAM], rtol=1e-12)
    np.testing.assert_allclose(arrays["param_a"], [0.4 * math.sqrt(2 / 3)], rtol=1e-12)
    np.testing.assert_array_equal(arrays["param_b"], [0.0])


def test_per_particle_arrays_stay_per_particle():
    # Two particles of different stiffness and friction: each keeps its own values.
    values = {
        "youngs_modulus": np.array([1.3e6, 2.6e6]),
        "poisson_ratio": np.array([0.3, 0.3]),
        "friction": np.array([math.tan(math.radians(30)), 1e-9]),
    }
    arrays = DruckerPragerSand.kernel_parameters(values)
    np.testing.assert_allclose(arrays["mu"], [MU, 2 * MU], rtol=1e-12)
    np.testing.assert_allclose(arrays["param_a"], [0.4 * math.sqrt(2 / 3), 0.0], atol=1e-8)


def test_goop_yields_at_its_uniaxial_yield_stress():
    # |dev tau| = 2 mu |dev eps| reaches sqrt(2/3) sigma_y at |dev eps| = sqrt(2/3) * 300 / 1e6.
    arrays = VonMisesGoop.kernel_parameters({**ELASTIC, "yield_stress": np.array([300.0])})
    np.testing.assert_allclose(arrays["param_a"], [math.sqrt(2 / 3) * 3e-4], rtol=1e-12)
    np.testing.assert_allclose(arrays["lam"], [LAM], rtol=1e-12)


def test_the_fluid_passes_viscosity_bulk_modulus_and_exponent_to_the_kernel():
    values = {"bulk_modulus": np.array([2e5]), "eos_exponent": np.array([7.0]), "viscosity": np.array([1e-3])}
    arrays = WeaklyCompressibleFluid.kernel_parameters(values)
    assert {name: float(a[0]) for name, a in arrays.items()} == {
        "mu": 1e-3,
        "lam": 0.0,
        "param_a": 2e5,
        "param_b": 7.0,
    }


def test_the_elastic_wave_speed_is_that_of_the_p_wave():
    # sqrt((lam + 2 mu) / rho) = sqrt(1.75e6 / 700) = 50 m/s.
    sand = DruckerPragerSand(youngs_modulus=1.3e6, poisson_ratio=0.3, density=700.0)
    assert sand.wave_speed() == pytest.approx(50.0, rel=1e-12)
    goop = VonMisesGoop(youngs_modulus=1.3e6, poisson_ratio=0.3, density=700.0)
    assert goop.wave_speed() == pytest.approx(50.0, rel=1e-12)


def test_the_fluid_sound_speed_allows_for_ten_percent_compression():
    # The Tait stiffness K J^-(gamma + 1) at J = 0.9: with gamma = 1, K = 810 Pa, rho = 1: sqrt(810 / 0.81) =
    # sqrt(1000).
    fluid = WeaklyCompressibleFluid(bulk_modulus=810.0, eos_exponent=1.0, density=1.0)
    assert fluid.wave_speed() == pytest.approx(math.sqrt(1000.0), rel=1e-12)
    # Stiffer with a larger exponent: gamma = 7 at the default density is sqrt(2e5 / 1000) * 0.9^-4.
    assert WeaklyCompressibleFluid().wave_speed() == pytest.approx(math.sqrt(200.0) * 0.9**-4, rel=1e-12)


def test_viscosity_limits_the_substep_and_its_absence_does_not():
    # nu dt / dx^2 <= 1 / (2 d): nu = 1e-3 / 1000 = 1e-6 m^2/s, dx = 1 cm, d = 2: dt <= 1e-4 / (4e-6) = 25 s.
    water = WeaklyCompressibleFluid(viscosity=1e-3)
    assert water.viscous_substep_limit(0.01, 2) == pytest.approx(25.0, rel=1e-12)
    assert water.viscous_substep_limit(0.01, 3) == pytest.approx(25.0 * 2 / 3, rel=1e-12)
    assert WeaklyCompressibleFluid().viscous_substep_limit(0.01, 2) == math.inf
    assert DruckerPragerSand().viscous_substep_limit(0.01, 2) == math.inf


def test_the_defaults_are_the_documented_materials():
    # Sand of a 30 degree friction angle; water inviscid unless asked.
    assert DruckerPragerSand().friction == pytest.approx(math.tan(math.radians(30)), rel=1e-12)
    assert WeaklyCompressibleFluid().viscosity == 0.0


@pytest.mark.parametrize(
    "model, bad",
    [
        (DruckerPragerSand, {"poisson_ratio": 0.5}),  # incompressible: lam divides by 1 - 2 nu = 0
        (DruckerPragerSand, {"friction": 0.0}),
        (WeaklyCompressibleFluid, {"eos_exponent": 0.5}),
        (VonMisesGoop, {"yield_stress": -1.0}),
        (UndrainedClay, {"cohesion": 0.0}),
        (WeaklyCompressibleFluid, {"youngs_modulus": 1e6}),  # a parameter the model does not have
    ],
)
def test_parameters_outside_the_models_range_are_refused(model, bad):
    with pytest.raises(ValidationError, match=next(iter(bad))):
        model(**bad)


def test_the_models_by_the_names_materials_give():
    # MODELS is the table under test (SIM300 takes the capitalised name for a constant).
    assert MODELS == {  # noqa: SIM300
        "drucker_prager": DruckerPragerSand,
        "weakly_compressible": WeaklyCompressibleFluid,
        "von_mises": VonMisesGoop,
        "tresca": UndrainedClay,
    }
