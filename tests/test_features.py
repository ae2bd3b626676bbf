"""The feature cache: layout, no-op second run, resume after a crash, invalidation, bad input."""

import logging
import os
import threading
import time

import numpy as np
import pytest
from tiny_clip import build_tiny_clip

from ocplace.errors import FeaturesError
from ocplace.models.backbone import PromptConfig, load_clip_backbone
from ocplace.models.features import (
    FeaturizeConfig,
    SceneToFeaturize,
    featurize,
    load_features,
    read_info,
    save_features,
)
from ocplace.models.shared_features import SharedFeatures

CONFIG = FeaturizeConfig(chunk_scenes=2)


@pytest.fixture(scope="module")
def backbone(tmp_path_factory, tokenizer_dir):
    return load_clip_backbone(
        str(build_tiny_clip(tmp_path_factory.mktemp("clip0"), seed=0, tokenizer_dir=tokenizer_dir)), max_batch=8
    )


@pytest.fixture(scope="module")
def other_backbone(tmp_path_factory, tokenizer_dir):
    return load_clip_backbone(
        str(build_tiny_clip(tmp_path_factory.mktemp("clip1"), seed=1, tokenizer_dir=tokenizer_dir)), max_batch=8
    )


def make_examples(count=5, seed=0):
    rng = np.random.default_rng(seed)
    examples = []
    for index in range(count):
        n = int(rng.integers(1, 6))
        texts = ("red bowl",) if index % 2 else ("table", "blue mug")
        targets = np.array([0] if index % 2 else [n, n - 1], np.int32)
        examples.append(
            SceneToFeaturize(
                f"train-{index:05d}",
                rng.integers(0, 256, (n, 24, 24, 3), dtype=np.uint8),
                rng.integers(0, 256, (30, 40, 3), dtype=np.uint8),
                texts,
                targets,
            )
        )
    return examples


class Counting:
    """Wraps a backbone and counts encoded images."""

    def __init__(self, backbone):
        self.backbone, self.images = backbone, 0
        self.dim, self.fingerprint, self.logit_scale = backbone.dim, backbone.fingerprint, backbone.logit_scale

    def encode_images(self, images):
        self.images += len(images)
        return self.backbone.encode_images(images)

    def encode_texts(self, texts):
        return self.backbone.encode_texts(texts)


def crashing_after(examples, count):
    for index, example in enumerate(examples):
        if index == count:
            raise KeyboardInterrupt
        yield example


def test_layout_matches_the_backbone(tmp_path, backbone):
    examples = make_examples()
    features = load_features(
        featurize(examples, backbone, tmp_path / "f.safetensors", dataset_hash="d1", config=CONFIG, progress=False)
    )
    assert features.visual.shape == (5, 6, 16) and features.text.shape == (5, 2, 16)
    assert features.scene_ids == tuple(e.scene_id for e in examples)
    assert features.phrases[0] == ("table", "blue mug")
    prompt = PromptConfig()
    for row, example in enumerate(examples):
        n, num_texts = len(example.crops), len(example.texts)
        np.testing.assert_array_equal(features.visual_mask[row], np.arange(6) < n + 1)
        np.testing.assert_array_equal(features.text_mask[row], np.arange(2) < num_texts)
        np.testing.assert_array_equal(features.targets[row, :num_texts], example.targets)
        np.testing.assert_allclose(features.visual[row, :n], backbone.encode_images(example.crops), atol=1e-5)
        np.testing.assert_allclose(
            features.visual[row, n], backbone.encode_images(example.workspace[None])[0], atol=1e-5
        )
        assert np.all(features.visual[row, n + 1 :] == 0)
        texts = [prompt.text_for(t) for t in example.texts]
        np.testing.assert_allclose(features.text[row, :num_texts], backbone.encode_texts(texts), atol=1e-5)
    assert features.info.backbone_fingerprint == backbone.fingerprint and features.info.dataset_hash == "d1"
    assert features.info.logit_scale == pytest.approx(backbone.logit_scale)


def test_second_run_is_a_no_op(tmp_path, backbone):
    out = featurize(
        make_examples(), backbone, tmp_path / "f.safetensors", dataset_hash="d1", config=CONFIG, progress=False
    )
    before = out.stat().st_mtime_ns
    assert featurize(crashing_after([], 0), backbone, out, dataset_hash="d1", config=CONFIG, progress=False) == out
    assert out.stat().st_mtime_ns == before


