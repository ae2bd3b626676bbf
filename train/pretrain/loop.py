"""The pretraining run: captions, rendering, contrastive training, saving the backbone.

Output directory (default `<cache>/backbones/offline-<recipe hash>/`):
    config.json, weights.safetensors, fingerprint.txt   the backbone (`models/offline_backbone.py`)
    run/run.json (`paths.RUN_FILE`)                      the recipe and pool this run belongs to
    run/metrics.jsonl                                    loss, temperature, learning rate per logged step
    run/renders/chunk_*.npz, run/checkpoints/            removed once the backbone is saved

With `share_renders` (the backbone seeds of one recipe, `reproduce --backbone-seeds N`) the chunks are
`<cache>/backbones/renders-<hash>/renders/chunk_*.npz` instead, beside the captions' sentences encoded so far
(`captions.npz`), kept for the recipe's other optimiser seeds: a seed varies the projections' initialisation and
the batch order, never the images or a caption's embedding.

Every random draw is a pure function of the recipe's seeds and the step, so a run resumed from
its newest checkpoint (and its rendered chunks) ends with the weights of an uninterrupted one.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import hashlib
import json
import logging
import math
import shutil
import time
import zipfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ocplace import serial
from ocplace.errors import TrainingError
from ocplace.models.offline_backbone import (
    CONFIG_FILE,
    FINGERPRINT_FILE,
    FrozenTextTower,
    OfflineBackbone,
    image_embeddings,
    init_params,
    join_params,
    load_saved_backbone,
    read_backbone_config,
    split_trainable,
    text_embeddings,
    trainable_mask,
)
from ocplace.models.offline_config import OfflineConfig
from ocplace.models.offline_recipes import OptimConfig, PretrainConfig, output_dir
from ocplace.paths import atomic_path
from ocplace.sim.corpus.build import build_corpus
from ocplace.train import checkpoints, runner
from ocplace.train import optim as optimisers  # `optim` names the recipe's OptimConfig here
from ocplace.train.pretrain.captions import CaptionBank
from ocplace.train.pretrain.classes import caption_bank, pretraining_classes
from ocplace.train.pretrain.loss import contrastive_loss
from ocplace.train.pretrain.pool import TrainingPool, training_pool
from ocplace.train.pretrain.render import RenderedImages, arrays_sha256, render_all

log = logging.getLogger(__name__)

RUN_DIR = "run"
CAPTIONS_FILE = "captions.npz"  # in the shared renders folder: the sentences of the captions encoded so far
LOG_EVERY = 10


@dataclasses.dataclass(frozen=True)
class PretrainResult:
    directory: Path
    backbone: OfflineBackbone
    probe_loss_before: float  # contrastive loss on a fixed, unaugmented batch at initialisation
    probe_loss_after: float  # ... and after training
    timings: dict  # seconds per phase of this invocation


# ----------------------------------------------------------------------------- pure training pieces


def colour_jitter(pixels, factors):
    """uint8 `(B, S, S, 3)` -> float32 in [0, 255]: per-image saturation, contrast, brightness factors `(B, 3)`."""
    x = pixels.astype(jnp.float32)
    saturation, contrast, brightness = (factors[:, i, None, None, None] for i in range(3))
    gray = x.mean(axis=-1, keepdims=True)
    x = gray + (x - gray) * saturation
    mean = x.mean(axis=(1, 2, 3), keepdims=True)
    x = mean + (x - mean) * contrast
    return jnp.clip(x * brightness, 0.0, 255.0)


def batch_loss(model: OfflineConfig, params, pixels, sentences, positives):
    images = image_embeddings(model, params, pixels)
    texts = text_embeddings(params, sentences)
    return contrastive_loss(images, texts, positives, jnp.exp(params["log_logit_scale"]))


@functools.lru_cache(maxsize=4)
def make_train_step(model: OfflineConfig, optim: OptimConfig):
    """Jitted `step(state, frozen, batch arrays, bank) -> (state, loss)` with state
    `(trainable, opt_state)`; `trainable` and `frozen` are the flat halves of `split_trainable`.

    Gradients are taken for the trainable half only, so no backward pass runs through a frozen
    trunk prefix. Cached per configuration: runs in one process (a resumed run, tests) compile once.
    """
    optimizer = optimisers.make(optim)
    max_log_scale = math.log(optim.max_logit_scale)

    def loss_fn(trainable, frozen, pixels, sentences, positives):
        return batch_loss(model, join_params(trainable, frozen), pixels, sentences, positives)

    def step(state, frozen, pixels, factors, captions, positives, bank_sentences):
        trainable, opt_state = state
        loss, grads = jax.value_and_grad(loss_fn)(
            trainable, frozen, colour_jitter(pixels, factors), bank_sentences[captions], positives
        )
        updates, opt_state = optimizer.update(grads, opt_state, trainable)
        trainable = optax.apply_updates(trainable, updates)
        trainable = {**trainable, "log_logit_scale": jnp.minimum(trainable["log_logit_scale"], max_log_scale)}
        return (trainable, opt_state), loss

    return jax.jit(step)


probe_loss = jax.jit(batch_loss, static_argnums=0)


# ----------------------------------------------------------------------------- batches


@dataclasses.dataclass(frozen=True)
class Batch:
    pixels: np.ndarray  # uint8 (B, S, S, 3)
    factors: np.ndarray  # float32 (B, 3) saturation, contrast, brightness
    labels: np.ndarray  # int32 (B,)
    captions: np.ndarray  # int32 (B,) caption index per image (the texts of the batch)
    positives: np.ndarray  # bool (B, B) caption j describes image i


@dataclasses.dataclass(frozen=True)
class BatchDraw:
    """What a step draws from its random stream, before any pixel is gathered."""

    indices: np.ndarray  # int (B,) rows of the rendered images
    turns: np.ndarray | None  # int (B,) quarter turns; None: not rotated
    flips: np.ndarray | None  # bool (B,) mirrored before turning
    factors: np.ndarray  # float32 (B, 3) saturation, contrast, brightness
    labels: np.ndarray  # int32 (B,)
    captions: np.ndarray  # int32 (B,)


def draw_batch(
    images: RenderedImages,
    by_class: list[np.ndarray],
    bank: CaptionBank,
    optim: OptimConfig,
    rng: np.random.Generator,
    augment: bool = True,
) -> BatchDraw:
    """A kind of class per image (`optim.kind_shares`: real objects, recoloured ones, primitives),
    then a class of that kind uniformly (so rarely visible objects are not starved), plus a share
    of workspace images; one caption per image. Augmentation: quarter turns, flips, colour factors."""
    table = bank.table_class
    num_table = min(
        max(round(optim.batch_size * optim.table_share), 1 if optim.table_share else 0), optim.batch_size - 1
    )
    classes = np.concatenate(
        [sample_classes(by_class, bank, optim, rng, optim.batch_size - num_table), np.full(num_table, table)]
    )
    indices = np.array([by_class[k][rng.integers(len(by_class[k]))] for k in classes])
    turns = flips = None
    factors = np.ones((len(indices), 3), np.float32)
    if augment:
        if optim.rotate:
            turns, flips = rng.integers(4, size=len(indices)), rng.random(len(indices)) < 0.5
        amplitude = optim.colour_jitter
        factors = rng.uniform(1 - amplitude, 1 + amplitude, size=(len(indices), 3)).astype(np.float32)
    labels = images.labels[indices]
    return BatchDraw(indices, turns, flips, factors, labels, bank.sample(rng, labels))


def gather_batch(images: RenderedImages, bank: CaptionBank, draw: BatchDraw) -> Batch:
    """The images `draw` picked, gathered and turned, with their positives."""
    pixels = images.images[draw.indices]
    if draw.turns is not None:
        flips = draw.flips if draw.flips is not None else np.zeros(len(pixels), bool)  # drawn with the turns
        pixels = np.stack(
            [np.rot90(p[:, ::-1] if flip else p, turns) for p, turns, flip in zip(pixels, draw.turns, flips)]
        )
    positives = bank.applies[draw.captions][:, draw.labels].T
    return Batch(np.ascontiguousarray(pixels), draw.factors, draw.labels, draw.captions, positives)


def sample_classes(
    by_class: list[np.ndarray], bank: CaptionBank, optim: OptimConfig, rng: np.random.Generator, count: int
) -> np.ndarray:
    """int `(count,)` non-table classes with images: a kind by its share (renormalised over the kinds
    present), then a class of that kind uniformly, or (`optim.balance` "group") a category group of that kind
    uniformly and then a class of it."""
    present = {
        kind: [k for k, own in enumerate(bank.kinds) if own == kind and len(by_class[k])]
        for kind, _ in optim.kind_shares
    }
    kinds = [kind for kind, _ in optim.kind_shares if present[kind]]
    shares = np.array([share for kind, share in optim.kind_shares if present[kind]], np.float64)
    drawn = rng.choice(len(kinds), size=count, p=shares / shares.sum())
    if optim.balance == "class":
        return np.array([rng.choice(present[kinds[d]]) for d in drawn])
    grouped = {kind: list(_by_group(classes, bank.groups).values()) for kind, classes in present.items()}
    picked = []
    for d in drawn:
        groups = grouped[kinds[d]]
        picked.append(rng.choice(groups[rng.integers(len(groups))]))
    return np.array(picked)


def _by_group(classes: list[int], groups: tuple[str, ...]) -> dict[str, list[int]]:
    """`classes` by their group, in first-seen order."""
    found: dict[str, list[int]] = {}
    for k in classes:
        found.setdefault(groups[k], []).append(k)
    return found


CAPTION_BATCH = 64


def step_rng(seed: int, step: int) -> np.random.Generator:
    return np.random.default_rng([seed, step])


def probe_rng(seed: int) -> np.random.Generator:
    return np.random.default_rng([seed, 2**31])


def run_draws(images, by_class, bank: CaptionBank, optim: OptimConfig) -> tuple[list[BatchDraw], BatchDraw]:
    """Every step's draw (indexed by step) and the probe's: a fixed, unaugmented batch on its own seed
    stream, to compare the loss before and after training. Each comes from its own seeded stream, so
    all are known before the first step."""
    steps = [draw_batch(images, by_class, bank, optim, step_rng(optim.seed, step)) for step in range(optim.steps)]
    return steps, draw_batch(images, by_class, bank, optim, probe_rng(optim.seed), augment=False)


def used_captions(draws: list[BatchDraw]) -> np.ndarray:
    """Sorted caption indices `draws` hold: of a run's steps and probe, the only rows of the bank it reads."""
    return np.unique(np.concatenate([draw.captions for draw in draws]))


