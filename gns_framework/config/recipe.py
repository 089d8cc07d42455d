"""Recipes: one YAML file per experiment, validated in one pass.

Components are named by their registered name (``processor: {name: interaction_network,
message_passing_steps: 10}``); the keys beside ``name`` are that component's ``Params``.
Every problem is reported at once with its location.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from ..contracts import COMPONENT_KINDS
from ..errors import RecipeError, did_you_mean
from ..runtime.precision import Precision
from ..safe_names import safe_component
from ..specs import ComponentSpec
from .paths import resolve_named_path
from .problems import problems_from
from .yaml_files import load_yaml_mapping

if TYPE_CHECKING:
    from ..plugins import Registry


REFERENCE_NOISE_STD = 6.7e-4
"""The reference's training noise (Sanchez-Gonzalez et al. 2020), tuned for DeepMind's datasets."""


class _Strict(BaseModel):
    # A number where a string is expected is that string (``name: 1e5``, see config.yaml_files).
    model_config = ConfigDict(extra="forbid", coerce_numbers_to_str=True)


PICKLE_GRANT = "allow_pickle"
"""The dataset key with which recipes once granted unpickling.

A grant in a recipe travels with it, and into every checkpoint trained from it,
to data the user never named, so it is given per command for one folder
(``--allow-pickle FOLDER``) instead: a recipe file holding it is refused, and a
checkpoint's stored copy is dropped unread (:func:`without_pickle_grant`).
"""


class DatasetSpec(ComponentSpec):
    """Dataset layout (``name``: a dataset plugin), its folder and the plugin's parameters."""

    name: str = "safe"
    path: str = Field(
        description="folder with metadata.json and <split> files; a relative path is read beside the recipe file, "
        "or from the working directory when nothing of that name is beside it (gns_framework.config.paths)"
    )
    frame_stride: int = Field(
        1,
        ge=1,
        description="stored frames per learned step: the model sees every k-th frame "
        "(dt and statistics scale with it); fewer, larger steps make rollouts cheaper and accumulate less error",
    )
    stride_offsets: Literal["first", "all"] = Field(
        "first",
        description="with frame_stride k > 1, the train windows come from frames 0, k, 2k, ... (first) or from "
        "every offset j < k, frames j, j + k, ... (all: k times the windows from the same simulations); "
        "validation and rollouts always start at the first frame",
    )
    mirror_axes: list[int] = Field(
        default_factory=list,
        description="horizontal axes along which the train split also holds every trajectory reflected across its "
        "box's mid-plane, walls swapped (gns_framework.data.mirror; never the axis gravity acts along: for the MPM's "
        "scenes, y up, give [0] in 2D, [0, 2] in 3D): the physics is symmetric, a network learns it only from data; "
        "each axis doubles the train windows; validation and rollouts see the data as stored",
    )
    memory: Literal["auto", "all", "windows"] = Field(
        "auto",
        description="all: every trajectory read once and kept (fastest when the data fits); windows: a process "
        "keeps the few trajectories it used last and reads, memory-mapped where the layout "
        "stores positions uncompressed (safe), the frames of its windows; auto: windows when several processes train",
    )


