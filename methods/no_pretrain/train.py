"""Training Ours w/o CLIP pre-train: image tower, projections and adapters from random weights.

The training split's crops and workspace images are decoded, cut like the pipeline cuts them
(`sim.dataset.loader.example_from_record`), resized to the tower's input size and cached once
as uint8 arrays, with the frozen MiniLM embeddings of the prompted reference phrases
(`no_pretrain_inputs`). Each step takes `batch_size` scenes (all their visual tokens), applies a
random symmetry of the square to every image and takes one AdamW step on Ours' grounding
loss. Example order, symmetries and initial weights are functions of the seed and the step, so
a resumed run ends with the weights of an uninterrupted one.

Run directory:
    run.json, metrics.jsonl, checkpoints/        as in train.ours
    backbone/                                    the trained tower as an offline backbone directory
                                                 (its own config.json, weights.safetensors, fingerprint.txt)
    weights.safetensors                          the trained adapters (`models.trained_adapters`), written last
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace import serial
from ocplace.methods.no_pretrain import model as no_pretrain
from ocplace.methods.no_pretrain.model import BACKBONE_DIR
from ocplace.methods.no_pretrain.recipe import NoPretrainRecipe
from ocplace.models import offline_backbone as ob
from ocplace.models import offline_config, trained_adapters
from ocplace.models.backbone import PromptConfig
from ocplace.paths import atomic_path, scratch_cache
from ocplace.train import optim, runner
from ocplace.train.batches import batch_indices, check_run_keys, run_config, subset_indices
from ocplace.train.schedule import Schedule
from ocplace.vocabulary import MAX_INSTRUCTION_TUPLES as MAX_TUPLES

# The format and its cache folder (`paths.scratch_cache`) keep their old name: renaming would orphan every cached input.
INPUTS_FORMAT = "ocplace-scratch-inputs-v1"
MAX_TOKENS = 6  # 5 crops + the workspace


# ----------------------------------------------------------------------------- cached inputs


@dataclasses.dataclass(frozen=True)
class NoPretrainInputs:
    """The training split as the tower sees it; arrays have one row per scene."""

    arrays: dict  # pixels uint8 (n, 6, S, S, 3), visual_mask (n, 6), sentences (n, 2, 384), text_mask, targets
    scene_ids: tuple[str, ...]
    key: str


def visual_pixels(config: offline_config.OfflineConfig, crops: np.ndarray, workspace: np.ndarray) -> np.ndarray:
    """uint8 `(N + 1, S, S, 3)`: the crops then the workspace, preprocessed like `OfflineBackbone.encode_images`."""
    return ob.preprocess_images(config, np.concatenate([crops, workspace[None]]))


def no_pretrain_inputs(
    dataset_dir: Path,
    split: str,
    config: offline_config.OfflineConfig,
    prompt: PromptConfig = PromptConfig(),
    progress: bool = False,
) -> NoPretrainInputs:
    """The split's preprocessed images and phrase embeddings, built once into the cache."""
    from safetensors import safe_open
    from safetensors.numpy import load_file, save_file

    from ocplace.runtime.progress import progress_bar
    from ocplace.sim.dataset.identity import dataset_hash
    from ocplace.sim.dataset.loader import iter_examples

    text_tower = ob.FrozenTextTower.load(config.text_max_length)
    digest = dataset_hash(dataset_dir, split)
    key = hashlib.sha256(
        json.dumps(
            [
                INPUTS_FORMAT,
                digest,
                config.image_size,
                config.text_max_length,
                serial.to_json(prompt),
                text_tower.digest,
            ]
        ).encode()
    ).hexdigest()
    path = scratch_cache() / f"{digest[:16]}-{split}-{config.image_size}px-{key[:12]}.safetensors"
    if path.exists():
        with safe_open(str(path), framework="numpy") as handle:
            scene_ids = tuple(json.loads(handle.metadata()["scene_ids"]))
        return NoPretrainInputs(load_file(str(path)), scene_ids, key)
    rows = []
    for example in progress_bar(iter_examples(dataset_dir, split), desc="crops", unit="scene", enabled=progress):
        rows.append(
            (
                example.scene_id,
                visual_pixels(config, example.crops, example.workspace),
                [prompt.text_for(text) for text in example.texts],
                example.targets,
            )
        )
    size = config.image_size
    arrays = {
        "pixels": np.zeros((len(rows), MAX_TOKENS, size, size, 3), np.uint8),
        "visual_mask": np.zeros((len(rows), MAX_TOKENS), bool),
        "sentences": np.zeros((len(rows), MAX_TUPLES, config.text_dim), np.float32),
        "text_mask": np.zeros((len(rows), MAX_TUPLES), bool),
        "targets": np.zeros((len(rows), MAX_TUPLES), np.int32),
    }
    texts = [text for _, _, scene_texts, _ in rows for text in scene_texts]
    embeddings = iter(np.concatenate([text_tower.encode(texts[i : i + 64]) for i in range(0, len(texts), 64)]))
    for row, (_, pixels, scene_texts, targets) in enumerate(rows):
        arrays["pixels"][row, : len(pixels)] = pixels
        arrays["visual_mask"][row, : len(pixels)] = True
        for k in range(len(scene_texts)):
            arrays["sentences"][row, k] = next(embeddings)
        arrays["text_mask"][row, : len(scene_texts)] = True
        arrays["targets"][row, : len(targets)] = targets
    scene_ids = tuple(scene_id for scene_id, *_ in rows)
    with atomic_path(path) as tmp:
        save_file(arrays, str(tmp), metadata={"key": key, "scene_ids": json.dumps(scene_ids)})
    return NoPretrainInputs(arrays, scene_ids, key)


