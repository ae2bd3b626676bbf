"""The end-to-end placement policy (docs/policy.md): place(), place_many(), the depth detector, bad input, the CLI."""

import hashlib
import json

import cv2
import jax
import numpy as np
import pytest

from ocplace.errors import (
    GroundingUncertain,
    NoFeasiblePlacement,
    NoObjectBoxes,
    ParseError,
    PolicyInputError,
)
from ocplace.methods.policy_method import scene_input
from ocplace.models import detection
from ocplace.models.backbone import PromptConfig, load_backbone
from ocplace.models.grounding import GroundingModel
from ocplace.models.parsing import make_parser
from ocplace.models.placement.sampler import SamplerConfig
from ocplace.models.policy import PlacementPolicy, SceneInput
from ocplace.sim import metric
from ocplace.sim.camera import DEFAULT_CAMERA
from ocplace.sim.dataset.config import smoke_config
from ocplace.sim.dataset.job import scene_dirs
from ocplace.sim.dataset.loader import example_from_record
from ocplace.sim.dataset.records import read_scene
from ocplace.sim.workspace import DEFAULT_TABLE

SAMPLER = SamplerConfig(num_samples=128)
DETECTOR_RECALL_FLOOR = 0.80  # measured 0.894 (160 of 179 boxes) on the smoke dataset


def _digest(image: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(image).tobytes()).hexdigest()


class OracleBackbone:
    """Knows which dataset object every crop shows: a perfect grounding to test the rest of the pipeline.

    Crops are recognised by their bytes (the policy must cut them exactly as the dataset loader does);
    a phrase embeds as its object name's one-hot vector, an unknown phrase as the uniform vector.
    """

    def __init__(self, records):
        names = {"table"}
        self.image_names = {}
        for record in records:
            by_id = {obj.object_id: obj.human_name for obj in record.objects}
            example = example_from_record(record)
            for crop, object_id in zip(example.crops, example.box_object_ids):
                self.image_names[_digest(crop)] = by_id[int(object_id)]
            self.image_names[_digest(example.workspace)] = "table"
            names |= set(by_id.values())
        self.names = sorted(names)
        self.dim, self.logit_scale, self.fingerprint = len(self.names), 100.0, "oracle"

    def _embed(self, name):
        vector = (
            np.full(self.dim, 1.0, np.float32)
            if name not in self.names
            else np.eye(self.dim, dtype=np.float32)[self.names.index(name)]
        )
        return vector / np.linalg.norm(vector)

    def encode_images(self, images):
        return np.stack([self._embed(self.image_names.get(_digest(image))) for image in images])

    def encode_texts(self, texts):
        return np.stack([self._embed(text.removeprefix("a photo of a ").removesuffix(".")) for text in texts])


@pytest.fixture(scope="module")
def records(smoke_dataset):
    return [read_scene(d) for split in ("seen", "unseen_inst") for d in scene_dirs(smoke_dataset, split)]


@pytest.fixture(scope="module")
def parser():
    return make_parser("offline")


@pytest.fixture(scope="module")
def oracle_policy(records, parser):
    backbone = OracleBackbone(records)
    return PlacementPolicy(
        backbone, GroundingModel.zero_shot(backbone.dim, backbone.logit_scale), PromptConfig(), parser, sampler=SAMPLER
    )


@pytest.fixture(scope="module")
def tiny_policy(tiny_backbone_spec, parser):
    return PlacementPolicy.from_run(
        load_backbone(tiny_backbone_spec), None, parser=parser, sampler=SAMPLER, threshold=0.0
    )


def _place(policy, record, **changes):
    scene = scene_input(record)
    arguments = dict(
        rgb=scene.rgb,
        depth=scene.depth,
        boxes_or_segmentation=scene.boxes_or_segmentation,
        instruction=scene.instruction,
        held_footprint=scene.held_footprint,
        key=jax.random.key(0),
        camera=scene.camera,
        object_aabbs=scene.object_aabbs,
    )
    return policy.place(**{**arguments, **changes})


def test_oracle_grounding_with_true_aabbs_passes_the_metric(oracle_policy, records):
    placements = oracle_policy.place_many([scene_input(r) for r in records], jax.random.key(1))
    assert len(placements) == len(records)
    for record, placement in zip(records, placements):
        assert placement.ok, placement.failure
        assert placement.tokens == tuple(t.token_index for t in record.tuples), record.id
        assert all(ref.probability > 0.99 for ref in placement.references)
        problem = record.problem()  # every object of these scenes has a box, so the policy sees every obstacle
        assert metric.placement_success(placement.mode[None], problem).all(), record.id
        assert metric.placement_success(placement.samples, problem).all(), record.id
        assert placement.heatmap.shape == oracle_policy.sampler.grid.shape