class ModelSpec(_Strict):
    """The recipe's ``model`` section: what the weights mean, and the training noise."""

    #: Fields that shape how the model is trained, not what its weights compute: a fine-tuning run
    #: (``gns train --init-from``) may change them. The normalisation statistics that the noise widened
    #: travel with the weights, so the fine-tuned weights keep the scale they were learned against.
    TRAINING_ONLY: ClassVar[frozenset[str]] = frozenset({"noise_std", "noise_relative"})

    history: int = Field(6, ge=2, description="C, positions per input window (C - 1 velocities)")
    latent_size: int = Field(128, ge=1)
    mlp_hidden_size: int = Field(128, ge=1)
    mlp_hidden_layers: int = Field(2, ge=0)
    type_embedding_size: int = Field(16, ge=1, description="used only when the scene has more than one type")
    connectivity_radius: float | None = Field(None, gt=0, description="default: the dataset's metadata")
    materials: list[str] | None = Field(None, description="materials the model handles; default: those in the data")
    material_properties: list[str] | None = Field(
        None, description="names of the data's material_property columns; default: the materials' properties"
    )
    noise_std: float = Field(
        REFERENCE_NOISE_STD,
        ge=0,
        description="random-walk noise std at the last input velocity, in dataset length units per frame",
    )
    noise_relative: float | None = Field(
        None,
        ge=0,
        description="random-walk noise std as a fraction of the data's velocity std (mean over dimensions of the "
        "metadata's vel_std); replaces noise_std, so one value fits data of any scale",
    )
    periodic: list[bool] | None = Field(
        None,
        description="per dimension, whether the domain wraps around; "
        "default: the metadata's periodic_boundary_conditions",
    )
    wall_features: bool = Field(True, description="distance-to-wall node features for the non-periodic dimensions")
    wall_conditions: bool | None = Field(
        None,
        description="each wall's friction coefficient as a node feature; default: when the training "
        "trajectories record walls that differ between them",
    )
    graph_builder: ComponentSpec = ComponentSpec(name="radius")
    encoder: ComponentSpec = ComponentSpec(name="mlp")
    processor: ComponentSpec = ComponentSpec(name="interaction_network")
    decoder: ComponentSpec = ComponentSpec(name="mlp")
    integrator: ComponentSpec = ComponentSpec(name="semi_implicit_euler")

    @model_validator(mode="after")
    def _one_noise_rule(self) -> ModelSpec:
        # A resolved recipe (checkpoints, recipe.yaml) holds both keys with noise_std at its default: that is
        # no conflict. Another noise_std beside noise_relative is.
        if self.noise_relative is not None and self.noise_std != REFERENCE_NOISE_STD:
            raise ValueError(
                f"give noise_std (absolute) or noise_relative (fraction of the velocity std), not both "
                f"(noise_std {self.noise_std} beside noise_relative {self.noise_relative})"
            )
        return self


class OptimizerSpec(_Strict):
    """Adam and its learning-rate schedule.

    ``exponential`` (the reference's): ``lr = lr_min + (lr_init - lr_min) * lr_decay ** (step / lr_decay_steps)``.
    ``cosine``: after ``warmup_steps`` of linear warm-up from 0 to ``lr_init``, a half cosine from ``lr_init``
    down to ``lr_min`` at ``anneal_fraction`` of the training steps (``training.steps``; by default the last),
    then ``lr_min`` to the end.
    """

    schedule: Literal["exponential", "cosine"] = Field("exponential", description="exponential (reference) or cosine")
    lr_init: float = Field(1e-4, gt=0)
    lr_min: float = Field(1e-6, ge=0)
    lr_decay: float = Field(0.1, gt=0, le=1, description="exponential schedule only")
    lr_decay_steps: float = Field(5e6, gt=0, description="exponential schedule only")
    warmup_steps: int = Field(0, ge=0, description="linear warm-up steps from lr 0 (both schedules)")
    anneal_fraction: float = Field(
        1.0, gt=0, le=1, description="cosine schedule only: fraction of training.steps at which lr reaches lr_min"
    )
    clip_grad_norm: float | None = Field(
        None, gt=0, description="scale the gradients down to this global L2 norm before each update; default: none"
    )

    @model_validator(mode="after")
    def _floor_below_start(self) -> OptimizerSpec:
        if self.lr_min > self.lr_init:
            raise ValueError(f"lr_min ({self.lr_min}) must not exceed lr_init ({self.lr_init})")
        return self