def test_resumes_after_a_crash_without_redoing_chunks(tmp_path, backbone):
    examples = make_examples()
    counting = Counting(backbone)
    out = tmp_path / "f.safetensors"
    with pytest.raises(KeyboardInterrupt):
        featurize(crashing_after(examples, 3), counting, out, dataset_hash="d1", config=CONFIG, progress=False)
    assert not out.exists()
    done = counting.images
    assert done == sum(len(e.crops) + 1 for e in examples[:2])  # the first chunk of two scenes
    featurize(examples, counting, out, dataset_hash="d1", config=CONFIG, progress=False)
    assert counting.images - done == sum(len(e.crops) + 1 for e in examples[2:])
    assert not list(tmp_path.glob(".f.safetensors.parts-*"))
    uninterrupted = featurize(
        examples, backbone, tmp_path / "g.safetensors", dataset_hash="d1", config=CONFIG, progress=False
    )
    resumed, whole = load_features(out), load_features(uninterrupted)
    for name in ("visual", "visual_mask", "text", "text_mask", "targets"):
        np.testing.assert_array_equal(getattr(resumed, name), getattr(whole, name))


def _waits_for_lock(path) -> bool:
    """Whether some thread or process is blocked in flock() on `path` (Linux lists waiters with `->`)."""
    inode = f":{os.stat(path).st_ino} "
    with open("/proc/locks") as locks:
        return any("->" in line and "FLOCK" in line and inode in line for line in locks)


def test_concurrent_featurize_encodes_once(tmp_path, backbone):
    examples, out = make_examples(), tmp_path / "f.safetensors"
    first_chunk_done, may_finish = threading.Event(), threading.Event()

    def held_after_first_chunk():  # the first encoder stops mid-file, holding the lock, until told to go on
        for index, example in enumerate(examples):
            if index == CONFIG.chunk_scenes:
                first_chunk_done.set()
                assert may_finish.wait(120)
            yield example

    first, second = Counting(backbone), Counting(backbone)
    results = {}

    def encode(name, source, counting):
        results[name] = featurize(source, counting, out, dataset_hash="d1", config=CONFIG, progress=False)

    one = threading.Thread(target=encode, args=("first", held_after_first_chunk(), first))
    one.start()
    assert first_chunk_done.wait(120)
    two = threading.Thread(target=encode, args=("second", iter(examples), second))
    two.start()
    lock = tmp_path / ".f.safetensors.lock"
    deadline = time.monotonic() + 120
    while not _waits_for_lock(lock):  # a condition, not a sleep: the second encoder is blocked on the lock
        assert time.monotonic() < deadline, "the second featurize never waited for the first"
        time.sleep(0.01)
    may_finish.set()
    one.join(120)
    two.join(120)
    assert results == {"first": out, "second": out}
    assert second.images == 0  # it found the first one's file and encoded nothing
    assert load_features(out).num_scenes == len(examples)


def test_a_new_backbone_or_dataset_invalidates_the_cache(tmp_path, backbone, other_backbone):
    out = tmp_path / "f.safetensors"
    featurize(make_examples(), backbone, out, dataset_hash="d1", config=CONFIG, progress=False)
    first = load_features(out)
    featurize(make_examples(), other_backbone, out, dataset_hash="d1", config=CONFIG, progress=False)
    second = load_features(out, expected_fingerprint=other_backbone.fingerprint)
    assert second.info.backbone_fingerprint == other_backbone.fingerprint != first.info.backbone_fingerprint
    assert not np.allclose(first.visual, second.visual)
    with pytest.raises(FeaturesError, match="another backbone"):
        load_features(out, expected_fingerprint=backbone.fingerprint)
    featurize(make_examples(count=3, seed=1), other_backbone, out, dataset_hash="d2", config=CONFIG, progress=False)
    assert read_info(out).dataset_hash == "d2" and load_features(out).num_scenes == 3


def test_bad_examples_are_named(tmp_path, backbone):
    good = make_examples(1)[0]
    bad = [
        SceneToFeaturize("train-00007", good.crops, good.workspace, ("red bowl",), np.array([9], np.int32)),
        SceneToFeaturize("train-00008", good.crops.astype(np.float32), good.workspace, ("x",), np.array([0], np.int32)),
        SceneToFeaturize("train-00009", good.crops, good.workspace, ("a", "b", "c"), np.zeros(3, np.int32)),
    ]
    for example in bad:
        with pytest.raises(FeaturesError, match=example.scene_id):
            featurize([example], backbone, tmp_path / "f.safetensors", dataset_hash="d", progress=False)


def test_unreadable_files_are_reported(tmp_path):
    with pytest.raises(FeaturesError, match="ocplace featurize"):
        load_features(tmp_path / "missing.safetensors")
    corrupt = tmp_path / "corrupt.safetensors"
    corrupt.write_bytes(b"not a safetensors file")
    with pytest.raises(FeaturesError, match="not a readable"):
        read_info(corrupt)


