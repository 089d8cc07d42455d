"""The graph-builder contract: build is required; the builder keeps its params and setup (once .scene); its defaults."""

from __future__ import annotations

import pytest
import torch

from gns_framework.contracts import Graph, GraphBuilder, ModelSetup, Params

SETUP = ModelSetup(dim=2, bounds=((0.0, 1.0), (0.0, 1.0)), connectivity_radius=0.5, particle_types=(5,))


def test_a_builder_without_build_cannot_be_built():
    class NoBuild(GraphBuilder):
        name = "no_build"

    with pytest.raises(TypeError, match="abstract method build"):
        NoBuild(Params(), SETUP)


class AllPairs(GraphBuilder):
    """Connects every ordered pair of distinct particles of the same example within the radius."""

    name = "all_pairs"

    def build(self, position, batch, num_examples):
        receivers, senders = torch.nonzero(
            (batch[:, None] == batch[None]) & ~torch.eye(len(batch), dtype=torch.bool), as_tuple=True
        )
        displacement = position[senders] - position[receivers]
        close = displacement.norm(dim=1) < self.setup.connectivity_radius
        return Graph(senders[close], receivers[close], displacement[close], len(position), batch=batch)


def test_a_builder_keeps_its_params_and_the_setup_it_connects_for():
    builder = AllPairs(Params(), SETUP)
    assert builder.params == Params() and builder.setup is SETUP
    position = torch.tensor([[0.0, 0.0], [0.3, 0.0], [0.0, 0.9], [0.1, 0.0]])
    graph = builder.build(position, torch.tensor([0, 0, 0, 1]), 2)
    # 0 and 1 are 0.3 apart (connected both ways); 2 is too far; 3 is another example.
    assert sorted(zip(graph.senders.tolist(), graph.receivers.tolist(), strict=True)) == [(0, 1), (1, 0)]


def test_by_default_a_builder_is_not_periodic_and_needs_no_optional_module():
    assert AllPairs.supports_periodic is False and AllPairs.optional_modules == ()


def test_by_default_a_builder_does_not_promise_edges_within_the_radius_alone():
    """A domain decomposition refuses a builder that does not declare it (decomposition/halo.py)."""
    assert AllPairs.joins_within_radius is False


def test_the_setup_under_its_old_name_scene_warns_and_is_the_setup():
    builder = AllPairs(Params(), SETUP)
    with pytest.warns(DeprecationWarning, match=r"AllPairs\.scene is now \.setup; the old name goes in 0\.3"):
        assert builder.scene is SETUP
    with pytest.raises(AttributeError):
        builder.scene = SETUP  # read-only: set .setup


class OwnInit(AllPairs):
    """A third-party builder with its own __init__, written for the new name."""

    name = "own_init"

    def __init__(self, params, setup):
        super().__init__(params, setup)
        self.radius = setup.connectivity_radius


class OldInit(AllPairs):
    """A third-party builder written before 0.2: its own parameter is still ``scene``."""

    name = "old_init"

    def __init__(self, params, scene):
        super().__init__(params, scene=scene)


@pytest.mark.parametrize("cls, init", [(AllPairs, "GraphBuilder"), (OwnInit, "OwnInit")])
def test_a_builder_still_takes_the_setup_as_scene_with_a_warning(cls, init):
    # The warning names the class whose __init__ took the old keyword: the contract's, or the builder's own.
    with pytest.warns(DeprecationWarning, match=rf"{init}\(scene=...\) is now {init}\(setup=...\); the old keyword"):
        builder = cls(Params(), scene=SETUP)
    assert builder.setup is SETUP
    assert cls(Params(), setup=SETUP).setup is SETUP


def test_a_builder_whose_own_parameter_is_scene_is_left_as_it_was():
    assert OldInit.__init__.__name__ == "__init__" and not hasattr(OldInit.__init__, "__wrapped__")
    with pytest.warns(DeprecationWarning, match=r"GraphBuilder\(scene=...\) is now GraphBuilder\(setup=...\)"):
        builder = OldInit(Params(), scene=SETUP)  # its super().__init__(params, scene=...) still works
    assert builder.setup is SETUP
