"""ClipBackbone on tiny random CLIP checkpoints written to disk like real ones."""

import socket

import numpy as np
import pytest
from tiny_clip import build_tiny_clip

from ocplace import serial
from ocplace.errors import BackboneError, BackboneUnavailable
from ocplace.models import backbone as backbone_module
from ocplace.models.backbone import (
    Backbone,
    ImagePreprocessing,
    PromptConfig,
    load_backbone,
    load_clip_backbone,
    normalize_pixels,
    resize_and_crop,
)


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory, tokenizer_dir):
    return build_tiny_clip(tmp_path_factory.mktemp("clip"), seed=0, tokenizer_dir=tokenizer_dir)


@pytest.fixture(scope="module")
def clip(clip_dir):
    return load_clip_backbone(str(clip_dir))


def random_images(count, height=40, width=52, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (count, height, width, 3), dtype=np.uint8)


def test_loads_with_shapes_and_unit_norms(clip):
    assert isinstance(clip, Backbone)
    images = clip.encode_images(random_images(5))
    texts = clip.encode_texts(["a photo of a red bowl.", "a photo of a table.", "a photo of a blue mug."])
    assert clip.dim == 16
    assert images.shape == (5, 16) and texts.shape == (3, 16)
    assert images.dtype == texts.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(images, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(texts, axis=1), 1.0, atol=1e-5)
    assert clip.logit_scale == pytest.approx(np.exp(2.6592), rel=1e-4)  # CLIPConfig's initial value
    assert len(set(np.round(images[:, 0], 6))) == 5  # different images, different embeddings


def test_batch_of_eight_equals_eight_singles(clip):
    images = random_images(8, seed=1)
    texts = [f"a photo of a {w}." for w in ("red bowl", "blue mug", "table", "shoe", "apple", "plate", "a", "b")]
    batched_images, batched_texts = clip.encode_images(images), clip.encode_texts(texts)
    singles_images = np.concatenate([clip.encode_images(images[i : i + 1]) for i in range(8)])
    singles_texts = np.concatenate([clip.encode_texts([t]) for t in texts])
    np.testing.assert_allclose(batched_images, singles_images, atol=1e-5)
    np.testing.assert_allclose(batched_texts, singles_texts, atol=1e-5)


def test_texts_padded_to_a_bucket_equal_texts_padded_to_the_context_length(clip):
    texts = ["a photo of a red bowl.", "to the left of the light brown boot with golden laces"]
    full = clip._tokenizer(
        texts, padding="max_length", max_length=clip.context_length, truncation=True, return_tensors="np"
    )
    reference = np.asarray(
        clip._text_fn(clip._params, full["input_ids"].astype(np.int32), full["attention_mask"].astype(np.int32))
    )
    np.testing.assert_allclose(clip.encode_texts(texts), reference, atol=1e-5)