def test_save_and_load_round_trip(tmp_path, backbone):
    features = load_features(
        featurize(
            make_examples(), backbone, tmp_path / "f.safetensors", dataset_hash="d1", config=CONFIG, progress=False
        )
    )
    subset = features.subset([4, 1])
    again = load_features(save_features(subset, tmp_path / "subset.safetensors"))
    assert again.scene_ids == ("train-00004", "train-00001") and again.info == features.info
    np.testing.assert_array_equal(again.visual, features.visual[[4, 1]])


def test_featurize_command_keys_by_the_split_files(tmp_path, backbone, monkeypatch):
    import argparse
    import json

    from ocplace.cli import featurize as featurize_cli
    from ocplace.sim.dataset.identity import dataset_hash

    dataset = tmp_path / "dataset"
    dataset.mkdir()
    files = {"train/train-00000/rgb.png": "aa", "train/train-00001/rgb.png": "bb", "seen/seen-00000/rgb.png": "cc"}
    (dataset / "manifest.json").write_text(json.dumps({"files": files}))
    read = []

    def reader(dataset_dir, split):  # a generator, like the dataset's: reads only when iterated
        read.append(split)
        yield from make_examples(2)

    monkeypatch.setattr("ocplace.models.backbone.load_backbone", lambda spec: backbone)
    monkeypatch.setattr("ocplace.sim.dataset.loader.iter_examples", reader)
    parser = argparse.ArgumentParser()
    featurize_cli.register(parser.add_subparsers())
    out = tmp_path / "train.safetensors"
    args = parser.parse_args(["featurize", "--dataset", str(dataset), "--backbone", "tiny", "--out", str(out)])
    assert args.func(args) == 0 and args.func(args) == 0
    assert read == ["train"]  # the second run found the file up to date and read nothing
    assert read_info(out).dataset_hash == dataset_hash(dataset, "train")
    files["seen/seen-00000/rgb.png"] = "dd"  # another split changed: same key
    (dataset / "manifest.json").write_text(json.dumps({"files": files}))
    assert read_info(out).dataset_hash == dataset_hash(dataset, "train")
    with pytest.raises(FeaturesError, match="no scenes in split"):
        dataset_hash(dataset, "unseen_obj")


# ----------------------------------------------------------------------------- test features shared by evaluations


def test_shared_features_are_encoded_once_and_read_back_bit_for_bit(tmp_path, backbone):
    images = np.random.default_rng(0).integers(0, 256, (3, 24, 24, 3), dtype=np.uint8)
    texts = ["a photo of a red bowl.", "a photo of a table."]
    first, second = Counting(backbone), Counting(backbone)
    encoded = SharedFeatures(first, tmp_path).encode_images(images)
    assert first.images == 3 and np.array_equal(encoded, backbone.encode_images(images))
    assert np.array_equal(SharedFeatures(second, tmp_path).encode_images(images), encoded)  # another evaluation
    assert np.array_equal(SharedFeatures(second, tmp_path).encode_texts(texts), backbone.encode_texts(texts))
    assert np.array_equal(SharedFeatures(first, tmp_path).encode_texts(texts), backbone.encode_texts(texts))
    assert second.images == 0 and len(list(tmp_path.glob("*.safetensors"))) == 2  # one batch of images, one of texts
    SharedFeatures(second, tmp_path).encode_images(images[:2])  # another batch is encoded, not cut from a stored one
    assert second.images == 2


def test_a_shared_feature_file_that_does_not_verify_is_encoded_again(tmp_path, backbone, other_backbone):
    images = np.random.default_rng(1).integers(0, 256, (2, 24, 24, 3), dtype=np.uint8)
    SharedFeatures(backbone, tmp_path).encode_images(images)
    [stored] = tmp_path.glob("images-*.safetensors")
    other = Counting(other_backbone)  # another fingerprint: the file is not its features
    assert np.array_equal(SharedFeatures(other, tmp_path).encode_images(images), other_backbone.encode_images(images))
    assert other.images == 2
    stored.write_bytes(b"not a safetensors file")  # corrupt (the other backbone's file replaced the first)
    again = Counting(other_backbone)
    assert np.array_equal(SharedFeatures(again, tmp_path).encode_images(images), other_backbone.encode_images(images))
    third = Counting(other_backbone)
    assert np.array_equal(SharedFeatures(third, tmp_path).encode_images(images), other_backbone.encode_images(images))
    assert again.images == 2 and third.images == 0  # the file written again verifies


