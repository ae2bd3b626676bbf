"""Rendering the pretraining images: crops of the pool's objects in settled MuJoCo scenes.

Scenes are drawn from the pool (`train.pretrain.pool`: the furniture corpus, or the training split's
objects), named primitives (`sim.primitives`) and the seen table textures only; the arena is
compiled with nothing else, so no other object or texture can appear. Crops are cut the way the
pipeline cuts them (`square_crop` at the benchmark loader's size), half of them with the pipeline's
padding and the rest with jittered padding and box position, then put through the backbone's own
preprocessing. Each settled scene is rendered again under new lighting, and renders may recolour the
table, so the towers do not learn the three seen tables by heart. Primitives are painted a colour
term per scene; some objects of each render also give a second crop with the object recoloured to a
colour term (`train.pretrain.colours`), labelled with its own class (`train.pretrain.classes`).

Chunks of scenes are written to `<run>/renders/chunk_*.npz` as they finish: a rerun renders only the
missing chunks. Scene `i` is a pure function of `(seed, i)`, so chunks render in parallel processes
(`render_all(workers=...)`, the pretraining task's CPUs) to the same images.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import multiprocessing
import zipfile
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import cv2
import numpy as np

from ocplace.errors import SceneError, TrainingError
from ocplace.models.offline_backbone import preprocess_images
from ocplace.models.offline_config import OfflineConfig
from ocplace.models.offline_recipes import RenderConfig
from ocplace.paths import atomic_path, primitives_cache
from ocplace.sim.boxes import boxes_from_segmentation, square_crop
from ocplace.sim.colour_terms import COLOUR_TERMS
from ocplace.sim.dataset.loader import letterbox
from ocplace.sim.primitives import Primitive, primitive_asset, primitive_set
from ocplace.sim.scene import SceneSpec, sample_scene_spec
from ocplace.train.pretrain.captions import PRIMITIVE, RECOLOURED
from ocplace.train.pretrain.classes import PretrainClasses, pretraining_classes
from ocplace.train.pretrain.colours import hsv_to_rgb, recolour_objects, sample_hsv
from ocplace.train.pretrain.pool import TrainingPool

RENDERS_DIR = "renders"
PARALLEL_MIN_SCENES = 40  # fewer scenes to render than this: one process, whatever `workers` says
MAX_SCENE_DRAWS = 20

log = logging.getLogger(__name__)


def scene_primitives(config: RenderConfig) -> tuple[Primitive, ...]:
    """The primitives a recipe drops into its scenes (none when `primitives_per_scene` is 0)."""
    if config.primitives_per_scene == 0:
        return ()
    return primitive_set(config.primitive_shapes, config.primitive_widths)


# MuJoCo's renderer holds at most 1,000 materials (and textures) per model: a pool with more visual parts than
# this (the tabletop corpus has about 600) is rendered from several arenas, scene i from group i mod k, each
# group a contiguous share of the pool filled up to the limit (a single model over it gets an arena of its own).
MAX_ARENA_PARTS = 900


def arena_groups(pool: TrainingPool) -> list[TrainingPool]:
    """The pool itself when its visual parts fit one arena, else contiguous groups, each filled up to the limit."""
    sizes = [len(asset.visual_parts) for asset in pool.assets]
    if sum(sizes) <= MAX_ARENA_PARTS:
        return [pool]
    groups, start, parts = [], 0, 0
    for index, size in enumerate(sizes):
        if parts + size > MAX_ARENA_PARTS and index > start:
            groups.append(TrainingPool(pool.assets[start:index], pool.textures))
            start, parts = index, 0
        parts += size
    groups.append(TrainingPool(pool.assets[start:], pool.textures))
    return groups


def training_arena(library, pool: TrainingPool, primitives: Sequence[Primitive] = ()):
    """A MuJoCo arena compiled with the pool's objects and textures, `primitives` and nothing else."""
    from ocplace.sim.mujoco_backend import MujocoScenes

    objects = list(pool.assets)
    # The primitives' meshes are rewritten whenever an arena is built.
    objects += [primitive_asset(primitive, primitives_cache()) for primitive in primitives]
    return MujocoScenes(objects, {name: library.textures[name].path for name in pool.textures})


