"""Ours' training: the CLIP-Adapters on cached features: Adam, steps fused with `lax.scan`, checkpoints, resume.

The example order is a pure function of (seed, step): epoch e visits the training scenes in the
order `default_rng([seed, e]).permutation(n)`. With the initial weights drawn from `seed` too, a
run is a pure function of its configuration and features, so a resumed run ends with exactly the
weights of an uninterrupted one.

Run directory:
    run.json                 configuration and the keys of the features it trains on
    metrics.jsonl            one record per fused chunk of steps; accuracies every `eval_every`
    checkpoints/step_*.safetensors   params + Adam state (the newest `keep_checkpoints`)
    weights.safetensors      the final adapters, with what the policy needs to use them
"""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import optax

from ocplace.methods.ours.recipe import OursRecipe
from ocplace.models import trained_adapters
from ocplace.models.adapters import AdapterConfig, apply_adapters, init_adapters
from ocplace.models.features import Features
from ocplace.models.grounding import GroundingModel, cosine_logits, grounding_loss
from ocplace.train import optim, runner
from ocplace.train.batches import batch_indices, check_run_keys, run_config, subset_indices
from ocplace.train.metrics import GroundingAccuracy, evaluate_features


@dataclasses.dataclass(frozen=True)
class TrainResult:
    run_dir: Path
    model: GroundingModel
    steps: int
    train_accuracy: GroundingAccuracy
    val_accuracy: GroundingAccuracy | None


def anchor_penalty(adapted, original, mask) -> jax.Array:
    """Mean over the real tokens of the squared distance of the adapted features from the backbone's:
    `(..., N, D)` features, `(..., N)` mask."""
    squared = jnp.sum((adapted - original) ** 2, axis=-1)
    return jnp.sum(jnp.where(mask, squared, 0.0)) / jnp.maximum(jnp.sum(mask), 1)


def train_step(adapter_config: AdapterConfig, config: OursRecipe, logit_scale: float, state, data, indices):
    """One Adam step on the examples `indices` `(B,)`; returns `(state, loss)`.

    `state` is `(params, opt_state)`; `data` is the tuple `Features.arrays()` on device.
    """

    def loss_fn(params, batch):
        visual, visual_mask, text, text_mask, targets = batch
        visual_star, text_star = apply_adapters(adapter_config, params, visual, text)
        loss = grounding_loss(cosine_logits(text_star, visual_star, visual_mask, logit_scale), targets, text_mask)
        if config.anchor:  # a Python branch: the paper's recipe compiles exactly as before
            pull = anchor_penalty(visual_star, visual, visual_mask) + anchor_penalty(text_star, text, text_mask)
            loss = loss + config.anchor * pull
        return loss

    params, opt_state = state
    loss, grads = jax.value_and_grad(loss_fn)(params, tuple(array[indices] for array in data))
    updates, opt_state = optim.make(config.schedule).update(grads, opt_state, params)
    return (optax.apply_updates(params, updates), opt_state), loss


def train_chunk(adapter_config: AdapterConfig, config: OursRecipe, logit_scale: float, state, data, indices):
    """`indices` `(num_steps, B)`: the steps fused with `lax.scan`; returns `(state, losses (num_steps,))`."""
    step = functools.partial(train_step, adapter_config, config, logit_scale)
    return jax.lax.scan(lambda carry, step_indices: step(carry, data, step_indices), state, indices)


# Jitted once per (adapter config, training config, logit scale); the state buffers are reused.
jit_train_step = jax.jit(train_step, static_argnums=(0, 1, 2), donate_argnums=3)
jit_train_chunk = jax.jit(train_chunk, static_argnums=(0, 1, 2), donate_argnums=3)


def init_state(adapter_config: AdapterConfig, optimizer: optax.GradientTransformation, seed: int):
    params = init_adapters(adapter_config, jax.random.key(seed))
    return params, optimizer.init(params)


def train_ours(
    features: Features,
    run_dir,
    recipe: OursRecipe,
    seed: int = 0,
    fraction: float = 1.0,
    val_features: Features | None = None,
    progress: bool = True,
    callback: Callable[[dict], None] | None = None,
) -> TrainResult:
    """Trains the adapters on `fraction` of `features` (a seeded subset, nested) into `run_dir`, resuming from its
    newest checkpoint; `seed` draws the initial weights and the example order.

    `callback(record)` is called after each chunk's metrics record is written (and its checkpoint,
    if one was due), e.g. to stop early by raising.
    """
    recipe.validate()
    check_run_keys(seed, fraction)
    run_dir, schedule = Path(run_dir), recipe.schedule
    train_set = features.subset(subset_indices(features.num_scenes, fraction, recipe.subset_seed))
    adapter_config = recipe.adapters.at(features.dim)
    logit_scale = float(recipe.logit_scale or features.info.logit_scale)
    train_config = run_config(recipe, seed, fraction)
    run_meta = _run_metadata(train_config, features, val_features, train_set)
    data = jax.device_put(train_set.arrays())

    def chunk(state, start: int, count: int):
        indices = batch_indices(train_set.num_scenes, seed, start, count, schedule.batch_size)
        return jit_train_chunk(adapter_config, recipe, logit_scale, state, data, jnp.asarray(indices))

    usual_record = runner.loss_and_learning_rate(optim.learning_rates(schedule))

    def record(state, step: int, losses) -> dict:
        fields = usual_record(state, step, losses)
        if step % recipe.eval_every == 0 or step == schedule.steps:
            fields.update(_evaluate(adapter_config, state[0], logit_scale, train_set, val_features))
        return fields

    def save(path: Path, state) -> None:
        trained_adapters.save_adapters(
            path,
            state[0],
            adapter_config,
            logit_scale,
            backbone_fingerprint=features.info.backbone_fingerprint,
            prompt=features.info.config.prompt,
            features_key=features.info.key,
            steps=schedule.steps,
            train_config_json=json.dumps(train_config),
        )

    spec = runner.Run.on(
        schedule,
        run_dir=run_dir,
        run_meta=run_meta,
        init_state=lambda: init_state(adapter_config, optim.make(schedule), seed),
        chunk=chunk,
        record=record,
        save_artefact=save,
        checkpoint_meta={"run": json.dumps(run_meta, sort_keys=True)},
    )
    params = runner.run(spec, progress, callback).state[0]
    model = GroundingModel(adapter_config, params, logit_scale)
    return TrainResult(
        run_dir,
        model,
        schedule.steps,
        evaluate_features(model, train_set),
        evaluate_features(model, val_features) if val_features is not None else None,
    )


def _evaluate(adapter_config, params, logit_scale, train_set: Features, val_features: Features | None) -> dict:
    model = GroundingModel(adapter_config, params, logit_scale)
    record = evaluate_features(model, train_set).as_dict("train_")
    if val_features is not None:
        record.update(evaluate_features(model, val_features).as_dict("val_"))
    return record


def _run_metadata(train_config: dict, features: Features, val_features: Features | None, train_set) -> dict:
    return {
        "train_config": train_config,
        "features_key": features.info.key,
        "backbone_fingerprint": features.info.backbone_fingerprint,
        "val_features_key": val_features.info.key if val_features is not None else None,
        "train_scenes": train_set.num_scenes,
    }
