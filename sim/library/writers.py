"""Writing a processed object: OBJ meshes, a standalone MJCF and a URDF over the same files."""

from __future__ import annotations

import io
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np

from ocplace.sim.library.meshes import TexturedMesh
from ocplace.sim.library.processing import Hull, MassProperties

VISUAL_OBJ = "visual.obj"
VISUAL_MTL = "visual.mtl"
TEXTURE_PNG = "texture.png"
MJCF_FILE = "object.xml"
URDF_FILE = "object.urdf"
FRICTION = (0.9, 0.005, 0.0001)  # sliding, torsional, rolling: a grippy tabletop object


def hull_filename(index: int) -> str:
    return f"hull_{index:03d}.obj"


def _rows(array: np.ndarray, fmt: str) -> str:
    buffer = io.StringIO()
    np.savetxt(buffer, array, fmt=fmt)
    return buffer.getvalue()


def write_visual_obj(directory: Path, mesh: TexturedMesh) -> None:
    """OBJ with one UV per vertex (seams already split) and an MTL naming the texture."""
    parts = []
    if mesh.texture is not None:
        (directory / VISUAL_MTL).write_text(f"newmtl material\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd {TEXTURE_PNG}\n")
        parts.append(f"mtllib {VISUAL_MTL}\nusemtl material\n")
    parts.append(_rows(mesh.vertices, "v %.6f %.6f %.6f"))
    faces = mesh.faces + 1
    if mesh.uv is not None:
        parts.append(_rows(mesh.uv, "vt %.6f %.6f"))
        parts.append(_rows(np.repeat(faces, 2, axis=1), "f %d/%d %d/%d %d/%d"))
    else:
        parts.append(_rows(faces, "f %d %d %d"))
    (directory / VISUAL_OBJ).write_text("".join(parts))


def write_hull_obj(path: Path, hull: Hull) -> None:
    path.write_text(_rows(hull.vertices, "v %.6f %.6f %.6f") + _rows(hull.faces + 1, "f %d %d %d"))


def _text(values) -> str:
    return " ".join(f"{float(v):.6g}" for v in values)


def _xml(element: ElementTree.Element) -> str:
    ElementTree.indent(element)
    return ElementTree.tostring(element, encoding="unicode") + "\n"


def mjcf_text(name: str, textured: bool, rgba, num_hulls: int, mass: MassProperties) -> str:
    """A standalone MuJoCo model: one free body with a visual mesh and convex hull geoms.

    Visual geom in group 2 (rendered, no contact); hulls in group 3 (contact, hidden by
    default). Mass and inertia are explicit, so MuJoCo does not re-derive them from meshes.
    """
    root = ElementTree.Element("mujoco", model=name)
    ElementTree.SubElement(root, "compiler", angle="radian", inertiafromgeom="false")
    asset = ElementTree.SubElement(root, "asset")
    material = f"{name}_material"
    if textured:
        ElementTree.SubElement(asset, "texture", name=f"{name}_texture", type="2d", file=TEXTURE_PNG)
        ElementTree.SubElement(
            asset, "material", name=material, texture=f"{name}_texture", rgba="1 1 1 1", specular="0.2", shininess="0.2"
        )
    else:
        ElementTree.SubElement(asset, "material", name=material, rgba=_text(rgba), specular="0.2", shininess="0.2")
    ElementTree.SubElement(asset, "mesh", name=f"{name}_visual", file=VISUAL_OBJ)
    for index in range(num_hulls):
        ElementTree.SubElement(asset, "mesh", name=f"{name}_hull_{index:03d}", file=hull_filename(index))
    worldbody = ElementTree.SubElement(root, "worldbody")
    body = ElementTree.SubElement(worldbody, "body", name=name)
    ElementTree.SubElement(body, "freejoint", name=f"{name}_joint")
    inertia = mass.inertia
    ElementTree.SubElement(
        body,
        "inertial",
        pos=_text(mass.center_of_mass),
        mass=f"{mass.mass:.6g}",
        fullinertia=_text([inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]),
    )
    ElementTree.SubElement(
        body,
        "geom",
        name=f"{name}_visual",
        type="mesh",
        mesh=f"{name}_visual",
        material=material,
        group="2",
        contype="0",
        conaffinity="0",
    )
    for index in range(num_hulls):
        ElementTree.SubElement(
            body,
            "geom",
            name=f"{name}_hull_{index:03d}",
            type="mesh",
            mesh=f"{name}_hull_{index:03d}",
            group="3",
            friction=_text(FRICTION),
            rgba="0.5 0.5 0.5 1",
        )
    return _xml(root)


def urdf_text(name: str, textured: bool, rgba, num_hulls: int, mass: MassProperties) -> str:
    """A PyBullet model of the same meshes; PyBullet reads the texture through `visual.mtl`."""
    robot = ElementTree.Element("robot", name=name)
    link = ElementTree.SubElement(robot, "link", name="base")
    contact = ElementTree.SubElement(link, "contact")
    ElementTree.SubElement(contact, "lateral_friction", value=f"{FRICTION[0]}")
    ElementTree.SubElement(contact, "spinning_friction", value=f"{FRICTION[1]}")
    ElementTree.SubElement(contact, "rolling_friction", value=f"{FRICTION[2]}")
    inertial = ElementTree.SubElement(link, "inertial")
    ElementTree.SubElement(inertial, "origin", xyz=_text(mass.center_of_mass), rpy="0 0 0")
    ElementTree.SubElement(inertial, "mass", value=f"{mass.mass:.6g}")
    i = mass.inertia
    ElementTree.SubElement(
        inertial,
        "inertia",
        ixx=f"{i[0, 0]:.6g}",
        iyy=f"{i[1, 1]:.6g}",
        izz=f"{i[2, 2]:.6g}",
        ixy=f"{i[0, 1]:.6g}",
        ixz=f"{i[0, 2]:.6g}",
        iyz=f"{i[1, 2]:.6g}",
    )
    visual = ElementTree.SubElement(link, "visual")
    ElementTree.SubElement(ElementTree.SubElement(visual, "geometry"), "mesh", filename=VISUAL_OBJ)
    color = (1.0, 1.0, 1.0, rgba[3]) if textured else rgba
    ElementTree.SubElement(
        ElementTree.SubElement(visual, "material", name=f"{name}_material"), "color", rgba=_text(color)
    )
    for index in range(num_hulls):
        collision = ElementTree.SubElement(link, "collision")
        ElementTree.SubElement(ElementTree.SubElement(collision, "geometry"), "mesh", filename=hull_filename(index))
    return '<?xml version="1.0"?>\n' + _xml(robot)
