"""The reference integrator: its target and its step are exact inverses (hypothesis, float64)."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gns_builtins.integrators.semi_implicit_euler import SemiImplicitEuler

finite = st.floats(-10, 10, allow_nan=False, width=64)


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 8), st.just(6), st.integers(2, 3)), elements=finite), st.data())
def test_semi_implicit_euler_inverse_round_trip(history, data):
    sequence = torch.from_numpy(history)
    acceleration = torch.from_numpy(data.draw(arrays(np.float64, history[:, 0].shape, elements=finite)))
    integrator = SemiImplicitEuler(SemiImplicitEuler.Params())
    next_position = integrator.next_position(sequence, acceleration)
    torch.testing.assert_close(integrator.target(sequence, next_position), acceleration, rtol=0, atol=1e-9)
    torch.testing.assert_close(
        integrator.next_position(sequence, integrator.target(sequence, next_position)), next_position
    )
