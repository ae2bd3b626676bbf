"""The pretraining corpus in the cache: converting the selected catalogue models once, the manifest,
the attribution file, and reading it back.

Layout (`ocplace.paths.corpus_cache()`):
    manifest.json          every catalogue model: kept (its folder) or skipped (why), the rule, the catalogues
    ATTRIBUTION.md         who made each converted model and under which licence (CC-BY asks for it)
    models/<key>-<hash>/   one converted model: part_*.obj/png, hull_000.obj, object.xml, asset.json (last)
    tmp/                   conversions in progress; a killed one leaves a folder here that the next build removes

A rerun converts only what is missing, so a build killed at any point resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import os
import re
import signal
import types
from collections.abc import Mapping, Sequence
from pathlib import Path

from ocplace.errors import CorpusError, MissingAssetPackage
from ocplace.paths import (
    corpus_cache,
    file_sha256,
    inside,
    refuse_links,
    remove_abandoned_tmp,
    remove_tree,
    write_text_atomic,
)
from ocplace.runtime.progress import progress_bar
from ocplace.sim.corpus.catalogue import CatalogueEntry, read_entries
from ocplace.sim.corpus.convert import ConversionConfig, ConversionResult, convert_model, read_converted
from ocplace.sim.corpus.cutout_sources import CUTOUT_SOURCES, CutoutSource
from ocplace.sim.library.types import ObjectAsset

DEFAULT_SOURCE = Path("/usr/share/sweethome3d/furniture")
SOURCE_ENV = "OCPLACE_CORPUS_SOURCE"  # a folder of .sh3f catalogues instead of Debian's
INSTALL_HINT = "sudo apt-get install sweethome3d-furniture (Debian/Ubuntu; `make setup` does it)"
CONVERSION_VERSION = 2  # bump when conversion writes something else: every model converts again (2: checksums)
MANIFEST_FILE = "manifest.json"
ATTRIBUTION_FILE = "ATTRIBUTION.md"
MODELS_DIRNAME = "models"
TMP_DIRNAME = "tmp"
# Set to N, `build_corpus` SIGKILLs its process right after committing its Nth converted model, so the
# resume test crashes a build at a known point instead of racing a kill against it. Unset: off.
DIE_AFTER_MODELS_ENV = "OCPLACE_TEST_DIE_AFTER_MODELS"
MACHINE_ERRORS = re.compile(r"\[Errno (28|30|122)\]")  # ENOSPC, EROFS, EDQUOT in a recorded skip reason
# /usr/share/doc/sweethome3d-furniture/copyright, per catalogue.
LICENCES = {
    "BlendSwap-CC-0": "CC0-1.0",
    "BlendSwap-CC-BY": "CC-BY-3.0",
    "KatorLegaz": "CC-BY-3.0-US (Andrew Kator & Jennifer Legaz)",
    "Reallusion": "CC-BY-3.0-US (Reallusion)",
    "Scopia": "CC-BY-3.0 (Scopia Visual Interfaces Systems, s.l.)",
}

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class CorpusModel:
    """A catalogue model and what became of it."""

    entry: CatalogueEntry
    status: str  # "ok", "rejected" (by the size rule) or "skipped" (could not be used, or too many faces)
    reason: str  # why it is not "ok"
    folder: str = ""  # of an "ok" model, relative to the corpus root
    asset: ObjectAsset | None = None
    large: bool = False  # of the `large` tier: over the tabletop size, shrunk (`SelectionRule.is_large`)
    cutout: str = ""  # of a cut-out: its source (`sim.corpus.cutout_sources`); rendered only when a recipe asks


@dataclasses.dataclass(frozen=True)
class Corpus:
    """The converted corpus: `assets` by key, in key order; `models` every catalogue model with its fate."""

    root: Path
    models: tuple[CorpusModel, ...]
    assets: Mapping[str, ObjectAsset]

    @functools.cached_property
    def large(self) -> frozenset[str]:
        """The names of the converted models of the `large` tier (a recipe renders them only when it asks)."""
        return frozenset(m.asset.name for m in self.models if m.asset is not None and m.status == "ok" and m.large)

    @functools.cached_property
    def cutouts(self) -> Mapping[str, str]:
        """The source of each converted cut-out, by name (a recipe renders them only when it asks for the source)."""
        return types.MappingProxyType(
            {m.asset.name: m.cutout for m in self.models if m.asset is not None and m.status == "ok" and m.cutout}
        )

    def summary(self) -> str:
        counts = {status: sum(m.status == status for m in self.models) for status in ("ok", "rejected", "skipped")}
        return (
            f"{counts['ok']} models converted ({len({a.human_name for a in self.assets.values()})} names, "
            f"{len(self.large)} of the large tier, {len(self.cutouts)} cut-outs), "
            f"{counts['rejected']} outside the size rule, {counts['skipped']} skipped"
        )


def source_dir(source: str | os.PathLike | None = None) -> Path:
    """Where the catalogues are: `source`, else `$OCPLACE_CORPUS_SOURCE`, else Debian's package folder."""
    return Path(source or os.environ.get(SOURCE_ENV) or DEFAULT_SOURCE)


