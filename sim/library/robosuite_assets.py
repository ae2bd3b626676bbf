"""robosuite's object meshes and textures, taken from its wheel into the cache.

robosuite (MIT) ships its tabletop objects (bread, lemon, can, ...) inside a 157 MB wheel that also
holds robots, controllers and a dependency list ocplace does not want. So the library build
downloads the wheel once with pip (`--no-deps`, by package name from the configured index), keeps
only `robosuite/models/assets/objects/`, the textures those objects name and the licence, and
deletes the wheel: about 5 MB stay in `<cache>/sources/robosuite-<version>/`.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from ocplace.errors import MissingAssetPackage
from ocplace.paths import honour_umask, sources_cache

ROBOSUITE_VERSION = "1.5.2"
WHEEL_NAME = f"robosuite-{ROBOSUITE_VERSION}-py3-none-any.whl"
_ASSETS = "robosuite/models/assets/"
_DOWNLOAD_TIMEOUT_S = 600


def robosuite_root() -> Path:
    """`<cache>/sources/robosuite-<version>/` with `objects/`, `textures/` and `LICENSE`.

    Fetched on first use: from a wheel already in `<cache>/sources/` (copy one there on a
    machine without PyPI), else downloaded with pip. Raises `MissingAssetPackage` when neither
    works.
    """
    root = sources_cache() / f"robosuite-{ROBOSUITE_VERSION}"
    if (root / "LICENSE").is_file():
        return root
    root.parent.mkdir(parents=True, exist_ok=True)
    wheel = root.parent / WHEEL_NAME
    if wheel.is_file():
        _extract(wheel, root)
        return root
    with tempfile.TemporaryDirectory(prefix=".download.", dir=root.parent) as download:
        _extract(_download(Path(download), root.parent), root)
    return root


def _download(directory: Path, sources: Path) -> Path:
    command = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        "--quiet",
        "--only-binary",
        ":all:",
        f"robosuite=={ROBOSUITE_VERSION}",
        "-d",
        str(directory),
    ]
    try:
        subprocess.run(command, check=True, capture_output=True, text=True, timeout=_DOWNLOAD_TIMEOUT_S)
    except (OSError, subprocess.SubprocessError) as error:
        lines = (getattr(error, "stderr", None) or str(error)).strip().splitlines()
        reason = lines[-1] if lines else type(error).__name__
        raise MissingAssetPackage(
            f"robosuite's object meshes are not in {sources} and `pip download robosuite=={ROBOSUITE_VERSION}` "
            f"failed ({reason}); where PyPI is reachable run "
            f"`python -m pip download --no-deps robosuite=={ROBOSUITE_VERSION} -d {sources}`, then rerun "
            "`ocplace assets build`"
        ) from error
    return directory / WHEEL_NAME


def _kept_members(archive: zipfile.ZipFile) -> dict[str, str]:
    """Archive member -> path under the root: every object file and the textures objects name."""
    names = archive.namelist()
    objects = [n for n in names if n.startswith(_ASSETS + "objects/") and not n.endswith("/")]
    referring = b"".join(archive.read(n) for n in objects if n.endswith((".xml", ".mtl")))
    textures = [
        n
        for n in names
        if n.startswith(_ASSETS + "textures/") and not n.endswith("/") and n.rsplit("/", 1)[1].encode() in referring
    ]
    kept = {n: n[len(_ASSETS) :] for n in objects + textures}
    licences = [n for n in names if n.endswith("dist-info/licenses/LICENSE") or n.endswith("dist-info/LICENSE")]
    if not objects or not licences:
        raise MissingAssetPackage(
            f"{archive.filename} holds no robosuite objects or licence; delete it and rerun `ocplace assets build`"
        )
    return kept | {licences[0]: "LICENSE"}


def _extract(wheel: Path, root: Path) -> None:
    """Writes the kept members into a temp folder and renames it onto `root` in one step."""
    try:
        archive = zipfile.ZipFile(wheel)
    except (OSError, zipfile.BadZipFile) as error:
        raise MissingAssetPackage(
            f"cannot read {wheel} ({error}); delete it and rerun `ocplace assets build`"
        ) from error
    work = Path(tempfile.mkdtemp(prefix=f".{root.name}.", dir=root.parent))
    try:
        with archive:
            for member, relative in _kept_members(archive).items():
                target = work / relative
                if not target.resolve().is_relative_to(work.resolve()):
                    raise MissingAssetPackage(
                        f"{wheel} names a file outside its folder ({member!r}); delete it "
                        "and rerun `ocplace assets build`"
                    )
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(archive.read(member))
        if not (root / "LICENSE").is_file():  # else a concurrent build finished first
            shutil.rmtree(root, ignore_errors=True)
            honour_umask(work)
            os.rename(work, root)
    finally:
        shutil.rmtree(work, ignore_errors=True)
