"""An MJCF (MuJoCo) version of ``export/``: ``export/scene.xml``, built with ``mujoco.MjSpec``
and compiled before it is written (a scene MuJoCo cannot load is never written).

Per object a free body with the exported mass, COM, principal inertia and axes; its convex
pieces as collision geoms (group 3) and its textured visual mesh as a geom that does not
collide (contype = conaffinity = 0, group 1). The support is a plane; the input camera is a
fixed camera. Paths in the file are relative to ``export/``.

Friction. PyBullet multiplies two bodies' coefficients; MuJoCo's default takes the larger of
the two geoms'. Every contact that can occur in a resting scene is therefore an explicit
``<pair>`` with friction mu_i * mu_j (object-support: every piece with the plane;
object-object: for two objects with pieces whose boxes are within ``PAIR_MARGIN_M``, every
two pieces, or only those near pieces when there are more than ``MAX_ALL_PAIRS``
combinations), and the dynamic contacts of those body pairs are excluded so that only the
pairs act. Objects farther apart keep dynamic contacts, with mu_i * mu_support per geom
(MuJoCo's max rule then gives the larger of the two products).
condim 3 (sliding friction only): PyBullet has no torsional or rolling friction by default.

Contact distance. Bullet keeps convex bodies a collision margin apart; each pair's MuJoCo
margin reproduces that rest distance (``OBJECT_MARGIN_M``). A MuJoCo contact rests at its
margin, so two pieces exported closer than that (physopt's poses are often in Bullet's
margin band, down to touching) would be pushed apart at the start: Bullet corrects such an
overlap gently, MuJoCo's stiff soft contact kicks, and a kick of 1-2 mm tipped a standing
screwdriver and rolled a marker in scenes that rest in PyBullet. Such a pair's margin is
therefore its distance in the exported poses (not below 0; ``fit_rest_distances``), so the
scene starts at rest where it was exported; pairs farther apart keep Bullet's margin.
MuJoCo's ``gap`` would separate detection from rest distance, but the installed MuJoCo
(4.0) ignores it for the rest distance (measured: a box with margin 10 mm and gap 5 mm
rests 10 mm up), so the margin is set itself.

Contact softness. PyBullet's contacts are hard and do not creep; MuJoCo's are soft, and on
a slope a soft frictional contact slips slowly. The scene uses the stiffest contact that
MuJoCo resolves stably (time constant 2 x timestep, at a 1/480 s step), an elliptic cone with impratio 10
(less slip, MuJoCo's recommendation for elliptic cones), and noslip iterations, MuJoCo's
post-processing that removes the remaining slip; docs/physics_parameters.md has the
measurement.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from r2s.errors import StageError
from r2s.io.atomic import atomic_write_text
from r2s.io.paths import EXPORT_MJCF_FILE

TIMESTEP_S = 1.0 / 480.0
"""Half PyBullet's 1/240 s step: MuJoCo's stiffest stable contact has a time constant of two
steps, and Bullet's contacts are rigid, so a smaller step brings MuJoCo's contacts closer to
Bullet's (measured: docs/physics_parameters.md)."""
SOLREF = (2.0 * TIMESTEP_S, 1.0)
"""Contact time constant (s) and damping ratio: the stiffest MuJoCo integrates stably."""
IMPRATIO = 10.0
NOSLIP_ITERATIONS = 10
PAIR_MARGIN_M = 0.05
"""Pieces of two objects whose world boxes are closer than this get explicit pairs."""
CONDIM = 3
CAMERA_PIXEL_M = 1e-5
"""Nominal pixel pitch of the camera's sensor (only ratios matter)."""
OBJECT_MARGIN_M = 0.001
"""Bullet's collision margin of a convex mesh: PyBullet rests a convex body 1 mm above the
plane and two convex bodies 2 mm apart. A MuJoCo contact with margin m comes to rest at
distance m, so each pair's margin is the sum of its two Bullet margins (plane: 0) and the
scene rests where the PyBullet judge had it rather than dropping 1-2 mm."""
REST_TOLERANCE_M = 1e-4
"""A pair exported less than this inside its Bullet margin keeps the Bullet margin: the push
is negligible (under 0.1 mm), and shrinking the margin would drop contacts at nearby hull
vertices (measured: a ball on one hull vertex then rolled 6 deg instead of 1 deg)."""
MAX_ALL_PAIRS = 1024
"""Above this many piece combinations, only the near pieces of two objects get pairs."""