class TrainingSpec(_Strict):
    steps: int = Field(1000, ge=1)
    batch_size: int = Field(2, ge=1, description="training windows per step (per process)")
    optimizer: OptimizerSpec = OptimizerSpec()
    log_every: int = Field(50, ge=1)
    validate_every: int = Field(200, ge=1)
    validation_windows: int = Field(32, ge=1, description="fixed windows of the valid split for the one-step loss")
    checkpoint_every: int = Field(500, ge=1)
    keep_checkpoints: int = Field(3, ge=1)
    device: str = Field("auto", description="auto, cpu, cuda or cuda:N")
    threads: int | None = Field(None, ge=1, description="torch intra-op threads (default: torch's)")
    recompute_activations: bool = Field(
        False, description="recompute edge activations in the backward: about half the memory, ~10% slower"
    )
    ema_decay: float | None = Field(
        None,
        gt=0,
        lt=1,
        description="keep an exponential average of the weights (e.g. 0.999, ~1000 steps): validation, best.pt and "
        "rollouts use it, training goes on with the weights; default: none",
    )
    deterministic: bool = Field(
        True,
        description="on GPUs, sums at nodes in a fixed order (a CSR segment sum), so runs and resumes are bit-equal; "
        "false: atomic index_add_, whose last bits vary run to run. CPUs are deterministic either way",
    )
    precision: Precision = Field(
        "float32",
        description="float32; tf32: float32 products on CUDA tensor cores in TF32 (float32 on CPUs); "
        "or bfloat16 matrix products under autocast (faster on AMX CPUs and GPUs)",
    )
    compile_node_side: bool = Field(
        False,
        description="compile the node side (node features, the encoder's and every step's node MLP, the decoder) "
        "with torch.compile, whole graphs or an error: fused kernels on GPUs; the first steps pay the compilation "
        "(gns_framework/runtime/compiled.py)",
    )
    capture_step: bool = Field(
        False,
        description="replay each training step from captures (CUDA graphs on GPUs): batches padded to capacity classes "
        "of at most 25 % more particles, one capture per class; one process, graph builder radius_fixed_capacity, a "
        "processor that reads nothing back (gns_framework/training/captured_step.py)",
    )
    pushforward_steps: int = Field(
        0,
        ge=0,
        description="push-forward training (Brandstetter et al. 2022): before each step the model rolls every window "
        "k steps on from its ground-truth inputs without gradient, k drawn from 0..pushforward_steps per step, and "
        "learns the next true frame from its own rolled-out inputs, so it learns to correct its rollouts' drift",
    )
    unrolled_loss_steps: int = Field(
        0,
        ge=0,
        description="loss through the model's own rollout (backpropagation through time): after the next frame the "
        "model rolls each window on this many steps with gradient, each step's error against the true frame in the "
        "loss, so errors that compound over a rollout cost in training (the loss logged is the mean over the steps); "
        "each step costs a forward and a backward pass and the activations of every step are kept until the backward",
    )
    validation_rollouts: int = Field(
        0,
        ge=0,
        description="valid trajectories rolled out in full at each validation (0: one-step loss only); "
        "the checkpoint with the best best_metric so far is kept as checkpoints/best.pt",
    )
    partitions: int = Field(
        1,
        ge=1,
        description="split each training step's scenes into this many pieces (slabs or blocks, whichever leaves the "
        "smaller halo), one per process, for scenes too large for one device (launch under torchrun with this many "
        "processes, or a multiple: teams of one process per piece, data-parallel over the teams): every process of "
        "a team takes the team's windows and the gradients are one process's on all the teams' windows "
        "(docs/domain_decomposition.md); 1: data-parallel over the processes",
    )
    best_metric: str = Field(
        "valid_rollout_mse",
        description="rollout metric (lower is better) that picks best.pt: valid_rollout_<name>, the mean over the "
        "validation rollouts of an installed metric measured in validation (`gns plugins --kind metric` lists them), "
        "or valid_rollout_<name>_worst, its largest; valid_rollout_deposit_error_pct is the mean of each rollout's "
        "final extent and height errors",
    )

    @model_validator(mode="after")
    def _unrolled_loss_on_one_step_kind(self) -> TrainingSpec:
        # The captured and the partitioned steps compute a one-step loss of their own.
        if self.unrolled_loss_steps and self.capture_step:
            raise ValueError("unrolled_loss_steps is not available with capture_step: set one of them to 0 / false")
        if self.unrolled_loss_steps and self.partitions > 1:
            raise ValueError("unrolled_loss_steps is not available with partitions > 1: set one of them to 0 / 1")
        return self


class RolloutGuardSpec(_Strict):
    """What a rollout does when a prediction is not finite or a particle leaves the domain."""

    margin: float | None = Field(
        None, ge=0, description="how far (dataset length units) a particle may pass a wall; default: no domain check"
    )
    on_violation: Literal["stop", "clamp"] = Field(
        "stop", description="stop: raise naming step, particles and cause; clamp: put the particles back and report it"
    )


class RolloutSpec(_Strict):
    split: str = "test"
    steps: int | None = Field(None, ge=1, description="default: to the end of each trajectory")
    trajectories: int | None = Field(None, ge=1, description="default: all of the split")
    guard: RolloutGuardSpec = RolloutGuardSpec()


