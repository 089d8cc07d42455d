"""Import checkpoints written by geoelements/gns (https://github.com/geoelements/gns, MIT).

geoelements' ``train.py`` writes ``model-<step>.pt`` (``torch.save`` of the
``LearnedSimulator.state_dict()``) and ``train_state-<step>.pt`` (a dict with
``optimizer_state`` = the Adam ``state_dict``, ``global_train_state = {"step": step}``
and, in most versions, the last ``loss``). The model's sizes are read from tensor
shapes; what the files do not hold comes from the dataset's ``metadata.json``
(domain, radius, statistics) and from arguments (the training noise std, which
geoelements folds into its normalisation, and the particle types of the scene).
The parameter mapping is in :mod:`.geoelements_layout`; ``docs/importing.md`` has
the user guide.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from ..assembly.learned import build_learned_simulator, plugin_versions
from ..assembly.scene import scene_to_dict
from ..config.recipe import REFERENCE_NOISE_STD, ModelSpec, validate_recipe
from ..contracts import ModelSetup
from ..data.metadata import DatasetMetadata, load_metadata, parse_metadata
from ..errors import CheckpointError, GnsError
from ..model.learned_simulator import LearnedSimulator
from ..moved import renamed_attribute
from ..plugins import Registry, load_registry
from ..specs import ComponentSpec
from ..training.optim import make_optimizer
from .geoelements_layout import Architecture, ParameterMap

HISTORY = 6
"""geoelements' INPUT_SEQUENCE_LENGTH: 6 positions, 5 velocities."""
NOISE_STD = REFERENCE_NOISE_STD
"""geoelements' default ``--noise_std`` (the reference's); its normalisation uses sqrt(std^2 + noise_std^2)."""
PROPERTY_NAME = "friction"
"""geoelements' ``material_property``: tan of the friction angle, one column."""


@dataclass
class ImportedCheckpoint:
    """A geoelements model as built-in components, and what a gns-framework checkpoint needs.

    Attributes:
        simulator: the built-in simulator with the imported parameters (eval mode).
        model: the recipe's ``model`` section that rebuilds ``simulator``.
        setup: the model setup it is sized for.
        metadata: the dataset metadata it normalises with.
        parameter_map: geoelements key -> built-in name and layout (for gradients and moments too).
        optimizer_state: ``torch.optim.Adam`` state_dict for ``simulator.parameters()``, or None.
        step: geoelements' ``global_train_state["step"]`` (0 without a train state).
        loss: the training loss stored in the train state, if any.
        source: the model file (or ``<state_dict>``), for messages.
    """

    simulator: LearnedSimulator
    model: ModelSpec
    setup: ModelSetup
    scene = renamed_attribute("scene", "setup")  # its name until 0.2
    metadata: DatasetMetadata
    parameter_map: ParameterMap
    optimizer_state: dict | None
    step: int
    loss: float | None
    source: str

    def checkpoint_state(self, name: str, dataset: Mapping[str, Any], registry: Registry) -> dict[str, Any]:
        """The mapping :func:`gns_framework.io.checkpoint.save_checkpoint` writes.

        Args:
            name: recipe name of the imported run.
            dataset: the recipe's ``dataset`` section (``name``, ``path`` and the plugin's keys).
            registry: installed components (versions are recorded).

        With a train state, the optimizer and the learning-rate schedule are stored
        too, so ``gns train --resume`` continues the geoelements run.
        """
        raw = {"name": name, "dataset": dict(dataset), "model": self.model.model_dump(mode="json")}
        recipe = validate_recipe(raw, registry, f"recipe of the model imported from {self.source}")
        state: dict[str, Any] = {
            "model": self.simulator.state_dict(),
            "step": self.step,
            "recipe": recipe.resolved(),
            "scene": scene_to_dict(self.setup),
            "metadata": self.metadata.to_json_dict(),
            "plugins": plugin_versions(recipe, registry, self.setup),
        }
        if self.optimizer_state is not None:
            optimizer, scheduler = make_optimizer(
                self.simulator.parameters(), recipe.training.optimizer, recipe.training.steps
            )
            optimizer.load_state_dict(self.optimizer_state)
            schedule = scheduler.state_dict()
            schedule.update(
                last_epoch=self.step, _step_count=self.step + 1, _last_lr=[g["lr"] for g in optimizer.param_groups]
            )
            scheduler.load_state_dict(schedule)
            state.update(
                optimizer=optimizer.state_dict(),
                scheduler=scheduler.state_dict(),
                rng={"torch": torch.get_rng_state(), "cuda": []},
            )
        return state


