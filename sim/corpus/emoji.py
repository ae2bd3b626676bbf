"""Microsoft's Fluent Emoji in 3-D style (npm `@lobehub/fluent-emoji-3d` 1.1.0, MIT): shaded 256 px images of
things, as cut-out models of the pretraining corpus (`sim.corpus.cutout`), fetched into the cache on first use.

Which emoji, and what each is called, was fixed from Unicode's names before any score (docs/offline_backbone.md,
"Cut-outs"): single code points (a variation selector allowed; no sequences: skin tones, families,
professions, flags) in the pictograph blocks U+1F330-U+1F6FF and U+1F900-U+1FAFF, whose Unicode name holds
none of `EXCLUDED_WORDS` (faces, hands, people, signs, symbols, shapes): 767 emoji. Each is named by its
Unicode name in lower case ("SAKE BOTTLE AND CUP" -> "sake bottle and cup").
"""

from __future__ import annotations

import os
import subprocess
import tarfile
import tempfile
import unicodedata
from pathlib import Path

from ocplace.errors import MissingAssetPackage
from ocplace.paths import inside, sources_cache
from ocplace.sim.corpus.catalogue import CatalogueEntry
from ocplace.sim.corpus.cutout import SIZE_CM

EMOJI_PACKAGE = "@lobehub/fluent-emoji-3d"
EMOJI_VERSION = "1.1.0"
EMOJI_TARBALL = f"lobehub-fluent-emoji-3d-{EMOJI_VERSION}.tgz"
EMOJI_ENV = "OCPLACE_EMOJI_SOURCE"  # a folder of `<code points>.webp` instead of the fetched package's
EMOJI_INSTALL_HINT = (
    f"npm pack {EMOJI_PACKAGE}@{EMOJI_VERSION} --pack-destination <cache>/sources (Node.js's npm; "
    "`ocplace corpus build --cutouts emoji` unpacks it)"
)
EMOJI_CATALOGUE = "fluentemoji"
EMOJI_LICENCE = "MIT (Microsoft Fluent Emoji, packaged by LobeHub as @lobehub/fluent-emoji-3d 1.1.0)"
EMOJI_CREATOR = "Microsoft (Fluent Emoji)"
BLOCKS = ((0x1F330, 0x1F6FF), (0x1F900, 0x1FAFF))
EXCLUDED_WORDS = frozenset(
    "face hand hands finger fingers fist thumbs person people man woman men women boy girl child adult baby older "
    "sign symbol arrow arrows button square squared circle circled heart mark clock oclock flag silhouette letter "
    "digit keycap triangle diamond shape dot information speech balloon zodiac".split()
)
_DOWNLOAD_TIMEOUT_S = 300


def emoji_dir() -> Path:
    """Where the emoji images are: `$OCPLACE_EMOJI_SOURCE`, else the package's folder in the cache."""
    explicit = os.environ.get(EMOJI_ENV)
    return Path(explicit) if explicit else sources_cache() / f"fluent-emoji-3d-{EMOJI_VERSION}" / "package" / "assets"


def fetch_emoji() -> Path:
    """`emoji_dir()`; the package's folder is unpacked on first use from its tarball in `<cache>/sources/`
    (fetched there with `npm pack` when missing; a folder `$OCPLACE_EMOJI_SOURCE` names is never fetched
    into). MissingAssetPackage when neither works."""
    folder = emoji_dir()
    if folder.is_dir() or os.environ.get(EMOJI_ENV):
        return folder
    sources = sources_cache()
    sources.mkdir(parents=True, exist_ok=True)
    tarball = sources / EMOJI_TARBALL
    if not tarball.is_file():
        _npm_pack(sources)
    with tempfile.TemporaryDirectory(prefix=".unpack.", dir=sources, ignore_cleanup_errors=True) as work:
        try:
            with tarfile.open(tarball) as archive:
                archive.extractall(work, filter="data")  # refuses members that lead outside `work`
        except (OSError, tarfile.TarError) as error:
            raise MissingAssetPackage(f"{tarball} cannot be unpacked ({error}); delete it and rerun") from error
        os.replace(work, folder.parent.parent)
    return folder


def _npm_pack(sources: Path) -> None:
    """Fetches the package's tarball into `sources`, with npm's own cache in a temporary folder there (npm would
    otherwise write into ~/.npm, outside the cache)."""
    with tempfile.TemporaryDirectory(prefix=".npm.", dir=sources) as npm_cache:
        command = ["npm", "pack", f"{EMOJI_PACKAGE}@{EMOJI_VERSION}", "--pack-destination", str(sources)]
        command += ["--cache", npm_cache, "--no-update-notifier", "--no-fund", "--no-audit"]
        try:
            subprocess.run(command, check=True, capture_output=True, text=True, timeout=_DOWNLOAD_TIMEOUT_S)
        except (OSError, subprocess.SubprocessError) as error:
            lines = (getattr(error, "stderr", None) or str(error)).strip().splitlines()
            raise MissingAssetPackage(
                f"the emoji are not in {sources} and `npm pack` failed ({lines[-1] if lines else error}); "
                f"install them: {EMOJI_INSTALL_HINT}"
            ) from error


def emoji_name(stem: str) -> str:
    """The name of the emoji `<code points>` (`1f34e` -> "red apple"), "" when it is not one the rule keeps."""
    points = [p for p in stem.lower().split("-") if p != "fe0f"]
    try:
        (point,) = (int(p, 16) for p in points)
        name = unicodedata.name(chr(point)).lower()
    except ValueError:  # a sequence, not hexadecimal, or a code point without a name
        return ""
    if not any(low <= point <= high for low, high in BLOCKS) or set(name.replace("-", " ").split()) & EXCLUDED_WORDS:
        return ""
    return name


def read_emoji(source: Path) -> tuple[list[CatalogueEntry], list[tuple[str, str]]]:
    """The emoji of `source` the rule keeps, as catalogue entries (in file order; `model` is the file name), and
    `(file, why)` for each that cannot be used (a file that resolves outside `source`)."""
    entries: list[CatalogueEntry] = []
    problems: list[tuple[str, str]] = []
    for image in sorted(source.glob("*.webp")):
        name = emoji_name(image.stem)
        if not name:
            continue
        try:
            inside(source, image.name)
        except ValueError:
            problems.append((image.name, "it leads outside the emoji folder (a symlink?)"))
            continue
        entries.append(
            CatalogueEntry(EMOJI_CATALOGUE, len(entries), name, "emoji", SIZE_CM, image.name, None, EMOJI_CREATOR)
        )
    return entries, problems
