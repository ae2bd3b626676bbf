"""Adapter training on cached features: Adam, steps fused with `lax.scan`, checkpoints, resume.

The example order is a pure function of (seed, step): epoch e visits the training scenes in the
order `default_rng([seed, e]).permutation(n)`. With the initial weights drawn from `seed` too, a
run is a pure function of its configuration and features, so a resumed run ends with exactly the
weights of an uninterrupted one.

Run directory:
    config.json              configuration and the keys of the features it trains on
    metrics.jsonl            one record per fused chunk of steps; accuracies every `eval_every`
    checkpoints/step_*.safetensors   params + Adam state (the newest `keep_checkpoints`)
    adapters.safetensors     the final adapters, with what the policy needs to use them
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import time
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace.models.adapters import AdapterConfig, init_adapters
from ocplace.models.features import Features
from ocplace.models.grounding import GroundingModel, adapted_logits, grounding_loss
from ocplace.train import checkpoints, optim
from ocplace.train.config import TrainConfig
from ocplace.train.metrics import GroundingAccuracy, MetricsLog, evaluate_features

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class TrainResult:
    run_dir: Path
    model: GroundingModel
    steps: int
    train_accuracy: GroundingAccuracy
    val_accuracy: GroundingAccuracy | None


def learning_rate_schedule(config: TrainConfig) -> optax.Schedule:
    """Linear warm-up from 0 to the peak over `warmup_steps`, then cosine decay to 0 at `steps`."""
    return optax.warmup_cosine_decay_schedule(
        0.0, config.learning_rate, config.warmup_steps, max(config.steps, config.warmup_steps + 1), 0.0
    )


def make_optimizer(config: TrainConfig) -> optax.GradientTransformation:
    return optim.adam(learning_rate_schedule(config))


def subset_indices(num_scenes: int, fraction: float, subset_seed: int) -> np.ndarray:
    """Sorted indices of a seeded `fraction` of the scenes; smaller fractions are prefixes of larger."""
    count = max(1, round(fraction * num_scenes))
    return np.sort(np.random.default_rng(subset_seed).permutation(num_scenes)[:count])


def batch_indices(num_examples: int, seed: int, start_step: int, num_steps: int, batch_size: int) -> np.ndarray:
    """int32 `(num_steps, batch_size)` example indices of steps `start_step ...`: epoch-wise shuffles."""
    flat = np.arange(start_step * batch_size, (start_step + num_steps) * batch_size)
    epochs, positions = np.divmod(flat, num_examples)
    indices = np.empty_like(flat)
    for epoch in np.unique(epochs):
        in_epoch = epochs == epoch
        indices[in_epoch] = np.random.default_rng([seed, int(epoch)]).permutation(num_examples)[positions[in_epoch]]
    return indices.reshape(num_steps, batch_size).astype(np.int32)


def train_step(adapter_config: AdapterConfig, config: TrainConfig, logit_scale: float, state, data, indices):
    """One Adam step on the examples `indices` `(B,)`; returns `(state, loss)`.

    `state` is `(params, opt_state)`; `data` is the tuple `Features.arrays()` on device.
    """

    def loss_fn(params, batch):
        visual, visual_mask, text, text_mask, targets = batch
        logits = adapted_logits(adapter_config, params, text, visual, visual_mask, logit_scale)
        return grounding_loss(logits, targets, text_mask)

    params, opt_state = state
    loss, grads = jax.value_and_grad(loss_fn)(params, tuple(array[indices] for array in data))
    updates, opt_state = make_optimizer(config).update(grads, opt_state, params)
    return (optax.apply_updates(params, updates), opt_state), loss


def train_chunk(adapter_config: AdapterConfig, config: TrainConfig, logit_scale: float, state, data, indices):
    """`indices` `(num_steps, B)`: the steps fused with `lax.scan`; returns `(state, losses (num_steps,))`."""
    step = functools.partial(train_step, adapter_config, config, logit_scale)
    return jax.lax.scan(lambda carry, step_indices: step(carry, data, step_indices), state, indices)


# Jitted once per (adapter config, training config, logit scale); the state buffers are reused.
jit_train_step = jax.jit(train_step, static_argnums=(0, 1, 2), donate_argnums=3)
jit_train_chunk = jax.jit(train_chunk, static_argnums=(0, 1, 2), donate_argnums=3)


def init_state(adapter_config: AdapterConfig, optimizer: optax.GradientTransformation, seed: int):
    params = init_adapters(adapter_config, jax.random.key(seed))
    return params, optimizer.init(params)


def train(
    features: Features,
    run_dir,
    config: TrainConfig,
    val_features: Features | None = None,
    progress: bool = True,
    callback: Callable[[dict], None] | None = None,
) -> TrainResult:
    """Trains the adapters on `features` into `run_dir`, resuming from its newest checkpoint.

    `callback(record)` is called after each chunk's metrics record is written (and its checkpoint,
    if one was due), e.g. to stop early by raising.
    """
    from tqdm import tqdm

    config.validate()
    run_dir = Path(run_dir)
    train_set = features.subset(subset_indices(features.num_scenes, config.fraction, config.subset_seed))
    adapter_config = AdapterConfig(features.dim, config.reduction, config.residual_ratio)
    logit_scale = float(config.logit_scale or features.info.logit_scale)
    run_meta = _run_metadata(config, features, val_features, train_set)
    checkpoints.claim_run_dir(run_dir, run_meta, "config.json")

    optimizer = make_optimizer(config)
    state = init_state(adapter_config, optimizer, config.seed)
    metrics = MetricsLog(run_dir / "metrics.jsonl")
    start = 0
    saved = checkpoints.list_checkpoints(run_dir)
    if saved:
        state, start, _ = checkpoints.load_checkpoint(saved[-1], state)
        log.info("resuming %s from step %d", run_dir, start)
    metrics.truncate_after(start)

    data = jax.device_put(train_set.arrays())
    schedule = learning_rate_schedule(config)
    ckpt_meta = {"run": json.dumps(run_meta, sort_keys=True)}
    step, began = start, time.perf_counter()
    with tqdm(total=config.steps, initial=start, unit="step", desc="train", disable=not progress) as bar:
        while step < config.steps:
            count = min(config.chunk_steps, config.steps - step)
            indices = batch_indices(train_set.num_scenes, config.seed, step, count, config.batch_size)
            state, losses = jit_train_chunk(adapter_config, config, logit_scale, state, data, jnp.asarray(indices))
            step += count
            record = {
                "step": step,
                "loss": float(np.mean(np.asarray(losses))),
                "learning_rate": float(schedule(step)),
                "elapsed_s": round(time.perf_counter() - began, 3),
            }
            if step % config.eval_every == 0 or step == config.steps:
                record.update(_evaluate(adapter_config, state[0], logit_scale, train_set, val_features))
            if step % config.checkpoint_every == 0 or step == config.steps:
                checkpoints.save_checkpoint(run_dir, step, state, ckpt_meta, config.keep_checkpoints)
            metrics.append(record)
            bar.update(count)
            bar.set_postfix(loss=f"{record['loss']:.4f}")
            if callback is not None:
                callback(record)

    params = state[0]
    model = GroundingModel(adapter_config, params, logit_scale)
    checkpoints.save_adapters(
        run_dir / checkpoints.ADAPTERS_FILE,
        params,
        adapter_config,
        logit_scale,
        backbone_fingerprint=features.info.backbone_fingerprint,
        prompt=features.info.config.prompt,
        features_key=features.info.key,
        steps=config.steps,
        train_config_json=config.to_json(),
    )
    return TrainResult(
        run_dir,
        model,
        config.steps,
        evaluate_features(model, train_set),
        evaluate_features(model, val_features) if val_features is not None else None,
    )


def _evaluate(adapter_config, params, logit_scale, train_set: Features, val_features: Features | None) -> dict:
    model = GroundingModel(adapter_config, params, logit_scale)
    record = evaluate_features(model, train_set).as_dict("train_")
    if val_features is not None:
        record.update(evaluate_features(model, val_features).as_dict("val_"))
    return record


def _run_metadata(config: TrainConfig, features: Features, val_features: Features | None, train_set) -> dict:
    return {
        "train_config": json.loads(config.to_json()),
        "features_key": features.info.key,
        "backbone_fingerprint": features.info.backbone_fingerprint,
        "val_features_key": val_features.info.key if val_features is not None else None,
        "train_scenes": train_set.num_scenes,
    }