def _catalogues(source: Path) -> list[Path]:
    named = sorted(source.glob("*.sh3f")) if source.is_dir() else []
    found = [path for path in named if path.is_file()]
    if len(found) < len(named):  # a FIFO or a device would block or stream forever
        log.warning("not regular files, left out: %s", ", ".join(p.name for p in named if p not in found))
    if not found:
        raise CorpusError(f"no furniture catalogues (*.sh3f) in {source}; install them: {INSTALL_HINT}")
    return found


def _model_folder(entry: CatalogueEntry, catalogue_hash: str, config: ConversionConfig) -> str:
    key = json.dumps(
        [CONVERSION_VERSION, catalogue_hash, dataclasses.asdict(entry), dataclasses.asdict(config)], sort_keys=True
    )
    return f"{MODELS_DIRNAME}/{entry.key}-{hashlib.sha256(key.encode()).hexdigest()[:12]}"


def _reuse(root: Path, folder: str) -> ObjectAsset | None:
    """The converted model in `folder` when it is there and as converted; a damaged one is warned about (and
    converted again by the build)."""
    try:
        directory = inside(root, folder)
        if not directory.exists():
            return None
        return read_converted(directory)
    except (OSError, ValueError, KeyError, TypeError) as error:
        log.warning("corpus model %s cannot be used (%s): it is converted again", folder, error)
        return None


def build_corpus(
    source: str | os.PathLike | None = None,
    config: ConversionConfig = ConversionConfig(),
    progress: bool = True,
    large: bool = False,
    cutouts: Sequence[str] = (),
    cutout_folders: Mapping[str, str | os.PathLike] | None = None,
) -> Corpus:
    """Converts the selected models of every catalogue in `source_dir(source)` that are not converted yet
    into `corpus_cache()`, writes the manifest and the attribution file, and returns the corpus. `large`:
    also the models over the tabletop size (`SelectionRule.is_large`), shrunk like every model; without it
    the ones an earlier build converted are kept, and no new one is converted. `cutouts`: also the images of
    these cut-out sources (`CUTOUT_SOURCES`: "stamps", "emoji"), the same way, each from its own folder or from
    `cutout_folders[name]`; a missing source is a warning saying how to install it.

    Models that cannot be used (a member outside its folder, a missing texture, a failed load, no
    volume, a truncated archive; a stamp without alpha or description) are skipped with one warning listing
    them all; CorpusError when nothing usable is left, no catalogue is found, or a cut-out source was asked for
    and none of its images is usable.
    """
    source = source_dir(source)
    root = corpus_cache()
    refuse_links(root / MODELS_DIRNAME)  # before anything is written into it
    remove_abandoned_tmp(root / TMP_DIRNAME)
    known_skips = _previous_skips(root)
    models: list[CorpusModel] = []
    catalogues: list[dict[str, object]] = []  # the manifest's entry of each catalogue file
    todo = []
    for path in _catalogues(source):
        licence = LICENCES.get(path.stem, "see the catalogue's LICENSE.TXT")
        try:
            entries, problems = read_entries(path)
        except CorpusError as error:
            catalogues.append({"file": path.name, "error": str(error)})
            models.append(CorpusModel(_unread(path), "skipped", str(error)))
            continue
        catalogue_hash = file_sha256(path)
        catalogues.append({"file": path.name, "sha256": catalogue_hash, "licence": licence, "models": len(entries)})
        models += [CorpusModel(_unread(path, index, name), "skipped", why) for index, name, why in problems]
        for entry in entries:
            reason = config.rule.size_problem(entry)
            tier = bool(reason) and config.rule.is_large(entry)
            if tier and config.rule.large_problem(entry, 100 * config.max_extent_m):
                reason, tier = config.rule.large_problem(entry, 100 * config.max_extent_m), False
            if reason and not tier:
                models.append(CorpusModel(entry, "rejected", reason))
                continue
            not_asked = f"{reason}; the large tier was not asked for"
            model, task = _plan(
                entry, catalogue_hash, path, licence, config, root, known_skips, large, not_asked, large=tier
            )
            models.append(model)
            if task:
                todo.append((len(models) - 1, *task))
    unknown = set(cutouts) - set(CUTOUT_SOURCES)
    if unknown:
        raise CorpusError(f"unknown cut-out sources {sorted(unknown)}; the sources are {', '.join(CUTOUT_SOURCES)}")
    cutout_records = {}
    for name, cutout_source in CUTOUT_SOURCES.items():  # `source` stays the catalogues' folder the manifest records
        folder = _cutout_folder(cutout_source, name in cutouts, cutout_folders or {})
        record = _plan_cutouts(cutout_source, folder, name in cutouts, config, root, known_skips, models, todo)
        if record:
            catalogues.append(record)
            cutout_records[name] = record
    die_after = int(os.environ.get(DIE_AFTER_MODELS_ENV, "0"))
    for count, (index, entry, path, licence, folder) in enumerate(
        progress_bar(todo, desc="corpus", unit="model", enabled=progress), start=1
    ):
        result = convert_model(entry, path, licence, config, root / folder, root / TMP_DIRNAME)
        models[index] = _outcome(result, models[index])
        if count == die_after:
            os.kill(os.getpid(), signal.SIGKILL)
    corpus = _finish(root, source, catalogues, models, config)
    skipped = [m for m in corpus.models if m.status == "skipped"]
    if skipped:
        # Said once, when the build looked at them; a cached corpus only recalls it at debug level.
        log.log(
            logging.WARNING if todo or any("error" in c for c in catalogues) else logging.DEBUG,
            "corpus: %d models skipped: %s",
            len(skipped),
            "; ".join(f"{m.entry.catalogue}#{m.entry.index} {m.entry.name} ({m.reason})" for m in skipped),
        )
    if not corpus.assets:
        raise CorpusError(f"no usable model in the catalogues of {source}: {corpus.summary()}")
    for name in set(cutouts) & set(cutout_records):
        if name not in corpus.cutouts.values():
            raise CorpusError(f"no usable image in {cutout_records[name]['file']}: every one was skipped (see above)")
    return corpus