# ----------------------------------------------------------------------------- the jitted step


@functools.partial(jax.jit, static_argnums=(0, 1), donate_argnums=2)
def train_step(model: no_pretrain.NoPretrainConfig, schedule: Schedule, state, frozen, batch, codes):
    """One AdamW step on the trainable half of the parameters (`ob.split_trainable`); returns `(state, loss)`."""
    trainable, opt_state = state

    def loss_fn(trainable):
        return no_pretrain.loss(model, ob.join_params(trainable, frozen), batch, codes)

    value, grads = jax.value_and_grad(loss_fn)(trainable)
    updates, opt_state = optim.make(schedule).update(grads, opt_state, trainable)
    return (optax.apply_updates(trainable, updates), opt_state), value


def step_codes(recipe: NoPretrainRecipe, seed: int, step: int) -> np.ndarray:
    """int32 `(batch_size, 6)` symmetry codes of a step (zeros without augmentation)."""
    batch_size = recipe.schedule.batch_size
    if not recipe.augment:
        return np.zeros((batch_size, MAX_TOKENS), np.int32)
    return np.random.default_rng([seed, step, 1]).integers(8, size=(batch_size, MAX_TOKENS), dtype=np.int32)


def train_on_inputs(
    arrays: dict,
    run_dir: Path,
    recipe: NoPretrainRecipe,
    run_meta: dict,
    progress: bool = True,
    *,
    prompt: PromptConfig,
    inputs_key: str,
    seed: int = 0,
) -> None:
    """Trains into `run_dir` (resuming from its newest checkpoint), then saves `backbone/` and the adapters."""
    schedule, model = recipe.schedule, recipe.model
    recipe.validate()
    run_dir = Path(run_dir)
    params = no_pretrain.init_params(model, jax.random.key(seed))
    params["backbone"] = no_pretrain.calibrate(model, params["backbone"], arrays)
    trainable, frozen = ob.split_trainable(no_pretrain.trainable_mask(model, params), params)
    num_scenes = len(arrays["pixels"])

    def chunk(state, start: int, count: int):
        losses = []
        for step in range(start, start + count):
            rows = batch_indices(num_scenes, seed, step, 1, schedule.batch_size)[0]
            batch = {name: jnp.asarray(array[rows]) for name, array in arrays.items()}
            codes = jnp.asarray(step_codes(recipe, seed, step))
            state, loss = train_step(model, schedule, state, frozen, batch, codes)
            losses.append(loss)
        return state, jnp.stack(losses)

    def record(state, step: int, losses: np.ndarray) -> dict:
        scale = no_pretrain.logit_scale(model, ob.join_params(state[0], frozen))
        return {"loss": runner.mean_loss(losses), "logit_scale": float(scale)}

    def save(path: Path, state) -> None:
        trained = jax.tree_util.tree_map(np.asarray, ob.join_params(state[0], frozen))
        save_trained(path, trained, recipe, run_meta["recipe"], prompt=prompt, inputs_key=inputs_key)

    spec = runner.Run.on(
        schedule,
        run_dir=run_dir,
        run_meta=run_meta,
        log_every=recipe.log_every,
        init_state=lambda: (trainable, optim.make(schedule).init(trainable)),
        chunk=chunk,
        record=record,
        save_artefact=save,
        checkpoint_meta={"step_of": str(schedule.steps)},
        desc="train no_pretrain",
    )
    runner.run(spec, progress)


