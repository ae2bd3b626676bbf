"""Training Ours w/o LLM (`no_llm`) on cached backbone features.

Visual tokens come from the shared feature cache (`models.features`, the same file `ocplace
featurize` writes and Ours trains on); the only extra encoding is one sentence token per scene,
cached beside it (`sentences_path`). Steps run in chunks fused with `lax.scan`; the example
order and the initial weights are functions of the seed (as in `train.ours`), so a resumed run
ends with the weights of an uninterrupted one.

Run directory:
    run.json             recipe, feature keys, backbone fingerprint, scene count
    metrics.jsonl        per chunk: step, loss, reference_loss, relation_loss, learning_rate, elapsed_s
    checkpoints/         params + Adam state (newest two)
    weights.safetensors  the trained model, with its config, logit scale and backbone fingerprint

Checkpoints and the model file carry a content hash (`models.weights_file`), checked on load.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace import serial
from ocplace.errors import FeaturesError
from ocplace.methods.no_llm.model import NoLlmConfig, NoLlmModel, encode_sentences, init_params, loss_terms
from ocplace.methods.no_llm.recipe import NoLlmRecipe
from ocplace.models.backbone import Backbone
from ocplace.models.features import Features, featurize_split, load_features
from ocplace.models.weights_file import save_weights
from ocplace.paths import atomic_path, features_cache
from ocplace.sim.relations import relation_index
from ocplace.train import checkpoints, optim, runner
from ocplace.train.batches import batch_indices, check_run_keys, run_config, subset_indices

# The paper's name in the cache key: renaming it would orphan every cached sentence file.
SENTENCES_FORMAT = "ocplace-gtref-sentences-v1"


# ----------------------------------------------------------------------------- cached inputs


@dataclasses.dataclass(frozen=True)
class Sentences:
    """One sentence token per scene, with each tuple's canonical relation (training only)."""

    scene_ids: tuple[str, ...]
    sentence: np.ndarray  # float32 (num_scenes, D)
    relations: np.ndarray  # int32 (num_scenes, 2) index into RELATION_NAMES; 0 for padding
    key: str


def sentences_key(backbone_fingerprint: str, dataset_hash: str, config: NoLlmConfig) -> str:
    payload = [SENTENCES_FORMAT, backbone_fingerprint, dataset_hash, config.sentence_template]
    return hashlib.sha256(json.dumps(payload).encode()).hexdigest()


def sentences_path(dataset_hash: str, split: str, backbone_fingerprint: str) -> Path:
    return features_cache() / f"{dataset_hash[:16]}-{split}-{backbone_fingerprint[:16]}-sentences.safetensors"


def split_sentences(dataset_dir: Path, split: str, backbone: Backbone, config: NoLlmConfig) -> Sentences:
    """Sentence tokens of a split, encoded once and cached (keyed like the feature cache)."""
    from safetensors import safe_open
    from safetensors.numpy import load_file, save_file

    from ocplace.sim.dataset.identity import dataset_hash
    from ocplace.sim.dataset.job import listed_scenes

    digest = dataset_hash(dataset_dir, split)
    key = sentences_key(backbone.fingerprint, digest, config)
    path = sentences_path(digest, split, backbone.fingerprint)
    if path.exists():
        with safe_open(str(path), framework="numpy") as handle:
            meta = handle.metadata() or {}
        if meta.get("key") == key:
            arrays = load_file(str(path))
            return Sentences(tuple(json.loads(meta["scene_ids"])), arrays["sentence"], arrays["relations"], key)
    scenes = [scene.info() for scene in listed_scenes(dataset_dir, split)]
    relations = np.zeros((len(scenes), 2), np.int32)
    for row, scene in enumerate(scenes):
        truth = scene.true_tuples()
        relations[row, : len(truth)] = [relation_index(t.relation) for t in truth]
    sentence = encode_sentences(backbone, config, [scene.instruction for scene in scenes])
    scene_ids = tuple(scene.id for scene in scenes)
    with atomic_path(path) as tmp:
        save_file(
            {"sentence": sentence, "relations": relations},
            str(tmp),
            metadata={"key": key, "scene_ids": json.dumps(scene_ids)},
        )
    return Sentences(scene_ids, sentence, relations, key)


def training_arrays(features: Features, sentences: Sentences) -> dict[str, np.ndarray]:
    """The batch dictionary `models.no_llm.loss_terms` reads, one row per scene."""
    if features.scene_ids != sentences.scene_ids:
        raise FeaturesError(
            "the feature file and the sentence cache list different scenes; delete the sentence "
            f"cache ({len(sentences.scene_ids)} scenes) so it is rebuilt"
        )
    return {
        "visual": features.visual,
        "visual_mask": features.visual_mask,
        "sentence": sentences.sentence,
        "targets": features.targets,
        "target_mask": features.text_mask,
        "relations": sentences.relations,
    }


# ----------------------------------------------------------------------------- the jitted loop