def caption_sentences(
    text_tower: FrozenTextTower, texts: tuple[str, ...], used: np.ndarray, progress: bool = False
) -> np.ndarray:
    """float32 `(C, D)`: the text tower's embedding of each caption in `used`, zeros in the other rows.

    The bank has many more captions than a short run draws (the demo's 75 steps draw under a third
    of 16,813), and a step only gathers its batch's rows, so the others are never encoded. Each
    caption is encoded in a batch of 64 as before; its row does not depend on its neighbours, but
    does on the batch's shape (tested bit for bit: `test_pretrain_data.py`).
    """
    from ocplace.runtime.progress import progress_bar

    sentences = None
    starts = range(0, len(used), CAPTION_BATCH)
    for start in progress_bar(starts, enabled=progress, desc="captions", unit="batch"):
        rows = used[start : start + CAPTION_BATCH]
        batch = [texts[i] for i in rows]
        # Always a full batch: the tower pads a short one to a power of two, and another batch shape
        # gives other bits (as the whole bank's last, partial batch was padded to 64, so is this one).
        encoded = text_tower.encode(batch + batch[-1:] * (CAPTION_BATCH - len(batch)))[: len(batch)]
        if sentences is None:
            sentences = np.zeros((len(texts), encoded.shape[1]), np.float32)
        sentences[rows] = encoded
    if sentences is None:
        raise TrainingError("no caption to encode: `used` is empty")
    return sentences


