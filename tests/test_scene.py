"""Scenes: drops settle on the table, renders are deterministic and consistent with each other."""

import subprocess
import sys

import cv2
import numpy as np
import pytest

from ocplace.sim.boxes import boxes_from_segmentation
from ocplace.sim.camera import DEFAULT_CAMERA
from ocplace.sim.mujoco_backend import MujocoScenes
from ocplace.sim.scene import SceneSpec, sample_scene_spec, split_pools
from ocplace.sim.workspace import DEFAULT_TABLE


def _spec(library, seed, split="seen"):
    objects, textures = split_pools(library, split)
    return sample_scene_spec(np.random.default_rng(seed), objects, textures)


@pytest.fixture(scope="module")
def scenes(library, arena):
    return [arena.build(_spec(library, seed)) for seed in range(4)]


def test_spec_rejects_held_object_in_scene():
    from ocplace.errors import SceneError

    with pytest.raises(SceneError, match="held object"):
        SceneSpec(("a", "b"), "wood", "a", 0)


def test_specs_draw_from_their_split(library):
    for split in ("seen", "unseen"):
        spec = _spec(library, 3, split)
        assert all(library.get(name).split == split for name in (*spec.objects, spec.held_object))
        assert library.textures[spec.table_texture].split == split


def test_same_seed_gives_identical_bytes(library, arena, scenes):
    again = arena.build(scenes[1].spec)
    assert again.rgb.tobytes() == scenes[1].rgb.tobytes()
    assert again.depth.tobytes() == scenes[1].depth.tobytes()
    assert again.segmentation.tobytes() == scenes[1].segmentation.tobytes()


def test_a_fresh_arena_of_the_same_library_renders_the_same_bytes(library, scenes):
    with MujocoScenes.from_library(library) as other:
        again = other.build(scenes[0].spec)
    assert again.rgb.tobytes() == scenes[0].rgb.tobytes()
    assert again.segmentation.tobytes() == scenes[0].segmentation.tobytes()


def test_objects_rest_on_the_table(scenes):
    half = np.asarray(DEFAULT_TABLE.half_extents)
    for scene in scenes:
        for obj in scene.objects:
            assert obj.aabb[0, 2] > -0.005, f"{obj.name} sank into the table"
            assert np.all(np.abs(obj.aabb[:, :2].mean(axis=0)) <= half), f"{obj.name} is off the table"


def test_settled_objects_stay_put(library, arena):
    import mujoco

    scene = arena.build(_spec(library, 11))
    names = scene.spec.objects
    before, _ = arena.poses(names)
    mujoco.mj_step(arena.model, arena.data, nstep=int(0.2 / arena.config.physics.timestep))
    after, _ = arena.poses(names)
    assert np.linalg.norm(after - before, axis=1).max() < 0.005


def test_resting_objects_touch_something(scenes):
    """Nothing floats: each object's lowest point is on the table or on top of another object."""
    for scene in scenes:
        tops = [obj.aabb[1, 2] for obj in scene.objects]
        for obj in scene.objects:
            lowest = obj.aabb[0, 2]
            assert lowest < 0.005 or any(abs(lowest - top) < 0.06 for top in tops), obj.name


def test_segmentation_ids_and_boxes_agree(scenes):
    for scene in scenes:
        ids = set(np.unique(scene.segmentation).tolist())
        assert ids <= set(range(len(scene.objects) + 1))
        boxes = boxes_from_segmentation(scene.segmentation)
        for object_id, (u0, v0, u1, v1), count in zip(boxes.object_ids, boxes.boxes, boxes.pixel_counts):
            mask = scene.segmentation == object_id
            assert mask.sum() == count >= 200
            assert mask[v0:v1, u0:u1].sum() == count
            assert mask[v0:v1, u0].any() and mask[v0:v1, u1 - 1].any()
            assert mask[v0, u0:u1].any() and mask[v1 - 1, u0:u1].any()


def test_object_pixels_back_project_into_their_aabbs(scenes):
    for scene in scenes:
        for obj in scene.objects:
            vs, us = np.nonzero(scene.segmentation == obj.object_id)
            if len(us) == 0:
                continue
            points = DEFAULT_CAMERA.pixel_to_world(np.stack([us, vs], axis=-1), scene.depth[vs, us])
            inside = np.all((points >= obj.aabb[0] - 0.004) & (points <= obj.aabb[1] + 0.004), axis=1)
            assert inside.mean() > 0.99, f"{obj.name}: {inside.mean():.3f} of its pixels inside its AABB"


def test_images_have_the_documented_types(scenes):
    scene = scenes[0]
    assert scene.rgb.shape == (480, 640, 3) and scene.rgb.dtype == np.uint8
    assert scene.depth.shape == (480, 640) and scene.depth.dtype == np.float32
    assert scene.segmentation.dtype == np.int32
    assert scene.depth.min() > 0.3 and scene.depth.max() < 1.5


def test_scene_command_writes_a_labelled_picture(tmp_path):
    out = tmp_path / "scene.png"
    result = subprocess.run(
        [sys.executable, "-m", "ocplace.cli", "scene", "--seed", "0", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    picture = cv2.imread(str(out))
    assert picture.shape == (480 + 28, 3 * 640, 3)
