"""The training envelope: measured from the data the model saw, and every quantity outside it named."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gns_framework.contracts import ModelSetup
from gns_framework.data.metadata import DatasetMetadata
from gns_framework.data.trajectory import Trajectory
from gns_framework.model.envelope import Envelope, measure_envelope, outside_envelope

SPACING = 0.01
DT = 0.01


def _metadata(dt: float = DT, dim: int = 2) -> DatasetMetadata:
    zeros = [0.0] * dim
    return DatasetMetadata(
        bounds=[(0.0, 2.0), (0.0, 1.0), (0.0, 1.0)][:dim],
        sequence_length=8,
        default_connectivity_radius=0.025,
        dim=dim,
        dt=dt,
        vel_mean=zeros,
        vel_std=[1.0] * dim,
        acc_mean=zeros,
        acc_std=[1.0] * dim,
    )


def _column(
    width: float,
    height: float,
    *,
    spacing: float = SPACING,
    friction: float = 0.7,
    speed: float = 0.5,
    extent=(1.0, 0.6),
    walls=((0.4, 0), (0.0, 0), (0.5, 0), (0.0, 0)),
    key: str = "c",
) -> Trajectory:
    """A lattice column falling at ``speed`` m/s (per DT) for 8 frames, in its own box."""
    xs, ys = np.meshgrid(np.arange(0, width, spacing), np.arange(0, height, spacing), indexing="ij")
    start = np.stack([xs.ravel(), ys.ravel()], axis=1) + spacing / 2
    frames = np.stack([start - [0.0, speed * DT * t] for t in range(8)]).astype(np.float32)
    n = start.shape[0]
    return Trajectory(
        frames,
        np.full(n, 6),
        np.full((n, 1), friction, np.float32),
        key=key,
        bounds=np.array([[0.0, extent[0]], [0.0, extent[1]]], np.float32),
        walls=np.array(walls, np.float32),
    ).validated("test")


def _against_right(trajectory: Trajectory, width: float) -> Trajectory:
    """The column moved from the left wall to the right one of its box."""
    shift = np.array([trajectory.bounds[0, 1] - width, 0.0], np.float32)
    return replace(trajectory, position=trajectory.position + shift)


SCENE = ModelSetup(
    dim=2, bounds=((0.0, 2.0), (0.0, 1.0)), connectivity_radius=0.025, particle_types=(6,), property_names=("friction",)
)
TRAINED = [
    _column(0.1, 0.2, friction=0.5, extent=(0.8, 0.5), key="a"),
    _column(0.3, 0.4, friction=0.9, extent=(2.0, 1.0), walls=((0.3, 0), (0.6, 0), (0.3, 0), (0.0, 0)), key="b"),
]
ENVELOPE = measure_envelope(_metadata(), TRAINED, SCENE, {6: "sand"}, frame_stride=2)


def test_the_envelope_is_measured_from_the_training_trajectories():
    e = ENVELOPE
    assert e.dim == 2 and e.step_dt == DT and e.frame_stride == 2
    assert e.particle_spacing == pytest.approx(SPACING, rel=1e-5)
    assert e.particle_types == [6] and e.materials == {"6": "sand"}
    assert e.properties == {"friction": [pytest.approx(0.5), pytest.approx(0.9)]}
    assert e.extent == [[pytest.approx(0.8), pytest.approx(2.0)], [pytest.approx(0.5), pytest.approx(1.0)]]
    assert e.walls["x_min"] == {"friction": [pytest.approx(0.3), pytest.approx(0.4)], "slip": False, "no_slip": False}
    assert e.walls["x_max"] == {"friction": [pytest.approx(0.6), pytest.approx(0.6)], "slip": True, "no_slip": False}
    assert e.max_speed == pytest.approx(0.5, rel=1e-4)
    assert e.particle_count == [200, 1200]
    assert Envelope.from_dict(e.to_dict()) == e


def test_data_inside_the_envelope_passes_even_in_a_box_never_seen():
    unseen_box = _column(0.2, 0.3, friction=0.6, extent=(1.37, 0.72), key="inside")
    assert outside_envelope(ENVELOPE, _metadata(), [unseen_box], history=6) == []


@pytest.mark.parametrize(
    "trajectory, metadata, quantity, value, trained",
    [
        (
            _column(0.1, 0.2, spacing=0.00625, key="k"),
            _metadata(),
            "nearest-neighbour distance (median)",
            "0.00625 m",
            "0.01 m",
        ),
        (_column(0.1, 0.2, key="k"), _metadata(dt=0.016), "learned step", "0.016 s", "0.01 s"),
        (_column(0.1, 0.2, friction=1.2, key="k"), _metadata(), "property friction", "1.2", "0.5 .. 0.9"),
        (_column(0.1, 0.2, extent=(2.5, 0.6), key="k"), _metadata(), "domain x extent", "2.5 m", "0.8 .. 2 m"),
        (_column(0.1, 0.2, extent=(1.0, 0.3), key="k"), _metadata(), "domain y extent", "0.3 m", "0.5 .. 1 m"),
        (
            _column(0.1, 0.2, walls=((0.0, 0), (0, 0), (0.5, 0), (0, 0)), key="k"),
            _metadata(),
            "wall x_min",
            "slip",
            "friction 0.3 .. 0.4",
        ),
        (
            _against_right(_column(0.1, 0.2, walls=((0.3, 0), (0.9, 0), (0.5, 0), (0, 0)), key="k"), 0.1),
            _metadata(),
            "wall x_max",
            "friction 0.9",
            "slip or friction 0.6 .. 0.6",
        ),
        (
            _against_right(_column(0.1, 0.2, walls=((0.3, 0), (0, 1), (0.5, 0), (0, 0)), key="k"), 0.1),
            _metadata(),
            "wall x_max",
            "no-slip",
            "slip or friction",
        ),
        (_column(0.1, 0.2, speed=2.0, key="k"), _metadata(), "input speed", "2 m/s", "up to 0.5 m/s"),
        (_column(0.6, 0.4, key="k"), _metadata(), "particle count", "2400", "200 .. 1200"),
        (
            replace(_column(0.1, 0.2, key="k"), particle_type=np.full(200, 7)),
            _metadata(),
            "particle types",
            "[7]",
            "[6]",
        ),
    ],
)
def test_each_quantity_outside_is_named_with_its_value_and_the_trained_range(
    trajectory, metadata, quantity, value, trained
):
    problems = outside_envelope(ENVELOPE, metadata, [trajectory], history=6)
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"{quantity} {value}")
    assert "trajectory 'k'" in problems[0] or quantity == "learned step"
    assert f"(trained: {trained}" in problems[0]


def test_another_dimension_is_refused_before_anything_else():
    assert outside_envelope(ENVELOPE, _metadata(dim=3), [], history=6) == ["dimension 3D (trained: 2D)"]


def test_only_the_inputs_are_judged_and_many_trajectories_are_counted_once_per_quantity():
    fast_later = _column(0.1, 0.2, key="later")
    position = fast_later.position.copy()
    position[7] -= [0.0, 0.2]  # a jump after the 6 input frames: what the model predicts, not what it is given
    assert outside_envelope(ENVELOPE, _metadata(), [replace(fast_later, position=position)], history=6) == []
    wide = [_column(0.1, 0.2, extent=(2.5, 0.6), key=f"w{i}") for i in range(3)]
    (line,) = outside_envelope(ENVELOPE, _metadata(), wide, history=6)
    assert "in trajectory 'w0' and 2 more" in line


def _envelope(**changes) -> Envelope:
    base = Envelope(
        dim=2,
        particle_spacing=0.0104,
        step_dt=0.01,
        frame_stride=2,
        particle_types=[6],
        materials={"6": "sand"},
        properties={"friction": [0.5, 0.7]},
        extent=[[0.75, 1.5], [0.5, 0.8]],
        walls={
            "x_min": {"friction": [0.3, 0.4], "slip": False, "no_slip": False},
            "y_min": {"friction": None, "slip": True, "no_slip": False},
        },
        max_speed=2.0,
        particle_count=[500, 3000],
        frames=[120, 120],
    )
    return replace(base, **changes)


def test_a_fine_tuned_models_envelope_joins_both_datasets():
    earlier = _envelope()
    later = _envelope(
        particle_spacing=0.0105,
        particle_types=[3, 6],
        materials={"3": "rigid", "6": "sand"},
        properties={"friction": [0.6, 0.9]},
        extent=[[1.0, 2.0], [0.4, 0.6]],
        walls={
            "x_min": {"friction": [0.35, 0.6], "slip": True, "no_slip": False},
            "y_min": {"friction": [0.3, 0.5], "slip": False, "no_slip": False},
        },
        max_speed=1.5,
        particle_count=[800, 4000],
        frames=[100, 120],
        boundary_spacing=[0.0104, 0.0125],
    )
    assert later.union(_envelope(boundary_spacing=[0.009, 0.011])).boundary_spacing == [0.009, 0.0125]
    joined = later.union(earlier)
    assert joined.particle_spacing == 0.0105, "the spacing is the new data's"
    assert joined.particle_types == [3, 6] and joined.materials == {"3": "rigid", "6": "sand"}
    assert joined.properties == {"friction": [0.5, 0.9]}
    assert joined.extent == [[0.75, 2.0], [0.4, 0.8]]
    assert joined.walls == {
        "x_min": {"friction": [0.3, 0.6], "slip": True, "no_slip": False},
        "y_min": {"friction": [0.3, 0.5], "slip": True, "no_slip": False},
    }
    assert joined.max_speed == 2.0 and joined.particle_count == [500, 4000] and joined.frames == [100, 120]
    assert joined.boundary_spacing == [0.0104, 0.0125], "only the new data had fixed particles"


def test_envelopes_of_another_stride_do_not_join():
    with pytest.raises(ValueError, match="stride 1"):
        _envelope().union(_envelope(frame_stride=1))


# --- fixed particles on a lattice of their own ------------------------------------------------------

OBSTACLE_TYPE = 3
OBSTACLE_SCENE = replace(SCENE, particle_types=(OBSTACLE_TYPE, 6), kinematic_types=(OBSTACLE_TYPE,))


def _with_obstacle(column: Trajectory, width: float, height: float, spacing: float) -> Trajectory:
    """``column`` beside a fixed block of particles on an unjittered lattice of ``spacing`` at x >= 0.5 m."""
    xs, ys = np.meshgrid(np.arange(0, width, spacing), np.arange(0, height, spacing), indexing="ij")
    block = np.stack([xs.ravel() + 0.5, ys.ravel()], axis=1).astype(np.float32)
    frames = np.concatenate([column.position, np.broadcast_to(block, (column.num_steps, *block.shape))], axis=1)
    n = frames.shape[1]
    types = np.concatenate([column.particle_type, np.full(len(block), OBSTACLE_TYPE)])
    assert column.material_property is not None
    properties = np.concatenate([column.material_property, np.full((len(block), 1), 0.0, np.float32)])
    assert len(types) == n
    return replace(column, position=frames, particle_type=types, material_property=properties).validated("test")


def test_the_spacing_is_the_materials_when_a_fixed_block_outnumbers_the_sand():
    # Generated obstacles sit on the cell lattice (here 1.3x the sand's spacing) and may outnumber the
    # sand: the median over all particles would then be the block's, and a scene drawn exactly like
    # the training data would be refused (as it was for scenes/sand_general_2d.yaml's hump scenes).
    trained = [_with_obstacle(t, 0.3, 0.3, 1.3 * SPACING) for t in TRAINED]
    envelope = measure_envelope(_metadata(), trained, OBSTACLE_SCENE, {3: "rigid", 6: "sand"}, frame_stride=2)
    assert envelope.particle_spacing == pytest.approx(SPACING, rel=1e-5)
    assert envelope.boundary_spacing == [pytest.approx(1.3 * SPACING, rel=1e-5)] * 2
    small_column = _with_obstacle(_column(0.1, 0.1, key="small"), 0.3, 0.3, 1.3 * SPACING)
    assert (small_column.particle_type == OBSTACLE_TYPE).mean() > 0.5
    assert outside_envelope(envelope, _metadata(), [small_column], history=6, kinematic_types=(OBSTACLE_TYPE,)) == []
    coarse_block = _with_obstacle(_column(0.1, 0.2, key="coarse"), 0.3, 0.3, 2 * SPACING)
    (line,) = outside_envelope(envelope, _metadata(), [coarse_block], history=6, kinematic_types=(OBSTACLE_TYPE,))
    assert line.startswith("boundary nearest-neighbour distance (median) 0.02 m in trajectory 'coarse'"), line
    assert "(trained: 0.013 .. 0.013 m +-10%)" in line
    assert ("boundary nearest-neighbour distance (median)", "0.013 .. 0.013 m (+-10%)") in envelope.rows()


def test_an_envelope_without_boundary_spacing_does_not_judge_fixed_particles():
    # Checkpoints written before the boundary spacing was recorded load with None.
    raw = ENVELOPE.to_dict()
    raw.pop("boundary_spacing")
    old = Envelope.from_dict(raw)
    assert old.boundary_spacing is None
    coarse_block = _with_obstacle(_column(0.1, 0.2, key="coarse"), 0.3, 0.3, 2 * SPACING)
    assert outside_envelope(old, _metadata(), [coarse_block], history=6, kinematic_types=(OBSTACLE_TYPE,)) == [
        "particle types [3] in trajectory 'coarse' (trained: [6])"
    ]


def test_a_face_the_material_never_comes_near_is_not_judged():
    """Issue 46: a rough top, or an unseen right wall a metre from a column that stays on the left, is no reason to
    refuse; the same wall under the column is."""
    far = _column(0.1, 0.2, walls=((0.3, 0), (0.9, 0), (0.5, 0), (0.5, 0)), key="k")
    assert outside_envelope(ENVELOPE, _metadata(), [far], history=6) == []
    near = _against_right(far, 0.1)
    assert [p.split(" (")[0] for p in outside_envelope(ENVELOPE, _metadata(), [near], history=6)] == [
        "wall x_max friction 0.9 in trajectory 'k'"
    ]


def _mixed(key: str = "m") -> Trajectory:
    """A column whose friction varies from particle to particle, with a kinematic floor (type 3) listed first and a
    few fast particles last: runs of its particles differ in every quantity."""
    column = _column(0.3, 0.4, key=key)
    n = column.num_particles
    friction = np.linspace(0.3, 1.2, n, dtype=np.float32)[:, None]
    types = np.where(np.arange(n) < n // 2, 3, 6)
    position = column.position.copy()
    position[:, -5:] -= np.arange(8, dtype=np.float32)[:, None, None] * np.float32([0.0, 0.03])
    return replace(column, position=position, particle_type=types, material_property=friction)


@pytest.mark.parametrize("parts", [1, 2, 3, 7])
def test_measures_of_runs_merge_into_those_of_the_whole_scene(parts):
    from functools import reduce

    from gns_framework.data.in_parts import particle_run
    from gns_framework.model.envelope import SceneMeasures, outside_envelope_of, scene_measures

    scene, metadata = _mixed(), _metadata()
    whole = scene_measures(scene, metadata, 6, kinematic_types=(3,))
    runs = [
        scene_measures(scene, metadata, 6, (3,), rows=particle_run(scene.num_particles, rank, parts))
        for rank in range(parts)
    ]
    assert sum(run.spacing is not None for run in runs) == 1, "the run from particle 0 measures the spacing"
    merged = reduce(SceneMeasures.merged, runs)
    assert merged == whole
    assert outside_envelope_of(ENVELOPE, metadata, [merged]) == outside_envelope(
        ENVELOPE, metadata, [scene], 6, kinematic_types=(3,)
    )
    assert any("property friction" in line for line in outside_envelope_of(ENVELOPE, metadata, [merged]))
    if parts > 1:
        assert not runs[0].moving and runs[-1].moving, "the first run holds only the floor: the test needs that"
        assert any(run.speed < merged.speed for run in runs)


def test_a_property_below_and_above_the_trained_range_names_the_farthest_value():
    low = replace(_column(0.1, 0.2, key="k"), material_property=np.full((200, 1), 0.2, np.float32))
    (line,) = outside_envelope(ENVELOPE, _metadata(), [low], history=6)
    assert line.startswith("property friction 0.2 in trajectory 'k'")
    values = np.full((200, 1), 0.7, np.float32)
    values[17] = 1.5
    (line,) = outside_envelope(ENVELOPE, _metadata(), [replace(low, material_property=values)], history=6)
    assert line.startswith("property friction 1.5 in trajectory 'k'")


def _obstacle_friction(trajectory: Trajectory, friction: float) -> Trajectory:
    """``trajectory`` with its fixed particles' friction column set to ``friction`` (an obstacle recording it)."""
    assert trajectory.material_property is not None
    values = trajectory.material_property.copy()
    values[trajectory.particle_type == OBSTACLE_TYPE] = friction
    return replace(trajectory, material_property=values)