@dataclasses.dataclass(frozen=True)
class RenderedImages:
    """Preprocessed pretraining images: `images` uint8 `(M, S, S, 3)`, `labels` int32 `(M,)` class
    indices (objects in pool order, the table last), `scenes` int32 `(M,)` scene index."""

    images: np.ndarray
    labels: np.ndarray
    scenes: np.ndarray

    @classmethod
    def concatenate(cls, parts: list[RenderedImages]) -> RenderedImages:
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(cls)))

    def save(self, path: Path) -> None:
        """Written atomically with the sha256 of its arrays, which `load` checks."""
        arrays = dataclasses.asdict(self)
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez(handle, sha256=np.array(arrays_sha256(arrays)), **arrays)

    @classmethod
    def load(cls, path: Path) -> RenderedImages | None:
        """The chunk in `path`; None (said in one line) when it is unreadable or its arrays are not the ones it was
        written with: it is then rendered again, never used."""
        try:
            with np.load(path, allow_pickle=False) as stored:
                arrays = {f.name: stored[f.name] for f in dataclasses.fields(cls)}
                if str(stored["sha256"]) != arrays_sha256(arrays):
                    raise ValueError("its arrays do not match the checksum written with them")
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as error:
            log.warning("rendered chunk %s cannot be used (%s): it is rendered again", path, error)
            return None
        return cls(**arrays)


