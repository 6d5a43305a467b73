"""A USD version of ``export/``: ``export/scene.usda`` (UsdPhysics, readable by any USD
physics consumer, e.g. Isaac Sim / PhysX).

Stage: metres (metersPerUnit 1), kilograms (kilogramsPerUnit 1), Z up, ``/World`` the default
prim, ``/World/PhysicsScene`` with r2s's gravity (direction and magnitude).

Per object ``/World/object_<id>`` (an Xform whose frame is the object frame, placed by
``world_from_object``) with RigidBodyAPI and MassAPI: mass, centerOfMass (object frame),
diagonalInertia and principalAxes all written explicitly (the inertia tensor about the COM
in the object frame is R diag(diagonalInertia) R^T, R the principalAxes rotation). Children:

- ``collision/piece_<k>``: the convex pieces, Mesh + CollisionAPI + MeshCollisionAPI with
  approximation ``convexHull``, purpose ``guide`` (not rendered);
- ``visual``: the visual mesh, no collision, a UsdPreviewSurface material reading the
  texture file through the ``st`` primvar (vertex interpolation).

Friction: one physics material per object (static = dynamic friction = r2s's per-body
value, restitution) bound with the ``physics`` purpose, and one for the support. Each
material also carries PhysX's ``physxMaterial:frictionCombineMode = multiply`` (PhysX
averages by default; with every material set to multiply a contact uses mu_i * mu_j, the
PyBullet coefficient that r2s's values are for). The support is a static plane collider
(UsdGeom.Plane, no rigid body). The input camera is ``/World/input_camera``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from r2s.io.mjcf import CV_TO_GL, plane_rotation

CAMERA_APERTURE_H = 20.955
"""Horizontal aperture of the camera prim (USD's default; only ratios matter)."""


@dataclass(frozen=True)
class UsdObject:
    """One object for the USD writer (object frame, SI units).

    pieces : convex meshes; visual_mesh : the visual mesh; texture_rel : texture file
    relative to export/ (None: ``rgba`` colour); inertia_about_com : (3, 3).
    """

    id: int
    label: str
    world_from_object: np.ndarray
    mass_kg: float
    com_in_object: np.ndarray
    inertia_about_com: np.ndarray
    friction: float
    restitution: float
    pieces: Sequence[trimesh.Trimesh]
    visual_mesh: trimesh.Trimesh
    texture_rel: Optional[str] = None
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)


