"""A scene's bodies: blocks of material and kinematic obstacles, which of them may move."""

from __future__ import annotations

from gns_framework.ground_truth.scene_bodies import Block, Obstacle


def test_a_block_defaults_to_one_unrotated_box():
    block = Block.model_validate({"material": "sand", "position": [0.1, 0.0], "size": [0.2, 0.3]})
    assert block.shape == "box" and block.count.is_fixed and block.count.low == 1
    assert block.angle.is_fixed and block.angle.low == 0.0


def test_only_unrotated_boxes_and_ellipsoids_may_move():
    box = {"material": "rigid", "position": [0.1, 0.0], "size": [0.1, 0.1]}
    assert not Obstacle.model_validate(box).is_static_shape
    assert Obstacle.model_validate({**box, "angle": 30}).is_static_shape
    assert Obstacle.model_validate(
        {"material": "rigid", "shape": "plane", "position": [0, 0], "angle": 20}
    ).is_static_shape