def shared_caption_sentences(
    text_tower: FrozenTextTower, texts: tuple[str, ...], used: np.ndarray, folder: Path, progress: bool = False
) -> np.ndarray:
    """`caption_sentences`, encoding only the captions `folder/captions.npz` does not hold yet for this bank and
    adding them there: a row's bits do not depend on its batch's other captions, so a recipe's backbone seeds
    read each other's rows and get what they would have encoded themselves (zeros outside `used`, as there)."""
    path = folder / CAPTIONS_FILE
    bank = hashlib.sha256("\n".join([text_tower.digest, *texts]).encode()).hexdigest()  # this tower's sentences
    known_rows, known = np.zeros(0, np.int64), None
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as saved:
                arrays = {name: saved[name] for name in ("bank", "rows", "sentences")}
                if str(saved["sha256"]) != arrays_sha256(arrays):
                    raise ValueError("its arrays do not match the checksum written with them")
            if str(arrays["bank"]) == bank:
                known_rows, known = arrays["rows"], arrays["sentences"]
        except (
            OSError,
            ValueError,
            KeyError,
            EOFError,
            zipfile.BadZipFile,
        ) as error:  # damaged or edited: encoded again, never used
            log.warning("caption sentences %s cannot be used (%s): they are encoded again", path, error)
    missing = np.setdiff1d(used, known_rows)
    encoded = caption_sentences(text_tower, texts, missing, progress) if len(missing) else None
    held = encoded if encoded is not None else known
    if held is None:
        raise TrainingError("no caption to encode: `used` is empty")
    width = held.shape[1]
    every = np.zeros((len(texts), width), np.float32)
    if known is not None:
        every[known_rows] = known
    if encoded is not None:
        every[missing] = encoded[missing]
        rows = np.union1d(known_rows, missing)
        arrays = {"bank": np.array(bank), "rows": rows, "sentences": every[rows]}
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez(handle, sha256=np.array(arrays_sha256(arrays)), **arrays)
    sentences = np.zeros_like(every)
    sentences[used] = every[used]
    return sentences