def test_bucket_sizes():
    sizes = [backbone_module.bucket_size(count, 32) for count in range(1, 40)]
    assert sizes[:12] == [1, 2, 3, 4, 6, 6, 8, 8, 12, 12, 12, 12] and sizes[-1] == 32
    assert all(count <= size <= max(count * 3 // 2, 2) for count, size in enumerate(sizes[:31], start=1))


def test_more_images_than_one_batch(clip_dir):
    small_batches = load_clip_backbone(str(clip_dir), max_batch=4)
    images = random_images(11, seed=2)
    np.testing.assert_allclose(
        small_batches.encode_images(images),
        np.concatenate([small_batches.encode_images(images[:6]), small_batches.encode_images(images[6:])]),
        atol=1e-5,
    )
    assert small_batches.encode_images(images[:0]).shape == (0, 16)


@pytest.mark.parametrize("weights", ["flax-safetensors", "pt-safetensors"])
def test_every_weight_format_gives_the_same_backbone(tmp_path, tokenizer_dir, clip, weights):
    other = load_clip_backbone(str(build_tiny_clip(tmp_path, seed=0, weights=weights, tokenizer_dir=tokenizer_dir)))
    images, texts = random_images(3, seed=3), ["a photo of a red bowl."]
    np.testing.assert_allclose(other.encode_images(images), clip.encode_images(images), atol=1e-6)
    np.testing.assert_allclose(other.encode_texts(texts), clip.encode_texts(texts), atol=1e-6)
    assert other.fingerprint == clip.fingerprint


def test_fingerprint_changes_with_the_weights(tmp_path, tokenizer_dir, clip, clip_dir):
    assert load_clip_backbone(str(clip_dir)).fingerprint == clip.fingerprint
    reseeded = load_clip_backbone(str(build_tiny_clip(tmp_path, seed=1, tokenizer_dir=tokenizer_dir)))
    assert reseeded.fingerprint != clip.fingerprint


@pytest.mark.parametrize("shape", [(37, 53), (53, 37), (224, 224), (480, 640), (300, 301)])
def test_preprocessing_matches_clip_image_processor(shape):
    from transformers import CLIPImageProcessor

    processor = CLIPImageProcessor()  # OpenAI's settings: 224 px, bicubic, their mean and std
    prep = ImagePreprocessing.from_processor(processor)
    image = np.random.default_rng(4).integers(0, 256, (*shape, 3), dtype=np.uint8)
    expected = processor(images=[image], return_tensors="np")["pixel_values"]
    ours = np.asarray(normalize_pixels(resize_and_crop(image, prep)[None], prep))
    assert ours.shape == expected.shape == (1, 3, 224, 224)
    np.testing.assert_allclose(ours, expected, atol=1e-5)


def closed_local_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_no_network_and_no_local_copy_fails_at_once(monkeypatch):
    monkeypatch.setattr(backbone_module, "_hub_host", lambda: ("127.0.0.1", closed_local_port()))
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    attempts = []
    original = backbone_module._load_clip

    def spy(name, local_only, max_batch):
        attempts.append(local_only)
        return original(name, local_only, max_batch)

    monkeypatch.setattr(backbone_module, "_load_clip", spy)
    with pytest.raises(BackboneUnavailable) as error:
        load_clip_backbone("ocplace-tests/no-such-clip")
    assert attempts == [True]  # the cache was searched; no download was tried
    message = str(error.value)
    assert "unreachable" in message and "no local copy" in message
    assert "clip:/path/to/" in message and "--backbone offline" in message


def test_offline_mode_is_respected(monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setattr(backbone_module, "_reachable", lambda host: pytest.fail("probed the network"))
    with pytest.raises(BackboneUnavailable, match="HF_HUB_OFFLINE"):
        load_clip_backbone("ocplace-tests/no-such-clip")


def test_missing_or_incomplete_directory_is_named(tmp_path):
    with pytest.raises(BackboneUnavailable, match="no CLIP directory"):
        load_clip_backbone(str(tmp_path / "nothing" / "here"))
    with pytest.raises(BackboneError, match="not a complete CLIP checkpoint"):
        load_clip_backbone(str(tmp_path))


def test_specs(clip_dir, clip):
    assert load_backbone(f"clip:{clip_dir}").fingerprint == clip.fingerprint
    with pytest.raises(BackboneError, match="registered kinds"):
        load_backbone("nonsense")


def test_rejects_images_that_are_not_uint8_rgb(clip):
    with pytest.raises(BackboneError, match="uint8"):
        clip.encode_images(np.zeros((2, 8, 8, 3), np.float32))
    with pytest.raises(BackboneError, match="uint8"):
        clip.encode_images(np.zeros((8, 8, 3), np.uint8))


def test_prompt():
    prompt = PromptConfig()
    assert prompt.text_for("red  bowl") == "a photo of a red bowl."
    assert prompt.text_for("table") == prompt.text_for("The table") == "a photo of a table."
    assert serial.from_json(PromptConfig, serial.to_json(prompt)) == prompt
