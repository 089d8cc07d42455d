"""Every registered integrator: exact inverses, the history forms they share, and which duplicates which.

Each scheme's own stability and order of accuracy are tested in its mirror (test_<integrator>.py).
"""

from __future__ import annotations

import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gns_framework.plugins import load_registry

REGISTRY = load_registry()
NAMES = REGISTRY.names("integrator")
SECOND_ORDER = ["semi_implicit_euler", "explicit_euler", "velocity_verlet"]


def make(name):
    cls = REGISTRY.get("integrator", name)
    return cls(cls.Params())


finite = st.floats(-10, 10, allow_nan=False, width=64)


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from(NAMES),
    arrays("float64", (5, 6, 3), elements=finite),
    arrays("float64", (5, 3), elements=finite),
)
def test_target_is_the_exact_inverse_of_next_position(name, sequence, prediction):
    integrator = make(name)
    sequence, prediction = torch.from_numpy(sequence), torch.from_numpy(prediction)
    recovered = integrator.target(sequence, integrator.next_position(sequence, prediction))
    assert torch.allclose(recovered, prediction, atol=1e-11, rtol=1e-12)


def test_constant_acceleration_is_reproduced_exactly():
    # p(t) = a t^2 / 2: every second-order scheme's history form must predict a.
    t = torch.arange(7, dtype=torch.float64)[None, :, None]
    a = torch.tensor([[0.3, -1.2]], dtype=torch.float64)
    trajectory = 0.5 * a[:, None] * t**2
    for name in SECOND_ORDER:
        integrator = make(name)
        assert torch.allclose(integrator.target(trajectory[:, :6], trajectory[:, 6]), a), name
    velocity = make("velocity_euler").target(trajectory[:, :6], trajectory[:, 6])
    assert torch.allclose(velocity, trajectory[:, 6] - trajectory[:, 5])


def test_velocity_euler_is_normalised_with_velocity_statistics():
    assert REGISTRY.get("integrator", "velocity_euler").predicts == "velocity"
    assert all(REGISTRY.get("integrator", n).predicts == "acceleration" for n in SECOND_ORDER)


SHARING = [n for n in NAMES if REGISTRY.get("integrator", n).same_position_map_as]


def test_the_duplicates_are_declared():
    assert sorted(SHARING) == ["explicit_euler", "velocity_verlet"]


@settings(max_examples=40, deadline=None)
@given(
    st.sampled_from(SHARING) if SHARING else st.nothing(),
    arrays("float64", (5, 3, 2), elements=finite),
    arrays("float64", (5, 2), elements=finite),
)
def test_an_integrator_that_says_it_shares_a_position_map_does(name, history, prediction):
    # The fact on the component is what training refuses it by: it must be true.
    mine, theirs = make(name), make(REGISTRY.get("integrator", name).same_position_map_as)
    history, prediction = torch.from_numpy(history), torch.from_numpy(prediction)
    torch.testing.assert_close(
        mine.next_position(history, prediction),
        theirs.next_position(history, prediction),
        rtol=0,
        atol=1e-12 * (1 + float(history.abs().max() + prediction.abs().max())),
    )
    following = theirs.next_position(history, prediction)
    torch.testing.assert_close(
        mine.target(history, following),
        theirs.target(history, following),
        rtol=0,
        atol=1e-11 * (1 + float(history.abs().max() + prediction.abs().max())),
    )


def test_every_other_acceleration_integrator_has_a_position_map_of_its_own():
    # A new integrator that duplicates semi-implicit Euler without saying so would train the same model.
    history = torch.tensor([[[0.0, 0.0], [0.1, 0.3], [0.25, 0.5]]], dtype=torch.float64)
    prediction = torch.tensor([[0.4, -0.2]], dtype=torch.float64)
    reference = make("semi_implicit_euler").next_position(history, prediction)
    for name in NAMES:
        if name in SHARING or name == "semi_implicit_euler":
            continue
        assert not torch.allclose(make(name).next_position(history, prediction), reference), name