# ----------------------------------------------------------------------------- the run


def pretrain(
    config: PretrainConfig,
    library,
    out_dir: str | Path | None = None,
    progress: bool = True,
    keep_run: bool = False,
    stop_after: int | None = None,
    render_workers: int = 1,
    share_renders: bool = False,
) -> PretrainResult:
    """Renders, trains and saves the offline backbone of `config` (resuming whatever was done): its phases in order,
    `_rendered`, `_captioned`, then `_Training` on the runner.

    `stop_after`: return after this many training steps without saving (to test resuming);
    `render_workers`: processes that render (the same images with any number);
    `share_renders`: render into (or read) the folder every optimiser seed of the recipe shares
    (`shared_renders_dir`), kept after the run, instead of the run's own folder; its encoded captions too.
    """
    config.validate()
    began = time.perf_counter()
    out_dir = Path(out_dir) if out_dir is not None else output_dir(config)
    run_dir = out_dir / RUN_DIR
    pool = training_pool(library, corpus_of(config), config.render)
    bank = caption_bank(pretraining_classes(library, pool.assets, config.render))
    run_meta = _run_metadata(config, pool, bank)
    if (out_dir / FINGERPRINT_FILE).exists() and _finished_meta(out_dir) == run_meta:
        log.info("the offline backbone of recipe %r is already built in %s", config.recipe, out_dir)
        backbone = load_saved_backbone(out_dir)
        summary = read_backbone_config(out_dir)["pretraining"]
        return PretrainResult(out_dir, backbone, summary["probe_loss_before"], summary["probe_loss_after"], {})
    checkpoints.claim_run_dir(run_dir, run_meta)
    timings = {"setup_s": time.perf_counter() - began}
    renders_root = shared_renders_dir(config, pool) if share_renders else run_dir
    images = _rendered(library, pool, renders_root, config, progress, render_workers, timings)
    inputs = _captioned(images, bank, config, renders_root if share_renders else None, progress, timings)
    training = _Training(config, bank, inputs, out_dir, run_meta, timings, began)
    outcome = runner.run(training.spec(run_dir), progress, stop_after=stop_after)
    if outcome.saved is None:
        return training.result(outcome.state)
    if not keep_run:
        shutil.rmtree(run_dir / "renders", ignore_errors=True)
        shutil.rmtree(run_dir / checkpoints.CHECKPOINT_DIR, ignore_errors=True)
    saved: PretrainResult = outcome.saved
    return saved


