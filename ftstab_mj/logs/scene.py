"""The 3D shapes of a MuJoCo model, read from its MJCF, for the viewers (Rerun, Foxglove).

Both log formats draw the same thing: every geom of a logged body, as a primitive placed in its
body's frame, and the static geoms of the world body. Body poses over time come from
SampleBatch.body_pos/body_quat; the shapes themselves never move relative to their body.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

# A model read from a log is untrusted: compiling it must neither read local files nor allocate
# what its numbers declare. These elements name files or generate/allocate in bulk; a log's model
# holding one is not compiled (its 3D is left out); so is one with an attribute naming a file or folder.
UNTRUSTED_ELEMENTS = frozenset({"include", "mesh", "hfield", "skin", "flex", "flexcomp", "composite",
                                "replicate", "plugin", "extension", "model", "attach", "instance", "frame"})
FILE_ATTRIBUTES = ("meshdir", "texturedir", "assetdir")  # and every attribute starting with "file"
MAX_ELEMENTS = 10_000  # elements in a log's model (ours have tens)
MAX_MODEL_CHARS = 1 << 20
# A <texture> is accepted when it reads no file (a builtin one: gradient, checker, flat) and MuJoCo
# allocates at most this many pixels for it (width x height, x 6 for a cube or skybox)
MAX_TEXTURE_PIXELS = 1 << 22

# MuJoCo geom types drawn (others, e.g. meshes and height fields, are left out of the viewers).
DRAWN = ("plane", "sphere", "capsule", "ellipsoid", "cylinder", "box")
PLANE_HALF_SIZE = 5.0  # m, half extent drawn for an infinite MuJoCo plane (size 0)
PLANE_HALF_THICKNESS = 1e-3  # m, a plane is drawn as a thin box


@dataclass(frozen=True)
class Shape:
    """One geom in its body's frame.

    kind: "box" | "ellipsoid" | "capsule" | "cylinder" (planes become thin boxes, spheres ellipsoids);
    half_sizes: (3,) m — box and ellipsoid half extents; capsule/cylinder: (radius, radius, half length);
    pos: (3,) m and quat: (4,) (w, x, y, z), the geom's pose in its body's frame; rgba: (4,) in [0, 1].
    """

    body: str  # "world" for static geoms
    name: str
    kind: str
    half_sizes: tuple
    pos: tuple
    quat: tuple
    rgba: tuple


def check_untrusted_model(model_xml: str, what: str) -> None:
    """Refuse (LogError, one line) an MJCF from a log that would make MuJoCo read a local file
    (include, mesh/texture/hfield/skin files, asset folders) or allocate in bulk (replicate,
    composite, flex, textures, height fields, plugins), or that is larger than our models can be.
    Parsed with the standard library's expat (entity expansion is bounded there), never compiled."""
    import xml.etree.ElementTree as ET

    from ftstab_mj.config.errors import LogError

    if len(model_xml) > MAX_MODEL_CHARS:
        raise LogError(f"{what}: expected a model of at most {MAX_MODEL_CHARS} characters, found {len(model_xml)}")
    if "<!DOCTYPE" in model_xml.upper() or "<!ENTITY" in model_xml.upper():
        raise LogError(f"{what}: expected an MJCF model without a DOCTYPE or entities, found one")
    try:
        root = ET.fromstring(model_xml)
    except ET.ParseError as exc:
        raise LogError(f"{what}: expected an MJCF model, found XML that does not parse ({exc})") from None
    for n, el in enumerate(root.iter()):
        if n >= MAX_ELEMENTS:
            raise LogError(f"{what}: expected at most {MAX_ELEMENTS} elements in the model, found more")
        tag = el.tag.lower() if isinstance(el.tag, str) else ""
        if tag == "texture":
            _check_texture(el, what)
        if tag in UNTRUSTED_ELEMENTS:
            raise LogError(f"{what}: the model holds a <{tag}> element; a model from a log is not compiled when it "
                           "could read local files or allocate in bulk")
        for attr, value in el.attrib.items():
            if attr.lower().startswith("file") or attr.lower() in FILE_ATTRIBUTES:
                raise LogError(f"{what}: the model names a file or folder (<{tag} {attr}={value[:60]!r}>); "
                               "a model from a log never makes replay read local files")


def _check_texture(el, what: str) -> None:
    """A builtin texture reads nothing; its size is bounded (a file texture is refused with the other files)."""
    from ftstab_mj.config.errors import LogError

    if el.get("builtin", "none") == "none":
        raise LogError(f"{what}: the model holds a <texture> that is not builtin; a model from a log never makes "
                       "replay read local files")
    try:
        w, h = int(float(el.get("width", "0"))), int(float(el.get("height", "0")))
    except ValueError:
        raise LogError(f"{what}: expected a <texture> width and height that are integers") from None
    pixels = max(w, 1) * max(h, 1) * (6 if el.get("type", "cube") in ("cube", "skybox") else 1)
    if pixels > MAX_TEXTURE_PIXELS:
        raise LogError(f"{what}: expected builtin <texture> elements of at most {MAX_TEXTURE_PIXELS} pixels, found {w} x {h}"
                       f" ({el.get('type', 'cube')})")


def model_shapes(model_xml: str, body_names) -> tuple[Shape, ...]:
    """Shapes of the geoms attached to the world body or to one of ``body_names``.

    Raises whatever MuJoCo raises for an invalid MJCF (the model was simulated, so it is valid).
    Kept for the last few models: a run's three readers (the MCAP scene, the Rerun shapes and its
    camera) parse the model once (2.4 ms for the cart each time).
    """
    return _model_shapes(model_xml, tuple(body_names))


@functools.lru_cache(maxsize=8)
def _model_shapes(model_xml: str, body_names: tuple) -> tuple[Shape, ...]:
    import mujoco

    from ftstab_mj.plants.callback import control_callback

    with control_callback(None):  # compiling runs a forward pass that would call a caller's callback
        m = mujoco.MjModel.from_xml_string(model_xml)
    wanted = set(body_names) | {"world"}
    out = []
    for g in range(m.ngeom):
        body = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])) or "world"
        gtype = mujoco.mjtGeom(int(m.geom_type[g])).name.removeprefix("mjGEOM_").lower()
        if body not in wanted or gtype not in DRAWN:
            continue
        size = m.geom_size[g]
        if gtype == "plane":
            hx = size[0] if size[0] > 0 else PLANE_HALF_SIZE
            hy = size[1] if size[1] > 0 else PLANE_HALF_SIZE
            kind, half = "box", (hx, hy, PLANE_HALF_THICKNESS)
        elif gtype == "sphere":
            kind, half = "ellipsoid", (size[0],) * 3
        elif gtype in ("capsule", "cylinder"):
            kind, half = gtype, (size[0], size[0], size[1])
        else:
            kind, half = gtype, tuple(size)
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
        out.append(Shape(body=body, name=name, kind=kind, half_sizes=tuple(float(x) for x in half),
                         pos=tuple(float(x) for x in m.geom_pos[g]), quat=tuple(float(x) for x in m.geom_quat[g]),
                         rgba=tuple(float(x) for x in m.geom_rgba[g])))
    return tuple(out)


def quat_rotate(quat_wxyz, v) -> np.ndarray:
    """Rotate v (3,) by the unit quaternion (w, x, y, z)."""
    w, x, y, z = quat_wxyz
    q = np.array([x, y, z])
    v = np.asarray(v, dtype=float)
    t = 2.0 * np.cross(q, v)
    return v + w * t + np.cross(q, t)