def test_place_with_segmentation_or_detector_lands_on_the_table(tiny_policy, records):
    record = records[0]
    bounds = DEFAULT_TABLE.bounds
    for given in (record.segmentation, None):
        placement = _place(tiny_policy, record, boxes_or_segmentation=given, object_aabbs=None)
        assert "aabbs_estimated" in placement.flags
        assert ("boxes_detected" in placement.flags) == (given is None)
        assert len(placement.boxes) == len(placement.aabbs) >= 3
        assert np.all((placement.samples >= bounds[0]) & (placement.samples <= bounds[1]))
        assert placement.samples.shape == (SAMPLER.num_samples, 2)
        assert np.allclose(placement.mode_px, record.camera.table_to_pixel(placement.mode))
        half = record.held_object.footprint_half_extents
        for box in placement.aabbs:  # the footprint avoids every (estimated) obstacle
            overlap = np.all((placement.mode + half > box[0]) & (placement.mode - half < box[1]))
            assert not overlap


def test_place_single_scene_equals_batched_path(tiny_policy, records):
    single = _place(tiny_policy, records[1])
    [batched] = tiny_policy.place_many([scene_input(records[1])], jax.random.key(0))
    assert single.tokens == batched.tokens and single.pairs == batched.pairs
    np.testing.assert_array_equal(single.samples, batched.samples)


def test_pixels_and_table_frame_round_trip(records):
    camera = records[0].camera
    xy = np.random.default_rng(0).uniform(DEFAULT_TABLE.bounds[0], DEFAULT_TABLE.bounds[1], size=(500, 2))
    pixels = camera.table_to_pixel(xy)
    np.testing.assert_allclose(camera.pixel_to_table(pixels), xy, atol=1e-9)
    np.testing.assert_allclose(pixels, DEFAULT_CAMERA.table_to_pixel(xy), atol=1e-6)  # the simulator's model
    back = camera.table_to_pixel(camera.pixel_to_table(np.round(pixels)))
    assert np.max(np.abs(back - np.round(pixels))) < 1.0
    world = camera.pixel_to_world(pixels, np.full(len(pixels), 0.6))
    np.testing.assert_allclose(world[:, 2], 0.0, atol=1e-9)


def test_detector_recall_on_the_smoke_dataset(smoke_dataset):
    recall = detection.dataset_box_recall(smoke_dataset, [split.name for split in smoke_config().splits])
    matched = sum(r.matched for r in recall.values())
    total = sum(r.total for r in recall.values())
    assert matched / total >= DETECTOR_RECALL_FLOOR, {k: (v.matched, v.total) for k, v in recall.items()}


def test_estimated_aabbs_cover_the_true_ones(records):
    coverage = []
    for record in records[:6]:
        boxes = record.boxes
        truth = np.array([record.objects[int(i) - 1].aabb for i in boxes.object_ids])[:, :, :2]
        estimate = detection.estimate_aabbs(record.depth, record.camera, boxes.boxes)
        low, high = np.maximum(truth[:, 0], estimate[:, 0]), np.minimum(truth[:, 1], estimate[:, 1])
        coverage += list(np.prod(np.clip(high - low, 0, None), axis=1) / np.prod(truth[:, 1] - truth[:, 0], axis=1))
    assert np.median(coverage) > 0.9


def test_box_iou_and_matching():
    boxes = np.array([[0, 0, 10, 10], [20, 20, 30, 30]])
    assert detection.box_iou(boxes, boxes[:1]).ravel().tolist() == [1.0, 0.0]
    assert detection.matched_count(np.array([[0, 0, 10, 5]]), boxes) == 1
    assert detection.matched_count(np.array([[0, 0, 10, 4]]), boxes) == 0  # IoU 0.4


def test_reference_not_in_the_scene_is_reported_not_placed(oracle_policy, records):
    with pytest.raises(GroundingUncertain, match="purple elephant") as caught:
        _place(oracle_policy, records[0], instruction="put it to the left of the purple elephant.")
    assert len(caught.value.candidates) == 3 and "box" in str(caught.value)


def test_low_confidence_threshold_is_configurable(tiny_backbone_spec, parser, records):
    cautious = PlacementPolicy.from_run(
        load_backbone(tiny_backbone_spec), None, parser=parser, sampler=SAMPLER, threshold=0.9
    )
    with pytest.raises(GroundingUncertain, match="threshold 0.90"):
        _place(cautious, records[0])


