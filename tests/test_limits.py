"""Limits before allocation (issue 30, item 5): particle counts, grid sizes, sequence lengths and tfrecord record
lengths are refused against stated limits and this machine's memory, with the estimate, before anything is
allocated. End to end through the commands and readers, then gns_framework.limits' estimates and checks one by one."""

from __future__ import annotations

import json
import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from scene_builders import mixed

from gns_builtins.datasets._formats import tfrecord_format as tf
from gns_framework import limits
from gns_framework.cli import generate as generate_command
from gns_framework.cli import main
from gns_framework.data.metadata import load_metadata
from gns_framework.errors import DatasetError, GnsError
from gns_framework.ground_truth import sampling
from gns_framework.ground_truth.scene_spec import parse_scene

HUGE = {  # 1 to 1000 blocks of 8192^2 particles each: up to 6.7e10 particles, about 500 GiB of positions a frame set
    "name": "huge",
    "dim": 2,
    "domain": {"bounds": [[0.0, 1.0], [0.0, 1.0]], "grid": 4096},
    "time": {"frame_dt": 0.01, "substeps": 10, "frames": 10},
    "blocks": [{"material": "sand", "position": [0.0, 0.0], "size": [1.0, 1.0], "count": {"range": [1, 1000]}}],
}


@pytest.fixture
def generate(sim_registry, monkeypatch, tmp_path):
    monkeypatch.setattr(generate_command, "load_registry", lambda: sim_registry)

    def run(scene: dict, *extra: str) -> int:
        path = tmp_path / "scene.yaml"
        path.write_text(yaml.safe_dump(scene))
        return main(
            ["generate", str(path), "--trajectories", "3", "--out", str(tmp_path / "data"), "--no-progress", *extra]
        )

    return run


@pytest.fixture
def no_allocation(monkeypatch):
    """Fail the test if particles are sampled or a simulator is built."""

    def refuse(*args, **kwargs):
        raise AssertionError("allocated before the limits were checked")

    monkeypatch.setattr(sampling, "fill", refuse)
    monkeypatch.setattr(generate_command, "build_ground_truth_simulator", refuse)


def test_a_scene_of_6e10_particles_is_refused_with_the_estimate_before_sampling(
    generate, no_allocation, tmp_path, capsys
):
    assert generate(HUGE) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "scene.yaml: blocks[0].count: the scene asks for about 6.71e+10 particles per trajectory" in err
    assert "up to 1000 bodies of 6.71e+07 particles at spacing 0.000122 m), more than the limit of 1e+08" in err
    assert not (tmp_path / "data").exists()


def test_sampling_itself_refuses_it_too(no_allocation):
    with pytest.raises(limits.LimitError, match=r"about 6\.71e\+10 particles per trajectory"):
        sampling.sample_scene(parse_scene(HUGE), 0)


def test_a_grid_of_6e10_nodes_is_refused(generate, no_allocation, capsys):
    scene = dict(
        HUGE,
        dim=3,
        domain={"bounds": [[0.0, 1.0]] * 3, "grid": 4096},
        blocks=[{"material": "sand", "position": [0.0, 0.0, 0.0], "size": [0.01, 0.01, 0.01]}],
    )
    assert generate(scene) == 2
    assert (
        "domain.grid: a grid of 4096 cells along the longest axis has about 6.88e+10 nodes in 3D, more than the "
        "limit of 1.07e+09" in capsys.readouterr().err
    )


def test_a_scene_beyond_this_machines_memory_is_refused(generate, no_allocation, monkeypatch, capsys):
    monkeypatch.setattr(limits, "physical_memory", lambda: 2**14)
    assert generate(mixed(frames=6)) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "scene.yaml: blocks: generating 3 trajectories of 6 frames of about" in err
    assert "more than this machine's 1.53e-05 GiB of memory" in err


def test_a_scene_within_the_limits_still_generates(generate):
    assert generate(mixed(frames=6)) == 0


