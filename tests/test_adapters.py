"""CLIP-Adapters, grounding logits, the loss and the accuracy metric."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ocplace.models.adapters import AdapterConfig, apply_adapters, count_parameters, init_adapters
from ocplace.models.grounding import GroundingModel, adapted_logits, cosine_logits, grounding_loss
from ocplace.train.metrics import grounding_accuracy


def random_tokens(seed, shape):
    x = np.random.default_rng(seed).normal(size=shape).astype(np.float32)
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def test_parameter_count_for_clip_b32_width():
    params = init_adapters(AdapterConfig(dim=512), jax.random.key(0))
    assert count_parameters(params) == 262_144
    shapes = jax.tree_util.tree_map(np.shape, params)
    assert shapes == {
        "visual": {"down": {"kernel": (512, 128)}, "up": {"kernel": (128, 512)}},
        "text": {"down": {"kernel": (512, 128)}, "up": {"kernel": (128, 512)}},
    }


def test_adapter_is_relu_mlp_blended_with_the_input():
    config = AdapterConfig(dim=8, reduction=4, residual_ratio=0.2)
    params = init_adapters(config, jax.random.key(1))
    x, t = random_tokens(0, (3, 8)), random_tokens(1, (2, 8))
    v_star, t_star = jax.jit(apply_adapters, static_argnums=0)(config, params, x, t)
    w1, w2 = params["visual"]["down"]["kernel"], params["visual"]["up"]["kernel"]
    expected = 0.2 * np.maximum(np.maximum(x @ w1, 0) @ w2, 0) + 0.8 * x
    np.testing.assert_allclose(v_star, expected, atol=1e-6)
    assert not np.allclose(t_star, t)


def test_zero_residual_ratio_reproduces_zero_shot_logits_exactly():
    dim = 64
    config = AdapterConfig(dim=dim, residual_ratio=0.0)
    params = init_adapters(config, jax.random.key(2))  # random, not zero: the blend must drop them
    text, visual = random_tokens(3, (4, 2, dim)), random_tokens(4, (4, 6, dim))
    mask = np.arange(6)[None] < np.array([[6], [4], [2], [1]])
    zero_shot = jax.jit(cosine_logits)(text, visual, mask, 100.0)
    np.testing.assert_array_equal(GroundingModel(config, params, 100.0).logits(text, visual, mask), zero_shot)
    np.testing.assert_array_equal(GroundingModel.zero_shot(dim, 100.0).logits(text, visual, mask), zero_shot)
    trained = GroundingModel(AdapterConfig(dim=dim, residual_ratio=0.2), params, 100.0)
    assert not np.allclose(trained.logits(text, visual, mask), zero_shot)


def test_normalised_blend_gives_the_adapter_its_ratio_of_the_norm_and_each_tower_its_own_ratio():
    config = AdapterConfig(dim=8, reduction=2, residual_ratio=0.3, text_ratio=0.1, normalise=True)
    params = jax.tree_util.tree_map(lambda w: 5.0 * w, init_adapters(config, jax.random.key(7)))  # a large A(x)
    x, t = random_tokens(8, (5, 8)), random_tokens(9, (4, 8))
    v_star, t_star = jax.jit(apply_adapters, static_argnums=0)(config, params, x, t)
    adapted_v = np.asarray(v_star) - 0.7 * x  # the adapter's part of the blend
    adapted_t = np.asarray(t_star) - 0.9 * t
    live = np.linalg.norm(adapted_v, axis=-1) > 0  # a dead ReLU output stays zero
    np.testing.assert_allclose(np.linalg.norm(adapted_v, axis=-1)[live], 0.3, rtol=1e-4)
    np.testing.assert_allclose(
        np.linalg.norm(adapted_t, axis=-1)[np.linalg.norm(adapted_t, axis=-1) > 0], 0.1, rtol=1e-4
    )
    plain = AdapterConfig(dim=8, reduction=2, residual_ratio=0.3)
    assert np.linalg.norm(np.asarray(apply_adapters(plain, params, x, t)[0]) - 0.7 * x, axis=-1).max() > 0.5


def test_ratios_chosen_after_training_interpolate_from_zero_shot():
    dim = 16
    config = AdapterConfig(dim=dim, normalise=True)
    model = GroundingModel(config, init_adapters(config, jax.random.key(4)), 100.0)
    text, visual = random_tokens(10, (3, 2, dim)), random_tokens(11, (3, 5, dim))
    zero_shot = GroundingModel.zero_shot(dim, 100.0).logits(text, visual)
    np.testing.assert_array_equal(model.with_ratios(0.0, 0.0).logits(text, visual), zero_shot)
    assert model.with_ratios(0.3, 0.0).config.ratios == (0.3, 0.0)
    assert not np.allclose(model.with_ratios(0.3, 0.0).logits(text, visual), zero_shot)


@pytest.mark.parametrize("normalise", [False, True])
def test_padded_tokens_get_zero_probability_and_finite_gradients(normalise):
    dim = 16
    config = AdapterConfig(dim=dim, normalise=normalise)
    params = init_adapters(config, jax.random.key(3))
    text = random_tokens(5, (1, 2, dim))
    visual = np.concatenate([random_tokens(6, (1, 3, dim)), np.zeros((1, 3, dim), np.float32)], axis=1)
    mask = np.array([[True] * 3 + [False] * 3])
    probs = GroundingModel(config, params, 100.0).probabilities(text, visual, mask)
    assert np.all(probs[..., 3:] == 0.0)
    np.testing.assert_allclose(probs.sum(-1), 1.0, atol=1e-6)

    def loss(p):
        logits = adapted_logits(config, p, text, visual, mask, 100.0)
        return grounding_loss(logits, jnp.array([[2, 0]]), jnp.array([[True, True]]))

    grads = jax.jit(jax.grad(loss))(params)
    assert all(np.all(np.isfinite(g)) for g in jax.tree_util.tree_leaves(grads))


def test_loss_is_mean_cross_entropy_over_real_tuples():
    logits = jnp.log(jnp.array([[[0.5, 0.25, 0.25], [0.1, 0.1, 0.8]], [[0.2, 0.2, 0.6], [1 / 3, 1 / 3, 1 / 3]]]))
    targets = jnp.array([[0, 2], [1, 0]])
    mask = jnp.array([[True, True], [True, False]])
    expected = -(np.log(0.5) + np.log(0.8) + np.log(0.2)) / 3
    assert float(jax.jit(grounding_loss)(logits, targets, mask)) == pytest.approx(expected, rel=1e-6)


def test_grounding_accuracy_per_tuple_and_per_scene():
    predictions = np.array([[0, 2], [1, 9], [3, 3]])
    targets = np.array([[0, 2], [1, 0], [3, 1]])
    mask = np.array([[True, True], [True, False], [True, True]])
    accuracy = grounding_accuracy(predictions, targets, mask)
    assert accuracy.num_tuples == 5 and accuracy.num_scenes == 3
    assert accuracy.tuple_accuracy == pytest.approx(4 / 5)
    assert accuracy.scene_accuracy == pytest.approx(2 / 3)