def test_image_without_boxes(oracle_policy, records):
    record = records[0]
    with pytest.raises(NoObjectBoxes, match="no object box"):
        _place(oracle_policy, record, boxes_or_segmentation=np.zeros((0, 4)), object_aabbs=np.zeros((0, 2, 2)))
    table_only = _place(
        oracle_policy,
        record,
        boxes_or_segmentation=np.zeros((0, 4)),
        object_aabbs=np.zeros((0, 2, 2)),
        instruction="put it to the left part of the table.",
    )
    assert "no_boxes" in table_only.flags and table_only.references[0].is_table
    assert table_only.mode[0] < DEFAULT_TABLE.bounds[0, 0] / 3


@pytest.mark.parametrize(
    "change, message",
    [
        ({"depth": np.zeros((240, 320), np.float32)}, "depth is 320x240"),
        ({"boxes_or_segmentation": np.zeros((240, 320), np.int32)}, "segmentation image of the image's size"),
        ({"camera": {**DEFAULT_CAMERA.to_json(), "width": 320}}, "camera is 320x480"),
        ({"boxes_or_segmentation": np.array([[10, 10, 5, 20]])}, "is empty or leaves"),
        ({"object_aabbs": np.zeros((1, 2, 2))}, "one per pixel box"),
        ({"held_footprint": (0.1, -0.1)}, "half-extents"),
        ({"rgb": np.zeros((480, 640), np.uint8)}, "uint8 \\(H, W, 3\\)"),
    ],
)
def test_bad_input_raises_a_clear_error(tiny_policy, records, change, message):
    with pytest.raises(PolicyInputError, match=message):
        _place(tiny_policy, records[0], **change)


def test_empty_feasible_region_and_unparseable_instruction(oracle_policy, records):
    with pytest.raises(NoFeasiblePlacement, match="footprint"):
        _place(oracle_policy, records[0], held_footprint=(0.35, 0.25))
    with pytest.raises(ParseError):
        _place(oracle_policy, records[0], instruction="hello there")


def test_place_many_flags_failures_per_scene(oracle_policy, records):
    good = scene_input(records[0])
    scenes = [
        good,
        SceneInput(
            good.rgb,
            good.depth[:10],
            good.boxes_or_segmentation,
            good.instruction,
            good.held_footprint,
            good.camera,
            good.object_aabbs,
            name="bad-depth",
        ),
        SceneInput(
            good.rgb,
            good.depth,
            good.boxes_or_segmentation,
            "put it left of the unicorn.",
            good.held_footprint,
            good.camera,
            good.object_aabbs,
            name="unicorn",
        ),
        good,
    ]
    placements = oracle_policy.place_many(scenes, jax.random.key(0))
    assert [p.ok for p in placements] == [True, False, False, True]
    assert "PolicyInputError" in placements[1].failure and placements[1].mode is None
    assert "low_confidence" in placements[2].flags and "unicorn" in placements[2].failure
    assert placements[2].pairs == (("unicorn", "left"),) and placements[2].tokens  # still reported


def _save_png(path, image):
    assert cv2.imwrite(str(path), image)
    return path


def test_cli_place_on_a_dataset_scene_and_on_images(smoke_dataset, tiny_backbone_spec, tmp_path, capsys):
    from ocplace.cli import main

    figure = tmp_path / "dataset.png"
    code = main(
        [
            "place",
            "--dataset",
            str(smoke_dataset),
            "--id",
            "1",
            "--backbone",
            tiny_backbone_spec,
            "--threshold",
            "0",
            "--samples",
            "128",
            "--out",
            str(figure),
        ]
    )
    out = capsys.readouterr().out
    assert code == 0 and figure.stat().st_size > 10_000
    assert "zero-shot" in out and "mode:" in out and "ground truth" in out

    record = read_scene(scene_dirs(smoke_dataset, "seen")[0])
    rgb = _save_png(tmp_path / "rgb.png", record.rgb[..., ::-1])
    depth = _save_png(tmp_path / "depth.png", np.round(record.depth * 1000).astype(np.uint16))
    camera = tmp_path / "camera.json"
    camera.write_text(json.dumps(record.meta["camera"]))
    figure = tmp_path / "images.png"
    code = main(
        [
            "place",
            "--rgb",
            str(rgb),
            "--depth",
            str(depth),
            "--camera",
            str(camera),
            "--instruction",
            record.instruction,
            "--held-footprint",
            "0.03",
            "0.03",
            "--backbone",
            tiny_backbone_spec,
            "--threshold",
            "0.9",
            "--samples",
            "128",
            "--out",
            str(figure),
        ]
    )
    out = capsys.readouterr().out
    assert code == 2 and figure.exists()  # not placed (threshold), and the figure says why
    assert "boxes_detected" in out and "GroundingUncertain" in out