def save_trained(
    adapters_path: Path,
    params: dict,
    recipe: NoPretrainRecipe,
    train_config: dict,
    *,
    prompt: PromptConfig,
    inputs_key: str,
) -> None:
    """Writes the tower to `backbone/` beside `adapters_path`, then the adapters (last: they mark the run finished);
    `train_config` is what the run recorded of its recipe, seed and fraction (`batches.run_config`)."""
    model = recipe.model
    text_digest = ob.FrozenTextTower.load(model.backbone.text_max_length).digest
    backbone_dir = ob.save_backbone(
        adapters_path.parent / BACKBONE_DIR,
        model.backbone,
        params["backbone"],
        text_digest,
        {"trained_by": "ocplace.methods.no_pretrain.train (Ours w/o CLIP pre-train)", "recipe": train_config},
    )
    fingerprint = (backbone_dir / ob.FINGERPRINT_FILE).read_text().strip()
    scale = float(np.exp(min(float(params["backbone"]["log_logit_scale"]), math.log(model.max_logit_scale))))
    trained_adapters.save_adapters(
        adapters_path,
        params["adapters"],
        model.adapters,
        scale,
        backbone_fingerprint=fingerprint,
        prompt=prompt,
        features_key=inputs_key,
        steps=recipe.schedule.steps,
        train_config_json=json.dumps(train_config),
    )


def train_no_pretrain(
    dataset_dir: Path,
    run_dir: Path,
    recipe: NoPretrainRecipe,
    seed: int = 0,
    fraction: float = 1.0,
    progress: bool = True,
) -> Path:
    """Caches the inputs, trains on `fraction` of them with `seed`, saves `backbone/` and the adapters
    (`WEIGHTS_FILE`); a finished run is kept."""
    recipe.validate()
    check_run_keys(seed, fraction)
    run_dir = Path(run_dir)
    prompt = PromptConfig()
    inputs = no_pretrain_inputs(dataset_dir, "train", recipe.model.backbone, prompt, progress)
    chosen = subset_indices(len(inputs.scene_ids), fraction, recipe.subset_seed)
    run_meta = {
        "recipe": run_config(recipe, seed, fraction),
        "inputs_key": inputs.key,
        "train_scenes": int(len(chosen)),
    }
    arrays = {name: array[chosen] for name, array in inputs.arrays.items()}
    train_on_inputs(arrays, run_dir, recipe, run_meta, progress, prompt=prompt, inputs_key=inputs.key, seed=seed)
    return run_dir