def test_the_estimate_bounds_what_sampling_fills():
    scene = parse_scene(mixed(frames=6))
    estimate, _ = limits.scene_particles(scene)
    sample = sampling.sample_scene(scene, 0)
    filled = sum(len(body.position) for body in [*sample.blocks, *sample.obstacles])
    assert filled <= estimate < 2 * filled


def test_sequence_length_1e12_is_refused(tmp_path):
    metadata = {
        "bounds": [[0, 1], [0, 1]],
        "sequence_length": 10**12,
        "default_connectivity_radius": 0.1,
        "dim": 2,
        "dt": 0.01,
        "vel_mean": [0, 0],
        "vel_std": [1, 1],
        "acc_mean": [0, 0],
        "acc_std": [1, 1],
    }
    (tmp_path / "metadata.json").write_text(json.dumps(metadata))
    with pytest.raises(
        GnsError,
        match=r"metadata.json: invalid metadata: .*sequence_length: 1e\+12 frames, more than "
        r"the limit of 1,000,000",
    ):
        load_metadata(tmp_path)


def tfrecord_header(length: int) -> bytes:
    raw = struct.pack("<Q", length)
    return raw + struct.pack("<I", tf.masked_crc32c(raw))


def test_a_tfrecord_record_length_of_2_40_is_refused_before_reading(tmp_path):
    path = tmp_path / "train.tfrecord"
    path.write_bytes(tfrecord_header(2**40) + b"\0" * 100)
    with pytest.raises(
        DatasetError,
        match=r"train.tfrecord: record 0: truncated data: the length field says "
        r"1,099,511,627,776 bytes but only 96 bytes follow in the file",
    ):
        list(tf.read_records(path))


def test_a_record_longer_than_this_machines_memory_is_refused(tmp_path, monkeypatch):
    path = tmp_path / "train.tfrecord"
    tf.write_records(path, [np.zeros(4096, np.uint8).tobytes()])
    monkeypatch.setattr(limits, "physical_memory", lambda: 1024)
    with pytest.raises(limits.LimitError, match="record 0: reading the record needs about"):
        list(tf.read_records(path))
    monkeypatch.setattr(limits, "physical_memory", lambda: None)
    assert [len(r) for r in tf.read_records(path)] == [4096]


