"""A learned simulator from a recipe's ``model`` section, sized for a scene; the versions of what it uses."""

from __future__ import annotations

from ..config.recipe import COMPONENT_SECTIONS, ModelSpec, Recipe
from ..contracts import ModelSetup, ModelSizes
from ..data.metadata import DatasetMetadata
from ..decomposition.halo import unbounded_reach
from ..errors import GnsError, RecipeError
from ..limits import model_size_problems
from ..model.features import FeatureBuilder, edge_feature_size, node_feature_size
from ..model.learned_simulator import LearnedSimulator
from ..model.noise import training_noise_std
from ..model.normalization import Stats
from ..plugins import Registry


def model_sizes(setup: ModelSetup, model: ModelSpec) -> ModelSizes:
    """Input, latent and output widths of the encoder, processor and decoder for ``setup``."""
    return ModelSizes(
        node_in=node_feature_size(setup, model.type_embedding_size),
        edge_in=edge_feature_size(setup),
        latent=model.latent_size,
        mlp_hidden=model.mlp_hidden_size,
        mlp_hidden_layers=model.mlp_hidden_layers,
        output=setup.dim,
        dim=setup.dim,
        connectivity_radius=setup.connectivity_radius,
    )


def training_problems(recipe: Recipe, registry: Registry) -> list[tuple[str, str]]:
    """What a recipe's components say against training it: an integrator whose position map is another's.

    Rolling out a model already trained with such an integrator is left alone (its
    checkpoints load); only training one more is refused.
    """
    problems: list[tuple[str, str]] = []
    try:
        integrator = registry.get("integrator", recipe.model.integrator.name)
        builder = registry.get("graph_builder", recipe.model.graph_builder.name)
        processor = registry.get("processor", recipe.model.processor.name)
    except GnsError:
        return problems  # an unknown name is the schema's to report
    if recipe.training.partitions > 1:
        problems += [("training.partitions", why) for why in unbounded_reach(builder, processor)]
    problems += size_problems(recipe, registry)
    same = integrator.same_position_map_as
    if same is not None:
        problems.append(
            (
                "model.integrator.name",
                f"{integrator.name!r} moves particles with {same!r}'s position map when it sees positions only, so a "
                f"learned model trains exactly the same with either: use {same!r} (the {integrator.name!r} scheme "
                "itself is studied under force laws by gns stability)",
            )
        )
    return problems


def size_problems(recipe: Recipe, registry: Registry) -> list[tuple[str, str]]:
    """The recipe's model estimated from its numbers: refused when too large to build
    (``limits.model_size_problems``)."""
    model = recipe.model
    steps = processor_steps(recipe, registry)
    return model_size_problems(model.latent_size, model.mlp_hidden_size, model.mlp_hidden_layers, steps)


def processor_steps(recipe: Recipe, registry: Registry) -> int | None:
    """The processor's message-passing steps (``message_passing_steps``, else its ``hops_param``), None without one."""
    try:
        processor, params = registry.resolve("processor", recipe.model.processor, ("model", "processor"))
    except GnsError:
        return None  # the schema reports the processor's own problems
    for name in ("message_passing_steps", processor.hops_param):
        value = getattr(params, name, None) if name else None
        if isinstance(value, int):
            return value
    return None


def build_learned_simulator(
    setup: ModelSetup, metadata: DatasetMetadata, model: ModelSpec, registry: Registry
) -> LearnedSimulator:
    """Instantiate the components a recipe names, sized from the setup and normalised by the data's statistics."""
    sizes = model_sizes(setup, model)
    builder_cls, builder_params = registry.resolve("graph_builder", model.graph_builder, ("model", "graph_builder"))
    encoder_cls, encoder_params = registry.resolve("encoder", model.encoder, ("model", "encoder"))
    processor_cls, processor_params = registry.resolve("processor", model.processor, ("model", "processor"))
    decoder_cls, decoder_params = registry.resolve("decoder", model.decoder, ("model", "decoder"))
    integrator_cls, integrator_params = registry.resolve("integrator", model.integrator, ("model", "integrator"))
    if setup.periodic_dims and not builder_cls.supports_periodic:
        periodic_builders = [e.name for e in registry.entries("graph_builder") if e.cls.supports_periodic]
        raise RecipeError(
            None,
            [
                (
                    "model.graph_builder.name",
                    f"{builder_cls.name!r} does not connect across the periodic dimensions "
                    f"{list(setup.periodic_dims)}; "
                    f"use one of: {', '.join(periodic_builders) or 'none installed'}",
                )
            ],
        )
    integrator = integrator_cls(integrator_params)
    noise_std = training_noise_std(model, metadata)
    velocity_stats = Stats(metadata.vel_mean, metadata.vel_std, noise_std)
    if integrator.predicts == "acceleration":
        output_stats = Stats(metadata.acc_mean, metadata.acc_std, noise_std)
    else:
        output_stats = Stats(metadata.vel_mean, metadata.vel_std, noise_std)
    context_stats = None
    if setup.context_size:
        # scene_from_data refuses a context without these statistics.
        assert metadata.context_mean is not None and metadata.context_std is not None
        context_stats = Stats(metadata.context_mean, metadata.context_std)
    return LearnedSimulator(
        setup=setup,
        features=FeatureBuilder(setup, velocity_stats, model.type_embedding_size, context_stats),
        graph_builder=builder_cls(builder_params, setup),
        encoder=encoder_cls(encoder_params, sizes),
        processor=processor_cls(processor_params, sizes),
        decoder=decoder_cls(decoder_params, sizes),
        integrator=integrator,
        output_stats=output_stats,
    )


def plugin_versions(recipe: Recipe, registry: Registry, setup: ModelSetup) -> dict[str, dict[str, str]]:
    """``kind/name -> {"distribution", "version", "plugin"}`` of every component the recipe uses and of the
    installed materials of the setup's particle types (an imported model may have types no material is installed for).

    Checkpoints store it as ``plugins``, so loading one where a component is missing
    says which distribution, at which version, to install (:mod:`.trained`).
    """
    model = recipe.model
    named = [(kind, getattr(model, kind).name) for kind in COMPONENT_SECTIONS]
    named.append(("dataset", recipe.dataset.name))
    named += [("material", e.name) for e in registry.entries("material") if e.cls.particle_type in setup.particle_types]
    return {f"{kind}/{name}": registry.entry(kind, name).record for kind, name in named}