def arrays_sha256(arrays: dict[str, np.ndarray]) -> str:
    """sha256 over each array's name, dtype, shape and bytes, in name order (a file's content, not its layout)."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}:{array.dtype.str}:{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


@contextlib.contextmanager
def random_lighting(model, rng: np.random.Generator, config: RenderConfig):
    """Scales the headlight and the top light, tints them and tilts the top light; restores them after."""
    headlight = model.vis.headlight
    saved = (headlight.ambient.copy(), headlight.diffuse.copy(), model.light_diffuse.copy(), model.light_dir.copy())
    try:
        low, high = config.light_range
        tint = rng.uniform(0.96, 1.04, size=3)
        headlight.ambient[:] = saved[0] * rng.uniform(low, high) * tint
        headlight.diffuse[:] = saved[1] * rng.uniform(low, high) * tint
        model.light_diffuse[:] = saved[2] * rng.uniform(low, high) * tint
        tilt = rng.uniform(-config.light_tilt, config.light_tilt, size=2)
        direction = saved[3] + np.concatenate([tilt, [0.0]])
        model.light_dir[:] = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
        yield
    finally:
        headlight.ambient[:], headlight.diffuse[:] = saved[0], saved[1]
        model.light_diffuse[:], model.light_dir[:] = saved[2], saved[3]


def recolour_table(rgb: np.ndarray, segmentation: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The image with its background pixels (table, floor) shifted in hue, saturation and value."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV).astype(np.float32)
    background = segmentation == 0
    hsv[..., 0] = np.where(background, (hsv[..., 0] + rng.uniform(0, 180)) % 180, hsv[..., 0])
    hsv[..., 1] = np.where(
        background, np.clip(hsv[..., 1] * rng.uniform(0.3, 2.5) + rng.uniform(0, 40), 0, 255), hsv[..., 1]
    )
    hsv[..., 2] = np.where(background, np.clip(hsv[..., 2] * rng.uniform(0.5, 1.5), 0, 255), hsv[..., 2])
    return cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB)


def jittered_box(box: np.ndarray, rng: np.random.Generator, shift: float) -> np.ndarray:
    u0, v0, u1, v1 = (float(x) for x in box)
    du, dv = rng.uniform(-shift, shift, size=2) * max(u1 - u0, v1 - v0)
    return np.array([u0 + du, v0 + dv, u1 + du, v1 + dv])


def crops_of_render(
    rgb: np.ndarray,
    segmentation: np.ndarray,
    labels_by_id: dict[int, int],
    rng: np.random.Generator,
    config: RenderConfig,
) -> tuple[list[np.ndarray], list[int]]:
    """One crop per object of `labels_by_id` with a box (`crop_size` px), cut like the pipeline or with jitter."""
    boxes = boxes_from_segmentation(segmentation)
    crops, labels = [], []
    for object_id, box in zip(boxes.object_ids, boxes.boxes, strict=True):
        if int(object_id) not in labels_by_id:
            continue
        if rng.random() < config.canonical_share:
            crops.append(square_crop(rgb, box, config.padding, size=config.crop_size))
        else:
            padding = rng.uniform(*config.padding_range)
            crops.append(square_crop(rgb, jittered_box(box, rng, config.shift), padding, size=config.crop_size))
        labels.append(labels_by_id[int(object_id)])
    return crops, labels


def recoloured_crops(
    rgb: np.ndarray,
    segmentation: np.ndarray,
    names: Sequence[str],
    classes: PretrainClasses,
    rng: np.random.Generator,
    config: RenderConfig,
) -> tuple[list[np.ndarray], list[int]]:
    """Crops of the objects drawn for recolouring (each with `recolour_share`), recoloured to one
    of their colour terms, labelled with the (object, colour) class."""
    recolourable = set(classes.bodies(RECOLOURED))
    targets = {}
    for object_id, name in enumerate(names, start=1):
        colours = classes.colours_of(name) if name in recolourable else ()
        if colours and rng.random() < config.recolour_share:
            targets[object_id] = colours[rng.integers(len(colours))]
    if not targets:
        return [], []
    recoloured = recolour_objects(rgb, segmentation, targets, rng)
    labels_by_id = {i: classes.label(names[i - 1], colour) for i, colour in targets.items()}
    return crops_of_render(recoloured, segmentation, labels_by_id, rng, config)


def with_primitives(
    spec: SceneSpec, classes: PretrainClasses, rng: np.random.Generator, config: RenderConfig
) -> tuple[SceneSpec, dict[str, str]]:
    """`spec` with `primitives_per_scene` distinct primitives dropped after its objects, and the
    colour term each is painted in."""
    bodies = classes.bodies(PRIMITIVE)
    if len(bodies) < config.primitives_per_scene:
        raise TrainingError(
            f"{config.primitives_per_scene} primitives per scene, but only {len(bodies)} primitives "
            "have a class; lower primitives_per_scene or add primitive_shapes"
        )
    chosen = [bodies[i] for i in rng.choice(len(bodies), size=config.primitives_per_scene, replace=False)]
    painted = {}
    for body in chosen:
        colours = classes.colours_of(body)
        painted[body] = colours[rng.integers(len(colours))]
    return dataclasses.replace(spec, objects=spec.objects + tuple(chosen)), painted


def paint(model, painted: dict[str, str], rng: np.random.Generator) -> None:
    """Sets the material colour of each primitive to a colour drawn in its colour term."""
    for body, colour in painted.items():
        material = model.geom_matid[model.geom(f"{body}_visual").id]
        model.mat_rgba[material, :3] = hsv_to_rgb(sample_hsv(COLOUR_TERMS[colour], rng))


def render_scene(
    arena, pool: TrainingPool, classes: PretrainClasses, index: int, config: RenderConfig, model: OfflineConfig
) -> RenderedImages:
    """Every image of scene `index`: object and primitive crops, the workspace and recoloured
    crops, `renders_per_scene` times."""
    rng = np.random.default_rng([config.seed, index])
    # Primitives and recolouring draw from their own stream: without them a scene is what it was.
    extra = np.random.default_rng([config.seed, index, 1])
    spec, painted, rgb, segmentation = _settled_scene(arena, pool, classes, rng, extra, config)
    labels_by_id = {i + 1: classes.label(name, painted.get(name, "")) for i, name in enumerate(spec.objects)}
    images, labels = [], []
    for render in range(config.renders_per_scene):
        if render > 0:
            with random_lighting(arena.model, rng, config):
                rgb, _, segmentation = arena.render(spec.objects)
        if rng.random() < config.table_jitter:
            rgb = recolour_table(rgb, segmentation, rng)
        crops, crop_labels = crops_of_render(rgb, segmentation, labels_by_id, rng, config)
        images += crops + [letterbox(rgb, config.crop_size)]
        labels += crop_labels + [classes.table]
        crops, crop_labels = recoloured_crops(rgb, segmentation, spec.objects, classes, extra, config)
        images += crops
        labels += crop_labels
    return RenderedImages(
        preprocess_images(model, np.stack(images)), np.array(labels, np.int32), np.full(len(labels), index, np.int32)
    )


def _settled_scene(
    arena,
    pool: TrainingPool,
    classes: PretrainClasses,
    rng: np.random.Generator,
    extra: np.random.Generator,
    config: RenderConfig,
    max_draws: int = MAX_SCENE_DRAWS,
):
    """`(spec, painted, rgb, segmentation)` of a freshly drawn scene (`painted`: the colour term of
    each primitive), rendered under random lighting; a scene whose objects keep falling off the
    table is replaced by the next draw."""
    for _ in range(max_draws):
        spec = sample_scene_spec(rng, list(pool.objects), list(pool.textures), num_objects=config.objects_per_scene)
        painted: dict[str, str] = {}
        if config.primitives_per_scene:
            spec, painted = with_primitives(spec, classes, extra, config)
            paint(arena.model, painted, extra)
        with random_lighting(arena.model, rng, config):
            try:
                scene = arena.build(spec)
            except SceneError as error:
                # Crowded drops of large models roll off now and then (about one scene in twelve of the
                # corpus); the next draw replaces them, so this is routine, not a warning.
                log.debug("pretraining scene redrawn: %s", error)
                continue
        if scene.spec.objects != spec.objects:
            raise TrainingError(f"the arena changed the scene's objects: {scene.spec.objects} != {spec.objects}")
        return spec, painted, scene.rgb, scene.segmentation
    raise TrainingError(
        f"{max_draws} scenes in a row could not be settled on the table; check the library with `ocplace scene`"
    )


def chunk_path(run_dir: Path, chunk: int) -> Path:
    return Path(run_dir) / RENDERS_DIR / f"chunk_{chunk:05d}.npz"


def render_all(
    library,
    pool: TrainingPool,
    run_dir: Path,
    config: RenderConfig,
    model: OfflineConfig,
    progress: bool = True,
    workers: int = 1,
) -> RenderedImages:
    """Renders the missing chunks into `run_dir`, in up to `workers` processes (each renders whole chunks: a
    scene is a pure function of its index, so the images are the same with any number), then returns every
    image of every chunk."""
    from ocplace.runtime.progress import progress_bar

    num_chunks = -(-config.scenes // config.chunk_scenes)
    chunks = {
        c: RenderedImages.load(chunk_path(run_dir, c)) if chunk_path(run_dir, c).exists() else None
        for c in range(num_chunks)
    }
    missing = [c for c, chunk in chunks.items() if chunk is None]
    done_scenes = config.scenes - sum(_chunk_scenes(c, config) for c in missing)
    to_render = sum(_chunk_scenes(c, config) for c in missing)
    # A render process starts in seconds (imports, arenas): worth it for the demo's 100 scenes, not for smoke's 2.
    workers = workers if to_render >= PARALLEL_MIN_SCENES else 1
    shares = [missing[k :: max(1, workers)] for k in range(min(max(1, workers), len(missing)))]
    with progress_bar(total=config.scenes, initial=done_scenes, unit="scene", desc="render", enabled=progress) as bar:
        if len(shares) == 1:
            render_chunks(library, pool, run_dir, config, model, shares[0], bar.update)
        elif shares:
            with ProcessPoolExecutor(len(shares), mp_context=multiprocessing.get_context("spawn")) as executor:
                futures = {
                    executor.submit(render_chunks, library, pool, run_dir, config, model, share): share
                    for share in shares
                }
                for future in as_completed(futures):
                    future.result()
                    bar.update(sum(_chunk_scenes(c, config) for c in futures[future]))
    for c in missing:
        chunks[c] = RenderedImages.load(chunk_path(run_dir, c))
    if any(chunk is None for chunk in chunks.values()):
        raise TrainingError(
            f"a chunk rendered now in {run_dir} cannot be read back (said above); run the command again"
        )
    return RenderedImages.concatenate([chunk for chunk in chunks.values() if chunk is not None])


def render_chunks(
    library, pool: TrainingPool, run_dir: Path, config: RenderConfig, model: OfflineConfig, chunks, done=None
) -> None:
    """Renders `chunks` (indices) into `run_dir` with arenas of its own; `done(scenes)` after each scene."""
    if not chunks:
        return
    classes = pretraining_classes(library, pool.assets, config)
    groups = arena_groups(pool)
    arenas = [training_arena(library, group, scene_primitives(config)) for group in groups]
    try:
        for chunk in chunks:
            parts = []
            for index in _chunk_scenes_range(chunk, config):
                group = index % len(groups)
                parts.append(render_scene(arenas[group], groups[group], classes, index, config, model))
                if done is not None:
                    done(1)
            RenderedImages.concatenate(parts).save(chunk_path(run_dir, chunk))
    finally:
        for arena in arenas:
            arena.close()


def _chunk_scenes_range(chunk: int, config: RenderConfig) -> range:
    return range(chunk * config.chunk_scenes, min((chunk + 1) * config.chunk_scenes, config.scenes))


def _chunk_scenes(chunk: int, config: RenderConfig) -> int:
    return len(_chunk_scenes_range(chunk, config))