def _rendered(
    library, pool: TrainingPool, root: Path, config: PretrainConfig, progress: bool, workers: int, timings: dict
) -> RenderedImages:
    """The pretraining images of the pool, rendered into (or read from) `root`; their time into `timings`."""
    mark, cpu_mark = time.perf_counter(), time.process_time()
    images = render_all(library, pool, root, config.render, config.model, progress, workers)
    timings["render_s"] = time.perf_counter() - mark
    timings["render_cpu_s"] = time.process_time() - cpu_mark
    return images


@dataclasses.dataclass(frozen=True)
class _Inputs:
    """What the training phase reads beside the recipe: the images, each class's image indices, every step's batch
    draw and the probe's, the captions' sentences and the frozen text tower (kept in the saved backbone)."""

    images: RenderedImages
    by_class: list[np.ndarray]
    draws: list[BatchDraw]
    probe_draw: BatchDraw
    sentences: jax.Array  # (num_captions, D) the caption bank's sentence embeddings
    text_tower: FrozenTextTower


def _captioned(
    images: RenderedImages,
    bank: CaptionBank,
    config: PretrainConfig,
    shared_root: Path | None,
    progress: bool,
    timings: dict,
) -> _Inputs:
    """Every step's batch drawn, and the sentences of the captions they use encoded (kept in `shared_root`, the
    shared renders' folder, when given); TrainingError when the renders hold no object crop."""
    by_class = [np.flatnonzero(images.labels == k) for k in range(len(bank.class_names))]
    if not len(by_class[bank.table_class]) or not any(len(c) for c in by_class[: bank.table_class]):
        raise TrainingError("rendering produced no object crops; check the library with `ocplace scene`")
    mark = time.perf_counter()
    text_tower = FrozenTextTower.load(config.model.text_max_length)
    draws, probe_draw = run_draws(images, by_class, bank, config.optim)
    used = used_captions([*draws, probe_draw])
    if shared_root is not None:
        sentences = shared_caption_sentences(text_tower, bank.texts, used, shared_root, progress)
    else:
        sentences = caption_sentences(text_tower, bank.texts, used, progress)
    timings["captions_s"] = time.perf_counter() - mark
    return _Inputs(images, by_class, draws, probe_draw, jnp.asarray(sentences), text_tower)