def import_geoelements_checkpoint(
    model: str | Path | Mapping[str, Tensor],
    metadata: str | Path | Mapping[str, Any] | DatasetMetadata,
    *,
    train_state: str | Path | Mapping[str, Any] | None = None,
    particle_types: Sequence[int] | None = None,
    material_properties: Sequence[str] | None = None,
    noise_std: float = NOISE_STD,
    registry: Registry | None = None,
) -> ImportedCheckpoint:
    """Build the built-in simulator equivalent to a geoelements/gns checkpoint.

    Args:
        model: ``model-<step>.pt`` (path) or the loaded ``state_dict``.
        metadata: the dataset's ``metadata.json`` (file or folder), its mapping, or parsed metadata.
            Nested per-split metadata (``{"train": ..., "rollout": ...}``) uses ``train``.
        train_state: ``train_state-<step>.pt`` (path or loaded dict), optional.
        particle_types: type ids of the scene. Default: every row of the checkpoint's
            embedding (``0 .. nparticle_types-1``); required when the checkpoint has no
            embedding (``nparticle_types == 1``). A type is kinematic when its installed material
            is (type 3, ``rigid``, as in geoelements).
        material_properties: names of the material-property columns (default ``friction``
            when the checkpoint has one).
        noise_std: the ``--noise_std`` the model was trained with.
        registry: installed components (default: discovered).

    Raises:
        CheckpointError: naming the file and the key for missing, unknown or mis-shaped tensors.
    """
    registry = registry or load_registry()
    source = str(model) if isinstance(model, (str, Path)) else "<state_dict>"
    reference = _read(model, "model") if isinstance(model, (str, Path)) else dict(model)
    metadata = _metadata(metadata)
    architecture = Architecture.infer(reference, source)
    _check_keys(reference, architecture, source)
    if architecture.dim != metadata.dim:
        raise CheckpointError(
            f"{source}: _encode_process_decode._encoder.edge_fn.0.NN-0.weight: {architecture.edge_in} edge inputs "
            f"mean a {architecture.dim}-D model, but the metadata has dim = {metadata.dim}"
        )
    walls_width = (HISTORY - 1) * metadata.dim + 2 * metadata.dim
    types = _particle_types(particle_types, architecture, source)
    names = _property_names(material_properties, architecture, walls_width, source)
    setup = ModelSetup(
        dim=metadata.dim,
        bounds=tuple((float(lo), float(hi)) for lo, hi in metadata.bounds),
        connectivity_radius=float(metadata.default_connectivity_radius),
        particle_types=types,
        kinematic_types=tuple(t for t in types if t in registry.kinematic_types()),
        property_names=names,
        history=HISTORY,
        boundary_clamp_limit=metadata.boundary_clamp_limit,
    )
    spec = ModelSpec(
        history=HISTORY,
        latent_size=architecture.latent,
        mlp_hidden_size=architecture.mlp_hidden,
        mlp_hidden_layers=architecture.mlp_hidden_layers,
        type_embedding_size=architecture.embedding_size,
        material_properties=list(names) or None,
        noise_std=noise_std,
        processor=ComponentSpec(name="interaction_network", message_passing_steps=architecture.message_passing_steps),
    )
    simulator = build_learned_simulator(setup, metadata, spec, registry)
    parameter_map = ParameterMap(architecture, types, walls_width)
    _load_parameters(simulator, parameter_map, reference, source)
    simulator.eval()

    optimizer_state, step, loss = None, 0, None
    if train_state is not None:
        state_source = str(train_state) if isinstance(train_state, (str, Path)) else "<train_state>"
        raw = _read(train_state, "train state") if isinstance(train_state, (str, Path)) else dict(train_state)
        optimizer_state, step, loss = _train_state(raw, list(reference), parameter_map, simulator, state_source)
    return ImportedCheckpoint(simulator, spec, setup, metadata, parameter_map, optimizer_state, step, loss, source)


def _read(path: str | Path, what: str) -> dict:
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: geoelements {what} file not found")
    try:
        loaded = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for foreign or damaged files
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise CheckpointError(f"{path}: not a readable geoelements {what} file: {reason}") from None
    if not isinstance(loaded, dict):
        raise CheckpointError(f"{path}: expected a dict (torch.save of a state_dict), got {type(loaded).__name__}")
    return loaded


def _metadata(metadata: str | Path | Mapping[str, Any] | DatasetMetadata) -> DatasetMetadata:
    if isinstance(metadata, DatasetMetadata):
        return metadata
    if isinstance(metadata, (str, Path)):
        return load_metadata(metadata, split="train")
    return parse_metadata(dict(metadata), "<metadata>", split="train")


def _check_keys(reference: dict, architecture: Architecture, source: str) -> None:
    expected = architecture.keys()
    unknown = [k for k in reference if k not in set(expected)]
    missing = [k for k in expected if k not in reference]
    if unknown:
        raise CheckpointError(
            f"{source}: {unknown[0]}: unknown key for a geoelements LearnedSimulator"
            + (f" ({len(unknown) - 1} more unknown)" if len(unknown) > 1 else "")
        )
    if missing:
        raise CheckpointError(
            f"{source}: {missing[0]}: missing" + (f" ({len(missing) - 1} more missing)" if len(missing) > 1 else "")
        )