def test_the_commands_give_one_line_for_a_bad_record(tmp_path, capsys):
    from synthetic import write_synthetic_dataset

    source = write_synthetic_dataset(tmp_path / "src", layout="tfrecord", train=1, valid=1, test=1)
    (source / "valid.tfrecord").write_bytes(tfrecord_header(2**40))
    assert main(["convert", str(source), "--from", "tfrecord", "--to", "safe", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "the length field says 1,099,511,627,776 bytes" in err


# ---- the estimates and checks themselves ------------------------------------------------------------------------


def _range(high: float) -> SimpleNamespace:
    """A drawn value whose largest draw is ``high``."""
    return SimpleNamespace(high=high)


def _scene(blocks=(), obstacles=(), extents=(1.0, 0.5), cell_size=0.1, particles_per_cell=2) -> SimpleNamespace:
    """A scene in [0, extents], its particles ``cell_size / particles_per_cell`` apart."""
    return SimpleNamespace(
        domain=SimpleNamespace(bounds=[(0.0, e) for e in extents], cell_size=cell_size, grid=round(1 / cell_size)),
        particle_spacing=cell_size / particles_per_cell,
        particles_per_cell=particles_per_cell,
        blocks=list(blocks),
        obstacles=list(obstacles),
        dim=len(extents),
        time=SimpleNamespace(frames=10),
    )


def _box(*size: float, count: float = 1) -> SimpleNamespace:
    return SimpleNamespace(shape="box", size=[_range(s) for s in size], count=_range(count))


def test_a_box_holds_its_largest_size_in_lattice_cells():
    scene = _scene()  # spacing 0.05
    assert limits.body_particles(_box(0.3, 0.2), scene) == 6 * 4
    assert limits.body_particles(_box(0.001, 0.2), scene) == 1 * 4  # thinner than a spacing: still one row
    assert limits.body_particles(SimpleNamespace(shape="box", size=None), scene) == 1.0


def test_a_plane_is_one_cell_deep_across_the_domain_but_its_height():
    # Across x (1.0 m / 0.05 + 1 = 21 points) and not along y, times particles_per_cell rows; in 3D across x and z.
    plane = SimpleNamespace(shape="plane")
    assert limits.body_particles(plane, _scene()) == 2 * 21
    assert limits.body_particles(plane, _scene(extents=(1.0, 0.5, 0.4))) == 2 * 21 * 9


def test_a_polygon_holds_at_most_its_bounding_box():
    triangle = SimpleNamespace(shape="polygon", vertices=[(0.1, 0.1), (0.4, 0.1), (0.1, 0.3)])
    assert limits.body_particles(triangle, _scene()) == 6 * 4  # 0.3 x 0.2 m at 0.05 m


def test_a_scene_holds_its_largest_count_of_each_body():
    scene = _scene(
        blocks=[_box(0.3, 0.2, count=3), _box(0.1, 0.1)], obstacles=[SimpleNamespace(shape="plane", count=_range(1))]
    )
    total, parts = limits.scene_particles(scene)
    assert parts == [("blocks[0]", 3.0, 24.0), ("blocks[1]", 1.0, 4.0), ("obstacles[0]", 1.0, 42.0)]
    assert total == 3 * 24 + 4 + 42


def test_the_grid_has_one_node_more_than_cells_per_axis():
    assert limits.grid_nodes(_scene()) == 11 * 6
    assert limits.grid_nodes(_scene(extents=(1.0, 0.5, 0.2))) == 11 * 6 * 3


def test_one_body_too_many_names_the_body_and_its_count(monkeypatch):
    monkeypatch.setattr(limits, "MAX_PARTICLES", 50)
    scene = _scene(blocks=[_box(0.1, 0.1), _box(0.3, 0.2)])  # 4 + 24 particles: within the limit
    limits.check_scene(scene, "s.yaml")
    scene.blocks[1] = _box(0.3, 0.2, count=2)  # 4 + 48: the second block, counted twice, is the largest part
    with pytest.raises(limits.LimitError, match=r"^s.yaml: blocks\[1\].count: the scene asks for about 52 particles"):
        limits.check_scene(scene, "s.yaml")
    scene.blocks = [_box(0.5, 0.5)]  # one body of 100: no count to blame
    with pytest.raises(limits.LimitError, match=r"^s.yaml: blocks\[0\]: .*\(blocks\[0\]: up to 1 body of 100"):
        limits.check_scene(scene, "s.yaml")


def test_the_memory_estimate_counts_every_stored_frame_and_the_working_state(monkeypatch):
    scene = _scene(blocks=[_box(0.3, 0.2)])  # 24 particles, 66 grid nodes, 10 frames, 2D
    stored = 4 * 10 * 24 * 2 * 4  # 4 trajectories x frames x particles x d x float32
    working = 24 * limits.PARTICLE_STATE_BYTES[2] + 66 * limits.GRID_NODE_BYTES[2]
    monkeypatch.setattr(limits, "physical_memory", lambda: stored + working)
    limits.check_scene(scene, "s.yaml", trajectories=4)  # exactly fits
    monkeypatch.setattr(limits, "physical_memory", lambda: stored + working - 1)
    with pytest.raises(limits.LimitError, match=r"s\.yaml: blocks: generating 4 trajectories of 10 frames of about 24"):
        limits.check_scene(scene, "s.yaml", trajectories=4)


def test_memory_is_not_judged_where_the_system_does_not_say(monkeypatch):
    monkeypatch.setattr(limits, "physical_memory", lambda: None)
    limits.check_memory("here", 1e30, "everything")


def test_physical_memory_is_pages_times_page_size(monkeypatch):
    pages = {"SC_PAGE_SIZE": 4096, "SC_PHYS_PAGES": 1000}
    monkeypatch.setattr(limits.os, "sysconf", lambda name: pages[name])
    assert limits.physical_memory() == 4096 * 1000

    def unsupported(name):
        raise ValueError(f"unrecognized configuration name {name!r}")

    monkeypatch.setattr(limits.os, "sysconf", unsupported)
    assert limits.physical_memory() is None


@pytest.mark.parametrize("nbytes, text", [(2**30, "1 GiB"), (1.5 * 2**30, "1.5 GiB"), (2**40, "1.02e+03 GiB")])
def test_sizes_are_written_in_gib_to_three_figures(nbytes, text):
    assert limits.gib(nbytes) == text


def test_the_sequence_length_limit_is_inclusive():
    limits.check_sequence_length("m.json", limits.MAX_SEQUENCE_LENGTH)
    with pytest.raises(limits.LimitError, match=r"m\.json: sequence_length: 1e\+06 frames, more than the limit"):
        limits.check_sequence_length("m.json", limits.MAX_SEQUENCE_LENGTH + 1)


def test_a_record_may_fill_its_file_but_not_pass_its_end_nor_the_record_limit(monkeypatch):
    monkeypatch.setattr(limits, "physical_memory", lambda: None)
    limits.check_record_length("f: record 0", 100, remaining=100)
    with pytest.raises(DatasetError, match="length field says 101 bytes but only 100 bytes follow"):
        limits.check_record_length("f: record 0", 101, remaining=100)
    limits.check_record_length("f: record 0", limits.MAX_RECORD_BYTES, remaining=2**40)
    with pytest.raises(limits.LimitError, match="f: record 0: 17,179,869,185 bytes, more than the limit"):
        limits.check_record_length("f: record 0", limits.MAX_RECORD_BYTES + 1, remaining=2**40)


# ---- archive members: headers and inflation checked before numpy allocates (issue 47) ----------------------------


def _replace_member(archive_path, member: str, raw: bytes, compress: int) -> None:
    import zipfile

    with zipfile.ZipFile(archive_path) as old:
        kept = {info.filename: (info, old.read(info)) for info in old.infolist() if info.filename != member}
    with zipfile.ZipFile(archive_path, "w") as new:
        for info, data in kept.values():
            new.writestr(info, data)
        new.writestr(zipfile.ZipInfo(member), raw, compress_type=compress)


def test_a_npy_header_claiming_6e10_particles_is_refused_before_numpy_allocates(tmp_path, capsys):
    import io
    import zipfile

    from synthetic import write_synthetic_dataset

    data = write_synthetic_dataset(tmp_path / "data", train=2, valid=1, test=1)
    with np.load(data / "train.npz") as archive:
        member = next(name for name in archive.files if name.endswith("/position"))
    forged = io.BytesIO()
    header = {"descr": "<f4", "fortran_order": False, "shape": (240, 64_000_000_000, 2)}
    np.lib.format.write_array_header_1_0(forged, header)
    forged.write(b"\0" * 4096)
    _replace_member(data / "train.npz", f"{member}.npy", forged.getvalue(), zipfile.ZIP_STORED)
    for memory in ("all", "windows"):
        assert main(["convert", str(data), "--from", "safe", "--to", "npz", "--out", str(tmp_path / memory)]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1, err
        assert f"train.npz: {member}: the .npy header promises 122,880,000,000,000 bytes of float32" in err
        assert "but only 4,096 follow (truncated or forged?)" in err


def test_a_zip_bomb_member_is_refused_before_it_is_inflated(tmp_path, monkeypatch):
    import zipfile

    from gns_builtins.datasets._formats.npz_common import open_npz, read_array_pickle

    path = tmp_path / "train.npz"
    with (
        zipfile.ZipFile(path, "w") as archive,
        archive.open(zipfile.ZipInfo("simulation_trajectory_0.npy"), "w", force_zip64=True) as member,
    ):
        member.write(b"")  # replaced below
    raw = bytearray()
    objects = np.empty(2, dtype=object)
    objects[0], objects[1] = np.zeros((80, 200_000, 2), np.float32), np.zeros(200_000, np.int64)  # 128 MB + 1.6 MB
    import io

    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, objects, allow_pickle=True)
    raw += buffer.getvalue()
    _replace_member(path, "simulation_trajectory_0.npy", bytes(raw), zipfile.ZIP_DEFLATED)
    assert path.stat().st_size < 1 << 20  # zeros: a thousandfold
    inflated = []
    real_read = zipfile.ZipExtFile.read
    monkeypatch.setattr(zipfile.ZipExtFile, "read", lambda self, n=-1: inflated.append(n) or real_read(self, n))
    archive = open_npz(path, allow_pickle=False)
    with pytest.raises(
        limits.LimitError, match=r"train\.npz: simulation_trajectory_0: .* inflate to 129,\d+,\d+ .*zip bomb"
    ):
        read_array_pickle(archive, path, "simulation_trajectory_0")
    assert all(n != -1 for n in inflated), "the payload was inflated before the check"


def test_members_that_compress_well_but_are_small_are_not_bombs():
    small = SimpleNamespace(file_size=limits.INFLATE_RATIO_ABOVE, compress_size=1000)
    limits.check_zip_member("x", small)
    large = SimpleNamespace(file_size=limits.INFLATE_RATIO_ABOVE * 2, compress_size=limits.INFLATE_RATIO_ABOVE // 50)
    limits.check_zip_member("x", large)  # 100x: as well as anything real compresses
    with pytest.raises(limits.LimitError, match="inflates to"):
        limits.check_zip_member("x", SimpleNamespace(file_size=limits.MAX_MEMBER_BYTES + 1, compress_size=1 << 40))


# ---- model sizes: estimated from the recipe's numbers before anything is built (issue 47) -------------------------


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        ("message_passing_steps: 3,", "model.processor.message_passing_steps"),
        ("latent_size: 64", "model.latent_size"),
    ],
)
def test_gns_check_refuses_a_model_no_machine_can_train_without_building_it(tmp_path, capsys, monkeypatch, edit, field):
    from gns_framework.model import learned_simulator

    def refuse(*args, **kwargs):
        raise AssertionError("built before the size was checked")

    monkeypatch.setattr(learned_simulator.LearnedSimulator, "__init__", refuse)
    text = Path("recipes/sand2d_general_grid.yaml").read_text()
    huge = edit.replace("3,", "100000000,") if "steps" in edit else edit.replace("64", "1000000000")
    assert edit in text
    recipe = tmp_path / "huge.yaml"
    recipe.write_text(text.replace(edit, huge, 1))
    assert main(["check", str(recipe), "--no-data"]) == 1  # gns check: 1 when a recipe has problems
    out = capsys.readouterr().err
    assert f"  {field}: latent_size" in out and "parameters, more than the limit of 2e+09" in out


def test_the_parameter_estimate_is_of_the_built_model_s_order():
    """The estimate is within 2x of the interaction network's real count (the paper's sizes and a small one)."""
    from tiny import tiny_recipe

    from gns_framework.assembly.learned import processor_steps
    from gns_framework.contracts import ModelSizes
    from gns_framework.plugins import load_registry

    registry = load_registry()
    for latent, steps in ((128, 10), (16, 2)):
        recipe = tiny_recipe(
            __import__("pathlib").Path("unused"),
            registry,
            latent_size=latent,
            mlp_hidden_size=latent,
            processor={"name": "interaction_network", "message_passing_steps": steps},
        )
        processor, params = registry.resolve("processor", recipe.model.processor, ("model", "processor"))
        sizes = ModelSizes(
            node_in=30,
            edge_in=3,
            latent=latent,
            mlp_hidden=latent,
            mlp_hidden_layers=recipe.model.mlp_hidden_layers,
            output=2,
            dim=2,
        )
        built = sum(p.numel() for p in processor(params, sizes).parameters())
        estimate = limits.estimate_model_parameters(
            latent, latent, recipe.model.mlp_hidden_layers, processor_steps(recipe, registry)
        )
        assert built / 2 < estimate < built * 2, (latent, steps, built, estimate)