def _plan(entry, digest: str, path: Path, licence, config, root: Path, known_skips, asked: bool, not_asked, **tier):
    """The model `entry` is now (reused, skipped before, or to convert: then also its conversion task).
    `tier`: `large=` or `cutout=`, the tier the model is of; `asked`: whether new ones of that tier convert,
    `not_asked`: the reason it is rejected when they do not."""
    folder = _model_folder(entry, digest, config)
    asset = _reuse(root, folder)
    if any(tier.values()) and asset is None and not asked:
        return CorpusModel(entry, "rejected", not_asked), None
    if asset is None and folder in known_skips:  # the same bytes and settings fail the same way
        return CorpusModel(entry, "skipped", known_skips[folder], folder, **tier), None
    model = CorpusModel(entry, "ok" if asset else "todo", "", folder, asset, **tier)
    return model, (None if asset else (entry, path, licence, folder))


def _plan_cutouts(source: CutoutSource, folder: Path | None, asked: bool, config, root, known_skips, models, todo):
    """Adds the images of `source` in `folder` to `models` (and what to convert to `todo`); their catalogue
    record, or None when there are none (a warning naming how to install them when they were asked for)."""
    if folder is None or not folder.is_dir():
        if asked:
            hint = source.install_hint
            log.warning("corpus: no %s in %s, so none as cut-outs; install them: %s", source.name, folder, hint)
        return None
    entries, problems = source.read(folder)
    for relative, why in problems:
        unread = CatalogueEntry(source.catalogue, 0, relative, "", (0.0,) * 3, relative, None, "")
        models.append(CorpusModel(unread, "skipped", why))
    for entry in entries:
        image = folder / entry.model
        not_asked = f"the cut-out source {source.name} was not asked for"
        digest = file_sha256(image)
        model, task = _plan(
            entry, digest, image, source.licence, config, root, known_skips, asked, not_asked, cutout=source.name
        )
        models.append(model)
        if task:
            todo.append((len(models) - 1, *task))
    return {"file": f"{source.name}:{folder}", "licence": source.licence, "models": len(entries)}


def _cutout_folder(source: CutoutSource, asked: bool, folders: Mapping[str, str | os.PathLike]) -> Path | None:
    if source.name in folders:
        return Path(folders[source.name])
    try:
        return source.locate(asked)
    except MissingAssetPackage as error:
        log.warning("corpus: %s", error)
        return None


def _previous_skips(root: Path) -> dict[str, str]:
    """Why each model the last build skipped was skipped, by its folder key (not converted again)."""
    try:
        records = json.loads((root / MANIFEST_FILE).read_text())["models"]
        skipped = [r for r in records if r["status"] == "skipped" and r["folder"]]
        # Builds before issue 43 recorded a full or read-only disk as the model's fault: such models convert again.
        return {r["folder"]: r["reason"] for r in skipped if not MACHINE_ERRORS.search(r["reason"])}
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def _unread(path: Path, index: int = 0, name: str = "") -> CatalogueEntry:
    """A placeholder entry for a model of `path` (or the whole catalogue: index 0) that could not be read."""
    return CatalogueEntry(path.stem, index, name or path.name, "", (0.0, 0.0, 0.0), "", None, "")


