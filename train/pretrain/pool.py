"""What pretraining may render: the objects of its pool, and the held-out corpus categories it is validated on.

Two pools (`RenderConfig.pool`):
- `corpus` (the default, the foundation backbone): the furniture corpus (`sim/corpus/`) under the
  recipe's protocol, minus the categories held out for validation; its `large` tier (models over the
  tabletop size, shrunk) only when the recipe asks (`RenderConfig.large_models`), and never a model of a
  held-out category; likewise its cut-outs (Tux Paint's stamps, Fluent Emoji: `RenderConfig.cutouts`). The held-out
  categories and the validation scenes come from the tabletop models alone, so they are the same with or
  without the large tier and the cut-outs. No object of the benchmark library
  (seen, unseen or unseen_cat) can be in it: the benchmark's training objects reach the model only
  through the adapters, as in the paper; neither by name and source nor by geometry (a copied mesh: its
  shape descriptor, `sim.library.shape_descriptor`).
- `task` (today's backbone of earlier results): the library's training split.

Tables are the library's seen textures in both.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection

from ocplace.errors import TrainingError
from ocplace.models.offline_recipes import RenderConfig
from ocplace.sim.corpus.build import Corpus
from ocplace.sim.corpus.selection import (
    benchmark_nouns,
    eligible_groups,
    is_validation_group,
    names_test_noun,
    noun_group,
    test_nouns,
)
from ocplace.sim.library.shape_descriptor import asset_descriptor, asset_vertices, same_mesh, same_shape
from ocplace.sim.library.types import CORPUS_SPLIT, ObjectAsset
from ocplace.sim.scene import split_pools
from ocplace.vocabulary import SHAPE_WORDS


@dataclasses.dataclass(frozen=True)
class TrainingPool:
    """The objects pretraining renders (`assets`, in pool order) and the seen table textures."""

    assets: tuple[ObjectAsset, ...]
    textures: tuple[str, ...]

    @property
    def objects(self) -> tuple[str, ...]:
        return tuple(asset.name for asset in self.assets)


def strict_drops(corpus: Corpus, library) -> dict[str, str]:
    """The corpus models `strict` leaves out, by key, with the test noun their name holds."""
    nouns = test_nouns(asset for asset in library.objects.values() if asset.split != "seen")
    drops = {key: names_test_noun(asset.human_name, nouns) for key, asset in corpus.assets.items()}
    return {key: noun for key, noun in drops.items() if noun}


def protocol_assets(
    corpus: Corpus, library, protocol: str, large: bool = False, cutouts: tuple[str, ...] = ()
) -> tuple[ObjectAsset, ...]:
    """The corpus' tabletop models (and its large tier when `large`, the cut-outs of the sources `cutouts`)
    under `protocol`: everything (`open`), or without the models `strict_drops` names."""
    dropped = strict_drops(corpus, library) if protocol == "strict" else {}
    return tuple(
        asset
        for key, asset in corpus.assets.items()
        if key not in dropped
        and (large or asset.name not in corpus.large)
        and (asset.name not in corpus.cutouts or corpus.cutouts[asset.name] in cutouts)
    )


def validation_groups(corpus: Corpus, library, config: RenderConfig) -> set[str]:
    """The corpus categories (head-noun groups, `sim.corpus.selection.noun_group`) held out of pretraining: a
    seeded hash over the groups that name no benchmark object and no primitive shape."""
    nouns = benchmark_nouns(library.objects.values(), [word for words in SHAPE_WORDS.values() for word in words])
    names = [asset.human_name for asset in protocol_assets(corpus, library, config.protocol)]
    return {
        group
        for group in eligible_groups(names, nouns)
        if is_validation_group(group, config.validation_share, config.validation_seed)
    }


def validation_assets(corpus: Corpus, library, config: RenderConfig) -> tuple[ObjectAsset, ...]:
    """Every corpus model of a held-out category (never rendered in pretraining)."""
    groups = validation_groups(corpus, library, config)
    return tuple(a for a in protocol_assets(corpus, library, config.protocol) if noun_group(a.human_name) in groups)


def validation_scene_assets(corpus: Corpus, library, config: RenderConfig) -> tuple[ObjectAsset, ...]:
    """The held-out models validation scenes show: at most `validation_cap` per category (by key), so that one
    category of many near-identical models (wall plugs) does not fill the scenes."""
    taken: dict[str, int] = {}
    chosen = []
    for asset in sorted(validation_assets(corpus, library, config), key=lambda a: a.name):
        group = noun_group(asset.human_name)
        if taken.get(group, 0) < config.validation_cap:
            taken[group] = taken.get(group, 0) + 1
            chosen.append(asset)
    return tuple(chosen)


def training_pool(library, corpus: Corpus | None, config: RenderConfig) -> TrainingPool:
    """The pool `config` renders (the first `max_objects` if > 0) and the seen table textures.

    Raises `TrainingError` if a benchmark library object, or a held-out validation name, is in a corpus
    pool, or if the `task` pool holds anything outside the training split, so that a change to this logic
    can never leak test objects into pretraining.
    """
    objects, textures = split_pools(library, "seen")
    if config.pool == "task":
        assets = tuple(library.get(name) for name in objects)
    else:
        if corpus is None:
            raise TrainingError("a corpus pool needs the corpus; build it with `ocplace corpus build`")
        groups = validation_groups(corpus, library, config)
        large = config.large_models == "shrink"
        assets = tuple(
            a
            for a in protocol_assets(corpus, library, config.protocol, large, config.cutouts)
            if noun_group(a.human_name) not in groups
        )
        names = {a.name for a in assets}
        asked: list[tuple[str, str, Collection[str]]] = [("the large tier", "--large", corpus.large)] if large else []
        for source in config.cutouts:
            tier = {name for name, of in corpus.cutouts.items() if of == source}
            asked.append((f"the cut-outs of {source}", f"--cutouts {source}", tier))
        for what, flag, members in asked:
            if not set(members) & names:
                raise TrainingError(
                    f"the recipe asks for {what} of the corpus, and no model of it outside the held-out categories "
                    f"is built: run `ocplace corpus build {flag}`"
                )
    if config.max_objects > 0:
        assets = assets[: config.max_objects]
    _check_pool(library, corpus, assets, textures, config)
    return TrainingPool(assets, tuple(textures))


def _check_pool(library, corpus, assets, textures, config: RenderConfig) -> None:
    allowed_split = "seen" if config.pool == "task" else CORPUS_SPLIT
    leaked = [a.name for a in assets if a.split != allowed_split]
    if config.pool != "task":
        library_sources = {a.source for a in library.objects.values()}
        leaked += [a.name for a in assets if a.name in library.objects or a.source in library_sources]
        groups = validation_groups(corpus, library, config)  # every held-out model is of one of these
        leaked += [a.name for a in assets if noun_group(a.human_name) in groups]
        if config.large_models != "shrink":
            leaked += [a.name for a in assets if a.name in corpus.large]
        leaked += [a.name for a in assets if a.name in corpus.cutouts and corpus.cutouts[a.name] not in config.cutouts]
    leaked += [t for t in textures if library.textures[t].split != "seen"]
    if leaked:
        raise TrainingError(f"objects or textures pretraining may not render are in its pool: {sorted(set(leaked))}")
    if config.pool != "task":
        copies = benchmark_copies(library, assets)
        if copies:
            raise TrainingError(
                "corpus models with the geometry of a benchmark object (descriptors and vertices match) are in the "
                f"pretraining pool: {copies}; remove their source from the corpus and rebuild it"
            )


def benchmark_copies(library, assets) -> dict[str, str]:
    """The models of `assets` whose mesh is a benchmark library object's (`sim.library.shape_descriptor`: the
    descriptors close, then the vertices on each other), mapped to that object: the guard against a copied
    mesh under another name or source label."""
    benchmark = {name: asset_descriptor(obj) for name, obj in library.objects.items()}
    benchmark_vertices = {}  # read once per library object that some model comes close to
    copies = {}
    for asset in assets:
        descriptor = asset_descriptor(asset)
        close = [name for name, other in benchmark.items() if same_shape(descriptor, other)]
        if not close:
            continue
        vertices = asset_vertices(asset)
        for name in close:
            if name not in benchmark_vertices:
                benchmark_vertices[name] = asset_vertices(library.get(name))
            if same_mesh(vertices, benchmark_vertices[name]):
                copies[asset.name] = name
                break
    return copies