class _Training:
    """The contrastive training on the runner: its initial state, a chunk of steps, what each logged step records,
    and the backbone saved at the end. Made where its clock starts (the initial weights and the probe's loss)."""

    def __init__(
        self,
        config: PretrainConfig,
        bank: CaptionBank,
        inputs: _Inputs,
        out_dir: Path,
        run_meta: dict,
        timings: dict,
        began: float,
    ):
        self.config, self.bank, self.inputs, self.out_dir, self.run_meta = config, bank, inputs, out_dir, run_meta
        self.timings, self.began = timings, began
        self.mark, self.cpu_mark = time.perf_counter(), time.process_time()
        params = init_params(config.model, jax.random.key(config.optim.seed))
        self.trainable, self.frozen = split_trainable(trainable_mask(config.model, params), params)
        probe = gather_batch(inputs.images, bank, inputs.probe_draw)
        self.probe_args = (probe.pixels, inputs.sentences[probe.captions], probe.positives)
        self.loss_before = float(probe_loss(config.model, params, *self.probe_args))
        self.train_step = make_train_step(config.model, config.optim)
        self.resumed = False
        self.usual_record = runner.loss_and_learning_rate(optimisers.learning_rates(config.optim))

    def spec(self, run_dir: Path) -> runner.Run:
        optim = self.config.optim
        self.resumed = bool(checkpoints.list_checkpoints(run_dir))
        return runner.Run(
            run_dir=run_dir,
            run_meta=self.run_meta,
            steps=optim.steps,
            chunk_steps=1,
            log_every=LOG_EVERY,
            checkpoint_every=optim.checkpoint_every,
            keep_checkpoints=optim.keep_checkpoints,
            init_state=lambda: (self.trainable, optimisers.make(optim).init(self.trainable)),
            chunk=self.chunk,
            record=self.record,
            artefact=self.out_dir / FINGERPRINT_FILE,
            save_artefact=self.save,
            checkpoint_meta={"run": json.dumps(self.run_meta, sort_keys=True)},
            desc="pretrain",
        )

    def chunk(self, state, start: int, count: int):
        images, bank, inputs = self.inputs.images, self.bank, self.inputs
        losses = []
        for step in range(start, start + count):
            batch = gather_batch(images, bank, inputs.draws[step])
            state, loss = self.train_step(
                state, self.frozen, batch.pixels, batch.factors, batch.captions, batch.positives, inputs.sentences
            )
            losses.append(loss)
        return state, jnp.stack(losses)

    def record(self, state, step: int, losses: np.ndarray) -> dict:
        logit_scale = float(jnp.exp(state[0]["log_logit_scale"]))
        return {**self.usual_record(state, step, losses), "logit_scale": logit_scale}

    def trained(self, state) -> tuple[OfflineBackbone, float]:
        """The backbone of `state` and its probe loss; stops the training clock first."""
        self.timings["train_s"] = time.perf_counter() - self.mark
        self.timings["train_cpu_s"] = time.process_time() - self.cpu_mark
        params = join_params(jax.device_get(state[0]), self.frozen)
        loss_after = float(probe_loss(self.config.model, params, *self.probe_args))
        backbone = OfflineBackbone(self.config.model, params, self.inputs.text_tower, source=str(self.out_dir))
        return backbone, loss_after

    def result(self, state) -> PretrainResult:
        """What a run stopped before its end returns: the backbone so far, not saved."""
        backbone, loss_after = self.trained(state)
        return PretrainResult(self.out_dir, backbone, self.loss_before, loss_after, self.timings)

    def save(self, fingerprint_path: Path, state) -> PretrainResult:
        backbone, loss_after = self.trained(state)
        self.timings["total_s"] = time.perf_counter() - self.began
        images, names = self.inputs.images, self.bank.class_names
        summary = {
            "run": self.run_meta,
            "images": int(len(images.labels)),
            "images_per_class": {name: int(len(c)) for name, c in zip(names, self.inputs.by_class, strict=True)},
            "probe_loss_before": self.loss_before,
            "probe_loss_after": loss_after,
            "final_logit_scale": backbone.logit_scale,
            "timings_s": {k: round(v, 1) for k, v in self.timings.items()},
            "resumed": self.resumed,
            "finished": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        }
        backbone.save(fingerprint_path.parent, {"pretraining": summary})
        return PretrainResult(self.out_dir, backbone, self.loss_before, loss_after, self.timings)


def shared_renders_dir(config: PretrainConfig, pool: TrainingPool) -> Path:
    """The renders of `config`'s backbone seeds, beside the backbones in the cache: keyed by the recipe less its
    optimiser and by the pool's objects and textures (as the backbone's own folder, not by the library's meshes)."""
    depends_on = {
        "recipe": dataclasses.replace(config, optim=OptimConfig()),
        "objects": pool.objects,
        "textures": pool.textures,
    }
    key = hashlib.sha256(serial.to_json(depends_on).encode()).hexdigest()[:12]
    return output_dir(config).parent / f"renders-{key}"


def corpus_of(config: PretrainConfig):
    """The corpus a recipe's pool is drawn from (built into the cache on first use), None for `task`."""
    if config.render.pool == "task":
        return None
    render = config.render
    return build_corpus(progress=False, large=render.large_models == "shrink", cutouts=render.cutouts)


def _run_metadata(config: PretrainConfig, pool: TrainingPool, bank: CaptionBank) -> dict:
    return {
        "recipe": serial.to_dict(config),
        "key": config.key(),
        "objects": list(pool.objects),
        "textures": list(pool.textures),
        "captions": len(bank.texts),
    }


def _finished_meta(out_dir: Path) -> dict | None:
    try:
        return json.loads((out_dir / CONFIG_FILE).read_text())["pretraining"]["run"]
    except (OSError, ValueError, KeyError):
        return None