class Recipe(_Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    seed: int = 0
    output_dir: str | None = Field(None, description="default: runs/<name> (the name made a safe folder name)")
    dataset: DatasetSpec
    model: ModelSpec = ModelSpec()
    training: TrainingSpec = TrainingSpec()
    rollout: RolloutSpec = RolloutSpec()

    @property
    def run_dir(self) -> Path:
        """``output_dir``, else ``runs/<name>``: the name is never a path (``..`` is not the working directory)."""
        return Path(self.output_dir) if self.output_dir else Path("runs") / safe_component(self.name)

    def resolved(self) -> dict[str, Any]:
        """The recipe with every default filled in (stored in checkpoints and tracked runs)."""
        return self.model_dump(mode="json")

    def on_dataset(self, path: str | Path) -> Recipe:
        """This recipe with its data read from ``path`` (``--dataset``), as a run then records it."""
        return self.model_copy(update={"dataset": self.dataset.model_copy(update={"path": str(path)})})


COMPONENT_SECTIONS = tuple(kind for kind in COMPONENT_KINDS if kind in ModelSpec.model_fields)
"""The component kinds a recipe's ``model`` names (graph_builder, encoder, processor, decoder, integrator)."""


def validate_recipe(raw: dict, registry: Registry, source: str | Path | None = None) -> Recipe:
    """Validate a recipe mapping against the schema and the installed components, all at once."""
    problems: list[tuple[str, str]] = []
    recipe: Recipe | None = None
    try:
        recipe = Recipe.model_validate(raw)
    except ValidationError as exc:
        problems += problems_from(exc, Recipe)
    problems += _component_problems(raw, registry)
    if problems or recipe is None:
        raise RecipeError(source, problems)
    return recipe


def _component_problems(raw: dict, registry: Registry) -> list[tuple[str, str]]:
    problems: list[tuple[str, str]] = []
    raw_model = raw.get("model")
    model: dict = raw_model if isinstance(raw_model, dict) else {}
    sections: list[tuple[tuple[str, ...], str, Any]] = [(("model", s), s, model.get(s)) for s in COMPONENT_SECTIONS]
    sections.append((("dataset",), "dataset", raw.get("dataset")))
    for loc, kind, spec in sections:
        if spec is None or not isinstance(spec, dict):
            continue
        component = spec
        if kind == "dataset":
            params = {k: v for k, v in spec.items() if k not in DatasetSpec.model_fields and k != PICKLE_GRANT}
            component = {"name": spec.get("name", "safe"), **params}
            if PICKLE_GRANT in spec:
                problems.append(
                    (
                        f"dataset.{PICKLE_GRANT}",
                        "a recipe cannot grant unpickling (the grant would travel with it and its checkpoints to other "
                        "data): remove the key and, only for data you trust, give the command --allow-pickle FOLDER; "
                        "geoelements .npz files of numpy arrays read without it",
                    )
                )
        if not isinstance(component.get("name"), str):
            continue
        try:
            registry.resolve(kind, component, loc)
        except RecipeError as exc:
            problems += exc.problems
    raw_training = raw.get("training")
    training: dict = raw_training if isinstance(raw_training, dict) else {}
    best = training.get("best_metric")
    if isinstance(best, str):
        tracked = registry.best_metric_choices()
        if best not in tracked:
            problems.append(
                (
                    "training.best_metric",
                    f"unknown validation metric {best!r}{did_you_mean(best, tracked)}; "
                    f"measured in validation: {', '.join(tracked)}",
                )
            )
    materials = model.get("materials")
    if isinstance(materials, list):
        known = registry.names("material")
        for i, material in enumerate(materials):
            if isinstance(material, str) and material not in known:
                problems.append(
                    (
                        f"model.materials[{i}]",
                        f"unknown material {material!r}{did_you_mean(material, known)}; installed: {', '.join(known)}",
                    )
                )
    return problems


def without_pickle_grant(raw: dict) -> dict:
    """A checkpoint's stored recipe without the ``dataset.allow_pickle`` older versions stored: it grants nothing."""
    dataset = raw.get("dataset")
    if not isinstance(dataset, dict) or PICKLE_GRANT not in dataset:
        return raw
    return {**raw, "dataset": {k: v for k, v in dataset.items() if k != PICKLE_GRANT}}


def load_recipe(path: str | Path, registry: Registry, overrides: dict | None = None) -> Recipe:
    """Read and validate a recipe file; ``overrides`` (nested mapping) replace keys first."""
    raw = load_yaml_mapping(path)
    if overrides:
        raw = _merged(raw, overrides)
    recipe = validate_recipe(raw, registry, path)
    overridden = overrides is not None and isinstance(overrides.get("dataset"), dict) and "path" in overrides["dataset"]
    if overridden:
        return recipe
    resolved = resolve_named_path(recipe.dataset.path, path, missing="as_named")
    return recipe if str(resolved) == recipe.dataset.path else recipe.on_dataset(resolved)


def _merged(base: dict, overrides: dict) -> dict:
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merged(out[key], value)
        else:
            out[key] = value
    return out