def train_step(model_config: NoLlmConfig, config: NoLlmRecipe, logit_scale: float, state, data, indices):
    """One Adam step on the scenes `indices` `(B,)`; returns `(state, (loss, reference, relation))`."""

    def loss_fn(params, batch):
        reference, relation = loss_terms(model_config, params, batch, logit_scale)
        return reference + config.relation_weight * relation, (reference, relation)

    params, opt_state = state
    batch = {name: array[indices] for name, array in data.items()}
    (loss, parts), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, batch)
    updates, opt_state = optim.make(config.schedule).update(grads, opt_state, params)
    return (optax.apply_updates(params, updates), opt_state), (loss, *parts)


@functools.partial(jax.jit, static_argnums=(0, 1, 2), donate_argnums=3)
def train_chunk(model_config: NoLlmConfig, config: NoLlmRecipe, logit_scale: float, state, data, indices):
    """`indices` `(num_steps, B)`; returns `(state, losses (3, num_steps))`."""
    step = functools.partial(train_step, model_config, config, logit_scale)
    state, losses = jax.lax.scan(lambda carry, step_indices: step(carry, data, step_indices), state, indices)
    return state, jnp.stack(losses)


def train_on_arrays(
    arrays: dict[str, np.ndarray],
    run_dir: Path,
    config: NoLlmRecipe,
    logit_scale: float,
    run_meta: dict,
    progress: bool = True,
    *,
    backbone_fingerprint: str,
    seed: int = 0,
    fraction: float = 1.0,
) -> NoLlmModel:
    """Trains on the scene rows of `arrays` into `run_dir` (resuming from its newest checkpoint) and
    saves `WEIGHTS_FILE`, tagged with the backbone whose features `arrays` hold; `seed` draws the initial
    weights and the example order, `fraction` (the share the caller chose the rows by) is recorded."""
    config.validate()
    run_dir = Path(run_dir)
    num_scenes = len(arrays["visual"])
    model_config = config.model_config(arrays["visual"].shape[-1])
    data = jax.device_put(arrays)
    learning_rates = optim.learning_rates(config.schedule)

    def init_state():
        params = init_params(model_config, jax.random.key(seed))
        return params, optim.make(config.schedule).init(params)

    def chunk(state, start: int, count: int):
        indices = batch_indices(num_scenes, seed, start, count, config.schedule.batch_size)
        return train_chunk(model_config, config, logit_scale, state, data, jnp.asarray(indices))

    def record(state, step: int, losses: np.ndarray) -> dict:
        loss, reference, relation = losses.mean(axis=1).tolist()
        return {
            "loss": loss,
            "reference_loss": reference,
            "relation_loss": relation,
            "learning_rate": float(learning_rates(step)),
        }

    def save(path: Path, state) -> NoLlmModel:
        model = NoLlmModel(model_config, jax.tree_util.tree_map(np.asarray, state[0]), logit_scale)
        save_model(
            path, model, backbone_fingerprint=backbone_fingerprint, train_config=run_config(config, seed, fraction)
        )
        return model

    spec = runner.Run.on(
        config.schedule,
        run_dir=run_dir,
        run_meta=run_meta,
        init_state=init_state,
        chunk=chunk,
        record=record,
        save_artefact=save,
        checkpoint_meta={"step_of": str(config.schedule.steps)},
        desc="train no_llm",
    )
    return runner.run(spec, progress).saved


def train_no_llm(
    dataset_dir: Path,
    backbone: Backbone,
    run_dir: Path,
    recipe: NoLlmRecipe,
    seed: int = 0,
    fraction: float = 1.0,
    progress: bool = True,
) -> Path:
    """Featurizes the train split (cached), trains on `fraction` of it with `seed`, writes `run_dir/WEIGHTS_FILE`
    (a finished run is kept)."""
    recipe.validate()
    check_run_keys(seed, fraction)
    run_dir = Path(run_dir)
    features = load_features(featurize_split(dataset_dir, "train", backbone, progress=progress), backbone.fingerprint)
    sentences = split_sentences(dataset_dir, "train", backbone, recipe.model_config(backbone.dim))
    chosen = subset_indices(features.num_scenes, fraction, recipe.subset_seed)
    arrays = {name: array[chosen] for name, array in training_arrays(features, sentences).items()}
    run_meta = {
        "train_config": run_config(recipe, seed, fraction),
        "features_key": features.info.key,
        "sentences_key": sentences.key,
        "backbone_fingerprint": backbone.fingerprint,
        "train_scenes": int(len(chosen)),
    }
    logit_scale = float(features.info.logit_scale)
    train_on_arrays(
        arrays,
        run_dir,
        recipe,
        logit_scale,
        run_meta,
        progress,
        backbone_fingerprint=backbone.fingerprint,
        seed=seed,
        fraction=fraction,
    )
    return run_dir


# ----------------------------------------------------------------------------- the model file


def save_model(path: Path, model: NoLlmModel, *, backbone_fingerprint: str, train_config: dict) -> None:
    """Writes the model file that `models.no_llm.load_model` reads back."""
    metadata = {
        "model_config": serial.to_json(model.config),
        "logit_scale": repr(model.logit_scale),
        "backbone_fingerprint": backbone_fingerprint,
        "train_config": json.dumps(train_config),
    }
    save_weights(path, checkpoints.flatten_state(model.params), metadata)
