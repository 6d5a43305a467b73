"""What diagnose measured: the residuals of the current model, with their structure.

Pure containers (frozen dataclasses of numpy arrays). They are filled from a scene by
:mod:`r2s.diagnose.measure` and by hand in tests; the effects in
:mod:`r2s.diagnose.effects` read them and never touch files.

Frames: everything is in the world frame of the current model (the declared camera pose,
corrected by the effects already kept in the scene's model). ``up`` is minus the model's
gravity direction.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Callable, Optional

import numpy as np
from scipy.spatial.transform import Rotation

from r2s.geometry.plane import signed_distance


# ---- registration residual: does the observation agree with metric priors? -------------

@dataclass(frozen=True)
class ScaleObs:
    """Registration of one object's metric prior to its observed points.

    Attributes
    ----------
    id : object id.
    scale : isotropic scale of the metric prior that fits the observation best
        (1.0 = the observation has the prior's size).
    depth_m : median observed depth (camera z) of the object's points, metres.
    fitness : fraction of observed points within the inlier distance of the scaled prior.
    rmse_m : RMS point-to-surface distance of the inliers, metres.
    n_points : observed points used.
    """

    id: int
    scale: float
    depth_m: float
    fitness: float = 1.0
    rmse_m: float = 0.0
    n_points: int = 0


@dataclass(frozen=True)
class RegistrationData:
    """Per-object scale disagreement between priors and the observation.

    ``scale_sigma`` is the relative scale uncertainty of one prior (a single-image shape
    model is a few per cent off in size): the noise level of ``log(scale)``. An object whose
    scale is far off (a misregistration) would dominate the block; the depth fits are
    robust (Huber) and the noise level is a robust spread, but its SSE stays in the total.
    """

    objects: tuple[ScaleObs, ...]
    scale_sigma: float = 0.01
    min_fitness: float = 0.5
    min_points: int = 0
    """Objects seen by fewer observed points are left out: on the benchmark's scenes the
    scale fits of objects seen by under 100 points err by 20 % RMS (log), against 2-4 %
    for those seen by 200 or more (docs/diagnose.md section 4)."""
    scale_floor: Optional[float] = None
    """The floor ``scale_sigma`` was measured against (None: ``scale_sigma`` is the floor)."""
    noise_dof: Optional[float] = None
    """Degrees of freedom of ``scale_sigma`` as an estimate (None: a known level)."""
    noise_prior: tuple = (0.02, 4.0)
    """(sigma, pseudo-observations) of the prior spread pooled into ``scale_sigma``."""

    def used(self) -> tuple[ScaleObs, ...]:
        """Objects whose registration is good enough to say something about scale."""
        return tuple(o for o in self.objects
                     if o.fitness >= self.min_fitness and o.n_points >= self.min_points
                     and np.isfinite(o.scale) and o.scale > 0)


# ---- support residual: the table's normal against the declared gravity ------------------

@dataclass(frozen=True)
class SupportData:
    """The support plane fitted to the table pixels, against the model's gravity.

    Attributes
    ----------
    normal : (3,) unit normal of the fitted plane, world frame, pointing up.
    point : (3,) a point on the plane.
    up : (3,) unit, minus the model's gravity direction.
    sigma_rad : noise level of each tilt component (fit noise plus unmodelled flatness).
    camera_center : (3,) optical centre (the pivot of a camera rotation error).
    n_points : table points in the fit.
    """

    normal: np.ndarray
    point: np.ndarray
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    sigma_rad: float = float(np.radians(0.3))
    camera_center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    n_points: int = 0
    model_normal: Optional[np.ndarray] = None
    """The table normal the model expects (None: ``up``, the table is level)."""
    points_camera: Optional[np.ndarray] = None
    """(N, 3) a subsample of the plane's inlier points, camera frame (a depth correction
    refits the plane on them)."""
    world_from_camera: Optional[np.ndarray] = None
    anchor_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """(3,) a point the model puts on the table, world frame: the declared world's origin
    (the table is ``z = 0`` there), moved with the world by a camera correction."""
    height_used: bool = False
    """Whether the declared world puts the table through its origin, so that the table's
    height is evidence (decided once per measurement:
    :func:`r2s.diagnose.stats.table_height.declares_table`)."""
    height_sigma_m: float = 0.002
    """Noise level of the table's height at ``anchor_world`` (m): the plane fit (a tenth of
    a millimetre on the benchmark) plus how well a real world frame sits on the table."""

    @property
    def height_m(self) -> float:
        """How much farther (m) the fitted table lies from the camera than the model puts
        it: the camera's distance to the fitted plane minus its distance to the model's
        table, the plane through ``anchor_world`` normal to ``model_normal`` (or ``up``).
        A camera rotation about its centre keeps both; a depth scale ``s`` makes it
        ``(s - 1)`` times the distance; a tilted table pivoting about the origin changes
        the first and, once the model holds the tilt, the second alike."""
        m = np.asarray(self.up if self.model_normal is None else self.model_normal,
                       dtype=np.float64)
        m = m / np.linalg.norm(m)
        model = float(m @ (np.asarray(self.camera_center, dtype=np.float64)
                           - np.asarray(self.anchor_world, dtype=np.float64)))
        return self.camera_distance_m - model

    def plane_distance_m(self, point_world: np.ndarray) -> float:
        """Signed distance (m) of a world point from the fitted plane (positive on the
        normal's side)."""
        return float(signed_distance(np.asarray(point_world, dtype=np.float64)[None],
                                     self.point, self.normal)[0])

    @property
    def camera_distance_m(self) -> float:
        """Distance (m) of the camera centre from the fitted plane."""
        return abs(self.plane_distance_m(self.camera_center))


# ---- physical residual: motion of the reconstruction in a PyBullet rollout --------------

@dataclass(frozen=True)
class Motion:
    """How one object moved over the rollout.

    translation_m : (3,) COM displacement, world frame.
    rotation_rad : (3,) rotation vector of ``R_end R_0^T`` (world frame axis * angle).
    """

    translation_m: np.ndarray
    rotation_rad: np.ndarray

    @property
    def translation_norm_m(self) -> float:
        return float(np.linalg.norm(self.translation_m))

    def tilt_rad(self, up: np.ndarray) -> float:
        """Angle (rad) between the object's up direction before and after: ``up`` against
        the rotation applied to it (0 for any turn about ``up``)."""
        u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
        turned = Rotation.from_rotvec(self.rotation_rad).apply(u)
        return float(np.arccos(np.clip(u @ turned, -1.0, 1.0)))

    @property
    def angle_rad(self) -> float:
        return float(np.linalg.norm(self.rotation_rad))


@dataclass(frozen=True)
class PhysicsModel:
    """The parameters a physical hypothesis changes.

    gravity : (3,) m/s^2, world frame.
    com_shift_world_m : object id -> (3,) shift of its centre of mass from the current one.
    friction : object id -> friction coefficient replacing the current one.
    """

    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    com_shift_world_m: dict = field(default_factory=dict)
    friction: dict = field(default_factory=dict)

    def with_changes(self, gravity: Optional[np.ndarray] = None,
                     com_shift_world_m: Optional[dict] = None,
                     friction: Optional[dict] = None) -> "PhysicsModel":
        """A copy with ``gravity`` replaced and the per-object dicts updated."""
        shifts = dict(self.com_shift_world_m)
        for k, v in (com_shift_world_m or {}).items():
            shifts[k] = np.asarray(v, dtype=np.float64)
        fric = dict(self.friction)
        fric.update(friction or {})
        return PhysicsModel(
            gravity=self.gravity if gravity is None else np.asarray(gravity, dtype=np.float64),
            com_shift_world_m=shifts, friction=fric)


@dataclass(frozen=True)
class PhysObject:
    """Static facts about one object at the start of the rollout.

    com_world : (3,) centre of mass (current model), world frame.
    support_contacts_world : (M, 3) points where the object rests on something below it.
    radius_m : half the diagonal of its bounding box (a plausibility scale for COM shifts).
    geometry_ok : its shape fits the observation well, so its motion is evidence about
        physics rather than about a bad shape.
    friction : its current friction coefficient.
    """

    id: int
    com_world: np.ndarray
    support_contacts_world: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    radius_m: float = 0.05
    geometry_ok: bool = True
    friction: float = 0.8
    world_from_object: np.ndarray = field(default_factory=lambda: np.eye(4))
    com_in_object: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Its pose and current COM in the object frame (to express a COM shift there)."""
    neighbours: frozenset = frozenset()
    """Ids of the objects it touches."""


Simulator = Callable[[PhysicsModel], dict]
"""``simulate(model) -> {object id: Motion}``: a rollout of the scene under ``model``."""


@dataclass(frozen=True)
class PhysicsData:
    """Rollout of the geometric reconstruction under the current model.

    ``motion`` is the rollout under ``base``; ``simulate`` reruns it under another model
    (effects call it to predict the residual they leave). Noise levels: a resting
    reconstruction still settles by a few millimetres and degrees.
    """

    base: PhysicsModel
    objects: dict
    motion: dict
    simulate: Optional[Simulator] = None
    horizon_s: float = 1.0
    stage: Optional[str] = None
    """The stage whose state was rolled out (None: not from a scene)."""
    density_evidence: bool = True
    """May an object that rocks in this rollout count as evidence about its density (a COM
    offset)? False for a reconstructed scene unless the user says so: such rocking is far
    more often the shape or pose a little off."""
    sigma_translation_m: float = 0.015
    sigma_rotation_rad: float = float(np.radians(5.0))
    cap: float = 4.0

    def moving(self, motion: dict, sigmas: float = 2.0) -> set:
        """Ids whose motion in ``motion`` exceeds ``sigmas`` noise levels."""
        return {i for i, m in motion.items()
                if max(m.translation_norm_m / self.sigma_translation_m,
                       m.angle_rad / self.sigma_rotation_rad) > sigmas}

    def with_motion(self, base: PhysicsModel, motion: dict) -> "PhysicsData":
        return replace(self, base=base, motion=motion)


# ---- interaction residual: predicted against observed outcome of a push -----------------

InteractionSimulator = Callable[[PhysicsModel], dict]
"""``simulate(model) -> {object id: (3,) displacement}`` of the push under ``model``."""


@dataclass(frozen=True)
class InteractionData:
    """An observed push: displacement of each object, observed and predicted.

    observed_m / predicted_m : object id -> (3,) displacement of the object, world frame.
    sigma_m : noise of an observed displacement component.
    resting_ids : objects at rest in a rollout without the push of the state the push is
        simulated on (None: that state is the physical residual's, whose movers say it).
    observed_tilt_rad / predicted_tilt_rad : see the fields.
    stage : the stage whose state the push is simulated on.
    """

    observed_m: dict
    predicted_m: dict
    simulate: Optional[InteractionSimulator] = None
    sigma_m: float = 0.005
    pushed_ids: tuple = ()
    resting_ids: Optional[frozenset] = None
    stage: Optional[str] = None
    observed_tilt_rad: dict = field(default_factory=dict)
    predicted_tilt_rad: dict = field(default_factory=dict)
    """object id -> how far the push turned the object's own up direction (rad; 0 for a
    slide or a spin about the vertical, pi for a flip), observed (when measured from the
    images) and predicted under the base model. Tilt, not the whole rotation: a spin
    about the vertical of a symmetric object is not observable."""
    simulate_motion: Optional[Callable[[PhysicsModel], dict]] = None
    """``simulate_motion(model) -> {object id: Motion}`` of the push (rotations too)."""

    def with_prediction(self, predicted_m: dict) -> "InteractionData":
        return replace(self, predicted_m=predicted_m)


# ---- depth residual map (reported and plotted; the scale evidence is in registration) ---

@dataclass(frozen=True)
class DepthMapData:
    """Observed minus rendered depth of the reconstruction, per pixel.

    residual_m : (H, W) float, NaN where either is missing or the ids disagree.
    depth_m : (H, W) observed depth.
    on_object : (H, W) bool, pixels of an object (else table).
    object_id : (H, W) int, the object whose rendered surface the residual is taken against
        (0: table or none), or None.
    grey : (H, W) grey level 0..1 of the image, or None.
    prior_ids : the objects whose shape is a registered prior (a completion is built from
        the same depth, so its residual says nothing about the depth's errors).
    view_cosine : (H, W) |cosine| between the pixel's ray and the rendered surface's normal
        (NaN: none), or None.
    masks : (H, W) int, the input's instance masks (0: none), or None.
    """

    residual_m: np.ndarray
    depth_m: np.ndarray
    on_object: np.ndarray
    object_id: Optional[np.ndarray] = None
    grey: Optional[np.ndarray] = None
    prior_ids: tuple = ()
    view_cosine: Optional[np.ndarray] = None
    masks: Optional[np.ndarray] = None


# ---- table shape: the table points' distance to one plane (r2s.diagnose.stats.table_shape) -----

@dataclass(frozen=True)
class TableShapeData:
    """Table pixels back-projected into the camera frame, for the table's shape.

    points_camera : (N, 3) table points (a seeded subsample of every table pixel with a
        reading), camera frame, as observed (the model's corrections already applied).
    grey : (N,) grey level 0..1 of each point's pixel (None: no image).
    K : (3, 3) intrinsics; width, height : image size, pixels.
    sigma_m : noise level of one tile's mean distance to the plane (table flatness plus
        the depth noise that does not average out over a tile).
    """

    points_camera: np.ndarray
    K: np.ndarray
    width: int
    height: int
    grey: Optional[np.ndarray] = None
    sigma_m: float = 0.001

    @cached_property
    def _tiles(self):
        from r2s.diagnose.stats.table_shape import table_tiles

        return table_tiles(self.points_camera, self.K, self.width, self.height, self.grey)

    def tiles(self):
        """:class:`r2s.diagnose.stats.table_shape.TableTiles` of the points (computed once)."""
        return self._tiles


# ---- everything ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Residuals:
    """All residual groups of one scene under its current model (any may be missing)."""

    registration: Optional[RegistrationData] = None
    support: Optional[SupportData] = None
    physics: Optional[PhysicsData] = None
    interaction: Optional[InteractionData] = None
    depth_map: Optional[DepthMapData] = None
    notes: tuple = ()
    table_shape: Optional[TableShapeData] = None