def test_a_shared_feature_file_with_damaged_floats_is_encoded_again(tmp_path, backbone, caplog):
    """Issue 43, defect 2: the store checked metadata and shapes, never content; a damaged file was used."""
    images = np.random.default_rng(3).integers(0, 256, (2, 24, 24, 3), dtype=np.uint8)
    SharedFeatures(backbone, tmp_path).encode_images(images)
    [stored] = tmp_path.glob("images-*.safetensors")
    damaged = bytearray(stored.read_bytes())
    damaged[-5] ^= 0x40  # one bit of the last float: still a valid, finite safetensors file
    stored.write_bytes(bytes(damaged))
    again = Counting(backbone)
    with caplog.at_level(logging.WARNING):
        features = SharedFeatures(again, tmp_path).encode_images(images)
    assert np.array_equal(features, backbone.encode_images(images)) and again.images == 2
    assert "does not verify" in caplog.text and "content hash" in caplog.text
    third = Counting(backbone)
    assert np.array_equal(SharedFeatures(third, tmp_path).encode_images(images), features) and third.images == 0


@pytest.mark.parametrize("store", ["read_only_dir", "full_disk"])
def test_a_store_that_cannot_be_written_is_a_warning_and_features_come_from_memory(store, backbone, caplog, request):
    """Issue 43, defect 3: an unwritable or full store turned every scene into a failure, exit 0."""
    folder = request.getfixturevalue(store) / "shared"
    images = np.random.default_rng(4).integers(0, 256, (2, 24, 24, 3), dtype=np.uint8)
    shared = SharedFeatures(backbone, folder)
    with caplog.at_level(logging.WARNING):
        assert np.array_equal(shared.encode_images(images), backbone.encode_images(images))
        assert np.array_equal(shared.encode_texts(["a bowl"]), backbone.encode_texts(["a bowl"]))
    assert caplog.text.count("cannot write the shared test features") == 1


def test_two_evaluations_asking_for_a_batch_at_once_encode_it_once(tmp_path, backbone):
    images = np.random.default_rng(2).integers(0, 256, (2, 24, 24, 3), dtype=np.uint8)
    encoding, may_finish = threading.Event(), threading.Event()

    class Held(Counting):  # the first evaluation stops while encoding, holding the lock, until told to go on
        def encode_images(self, images):
            encoding.set()
            assert may_finish.wait(120)
            return super().encode_images(images)

    first, second = Held(backbone), Counting(backbone)
    results = {}

    def encode(name, counting):
        results[name] = SharedFeatures(counting, tmp_path).encode_images(images)

    one = threading.Thread(target=encode, args=("first", first))
    one.start()
    assert encoding.wait(120)
    two = threading.Thread(target=encode, args=("second", second))
    two.start()
    [lock] = tmp_path.glob(".images-*.lock")
    deadline = time.monotonic() + 120
    while not _waits_for_lock(lock):  # a condition, not a sleep: the second is blocked on the lock
        assert time.monotonic() < deadline, "the second request never waited for the first"
        time.sleep(0.01)
    may_finish.set()
    one.join(120)
    two.join(120)
    assert first.images == 2 and second.images == 0
    assert np.array_equal(results["first"], results["second"])


def test_without_objects_hides_their_crops_and_the_tuples_about_them(smoke_dataset, tiny_backbone_spec, library):
    from ocplace.models.backbone import load_backbone
    from ocplace.models.features import featurize_split, load_features, without_objects
    from ocplace.sim.dataset.job import listed_scenes
    from ocplace.sim.library.library import colour_variants

    features = load_features(featurize_split(smoke_dataset, "train", load_backbone(tiny_backbone_spec), progress=False))
    variants = set(colour_variants(library))
    held = without_objects(features, smoke_dataset, "train", variants)
    assert held.info.key != features.info.key and held.info.backbone_fingerprint == features.info.backbone_fingerprint
    infos = {scene.name: scene.info() for scene in listed_scenes(smoke_dataset, "train")}
    hidden_tuples = 0
    for scene_id in features.scene_ids:
        info = infos[scene_id]
        names = {obj.object_id: obj.name for obj in info.objects}
        token_names = [names[int(i)] for i in info.boxes.object_ids]
        about_variants = [
            t.token_index < len(token_names) and token_names[t.token_index] in variants for t in info.tuples
        ]
        hidden_tuples += sum(about_variants)
        if all(about_variants):
            assert scene_id not in held.scene_ids  # nothing left to learn from
            continue
        row = held.scene_ids.index(scene_id)
        visible = [name not in variants for name in token_names] + [True]  # the table stays
        assert held.visual_mask[row, : len(visible)].tolist() == visible
        assert held.text_mask[row, : len(about_variants)].tolist() == [not v for v in about_variants]
    assert hidden_tuples > 0  # the smoke scenes do show colour variants
    assert held.text_mask.sum() == features.text_mask.sum() - hidden_tuples