def _particle_types(particle_types: Sequence[int] | None, architecture: Architecture, source: str) -> tuple[int, ...]:
    if particle_types is None:
        if not architecture.uses_embedding:
            raise CheckpointError(
                f"{source}: _particle_type_embedding.weight: the model has no type embedding (nparticle_types = 1); "
                "give the particle type id(s) of its data (particle_types=..., --particle-types)"
            )
        return tuple(range(architecture.num_types))
    types = tuple(sorted({int(t) for t in particle_types}))
    if not types or types[0] < 0:
        raise GnsError(f"particle_types: expected non-negative type ids, got {list(particle_types)}")
    if architecture.uses_embedding and types[-1] >= architecture.num_types:
        raise CheckpointError(
            f"{source}: _particle_type_embedding.weight: has {architecture.num_types} rows, "
            f"so type {types[-1]} is not embedded"
        )
    return types


def _property_names(
    names: Sequence[str] | None, architecture: Architecture, walls_width: int, source: str
) -> tuple[str, ...]:
    embedded = walls_width + (architecture.embedding_size if architecture.uses_embedding else 0)
    count = architecture.node_in - embedded
    if count < 0:
        raise CheckpointError(
            f"{source}: _encode_process_decode._encoder.node_fn.0.NN-0.weight: {architecture.node_in} node inputs, "
            f"fewer than the {embedded} the velocities, walls and type embedding need"
        )
    names = tuple(names) if names is not None else (PROPERTY_NAME,) * min(count, 1)
    if len(names) != count:
        raise CheckpointError(
            f"{source}: _encode_process_decode._encoder.node_fn.0.NN-0.weight: {architecture.node_in} node inputs "
            f"leave {count} material-property column(s), but {len(names)} name(s) were given: {list(names)}"
        )
    return names


def _load_parameters(simulator: LearnedSimulator, parameter_map: ParameterMap, reference: dict, source: str) -> None:
    ours = parameter_map.state_dict(reference)
    origin = {parameter_map.name(k): k for k in reference if parameter_map.name(k) is not None}
    parameters = dict(simulator.named_parameters())
    for name, value in ours.items():
        target = parameters.get(name)
        key = origin.get(name, name)
        if target is None:
            raise CheckpointError(f"{source}: {key}: maps to {name}, which the built-in model does not have")
        if tuple(value.shape) != tuple(target.shape):
            raise CheckpointError(
                f"{source}: {key}: shape {tuple(reference[key].shape)} does not fit the model its other tensors "
                f"describe (built-in {name} needs {tuple(target.shape)} after conversion, got {tuple(value.shape)})"
            )
    uncovered = sorted(set(parameters) - set(ours))
    if uncovered:
        raise CheckpointError(f"{source}: no geoelements tensor gives the built-in parameter {uncovered[0]}")
    with torch.no_grad():
        for name, value in ours.items():
            parameters[name].copy_(value)


def _train_state(
    raw: dict, reference_keys: list[str], parameter_map: ParameterMap, simulator: LearnedSimulator, source: str
) -> tuple[dict, int, float | None]:
    """The Adam state for ``simulator.parameters()``, the step and the stored loss."""
    optimizer = raw.get("optimizer_state")
    if not isinstance(optimizer, dict) or "state" not in optimizer or "param_groups" not in optimizer:
        raise CheckpointError(f"{source}: optimizer_state: missing or not an optimizer state_dict")
    groups = optimizer["param_groups"]
    indices = [i for g in groups for i in g["params"]]
    if len(groups) != 1 or len(indices) != len(reference_keys):
        raise CheckpointError(
            f"{source}: optimizer_state.param_groups: expected one group over the model's {len(reference_keys)} "
            f"parameters, got {len(groups)} group(s) over {len(indices)}"
        )
    ours = [name for name, _ in simulator.named_parameters()]
    position = {name: i for i, name in enumerate(ours)}
    state: dict[int, dict] = {}
    for index, key in zip(indices, reference_keys, strict=True):
        name = parameter_map.name(key)
        if name is None or index not in optimizer["state"]:
            continue
        # Cloned, so the imported optimizer never shares (and steps) the source's tensors.
        state[position[name]] = {
            field: (parameter_map.tensor(key, value) if _is_moment(value) else value).clone()
            if isinstance(value, Tensor)
            else value
            for field, value in optimizer["state"][index].items()
        }
    group = {**groups[0], "params": list(range(len(ours)))}
    train = raw.get("global_train_state")
    if not isinstance(train, dict) or "step" not in train:
        raise CheckpointError(f"{source}: global_train_state.step: missing")
    loss = raw.get("loss")
    return {"state": state, "param_groups": [group]}, int(train["step"]), None if loss is None else float(loss)


def _is_moment(value: Any) -> bool:
    """Adam's per-element moments (exp_avg, exp_avg_sq, max_exp_avg_sq), not its scalar step."""
    return isinstance(value, Tensor) and value.ndim > 0