def _outcome(result: ConversionResult, planned: CorpusModel) -> CorpusModel:
    if result.status == "ok":
        return dataclasses.replace(planned, status="ok", asset=result.asset)
    return dataclasses.replace(planned, status="skipped", reason=result.reason)


def _finish(root: Path, source: Path, catalogues: list[dict[str, object]], models: list[CorpusModel], config) -> Corpus:
    records = [
        {
            "key": m.entry.key,
            "status": m.status,
            "reason": m.reason,
            "folder": m.folder,
            "large": m.large,
            "cutout": m.cutout,
            **dataclasses.asdict(m.entry),
        }
        for m in models
    ]
    manifest = {
        "version": CONVERSION_VERSION,
        "source": str(source),
        "catalogues": catalogues,
        "conversion": dataclasses.asdict(config),
        "models": records,
    }
    write_text_atomic(root / MANIFEST_FILE, json.dumps(manifest, indent=1) + "\n")
    write_text_atomic(root / ATTRIBUTION_FILE, attribution(models, catalogues))
    _remove_unreferenced(root, {m.folder for m in models if m.status == "ok"})
    return _corpus(root, models)


def _corpus(root: Path, models: list[CorpusModel]) -> Corpus:
    kept = sorted((m for m in models if m.status == "ok"), key=lambda m: m.entry.key)
    assets = types.MappingProxyType({m.asset.name: m.asset for m in kept if m.asset is not None})
    return Corpus(root, tuple(models), assets)


def _remove_unreferenced(root: Path, folders: set[str]) -> None:
    """Model folders of earlier conversions (another catalogue version or setting)."""
    models_dir = root / MODELS_DIRNAME
    refuse_links(models_dir)
    if models_dir.is_dir():
        for path in models_dir.iterdir():
            if f"{MODELS_DIRNAME}/{path.name}" not in folders:
                remove_tree(path)


def attribution(models: list[CorpusModel], catalogues: list[dict[str, object]]) -> str:
    """The attribution file: every converted model, its creator, catalogue and licence."""
    lines = [
        "# Attribution of the ocplace pretraining corpus",
        "",
        "Converted (rescaled, re-oriented, textures resized) from Debian's `sweethome3d-furniture`",
        "catalogues, http://www.sweethome3d.com/importModels.jsp; licences as in",
        "/usr/share/doc/sweethome3d-furniture/copyright. Cut-outs, images extruded into thin prisms: catalogue",
        "`tuxpaint`, Tux Paint's stamps (Debian's `tuxpaint-stamps-default`, GPL-2.0-or-later, see",
        "/usr/share/doc/tuxpaint-stamps-default/copyright); catalogue `fluentemoji`, Microsoft's Fluent Emoji",
        "(npm `@lobehub/fluent-emoji-3d` 1.1.0, MIT).",
        "",
        "| catalogue | licence |",
        "| --- | --- |",
        *(f"| {c['file']} | {c.get('licence', c.get('error', ''))} |" for c in catalogues),
        "",
        "| model | name | creator | licence |",
        "| --- | --- | --- | --- |",
    ]
    for m in models:
        if m.status == "ok" and m.asset is not None:
            lines.append(
                f"| {m.entry.key} | {m.entry.name} | {m.entry.creator or m.entry.catalogue} | {m.asset.licence} |"
            )
    return "\n".join(lines) + "\n"


def _model_of(root: Path, record: dict) -> CorpusModel:
    fields = {field.name: record[field.name] for field in dataclasses.fields(CatalogueEntry)}
    rotation = fields["rotation"]
    entry = CatalogueEntry(
        **fields | {"size_cm": tuple(fields["size_cm"]), "rotation": None if rotation is None else tuple(rotation)}
    )
    asset = read_converted(inside(root, record["folder"])) if record["status"] == "ok" else None
    return CorpusModel(
        entry,
        record["status"],
        record["reason"],
        record["folder"],
        asset,
        record.get("large", False),
        record.get("cutout") or "",
    )


def load_corpus() -> Corpus:
    """The corpus as last built, without touching the catalogues; CorpusError when it is not built."""
    root = corpus_cache()
    try:
        manifest = json.loads((root / MANIFEST_FILE).read_text())
        if manifest.get("version") != CONVERSION_VERSION:
            raise ValueError("built by another ocplace version")
        models = [_model_of(root, record) for record in manifest["models"]]
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as error:
        raise CorpusError(
            f"the corpus in {root} is missing, incomplete or damaged ({error}); run `ocplace corpus build`"
        ) from error
    return _corpus(root, models)