def principal_axes(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (3,) and the right-handed rotation (3, 3) whose columns are the axes."""
    evals, evecs = np.linalg.eigh(np.asarray(inertia, dtype=float))
    if np.linalg.det(evecs) < 0:
        evecs[:, 0] *= -1
    return np.maximum(evals, 1e-12), evecs


def _matrix(pose: np.ndarray):
    from pxr import Gf

    # USD composes row vectors (p' = p M), hence the transpose of r2s's column convention
    return Gf.Matrix4d(np.asarray(pose, dtype=float).T.tolist())


def _mesh_prim(stage, path: str, mesh: trimesh.Trimesh):
    from pxr import UsdGeom, Vt

    prim = UsdGeom.Mesh.Define(stage, path)
    prim.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(mesh.vertices, dtype=np.float32)))
    faces = np.asarray(mesh.faces, dtype=np.int32)
    prim.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    prim.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
    prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    return prim


def _physics_material(stage, path: str, friction: float, restitution: float):
    from pxr import Sdf, UsdPhysics, UsdShade

    mat = UsdShade.Material.Define(stage, path)
    api = UsdPhysics.MaterialAPI.Apply(mat.GetPrim())
    api.CreateStaticFrictionAttr(float(friction))
    api.CreateDynamicFrictionAttr(float(friction))
    api.CreateRestitutionAttr(float(restitution))
    prim = mat.GetPrim()
    prim.AddAppliedSchema("PhysxMaterialAPI")
    prim.CreateAttribute("physxMaterial:frictionCombineMode", Sdf.ValueTypeNames.Token
                         ).Set("multiply")
    return mat


def _bind(prim, material, purpose: str) -> None:
    from pxr import UsdShade

    api = UsdShade.MaterialBindingAPI.Apply(prim)
    api.Bind(material, UsdShade.Tokens.weakerThanDescendants, purpose)


def _render_material(stage, path: str, texture_rel: Optional[str], rgba) -> object:
    from pxr import Gf, Sdf, UsdShade

    mat = UsdShade.Material.Define(stage, path)
    surf = UsdShade.Shader.Define(stage, path + "/surface")
    surf.CreateIdAttr("UsdPreviewSurface")
    surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
    surf.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    colour = surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
    if texture_rel is None:
        colour.Set(Gf.Vec3f(*[float(c) for c in rgba[:3]]))
        return mat
    reader = UsdShade.Shader.Define(stage, path + "/st_reader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex = UsdShade.Shader.Define(stage, path + "/texture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./" + texture_rel)
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.ConnectableAPI(), "result")
    colour.ConnectToSource(tex.ConnectableAPI(), "rgb")
    return mat


def _camera(stage, camera) -> None:
    from pxr import Gf, UsdGeom

    K = np.asarray(camera.K, dtype=float)
    w, h = float(camera.width), float(camera.height)
    cam = UsdGeom.Camera.Define(stage, "/World/input_camera")
    pose = np.eye(4)
    pose[:3, :3] = np.asarray(camera.world_from_camera, dtype=float)[:3, :3] @ CV_TO_GL
    pose[:3, 3] = np.asarray(camera.world_from_camera, dtype=float)[:3, 3]
    cam.AddTransformOp().Set(_matrix(pose))
    h_ap = CAMERA_APERTURE_H
    focal = K[0, 0] * h_ap / w          # same units as the aperture
    v_ap = focal * h / K[1, 1]
    cam.CreateFocalLengthAttr(float(focal))
    cam.CreateHorizontalApertureAttr(float(h_ap))
    cam.CreateVerticalApertureAttr(float(v_ap))
    # The principal point off the image centre moves the film window the other way: K is in
    # pixel-centre coordinates (the image centre is at (w - 1) / 2), the window spans [0, w];
    # image x is camera +x, image y is camera -y.
    cam.CreateHorizontalApertureOffsetAttr(float(-(K[0, 2] + 0.5 - 0.5 * w) * h_ap / w))
    cam.CreateVerticalApertureOffsetAttr(float((K[1, 2] + 0.5 - 0.5 * h) * v_ap / h))
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.01, 100.0))
    cam.GetPrim().SetCustomDataByKey("r2s:image_size_px", Gf.Vec2i(int(w), int(h)))


def build_stage(objects: Sequence[UsdObject], gravity: Sequence[float], support: dict,
                camera=None, path: str = "scene.usda"):
    """The scene as a ``pxr.Usd.Stage`` created in memory (``path`` names its layer)."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, Vt

    stage = Usd.Stage.CreateInMemory(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(root.GetPrim())
    scene = UsdPhysics.Scene.Define(stage, "/World/PhysicsScene")
    g = np.asarray(gravity, dtype=float)
    magnitude = float(np.linalg.norm(g))
    direction = g / magnitude if magnitude > 0 else np.array([0.0, 0.0, -1.0])
    scene.CreateGravityDirectionAttr(Gf.Vec3f(*direction.tolist()))
    scene.CreateGravityMagnitudeAttr(magnitude)

    mu_s = float(support.get("friction", 0.8))
    support_mat = _physics_material(stage, "/World/PhysicsMaterials/support", mu_s, 0.0)
    plane = UsdGeom.Plane.Define(stage, "/World/support")
    plane.CreateAxisAttr("Z")
    plane.CreateWidthAttr(2.0)
    plane.CreateLengthAttr(2.0)
    plane_pose = np.eye(4)
    plane_pose[:3, :3] = plane_rotation(support["normal"])
    plane_pose[:3, 3] = np.asarray(support["point"], dtype=float)
    plane.AddTransformOp().Set(_matrix(plane_pose))
    UsdPhysics.CollisionAPI.Apply(plane.GetPrim())
    _bind(plane.GetPrim(), support_mat, "physics")

    for obj in objects:
        base = f"/World/object_{int(obj.id)}"
        xform = UsdGeom.Xform.Define(stage, base)
        xform.AddTransformOp().Set(_matrix(obj.world_from_object))
        prim = xform.GetPrim()
        prim.SetCustomDataByKey("r2s:id", int(obj.id))
        prim.SetCustomDataByKey("r2s:label", str(obj.label))
        UsdPhysics.RigidBodyAPI.Apply(prim)
        mass = UsdPhysics.MassAPI.Apply(prim)
        moments, axes = principal_axes(obj.inertia_about_com)
        x, y, z, w = Rotation.from_matrix(axes).as_quat()
        mass.CreateMassAttr(float(obj.mass_kg))
        mass.CreateCenterOfMassAttr(Gf.Vec3f(*[float(c) for c in obj.com_in_object]))
        mass.CreateDiagonalInertiaAttr(Gf.Vec3f(*[float(m) for m in moments]))
        mass.CreatePrincipalAxesAttr(Gf.Quatf(float(w), Gf.Vec3f(float(x), float(y), float(z))))
        phys_mat = _physics_material(stage, f"/World/PhysicsMaterials/object_{int(obj.id)}",
                                     obj.friction, obj.restitution)
        UsdGeom.Scope.Define(stage, base + "/collision")
        for k, piece in enumerate(obj.pieces):
            mesh = _mesh_prim(stage, f"{base}/collision/piece_{k}", piece)
            mesh.CreatePurposeAttr(UsdGeom.Tokens.guide)
            UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
            UsdPhysics.MeshCollisionAPI.Apply(mesh.GetPrim()).CreateApproximationAttr(
                UsdPhysics.Tokens.convexHull)
            _bind(mesh.GetPrim(), phys_mat, "physics")
        visual = _mesh_prim(stage, f"{base}/visual", obj.visual_mesh)
        uv = getattr(obj.visual_mesh.visual, "uv", None)
        if obj.texture_rel is not None and uv is not None:
            st = UsdGeom.PrimvarsAPI(visual.GetPrim()).CreatePrimvar(
                "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
            st.Set(Vt.Vec2fArray.FromNumpy(np.asarray(uv, dtype=np.float32)))
        render = _render_material(stage, f"/World/Looks/object_{int(obj.id)}",
                                  obj.texture_rel if uv is not None else None, obj.rgba)
        _bind(visual.GetPrim(), render, "allPurpose")
    if camera is not None:
        _camera(stage, camera)
    return stage


def write_usd(export_dir: Path, objects: Sequence[UsdObject], gravity: Sequence[float],
              support: dict, camera=None) -> Path:
    """Write ``export_dir/scene.usda`` atomically."""
    from r2s.io.atomic import atomic_write_text

    path = Path(export_dir) / "scene.usda"
    stage = build_stage(objects, gravity, support, camera, path.name)
    atomic_write_text(path, stage.GetRootLayer().ExportToString())
    return path
