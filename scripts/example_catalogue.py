"""Writes a small example catalogue of your own objects: seven meshes made here (no download), one textured.

    python scripts/example_catalogue.py my_objects
    ocplace assets build --catalogue my_objects/catalogue.json

The tutorial in docs/library.md ("Test on your own objects") and its test run on it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

# (name, human name, category, shape, size in mm, colour); the categories are none of the benchmark's training ones.
OBJECTS = (
    ("lab_canister", "green canister", "canister", "cylinder", (70, 110), (0.1, 0.6, 0.2)),
    ("lab_puck", "black puck", "puck", "cylinder", (80, 25), (0.05, 0.05, 0.05)),
    ("lab_beacon", "orange beacon", "beacon", "cone", (80, 120), (0.95, 0.45, 0.05)),
    ("lab_marble", "blue marble", "marble", "sphere", (60, 60), (0.1, 0.25, 0.9)),
    ("lab_crate", "wooden crate", "crate", "box", (140, 90), (0.6, 0.4, 0.2)),
    ("lab_capsule", "white capsule", "capsule", "capsule", (50, 130), (0.92, 0.92, 0.9)),
    ("lab_checker", "checkered tile", "tile", "textured box", (110, 20), (1.0, 1.0, 1.0)),
)


def _mesh(shape: str, width: float, height: float) -> trimesh.Trimesh:
    if shape == "cylinder":
        return trimesh.creation.cylinder(radius=width / 2, height=height, sections=48)
    if shape == "cone":
        return trimesh.creation.cone(radius=width / 2, height=height, sections=48)
    if shape == "sphere":
        return trimesh.creation.icosphere(subdivisions=3, radius=width / 2)
    if shape == "capsule":
        return trimesh.creation.capsule(radius=width / 2, height=height - width, count=[24, 24])
    return trimesh.creation.box(extents=(width, width * 0.8, height))


def _checker_texture(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The box with UVs from its top view and a red-and-white checker image."""
    mesh = trimesh.Trimesh(mesh.vertices[mesh.faces].reshape(-1, 3), np.arange(len(mesh.faces) * 3).reshape(-1, 3))
    low, high = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    uv = (mesh.vertices[:, :2] - low[:2]) / (high[:2] - low[:2])
    rows, columns = np.indices((64, 64)) // 8
    cells = (rows + columns) % 2
    image = np.where(cells[..., None] == 1, [220, 30, 30], [245, 245, 245]).astype(np.uint8)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(image))
    return mesh


def write_example(out: Path) -> Path:
    """The meshes (in millimetres, as a scanner writes them) and `catalogue.json` in `out`; returns the file."""
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    entries = []
    for name, human, category, shape, (width, height), colour in OBJECTS:
        mesh = _mesh(shape.split()[-1], width, height)
        entry: dict[str, object] = {
            "name": name,
            "human_name": human,
            "category": category,
            "units": "mm",
            "licence": "CC0 (made here)",
        }
        if shape.startswith("textured"):
            folder = out / "meshes" / name
            folder.mkdir(exist_ok=True)
            _checker_texture(mesh).export(folder / "model.obj")
            entry |= {"mesh": f"meshes/{name}/model.obj", "texture": f"meshes/{name}/material_0.png"}
        else:
            mesh.export(out / "meshes" / f"{name}.obj")
            entry |= {"mesh": f"meshes/{name}.obj", "rgba": list(colour)}
        entries.append(entry)
    catalogue = {
        "format": "ocplace-catalogue",
        "version": 1,
        "name": "lab",
        "subsets": {"lab": {"new_categories": True}},
        "objects": entries,
    }
    path = out / "catalogue.json"
    path.write_text(json.dumps(catalogue, indent=1) + "\n")
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder to write the meshes and catalogue.json into")
    print(write_example(parser.parse_args().out))


if __name__ == "__main__":
    main()