def test_a_fixed_particle_s_property_is_judged_against_the_fixed_particles_seen_when_trained():
    """An obstacle's surface friction, recorded as its particles' friction, is an input: a model trained where obstacles
    recorded none (0) refuses one that records it, and one trained on 0.3 .. 0.5 refuses 0.7 (not against the sand's
    0.5 .. 0.9, which it lies in)."""
    plain = [_with_obstacle(t, 0.3, 0.3, 1.3 * SPACING) for t in TRAINED]
    fixed = (OBSTACLE_TYPE,)
    blind = measure_envelope(_metadata(), plain, OBSTACLE_SCENE, {3: "rigid", 6: "sand"}, frame_stride=2)
    assert blind.fixed_properties == {"friction": [0.0, 0.0]} and blind.properties == ENVELOPE.properties
    recording = _obstacle_friction(_with_obstacle(_column(0.1, 0.2, key="r"), 0.3, 0.3, 1.3 * SPACING), 0.44)
    (line,) = outside_envelope(blind, _metadata(), [recording], history=6, kinematic_types=fixed)
    assert line == "property friction of fixed particles 0.44 in trajectory 'r' (trained: 0 .. 0)"
    seeing = measure_envelope(
        _metadata(),
        [_obstacle_friction(t, f) for t, f in zip(plain, (0.3, 0.5), strict=True)],
        OBSTACLE_SCENE,
        {3: "rigid", 6: "sand"},
        frame_stride=2,
    )
    assert seeing.fixed_properties == {"friction": [pytest.approx(0.3), pytest.approx(0.5)]}
    assert ("property friction of fixed particles", "0.3 .. 0.5") in seeing.rows()
    assert outside_envelope(seeing, _metadata(), [recording], history=6, kinematic_types=fixed) == []
    (line,) = outside_envelope(
        seeing, _metadata(), [_obstacle_friction(recording, 0.7)], history=6, kinematic_types=fixed
    )
    assert line.startswith("property friction of fixed particles 0.7 in trajectory 'r'")
    assert seeing.union(blind).fixed_properties == {"friction": [0.0, pytest.approx(0.5)]}
    raw = seeing.to_dict()
    raw.pop("fixed_properties")
    assert outside_envelope(Envelope.from_dict(raw), _metadata(), [recording], 6, kinematic_types=fixed) == [], (
        "a checkpoint from before fixed particles' properties were measured does not judge them"
    )
