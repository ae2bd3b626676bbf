"""Ours w/o LLM (`no_llm`): no parser, the whole instruction is one text token.

The visual tokens are Ours' (the N crops, then the workspace image standing for the table) and
go through the same CLIP-Adapters; the sentence token goes through the text adapter. The L
visual tokens most similar to the sentence are the references (L, the number of references, is
the only ground-truth input: 1 for the table and 1obj levels, 2 for 2obj), and an MLP on the
concatenated adapted [visual token, sentence token] picks each reference's canonical relation.

    V (T, D) --visual adapter--> V*     s (D,) --text adapter--> s*
    logits_t = logit_scale * cos(s*, V*_t)            (T,)  -inf at padded tokens
    references = top-L tokens by logit                (L,)
    relation_j = argmax MLP([V*_j, s*])               (9,)  "middle" masked out for objects
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from pathlib import Path
from typing import cast

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace import serial
from ocplace.methods.no_llm.recipe import NoLlmConfig
from ocplace.models.adapters import GroundingAdapters, apply_adapters
from ocplace.models.backbone import Backbone, update_with_params
from ocplace.models.grounding import cosine_logits, grounding_loss
from ocplace.models.weights_file import WEIGHTS_KINDS, expect_kind, load_weights, unflatten_state
from ocplace.paths import trained_weights
from ocplace.sim.relations import RELATION_NAMES, RELATIONS

NUM_RELATIONS = len(RELATION_NAMES)
MAX_REFERENCES = 2  # the 2obj level names two references
REFERENCES_BY_LEVEL = {"table": 1, "1obj": 1, "2obj": 2}


class RelationHead(nn.Module):
    """MLP `(..., 2D) -> (..., 9)`: relation logits of a [visual token, sentence token] pair."""

    hidden: int

    @nn.compact
    def __call__(self, pair: jax.Array) -> jax.Array:
        return nn.Dense(NUM_RELATIONS, name="out")(nn.relu(nn.Dense(self.hidden, name="hidden")(pair)))


@functools.partial(jax.jit, static_argnums=0)
def init_params(config: NoLlmConfig, key) -> dict:
    """`{"adapters": {"visual", "text"}, "relation": {"hidden", "out"}}`."""
    adapter_key, head_key = jax.random.split(key)
    token = jnp.zeros((1, config.dim), jnp.float32)
    return {
        "adapters": GroundingAdapters(config.adapters).init(adapter_key, token, token)["params"],
        "relation": RelationHead(config.hidden).init(head_key, jnp.zeros((1, 2 * config.dim)))["params"],
    }


def adapted_tokens(config: NoLlmConfig, params: dict, visual, sentence):
    """`(V* (..., T, D), s* (..., D))` for visual tokens `(..., T, D)` and sentence tokens `(..., D)`."""
    visual_star, text_star = apply_adapters(config.adapters, params["adapters"], visual, sentence[..., None, :])
    return visual_star, text_star[..., 0, :]


def token_logits(visual_star, sentence_star, visual_mask, logit_scale):
    """`(..., T)` logit_scale * cos(s*, V*_t); -inf at padded tokens."""
    return cosine_logits(sentence_star[..., None, :], visual_star, visual_mask, logit_scale)[..., 0, :]


def allowed_relations(visual_mask) -> jax.Array:
    """`(..., T, 9)` bool: every relation for the table token (the last real one), "middle" never for objects."""
    num_tokens = visual_mask.shape[-1]
    is_table = jnp.arange(num_tokens) == (jnp.sum(visual_mask, axis=-1, keepdims=True) - 1)
    for_objects = jnp.asarray([r.applies_to_objects for r in RELATIONS])
    return is_table[..., None] | for_objects


def relation_logits(config: NoLlmConfig, params: dict, visual_star, sentence_star, visual_mask):
    """`(..., T, 9)` relation logits for every visual token as the reference; -inf where not allowed."""
    sentence = jnp.broadcast_to(sentence_star[..., None, :], visual_star.shape)
    head = RelationHead(config.hidden)
    logits = cast(jax.Array, head.apply({"params": params["relation"]}, jnp.concatenate([visual_star, sentence], -1)))
    return jnp.where(allowed_relations(visual_mask), logits, -jnp.inf)


def select_references(logits, num_references):
    """Top-L tokens: `(indices (..., 2) int32, mask (..., 2) bool)`, most similar first.

    `num_references` `(...)` int L in 1..2; a slot beyond L, or one that would need a padded
    token (a scene with fewer real tokens than L), is masked off.
    """
    top_logits, indices = jax.lax.top_k(logits, MAX_REFERENCES)
    mask = (jnp.arange(MAX_REFERENCES) < jnp.asarray(num_references)[..., None]) & jnp.isfinite(top_logits)
    return indices.astype(jnp.int32), mask


def gather_tokens(array, indices):
    """`array` `(..., T, F)` at `indices` `(..., K)` -> `(..., K, F)`."""
    return jnp.take_along_axis(array, indices[..., None], axis=-2)


@dataclasses.dataclass(frozen=True)
class Prediction:
    references: np.ndarray  # (..., 2) int32 visual-token index per reference (N = the table)
    reference_mask: np.ndarray  # (..., 2) bool: the first L slots (that have a real token)
    relations: np.ndarray  # (..., 2) int32 index into RELATION_NAMES
    token_probabilities: np.ndarray  # (..., T) softmax of the sentence-token similarities
    relation_probabilities: np.ndarray  # (..., 2, 9)


def predict_arrays(config: NoLlmConfig, params, visual, visual_mask, sentence, num_references, logit_scale):
    """Pure: the arrays of a `Prediction` (see there for shapes)."""
    visual_star, sentence_star = adapted_tokens(config, params, visual, sentence)
    logits = token_logits(visual_star, sentence_star, visual_mask, logit_scale)
    references, mask = select_references(logits, num_references)
    relation_probs = jax.nn.softmax(
        gather_tokens(relation_logits(config, params, visual_star, sentence_star, visual_mask), references), axis=-1
    )
    return (
        references,
        mask,
        jnp.argmax(relation_probs, axis=-1).astype(jnp.int32),
        jax.nn.softmax(logits, axis=-1),
        relation_probs,
    )


_jitted_predict = jax.jit(predict_arrays, static_argnums=0)


def loss_terms(config: NoLlmConfig, params, batch: dict, logit_scale):
    """`(reference loss, relation loss)` for a batch of scenes.

    batch: visual `(B, T, D)`, visual_mask `(B, T)`, sentence `(B, D)`, targets, relations
    `(B, 2)` int32 (the ground-truth token and relation of each tuple), target_mask `(B, 2)`.
    The reference loss is Ours' grounding loss with the sentence as every tuple's text: a
    softmax over the tokens per ground-truth reference, so at its optimum each of the L
    references gets probability 1/L and the top L are exactly them.
    """
    visual_star, sentence_star = adapted_tokens(config, params, batch["visual"], batch["sentence"])
    logits = token_logits(visual_star, sentence_star, batch["visual_mask"], logit_scale)
    per_reference = jnp.broadcast_to(logits[..., None, :], (*batch["targets"].shape, logits.shape[-1]))
    reference_loss = grounding_loss(per_reference, batch["targets"], batch["target_mask"])
    relations = gather_tokens(
        relation_logits(config, params, visual_star, sentence_star, batch["visual_mask"]), batch["targets"]
    )
    per_tuple = optax.softmax_cross_entropy_with_integer_labels(relations, batch["relations"])
    relation_loss = jnp.sum(jnp.where(batch["target_mask"], per_tuple, 0.0)) / jnp.maximum(
        jnp.sum(batch["target_mask"]), 1
    )
    return reference_loss, relation_loss


@dataclasses.dataclass(frozen=True)
class NoLlmModel:
    """Trained no_llm parameters and what is needed to apply them to backbone features."""

    config: NoLlmConfig
    params: dict
    logit_scale: float

    def predict(self, visual, visual_mask, sentence, num_references) -> Prediction:
        """visual `(..., T, D)`, visual_mask `(..., T)`, sentence `(..., D)`, num_references `(...)`."""
        arrays = _jitted_predict(
            self.config,
            self.params,
            jnp.asarray(visual, jnp.float32),
            jnp.asarray(visual_mask, bool),
            jnp.asarray(sentence, jnp.float32),
            jnp.asarray(num_references, jnp.int32),
            self.logit_scale,
        )
        return Prediction(*(np.asarray(a) for a in arrays))


def encode_sentences(backbone: Backbone, config: NoLlmConfig, instructions, batch: int = 64) -> np.ndarray:
    """`(len(instructions), D)` sentence tokens."""
    texts = [config.sentence_text(text) for text in instructions]
    if not texts:
        return np.zeros((0, backbone.dim), np.float32)
    return np.concatenate([backbone.encode_texts(texts[i : i + batch]) for i in range(0, len(texts), batch)])


# ----------------------------------------------------------------------------- the trained model file


@dataclasses.dataclass(frozen=True)
class TrainedNoLlm:
    model: NoLlmModel
    backbone_fingerprint: str
    train_config: dict
    sha256: str  # of the weights (`params_sha256`)


def load_model(run_dir: Path) -> TrainedNoLlm:
    """The trained model of a finished run, verified."""
    path = trained_weights(
        run_dir,
        "no_llm model",
        "train it first (`ocplace reproduce` trains every registered method's missing runs, or call "
        "ocplace.methods.no_llm.train.train_no_llm)",
    )
    arrays, metadata = load_weights(
        path, f"delete {path.parent} and rerun `ocplace reproduce` (it trains missing runs)"
    )
    needed = ["model_config", "logit_scale", "backbone_fingerprint", "train_config"]
    expect_kind(path, metadata, needed, WEIGHTS_KINDS["model_config"], "OUT/runs/no_llm/fraction-1.00")
    config = serial.from_json(NoLlmConfig, metadata["model_config"])
    template = jax.eval_shape(lambda: init_params(config, jax.random.key(0)))
    params = unflatten_state(arrays, template)
    return TrainedNoLlm(
        NoLlmModel(config, params, float(metadata["logit_scale"])),
        metadata["backbone_fingerprint"],
        json.loads(metadata["train_config"]),
        params_sha256(params),
    )


def params_sha256(params) -> str:
    """sha256 over every weight's path, dtype, shape and bytes: a file's hash would not do, because
    safetensors writes its metadata in no fixed order."""
    digest = hashlib.sha256()
    update_with_params(digest, params)
    return digest.hexdigest()