@dataclass(frozen=True)
class MjcfObject:
    """One object for the MJCF writer (object frame, SI units).

    collision_meshes : paths relative to export/; collision_bounds : per piece (2, 3) box in
    the object frame; inertia_about_com : (3, 3); visual_obj / visual_png : the textured
    visual mesh (relative paths; png None = untextured, drawn with ``rgba``).
    """

    id: int
    world_from_object: np.ndarray
    mass_kg: float
    com_in_object: np.ndarray
    inertia_about_com: np.ndarray
    friction: float
    collision_meshes: Sequence[str]
    collision_bounds: Sequence[np.ndarray]
    visual_obj: Optional[str] = None
    visual_png: Optional[str] = None
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)


def _wxyz(rot: np.ndarray) -> list[float]:
    x, y, z, w = Rotation.from_matrix(rot).as_quat()
    return [float(w), float(x), float(y), float(z)]


def _principal(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (3,) and axes (3, 3) as columns of a right-handed rotation."""
    evals, evecs = np.linalg.eigh(np.asarray(inertia, dtype=float))
    if np.linalg.det(evecs) < 0:
        evecs[:, 0] *= -1
    return np.maximum(evals, 1e-12), evecs


def plane_rotation(normal: Sequence[float]) -> np.ndarray:
    """(3, 3) rotation taking +Z to the unit ``normal``."""
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3) if n[2] > 0 else np.diag([1.0, -1.0, -1.0])
    angle = np.arccos(np.clip(n @ z, -1.0, 1.0))
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()


def camera_fovy_deg(K: np.ndarray, height_px: int) -> float:
    """Vertical field of view (degrees) of a pinhole camera."""
    return float(np.degrees(2.0 * np.arctan(0.5 * height_px / float(K[1, 1]))))


CV_TO_GL = np.diag([1.0, -1.0, -1.0])
"""OpenCV camera axes (x right, y down, z forward) to OpenGL/MuJoCo/USD camera axes (x right,
y up, looking down -z): world_from_gl = world_from_cv[:3, :3] @ CV_TO_GL."""


def _world_boxes(obj: MjcfObject) -> list[np.ndarray]:
    out = []
    pose = np.asarray(obj.world_from_object, dtype=float)
    for lo_hi in obj.collision_bounds:
        lo, hi = np.asarray(lo_hi, dtype=float)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])])
        world = corners @ pose[:3, :3].T + pose[:3, 3]
        out.append(np.stack([world.min(0), world.max(0)]))
    return out


def _box_gap(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(np.maximum(0.0, np.maximum(a[0] - b[1], b[0] - a[1]))))


def build_spec(objects: Sequence[MjcfObject], gravity: Sequence[float], support: dict,
               camera=None):
    """The scene as a ``mujoco.MjSpec`` (not yet compiled).

    ``support``: {"point", "normal", "friction"}; ``camera``: an
    :class:`r2s.io.input_scene.Camera` or None.
    """
    import mujoco

    spec = mujoco.MjSpec()
    spec.modelname = "r2s-scene"
    spec.meshdir = "."
    spec.texturedir = "."
    spec.option.timestep = TIMESTEP_S
    spec.option.gravity = [float(g) for g in gravity]
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = IMPRATIO
    spec.option.noslip_iterations = NOSLIP_ITERATIONS
    mu_s = float(support.get("friction", 0.8))
    _add_support_and_light(spec, support, mu_s)
    if camera is not None:
        _add_input_camera(spec, camera)
    geom_names = {int(obj.id): _add_object(spec, obj, mu_s) for obj in objects}
    _add_pairs(spec, objects, geom_names, mu_s)
    return spec


def _add_support_and_light(spec, support: dict, mu_s: float) -> None:
    """The support plane (static, friction ``mu_s``) and an overhead directional light."""
    import mujoco

    world = spec.worldbody
    plane = world.add_geom()
    plane.name = "support"
    plane.type = mujoco.mjtGeom.mjGEOM_PLANE
    plane.size = [5.0, 5.0, 0.1]
    plane.pos = [float(x) for x in support["point"]]
    plane.quat = _wxyz(plane_rotation(support["normal"]))
    plane.friction = [mu_s, 0.0, 0.0]
    plane.condim = CONDIM
    plane.solref = list(SOLREF)
    plane.rgba = [0.55, 0.5, 0.45, 1.0]
    spec.visual.headlight.ambient = [0.4, 0.4, 0.4]
    spec.visual.headlight.diffuse = [0.5, 0.5, 0.5]
    light = world.add_light()
    light.name = "overhead"
    light.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
    light.pos = [float(x) for x in np.asarray(support["point"], float) + [0.0, 0.0, 2.0]]
    light.dir = [0.0, 0.0, -1.0]
    light.diffuse = [0.6, 0.6, 0.6]


def _add_input_camera(spec, camera) -> None:
    """The input camera, ``input_camera``, with its full pinhole model."""
    cam = spec.worldbody.add_camera()
    cam.name = "input_camera"
    pose = np.asarray(camera.world_from_camera, dtype=float)
    cam.pos = [float(x) for x in pose[:3, 3]]
    cam.quat = _wxyz(pose[:3, :3] @ CV_TO_GL)
    K = np.asarray(camera.K, dtype=float)
    w, h = float(camera.width), float(camera.height)
    cam.fovy = camera_fovy_deg(K, camera.height)
    # The full pinhole model: with a sensor size MuJoCo uses focal length and principal
    # point (pixels) instead of fovy. MuJoCo's principal point is the image centre's
    # offset from it (measured by rendering: tests/test_export_formats.py), and K's
    # pixel-centre coordinates put the image centre at ((w - 1) / 2, (h - 1) / 2).
    cam.resolution = [w, h]
    cam.sensor_size = [w * CAMERA_PIXEL_M, h * CAMERA_PIXEL_M]
    cam.focal_pixel = [float(K[0, 0]), float(K[1, 1])]
    cam.principal_pixel = [float(0.5 * w - 0.5 - K[0, 2]), float(0.5 * h - 0.5 - K[1, 2])]


def _add_object(spec, obj: MjcfObject, mu_s: float) -> list[str]:
    """One free body: explicit inertia, convex collision geoms (group 3) and a textured
    visual geom that does not collide (group 1). Returns the collision geoms' names."""
    import mujoco

    oid = int(obj.id)
    pose = np.asarray(obj.world_from_object, dtype=float)
    body = spec.worldbody.add_body()
    body.name = f"object_{oid}"
    body.pos = [float(x) for x in pose[:3, 3]]
    body.quat = _wxyz(pose[:3, :3])
    body.add_freejoint()
    moments, axes = _principal(obj.inertia_about_com)
    body.explicitinertial = True
    body.mass = float(obj.mass_kg)
    body.ipos = [float(x) for x in obj.com_in_object]
    body.iquat = _wxyz(axes)
    body.inertia = [float(x) for x in moments]
    mu = float(obj.friction) * mu_s
    names = []
    for k, rel in enumerate(obj.collision_meshes):
        mesh = spec.add_mesh()
        mesh.name = f"m{oid}_{k}"
        mesh.file = rel
        geom = body.add_geom()
        geom.name = f"c{oid}_{k}"
        geom.type = mujoco.mjtGeom.mjGEOM_MESH
        geom.meshname = mesh.name
        geom.friction = [mu, 0.0, 0.0]
        geom.condim = CONDIM
        geom.solref = list(SOLREF)
        geom.margin = OBJECT_MARGIN_M
        geom.group = 3
        geom.rgba = [0.3, 0.6, 0.9, 0.4]
        names.append(geom.name)
    if obj.visual_obj is not None:
        _add_visual(spec, body, obj)
    return names


def _add_visual(spec, body, obj: MjcfObject) -> None:
    """The visual mesh of ``obj`` on ``body``: no contacts, no mass, texture if any."""
    import mujoco

    oid = int(obj.id)
    vmesh = spec.add_mesh()
    vmesh.name = f"v{oid}"
    vmesh.file = obj.visual_obj
    vis = body.add_geom()
    vis.name = f"visual_{oid}"
    vis.type = mujoco.mjtGeom.mjGEOM_MESH
    vis.meshname = vmesh.name
    vis.contype = 0
    vis.conaffinity = 0
    vis.group = 1
    vis.mass = 0.0
    if obj.visual_png is not None:
        tex = spec.add_texture()
        tex.name = f"t{oid}"
        tex.file = obj.visual_png
        tex.type = mujoco.mjtTexture.mjTEXTURE_2D
        tex.colorspace = mujoco.mjtColorSpace.mjCOLORSPACE_SRGB
        mat = spec.add_material()
        mat.name = f"mat{oid}"
        mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
        vis.material = mat.name
    else:
        vis.rgba = list(obj.rgba)


def _add_pair(spec, g1: str, g2: str, mu: float, margin_m: float) -> None:
    pair = spec.add_pair()
    pair.margin = float(margin_m)
    pair.geomname1 = g1
    pair.geomname2 = g2
    pair.condim = CONDIM
    pair.friction = [mu, mu, 0.0, 0.0, 0.0]
    pair.solref = list(SOLREF)


def _add_pairs(spec, objects: Sequence[MjcfObject], names: dict[int, list[str]],
               mu_s: float) -> None:
    """Explicit pairs with PyBullet's product friction (see the module docstring)."""
    for obj in objects:
        for g in names[obj.id]:
            _add_pair(spec, "support", g, float(obj.friction) * mu_s, OBJECT_MARGIN_M)
        exclude = spec.add_exclude()
        exclude.bodyname1 = "world"
        exclude.bodyname2 = f"object_{obj.id}"
    boxes = {o.id: _world_boxes(o) for o in objects}
    for a, b in combinations(objects, 2):
        near = [(i, j) for i, ba in enumerate(boxes[a.id]) for j, bb in enumerate(boxes[b.id])
                if _box_gap(ba, bb) < PAIR_MARGIN_M]
        if not near:
            continue
        mu = float(a.friction) * float(b.friction)
        n_a, n_b = len(names[a.id]), len(names[b.id])
        if n_a * n_b <= MAX_ALL_PAIRS:
            near = [(i, j) for i in range(n_a) for j in range(n_b)]
        for i, j in near:
            _add_pair(spec, names[a.id][i], names[b.id][j], mu, 2 * OBJECT_MARGIN_M)
        exclude = spec.add_exclude()
        exclude.bodyname1 = f"object_{a.id}"
        exclude.bodyname2 = f"object_{b.id}"


def fit_rest_distances(spec) -> list[float]:
    """Lower each ``<pair>``'s margin (its MuJoCo rest distance) to the pair's distance in
    the spec's initial poses where that is more than ``REST_TOLERANCE_M`` smaller (clamped
    at 0); compiles ``spec`` (its files must resolve). Returns the initial distances (m,
    one per pair in spec order, capped at the pair's original margin)."""
    import mujoco

    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    distances = []
    for pair in spec.pairs:
        g1 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, pair.geomname1)
        g2 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, pair.geomname2)
        margin = float(pair.margin)
        dist = min(margin, float(mujoco.mj_geomDistance(model, data, g1, g2, margin, None)))
        if dist < margin - REST_TOLERANCE_M:
            pair.margin = max(0.0, dist)
        distances.append(dist)
    return distances


def write_mjcf(export_dir: Path, objects: Sequence[MjcfObject], gravity: Sequence[float],
               support: dict, camera=None) -> Path:
    """Build, compile (the check) and write ``export_dir/scene.xml``."""
    import mujoco

    export_dir = Path(export_dir)
    spec = build_spec(objects, gravity, support, camera)
    spec.modelfiledir = str(export_dir)
    try:
        fit_rest_distances(spec)
        spec.compile()
    except Exception as exc:
        raise StageError(f"{export_dir / EXPORT_MJCF_FILE}: MuJoCo cannot compile the scene "
                         f"({exc})") from None
    path = export_dir / EXPORT_MJCF_FILE
    atomic_write_text(path, spec.to_xml())
    return path
