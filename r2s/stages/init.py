"""The ``init`` stage: the initial reconstruction (the paper's "SAM3D+ICP" baseline).

From ``input/`` alone: back-project the depth, fit the support plane on the pixels that
belong to no object, then per object either register its prior mesh to the observed
points (robust visibility-aware ICP with a free-space term and a bounded scale; a global
search when no pose is given) or, without a prior, complete a closed mesh from the
observation (height field over the support plane). With ``fit_view`` (off by default),
registered priors are then fitted to their view (pose and a bounded scale per axis against the silhouette, the
depth, the free space and the support plane they rest on; priors reaching into other
objects refitted with them as obstacles; geometry/prior_silhouette.py), and a prior that
still does not match its mask is replaced by the completion. Then, per object still
holding a prior (``prior_choice``, 'auto' by default), the object is also completed from
the observation, both are scored against the view (silhouette IoU with the others
z-buffered, UCD, free space; geometry/prior_choice.py) and the completion replaces the
prior only where it is better on all three by calibrated margins, or where the prior of an
object standing alone on the table rolls away when set down there and the completion rests
at about the same view score (a warning line says which). Where the priors kept overlap
by 5 mm or more somewhere (single-image shapes, wrong where the camera cannot see), each
overlap goes to the prior whose observed surface is nearer and the other's surface there
is moved onto the owner's (``prior_yield_hidden_overlap``), and a prior reaching a few
millimetres below the table has that part moved up onto it (``prior_lift_below_table``;
geometry/hidden_overlap.py).
No dynamics here: settling and stability are left for the later stages.

Object frames: a registered prior keeps its own axes, with the origin moved to the centre
of its bounding box and the estimated scale (per axis with ``fit_view``) applied to the
mesh (``world_from_object`` is rigid); a completed object has the support plane's axes and its origin at the centre of
its footprint, on its base. Extra keys per object in ``state.json``: ``icp_fitness``,
``icp_rmse_m`` (for completed objects: of the observed points against the completed
surface), ``scale``, ``observed_points``, ``num_observed_points``; for an object given a
prior, ``prior_choice``: ``chosen`` ("prior" or "completion") and the ``prior``'s and the
``completion``'s scores (``iou``, ``ucd_mm``, ``free_space``) and, for an object standing alone
on the table, ``rest_alone``: how far each moved (``moved_mm``) and turned (``turned_deg``)
when set down there alone; for a prior whose surface was moved out of another prior
(or the table), ``hidden_overlap``: ``moved_vertices``, ``deepest_mm`` and ``yielded_to``
(ids) (and ``below_table_vertices``).

Writes ``init/``: ``state.json``, ``meshes/<id>.glb`` (object frame, coloured),
``points/<id>.npy`` (the object's observed points, world frame, float32 (N, 3)),
``support_points.npy`` (a subsample of the support plane's points) and ``init.png`` (the
fit drawn over the input image).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Callable, Literal, Optional, Sequence

import numpy as np
import trimesh
from PIL import Image
from pydantic import Field
from scipy import ndimage
from scipy.spatial import cKDTree

from r2s.errors import InputError, StageError
from r2s.forked_map import forked_map
from r2s.geometry import sanity
from r2s.geometry.camera import backproject, instance_points, transform_points
from r2s.geometry.carving import carve_view
from r2s.geometry.colors import color_mesh_from_image, has_appearance
from r2s.geometry.border_extension import border_cap_points
from r2s.geometry.completion import (NO_BRIDGE, RELAXED_BRIDGE, STRICT_BRIDGE, BridgeGuards,
                                      CompletedShape, complete_from_points)
from r2s.geometry.hidden_back import MIN_DEEPER_M, hidden_back
from r2s.geometry.hidden_carrier import HiddenTop, hidden_tops, view_axes
from r2s.geometry.hidden_support import support_extension
from r2s.geometry.hidden_overlap import lift_onto_plane, sunk_too_far, yield_hidden_overlaps
from r2s.geometry.hidden_partition import Claimant, exclusion, overlaps
from r2s.geometry.free_space import view_constraint
from r2s.geometry.mask_edges import foreign_rim_pixels
from r2s.geometry.mask_holes import fill_mask_holes
from r2s.geometry.point_cleanup import object_point_mask, part_labels
from r2s.geometry.silhouette_completion import complete_from_silhouette
from r2s.geometry.silhouette_snap import snap_outline
from r2s.geometry.overlay import fit_overlay, render_instances
from r2s.geometry.prior_choice import (ChoiceMargins, Rest, choose, score_in_view,
                                       stands_alone_on_table)
from r2s.geometry.prior_refine import RefinedPose, RefineOptions, refine_axis_scale
from r2s.geometry.prior_silhouette import SilhouetteFitOptions, fit_priors_to_view
from r2s.geometry.plane import FLOATING_M, PlaneFit, fit_support_plane, signed_distance, \
    standing_gap_m, world_from_plane
from r2s.geometry.registration import (IcpOptions, RegistrationResult, register_prior,
                                       surface_fit, voxel_downsample)
from r2s.geometry.unsegmented import MIN_HEIGHT_M as UNSEGMENTED_MIN_HEIGHT_M
from r2s.geometry.unsegmented import UNSEGMENTED_KEY, unsegmented_regions
from r2s.scene_model import corrected_input
from r2s.io.atomic import atomic_write_bytes
from r2s.io.input_scene import InputScene, ObjectSpec, load_input
from r2s.io.mesh_io import load_mesh, save_mesh
from r2s.io.paths import INIT_ALTERNATES_DIR, INIT_REPLACED_PRIORS_DIR, ScenePaths
from r2s.io.state import DEFAULT_GRAVITY, ObjectState, SceneState, SupportPlane, write_state
from r2s.runner.base import StageContext, StageOptions, StageSpec
from r2s.io.manifest import Manifest

SUPPORT_FRICTION = 0.8
"""Friction written for the support plane (no stage before physopt estimates it)."""

MIN_OBJECT_POINTS = 20


class Options(StageOptions):
    plane_threshold_m: float = Field(0.005, gt=0, description="RANSAC inlier distance of the "
                                     "support plane fit.")
    plane_iterations: int = Field(500, ge=10, description="RANSAC samples of the plane fit.")
    plane_max_tilt_deg: Optional[float] = Field(
        45.0, gt=0, le=90, description="Only planes within this angle of world +z are support "
        "candidates (a wall is not a table); None = any.")
    plane_candidates: int = Field(
        3, ge=1, description="Level planes tried among the background pixels when the objects "
        "float above the largest (the floor seen past the table's edge is not the table); "
        "the support is the one they stand on; 1 = always the largest plane.")
    plane_floating_m: float = Field(
        FLOATING_M, gt=0, description="The objects' gap above the largest plane (a quarter of "
        "the objects' lowest points are farther) at which other planes are tried, and above "
        "the support at which the result is flagged.")
    drop_foreign_rim: bool = Field(
        True, description="Drop mask rim pixels on the far side of a depth jump (a mask "
                          "that bleeds past the outline; see geometry/mask_edges.py).")
    mask_erosion_px: int = Field(0, ge=0, description="Erode each instance mask by this many "
                                 "pixels before back-projecting (drops mixed edge pixels; "
                                 "the robust ICP loss already ignores most of them).")
    voxel_size_m: float = Field(0.002, ge=0, description="Voxel size that evens out the "
                                "observed points' density before registration (0 = off).")
    icp_max_correspondence_m: float = Field(0.04, gt=0, description="Coarsest correspondence "
                                            "distance of the ICP schedule (halved each level).")
    icp_levels: int = Field(4, ge=1, description="Levels of the ICP distance schedule.")
    icp_iterations: int = Field(15, ge=1, description="ICP iterations per level.")
    icp_trim_fraction: float = Field(0.1, ge=0, lt=0.9, description="Fraction of the worst "
                                     "correspondences dropped each ICP iteration.")
    icp_inlier_m: float = Field(0.005, gt=0, description="Distance under which an observed "
                                "point counts as explained (fitness, rmse).")
    silhouette_weight: float = Field(1.0, ge=0, description="Weight of the free-space term: "
                                     "the prior may not cover pixels where the camera sees "
                                     "past it (0 = plain ICP).")
    silhouette_margin_px: float = Field(1.5, gt=0, description="How far (pixels) outside "
                                        "its mask a prior may project before the "
                                        "free-space term pushes it back; raise it for "
                                        "masks with uncertain edges.")
    silhouette_unread_others_seen_past: bool = Field(
        False, description="Free-space term: a pixel of another instance's mask without a "
                           "depth reading counts as seen past, as everywhere else (the rule "
                           "before 2026-11-25). Off: it says nothing, since that instance may "
                           "hide this one there (geometry/free_space.py).")
    icp_yaw_hypotheses: int = Field(8, ge=1, description="With a given prior pose, also try "
                                    "it turned about the support normal by 360/N degree "
                                    "steps (1 = only the given pose).")
    estimate_scale: bool = Field(True, description="Estimate an isotropic scale correction "
                                 "of each prior with its pose.")
    scale_min: float = Field(0.85, gt=0, le=1, description="Smallest allowed prior scale.")
    scale_max: float = Field(1.15, ge=1, description="Largest allowed prior scale.")
    scale_prior_weight: float = Field(0.0, ge=0, description="Pull of the scale towards 1 "
                                      "(0 = none: the free-space term bounds it).")
    global_fallback_fitness: float = Field(0.5, ge=0, le=1, description="Run the global pose "
                                           "search too when ICP from the given prior pose "
                                           "explains fewer observed points than this.")
    axis_scale: bool = Field(False, description="After registration, refine the prior's "
                             "scale per axis (single-image priors get proportions wrong per "
                             "axis) with its pose, and keep it out of the support plane "
                             "(geometry/prior_refine.py). Off by default: measured neutral "
                             "on init's CD (docs/realistic.md).")
    axis_scale_min: float = Field(0.8, gt=0, le=1, description="Smallest per-axis scale.")
    axis_scale_max: float = Field(1.25, ge=1, description="Largest per-axis scale.")
    rest_on_support: bool = Field(False, description="With axis_scale: pull a prior whose "
                                  "bottom is within 20 mm of the support plane onto it (else "
                                  "only out of it).")
    fit_view: bool = Field(False, description="After registration, fit each prior's pose "
                           "and per-axis scale to its silhouette, depth, the free space "
                           "around it and the support plane it is seen resting on "
                           "(geometry/prior_silhouette.py).")
    fit_view_scale_min: float = Field(0.82, gt=0, le=1, description="Smallest per-axis "
                                      "scale of fit_view (relative to the prior).")
    fit_view_scale_max: float = Field(1.22, ge=1, description="Largest per-axis scale of "
                                      "fit_view.")
    fit_view_evaluations: int = Field(400, ge=10, description="Cost evaluations per object "
                                      "of fit_view.")
    prior_fallback_iou: float = Field(0.5, ge=0, le=1, description="With fit_view: a prior "
                                      "whose fitted silhouette IoU against its own mask "
                                      "stays below this is replaced by the completion "
                                      "from the observation (flagged).")
    prior_choice: Literal["auto", "prior", "completion"] = Field(
        "auto", description="Per object with a prior: 'auto' also completes it from the "
        "observation, scores both against the view (silhouette IoU with the others "
        "z-buffered, UCD, free space) and keeps the completion only where it is better on "
        "all three by the margins below (geometry/prior_choice.py); 'prior' always keeps "
        "the prior, 'completion' always completes (both scored and recorded).")
    prior_choice_iou_gain: float = Field(0.05, ge=0, le=1, description="'auto': the "
                                         "completion's silhouette IoU must exceed the "
                                         "prior's by at least this.")
    prior_choice_ucd_gain_mm: float = Field(1.0, ge=0, description="'auto': ... and its UCD "
                                            "must be lower by at least this, mm.")
    prior_choice_free_space_slack: float = Field(0.02, ge=0, description="'auto': ... and "
                                                 "its free-space violation may exceed the "
                                                 "prior's by at most this.")
    prior_choice_large_iou_gain: float = Field(0.10, ge=0, le=1, description="'auto': a "
                                               "completion whose silhouette IoU exceeds the "
                                               "prior's by at least this replaces it with any "
                                               "UCD gain (none lost) and the free-space slack.")
    prior_choice_large_ucd_gain_mm: float = Field(2.0, ge=0, description="'auto': a "
                                                  "completion whose UCD is at most half the "
                                                  "prior's and lower by at least this (mm) "
                                                  "replaces it when its IoU is at most 0.05 "
                                                  "lower (geometry/prior_choice.py).")
    prior_choice_rest: bool = Field(True, description="'auto': also set the prior and the "
                                    "completion of an object standing alone on the table "
                                    "down there and roll each out for 1 s; a prior that "
                                    "moves >= 10 mm or turns >= 15 deg gives way to a "
                                    "completion that rests and is at most 0.02 worse in "
                                    "silhouette IoU, 0.5 mm in UCD and 0.02 in free space "
                                    "(geometry/prior_choice.py RestRule).")
    completion_cell_m: float = Field(0.002, gt=0, description="Grid cell of the height-field "
                                     "completion of objects without a prior, m (0.003 "
                                     "before 2026-11-27: its walls stood up to a pixel "
                                     "outside the silhouette; docs/completion.md).")
    completion_hull_margin_px: float = Field(0.25, ge=0, description="Grow a completed "
                                             "object's footprint by this many pixels' "
                                             "footprint on the surface.")
    completion_clean_points: bool = Field(
        True, description="Before completing, drop mask points on the support plane and "
                          "regions of the mask across a depth jump from the object's main "
                          "surface (bleed; see geometry/point_cleanup.py).")
    completion_parts_by_mask: bool = Field(
        True, description="In the point cleanup, size the parts of a mask cut apart by an "
                          "occluder by their mask pixels, not their depth readings, so a "
                          "thin part that reads depth in few pixels is not dropped as a "
                          "speck (see geometry/point_cleanup.py).")
    completion_footprint_by_part: bool = Field(
        True, description="A completed object seen in parts of its mask cut apart by an "
                          "occluder gets the union of the parts' own footprints, not one "
                          "hull across the occluder, where another object is seen standing "
                          "between the parts (see geometry/completion.py).")
    completion_fill_holes_px: float = Field(
        6.0, ge=0, description="Before completing, give each mask pixel without a depth "
                               "reading within this many pixels of a kept point a point on "
                               "its ray (completion_fill_holes_rule says where), so the "
                               "footprint covers the mask where the sensor read nothing "
                               "(dark, glossy and thin surfaces, the band along depth edges, "
                               "the grazing top and back of round objects). 0 = off, the "
                               "default before 2026-11-27 (see geometry/mask_holes.py, "
                               "docs/completion.md).")
    completion_fill_holes_rule: Literal["depth", "height"] = Field(
        "height", description="With completion_fill_holes_px: 'depth' gives an unread pixel "
                              "its nearest kept point's depth; 'height' does too, unless its "
                              "ray passes above that point there: then it takes the depth "
                              "where the ray comes down to the point's height above the "
                              "table (the grazing top and back of a round object; see "
                              "geometry/mask_holes.py).")
    completion_carve: bool = Field(
        True, description="Carve a completed object against the depth image: no material "
                          "where the camera saw past it (see geometry/carving.py).")
    completion_snap_outline_px: float = Field(
        2.0, ge=0, description="After completing, move the shape's outer silhouette, in the "
                               "support plane, onto its mask's sub-pixel outline by at most "
                               "this many pixels per pass (3 passes), where the outline meets "
                               "background and the camera did not see past the new surface; "
                               "0 = off, the default before 2026-11-28 (see "
                               "geometry/silhouette_snap.py, docs/completion.md).")
    completion_carve_band_px: int = Field(
        1, ge=0, description="Carving spares the mask's uncertain rim: this many pixels "
                             "outside the object's kept pixels, where mixed readings and "
                             "mask bleed put the reading on the wrong surface (see "
                             "geometry/carving.py).")
    completion_other_inner_px: int = Field(
        3, ge=0, description="Pixels at least this many pixels inside another instance's "
                             "mask show that object: a completed object keeps nothing in "
                             "front of their readings (no sensor margin), and loses every "
                             "column whose top the camera saw there at about its depth "
                             "(nothing hid that top); 0 = off (see geometry/carving.py, "
                             "geometry/completion.py).")
    completion_other_mask_margin_m: float = Field(
        0.002, description="A completed object keeps nothing more than this far (metres) in "
                           "front of the reading at any pixel of another instance's mask "
                           "outside its own rim band (the camera saw that object there); "
                           "negative = off, the default before 2026-11-29 (see "
                           "geometry/carving.py, docs/completion.md).")
    completion_carve_silhouette: bool = Field(
        True, description="Carve a completed object where the sensor read no depth but no "
                          "instance mask covers the pixel (the camera saw background there: "
                          "the stereo shadow beside objects, a dark table; see "
                          "geometry/carving.py).")
    completion_carve_table: bool = Field(
        True, description="Carve against the fitted support plane where the camera sees the "
                          "table (a 2 mm margin instead of the sensor's; see "
                          "geometry/carving.py).")
    completion_partition_hidden: bool = Field(
        True, description="Where two completed objects fill the same hidden space, give it "
                          "to the one whose observed surface is nearer (a prior keeps all "
                          "of its inside; see geometry/hidden_partition.py).")
    prior_yield_hidden_overlap: bool = Field(
        True, description="In a scene whose registered priors overlap by 5 mm or more "
                          "somewhere (single-image shapes), give each overlap to the prior "
                          "whose observed surface is nearer and move the other's surface "
                          "there onto the owner's (space the camera cannot see: the render "
                          "does not change, and the later stages need not push the objects "
                          "apart; see geometry/hidden_overlap.py).")
    prior_lift_below_table: bool = Field(
        True, description="In such a scene, also move the part of a prior that reaches at "
                          "most 5 mm below the table up onto it (deeper is a pose error: "
                          "geomopt lifts the whole object; see geometry/hidden_overlap.py).")
    completion_rest_on_others: bool = Field(
        True, description="When a completed object is completed again without the hidden "
                          "space others own: in every column where another object's top "
                          "lies below its top, its base rests on that object instead of "
                          "reaching down to the table (see geometry/completion.py).")
    completion_hidden_tops: bool = Field(
        True, description="A completed object that shows no top of its own (a face only) "
                          "and carries another object whose lowest points touch its top "
                          "edge gets a hidden top under that object, and the carried "
                          "object stands on it (see geometry/hidden_carrier.py).")
    completion_hidden_supports: bool = Field(
        True, description="A completed object whose centre of mass is not over what its "
                          "base touches gets the least continuation of one completed "
                          "carrier's top under it that carries it (the part of the carrier "
                          "it hides; see geometry/hidden_support.py).")
    completion_bridge_alternative: bool = Field(
        True, description="When a completed object lying across others is not bridged "
                           "only because of the strict guards, also complete it with "
                           "looser ones (geometry/completion.py RELAXED_BRIDGE) into "
                           "init/alternates/; when it is bridged, also complete it "
                           "unbridged (its free columns reaching down to the table); for "
                           "physopt to swap in where the first completion cannot rest "
                           "near where it was seen.")
    completion_table_alternative: bool = Field(
        True, description="A completed object whose base rests on other objects (more than "
                          "10 mm above the table) is also completed down to the table "
                          "through the space hidden from the camera, into init/alternates/ "
                          "(a top seen above an occluder may belong to something standing "
                          "behind it); for physopt to swap in where the first completion "
                          "cannot rest near where it was seen.")
    completion_deepened_alternative: bool = Field(
        True, description="A completed object standing on the table that was seen only as "
                          "a face (something nearer hides its top) is also completed with a "
                          "hidden back as deep as the face is wide, into init/alternates/ "
                          "(r2s/geometry/hidden_back.py), for physopt to swap in where the "
                          "first completion cannot rest near where it was seen.")
    completion_extend_fraction: float = Field(
        0.0, ge=0, description="Sweep a completed object's footprint towards the camera "
                               "into space hidden by nearer things, by up to this fraction "
                               "of its visible size (0 = off; see geometry/completion.py).")
    completion_border_extent_m: float = Field(
        0.15, ge=0, description="An object a left or right image border cuts is completed "
                                "beyond it: its visible part next to the cut continued, as "
                                "far as it is seen deep and wide, at most this far (0 = end "
                                "at the border; see geometry/border_extension.py).")
    silhouette_min_px: int = Field(
        200, ge=0, description="An instance whose mask has too few depth readings to be "
                               "completed (a transparent, black or mirror-like object) is "
                               "built from its silhouette standing on the table when its "
                               "mask has at least this many pixels; source 'silhouette', "
                               "with a warning (see geometry/silhouette_completion.py). "
                               "0 = never: such instances are left out.")
    find_unsegmented: bool = Field(True, description="Look for unmasked things standing on "
                                   "the table (a segmenter's missed objects; "
                                   "r2s/geometry/unsegmented.py): a warning line each, "
                                   "listed in state.json, and the objects that may rest on "
                                   "one flagged in the export.")
    support_points_max: int = Field(20000, ge=100, description="Most support-plane points "
                                    "kept in support_points.npy.")
    seed: int = Field(0, description="Random seed (RANSAC, subsampling).")


def inputs(paths: ScenePaths, options: Options, manifest: Manifest) -> list[Path]:
    return [paths.input]


def _icp_options(o: Options) -> IcpOptions:
    schedule = tuple(o.icp_max_correspondence_m / 2 ** k for k in range(o.icp_levels))
    return IcpOptions(max_correspondence_m=schedule, iterations_per_level=o.icp_iterations,
                      trim_fraction=o.icp_trim_fraction, estimate_scale=o.estimate_scale,
                      scale_bounds=(o.scale_min, o.scale_max),
                      scale_prior_weight=o.scale_prior_weight, inlier_m=o.icp_inlier_m,
                      global_fallback_fitness=o.global_fallback_fitness,
                      silhouette_weight=o.silhouette_weight,
                      local_yaw_steps=o.icp_yaw_hypotheses, seed=o.seed)


def _fit_support(scene: InputScene, o: Options) -> tuple[PlaneFit, np.ndarray]:
    """The support plane and the (subsampled) mask-0 points it was fitted on."""
    cam = scene.camera
    points = backproject(scene.depth_m, cam.K, cam.world_from_camera, scene.masks == 0)
    if len(points) < 100:
        raise StageError("too few depth pixels outside the object masks to fit the support "
                         f"plane ({len(points)}; need 100)")
    rng = np.random.default_rng(o.seed)
    if len(points) > 200000:
        points = points[rng.choice(len(points), size=200000, replace=False)]
    try:
        objects = instance_points(scene.depth_m, cam.K, cam.world_from_camera, scene.masks,
                                  scene.ids, rng, per_instance=4000)
        fit = fit_support_plane(points, objects,
                                threshold_m=o.plane_threshold_m,
                                iterations=o.plane_iterations, seed=o.seed,
                                viewpoint=cam.world_from_camera[:3, 3],
                                max_tilt_deg=o.plane_max_tilt_deg,
                                max_candidates=o.plane_candidates,
                                floating_m=o.plane_floating_m)
    except ValueError as exc:
        raise StageError(f"no support plane found: {exc}") from None
    return fit, points


def _prior_size_flags(scene: InputScene, observed: dict) -> list[str]:
    """A warning line when the priors, taken together, disagree in size with the depth
    (:func:`r2s.geometry.sanity.priors_disagree_with_depth`; ``observed``: id -> (points,
    pixels)). Degenerate priors and objects seen by too few points are left out."""
    ratios = []
    for spec in scene.objects:
        pts = observed[spec.id][0]
        if spec.prior_mesh is None or len(pts) < MIN_OBJECT_POINTS:
            continue
        prior = load_mesh(spec.prior_mesh)
        if sanity.degenerate_prior(prior) is None:
            ratios.append(sanity.prior_size_ratio(prior, pts))
    problem = sanity.priors_disagree_with_depth(ratios)
    return [problem] if problem else []


def _support_flags(plane: PlaneFit, observed: dict, o: Options) -> list[str]:
    """A warning line when the objects float above the support (``observed``: id ->
    (points, pixels)): the table they stand on was not found."""
    gap_m = standing_gap_m(plane, [pts for pts, _ in observed.values()])
    if not gap_m > o.plane_floating_m:
        return []
    return [f"support plane: the objects' lowest points are {1000 * gap_m:.0f} mm or more "
            "above it (three quarters of the objects): the table they stand on may not be in "
            "view, or may not be level"]


def _unsegmented(scene: InputScene, plane: PlaneFit, observed: dict, o: Options,
                 flags: list[str]) -> tuple[dict[str, list[dict]], np.ndarray | None]:
    """Unmasked things standing on the table (r2s/geometry/unsegmented.py): the state's
    extra key with their records (``rests_on_it``: the touching objects whose lowest
    observed points are above the table and no higher than the region's top, so that it
    may carry them; none found: no key) and their pixels, (H, W) bool or None; a warning
    line in ``flags`` for each of the largest three."""
    if not o.find_unsegmented:
        return {}, None
    cam = scene.camera
    regions = unsegmented_regions(scene.depth_m, cam.K, cam.world_from_camera, scene.masks,
                                  plane.point, plane.normal)
    records, lines = [], []
    for k, r in enumerate(regions):
        carried = []
        for i in r.touching_ids:
            pts = observed.get(i, (np.zeros((0, 3)),))[0]
            if len(pts) == 0:
                continue
            low = float(np.percentile(signed_distance(pts, plane.point, plane.normal), 1))
            if UNSEGMENTED_MIN_HEIGHT_M < low <= r.height_m + UNSEGMENTED_MIN_HEIGHT_M:
                carried.append(i)
        records.append({"area_px": r.area_px, "box_px": list(r.box_px),
                        "height_m": round(r.height_m, 4),
                        "centre_world": [round(float(v), 5) for v in r.centre_world],
                        "world_from_box": r.world_from_box.round(5).tolist(),
                        "size_m": [round(float(v), 4) for v in r.size_m],
                        "touching_ids": list(r.touching_ids), "rests_on_it": carried})
        if k < 3:
            what = (f"; object{'s' if len(carried) > 1 else ''} "
                    f"{', '.join(map(str, carried))} may rest on it and be reconstructed as "
                    "if on the table" if carried else "")
            lines.append(f"unsegmented: {r.describe()}: an object without a mask? It is left "
                         f"out of the twin{what}")
    if len(regions) > 3:
        lines.append(f"unsegmented: {len(regions) - 3} more such regions (init/state.json)")
    flags += lines
    if not records:
        return {}, None
    return {UNSEGMENTED_KEY: records}, np.any([r.pixels for r in regions], axis=0)


def _object_points(scene: InputScene, obj_id: int, o: Options, plane: PlaneFit
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The instance's world points and their (row, col) pixels (mask optionally eroded;
    points clearly below the support plane dropped)."""
    cam = scene.camera
    mask = scene.masks == obj_id
    if o.mask_erosion_px > 0:
        eroded = ndimage.binary_erosion(mask, iterations=o.mask_erosion_px)
        if np.count_nonzero(eroded & np.isfinite(scene.depth_m)) >= MIN_OBJECT_POINTS:
            mask = eroded
    pts, pix = backproject(scene.depth_m, cam.K, cam.world_from_camera, mask,
                           return_pixels=True)
    keep = signed_distance(pts, plane.point, plane.normal) > -2 * o.plane_threshold_m
    if o.drop_foreign_rim and len(pts):
        keep &= ~foreign_rim_pixels(scene.depth_m, mask)[pix[:, 0], pix[:, 1]]
    if keep.sum() >= MIN_OBJECT_POINTS:
        pts, pix = pts[keep], pix[keep]
    return pts, pix


def _checked_prior(spec: ObjectSpec, pts: np.ndarray, flags: list[str]) -> trimesh.Trimesh:
    """The prior mesh, refused when degenerate or in other units (one line naming it); a
    size that is merely doubtful is added to ``flags``."""
    prior = load_mesh(spec.prior_mesh)
    problem = sanity.degenerate_prior(prior)
    if problem is None:
        problem, is_error = sanity.prior_size_problem(prior, pts)
        if problem and not is_error:
            flags.append(f"object {spec.id}: {problem}")
            problem = None
    if problem:
        raise InputError(spec.prior_mesh, f"object {spec.id}: {problem}")
    return prior


def _register(scene: InputScene, spec: ObjectSpec, pts: np.ndarray, plane: PlaneFit,
              o: Options, flags: list[str]
              ) -> tuple[trimesh.Trimesh, RefinedPose, RegistrationResult]:
    """The prior (its own frame), its registered pose (object frame: origin at the prior's
    bounding-box centre; scale per axis) and the registration's result."""
    cam = scene.camera
    prior = _checked_prior(spec, pts, flags)
    others = (None if o.silhouette_unread_others_seen_past
              else (scene.masks > 0) & (scene.masks != spec.id))
    view = view_constraint(cam.K, cam.world_from_camera, scene.depth_m, scene.masks == spec.id,
                           margin_px=o.silhouette_margin_px, other_masks=others)
    reg_pts = voxel_downsample(pts, o.voxel_size_m)
    if len(reg_pts) < MIN_OBJECT_POINTS:
        reg_pts = pts
    try:
        result = register_prior(prior, reg_pts, spec.world_from_prior, view=view,
                                up=plane.normal, options=_icp_options(o))
    except ValueError as exc:
        raise StageError(f"object {spec.id}: registration failed ({exc})") from None
    centre = 0.5 * (prior.vertices.min(axis=0) + prior.vertices.max(axis=0))
    pose = RefinedPose(world_from_object=result.world_from_object,
                       axis_scale=np.full(3, result.scale), centre=centre, on_support=False)
    if o.axis_scale:
        pose = refine_axis_scale(
            prior, reg_pts, result.world_from_object, result.scale, cam.world_from_camera[:3, 3],
            view, (plane.point, plane.normal),
            RefineOptions(scale_bounds=(o.axis_scale_min, o.axis_scale_max), seed=o.seed,
                          support_one_sided=not o.rest_on_support, contact_m=0.02))
    return prior, pose, result


def _fit_priors(scene: InputScene, priors: dict[int, tuple[trimesh.Trimesh, RefinedPose]],
                shapes: dict[int, tuple], plane: PlaneFit, o: Options) -> dict[int, float]:
    """Set each prior's mesh (object frame, coloured) and pose in ``shapes`` (id ->
    (mesh, world_from_object, registration or None)), fitted to its view and kept out of
    the other objects when ``fit_view`` (geometry/prior_silhouette.py). Returns the
    silhouette IoU of each fit against its own mask (empty without ``fit_view``)."""
    cam = scene.camera
    poses = {i: pose for i, (_, pose) in priors.items()}
    ious: dict[int, float] = {}
    if o.fit_view and priors:
        fixed = {i: _posed(mesh, pose) for i, (mesh, pose, _) in shapes.items()
                 if i not in priors}
        fo = SilhouetteFitOptions(scale_bounds=(o.fit_view_scale_min, o.fit_view_scale_max),
                                  max_evaluations=o.fit_view_evaluations)
        fits = fit_priors_to_view(priors, fixed, cam.K, cam.world_from_camera, scene.depth_m,
                                  scene.masks, (plane.point, plane.normal), fo)
        poses = {i: f.pose for i, f in fits.items()}
        ious = {i: f.after.iou for i, f in fits.items()}
    for i, pose in poses.items():
        mesh, world_from_object = pose.object_mesh(priors[i][0])
        if not has_appearance(mesh):
            mesh = color_mesh_from_image(mesh, world_from_object, scene.rgb, scene.depth_m,
                                         cam.K, cam.world_from_camera, scene.masks == i)
        shapes[i] = (mesh, world_from_object, shapes[i][2])
    return ious


def _fallback_to_completion(scene: InputScene, observed: dict, shapes: dict[int, tuple],
                            ious: dict[int, float], plane: PlaneFit, o: Options,
                            flags: list[str]) -> None:
    """Replace (in ``shapes``) each prior whose fitted silhouette IoU is below
    ``prior_fallback_iou`` by the completion from the observation, with a flag."""
    specs = {spec.id: spec for spec in scene.objects}
    for i, iou in sorted(ious.items()):
        if iou >= o.prior_fallback_iou:
            continue
        mesh, world_from_object = _complete(scene, specs[i], observed, plane, o)
        shapes[i] = (mesh, world_from_object, None)
        flags.append(f"object {i}: its prior does not fit what the camera saw (silhouette "
                     f"IoU {iou:.2f} < {o.prior_fallback_iou:.2f}); completed from the "
                     "observation instead")


def _posed(mesh: trimesh.Trimesh, world_from_object: np.ndarray) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).apply_transform(
        world_from_object)


def _choose_prior_or_completion(scene: InputScene, observed: dict, shapes: dict[int, tuple],
                                plane: PlaneFit, o: Options, flags: list[str]
                                ) -> tuple[dict[int, dict], dict[int, tuple], dict[int, tuple]]:
    """Per object still holding a registered prior: complete it from the observation too,
    score both against the view with every other object as it stands (so the choice does
    not depend on the order of the objects) and, by ``o.prior_choice``, keep one (in
    ``shapes``; geometry/prior_choice.py). Returns id -> {chosen, prior, completion} (the
    scores), for the state's extra keys, id -> (mesh, world_from_object) of the
    completions of the priors kept (physopt may still swap them in), and the same of the
    registered priors replaced (diagnose still measures their scale)."""
    cam = scene.camera
    specs = {spec.id: spec for spec in scene.objects}
    posed = {i: _posed(mesh, pose) for i, (mesh, pose, _) in shapes.items()}
    margins = ChoiceMargins(iou_gain=o.prior_choice_iou_gain,
                            large_iou_gain=o.prior_choice_large_iou_gain,
                            ucd_gain_mm=o.prior_choice_ucd_gain_mm,
                            free_space_slack=o.prior_choice_free_space_slack,
                            large_ucd_gain_mm=o.prior_choice_large_ucd_gain_mm)
    def judge(i: int) -> tuple[Optional[tuple], dict, Optional[str]]:
        """(the completion or None, the record, a flag line or None) of prior ``i``."""
        others = [(j, m) for j, m in posed.items() if j != i]
        try:
            completion = _complete(scene, specs[i], observed, plane, o)
        except StageError:  # too few or collinear points: nothing to compare, keep the prior
            return None, {"chosen": "prior", "prior": None, "completion": None}, None
        scores = [score_in_view(candidate, i, others, observed[i][0], cam.K,
                                cam.world_from_camera, scene.depth_m, scene.masks)
                  for candidate in (posed[i], _posed(*completion))]
        rest = None
        if o.prior_choice_rest and stands_alone_on_table(
                posed[i], [m for _, m in others], plane.point, plane.normal):
            try:
                rest = tuple(_rest_alone(mesh, pose, plane)
                             for mesh, pose in (shapes[i][:2], completion))
            except ValueError:  # a flat or degenerate candidate: the view decides alone
                rest = None
        chosen, numbers = choose(scores[0], scores[1], margins, rest)
        if o.prior_choice != "auto":
            chosen = o.prior_choice
        record = {"chosen": chosen, "prior": scores[0].as_dict(),
                  "completion": scores[1].as_dict()}
        if rest is not None:
            record["rest_alone"] = {name: r.as_dict()
                                    for name, r in zip(("prior", "completion"), rest)}
        flag = None
        if chosen == "completion":
            flag = (f"object {i}: its prior was replaced by the completion from the "
                    f"observation ({numbers})")
        return completion, record, flag

    # each prior against the others as they stand, independent: side by side on the cores
    ids = sorted(i for i, shape in shapes.items() if shape[2] is not None)
    records: dict[int, dict] = {}
    completions: dict[int, tuple] = {}
    for i, (completion, record, flag) in zip(ids, forked_map(judge, ids)):
        records[i] = record
        if completion is not None:
            completions[i] = completion
        if flag:
            flags.append(flag)
    replaced = {}
    for i, record in records.items():
        if record["chosen"] == "completion":
            replaced[i] = shapes[i][:2]
            shapes[i] = (*completions[i], None)
    return records, {i: completions[i] for i, r in records.items()
                     if r["chosen"] == "prior" and i in completions}, replaced


def _save_alternates(out: Path, alternates: dict[int, tuple], scene: InputScene,
                     plane: PlaneFit, bridged: Optional[dict[int, tuple]] = None) -> None:
    """``init/alternates/``: the completion of every prior kept and the second completion
    of the completed objects that have one (``bridged``: id -> (mesh, pose, kind);
    ``meshes/<id>.glb``, object frame, and ``state.json`` with its pose), for physopt to
    swap in where the object as init keeps it can rest only far from where it was seen.
    The second kind carries ``alternate``: ``"bridged completion"``, ``"unbridged
    completion"``, ``"completion to the table"`` or ``"deepened completion"``."""
    kinds = {i: v[2] for i, v in (bridged or {}).items()}
    alternates = {**alternates, **{i: v[:2] for i, v in (bridged or {}).items()}}
    _save_shapes(out / INIT_ALTERNATES_DIR, alternates, scene, plane, source="completed",
                 extra={i: {"alternate": k} for i, k in kinds.items()})


def _save_shapes(folder: Path, shapes: dict[int, tuple], scene: InputScene, plane: PlaneFit,
                 source: str, extra: Optional[dict[int, dict]] = None) -> None:
    """``folder/meshes/<id>.glb`` (object frame) and ``folder/state.json`` (poses, ``source``,
    per id the ``extra`` keys) of ``shapes``: id -> (mesh, world_from_object); nothing
    when it is empty."""
    if not shapes:
        return
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    labels = {spec.id: spec.label for spec in scene.objects}
    objects = []
    for i, (mesh, pose) in sorted(shapes.items()):
        save_mesh(mesh, folder / "meshes" / f"{i}.glb")
        objects.append(ObjectState(id=i, label=labels[i], mesh=f"meshes/{i}.glb",
                                   world_from_object=np.asarray(pose).tolist(),
                                   source=source, **(extra or {}).get(i, {})))
    write_state(folder, SceneState(
        stage="init", gravity=list(DEFAULT_GRAVITY), support=_support_plane(plane),
        objects=objects))


def _support_plane(plane: PlaneFit) -> SupportPlane:
    return SupportPlane(point=[float(v) for v in plane.point],
                        normal=[float(v) for v in plane.normal], friction=SUPPORT_FRICTION)


def _rest_alone(mesh: trimesh.Trimesh, world_from_object: np.ndarray, plane: PlaneFit
                ) -> Rest:
    """How far ``mesh`` (object frame) at ``world_from_object`` goes when set down alone on
    the support plane and rolled out (sim/rest_on_plane.py)."""
    from r2s.sim.rest_on_plane import rest_on_plane  # pybullet: only where a prior is tested

    r = rest_on_plane(mesh, world_from_object, plane.point, plane.normal)
    return Rest(moved_m=r.moved_m, turned_deg=r.turned_deg, com_drop_m=r.com_drop_m)


def _complete(scene: InputScene, spec: ObjectSpec, observed: dict, plane: PlaneFit,
              o: Options, exclude: Optional[Callable[[np.ndarray], np.ndarray]] = None,
              under: Sequence[trimesh.Trimesh] = (),
              bridge_guards: BridgeGuards = STRICT_BRIDGE) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A closed, coloured mesh completed from the observation (object frame) and its pose.
    ``observed``: id -> (points, pixels) of every object; the others' points are what the
    object may stand on; ``under``: other objects' meshes (world frame) it may lie across
    (its base rests on their tops, column by column, when ``bridge_guards`` allow).
    :func:`_complete_shape` also says whether it was bridged."""
    shape = _complete_shape(scene, spec, observed, plane, o, exclude, under, bridge_guards)
    return shape.mesh, shape.world_from_object


def _complete_shape(scene: InputScene, spec: ObjectSpec, observed: dict, plane: PlaneFit,
                    o: Options, exclude: Optional[Callable[[np.ndarray], np.ndarray]] = None,
                    under: Sequence[trimesh.Trimesh] = (),
                    bridge_guards: BridgeGuards = STRICT_BRIDGE,
                    stand_on_others: bool = True) -> CompletedShape:
    """:func:`_complete`'s :class:`r2s.geometry.completion.CompletedShape`; with
    ``stand_on_others`` False the other objects' points are not taken for what it stands
    on (its hidden columns reach the table)."""
    tops = getattr(observed, "hidden_tops", {})
    others = [(tops[j].support_world(observed[j][0], plane.point, plane.normal)
               if j in tops and tops[j].carried_id == spec.id
               else _with_hidden_top(observed[j][0], tops, j))
              for j in sorted(observed) if j != spec.id] or None
    cam = scene.camera
    raw_pix = observed[spec.id][1]
    pixel_m = float(np.median(scene.depth_m[raw_pix[:, 0], raw_pix[:, 1]])) / float(cam.K[0, 0])
    own = scene.masks == spec.id
    own_px = np.argwhere(own)
    other_masks = (scene.masks > 0) & ~own
    pts, pix = _clean_points(scene, *observed[spec.id], own_px, other_masks, plane, o)
    filled, filled_pix = fill_mask_holes(own, scene.depth_m, pix, cam.K,
                                         cam.world_from_camera, o.completion_fill_holes_px,
                                         others=other_masks,
                                         up=(plane.normal
                                             if o.completion_fill_holes_rule == "height"
                                             else None))
    table = (plane.point, plane.normal) if o.completion_carve_table else None
    view = (carve_view(cam.K, cam.world_from_camera, scene.depth_m, pix, plane=table,
                       band_px=o.completion_carve_band_px,
                       masks=scene.masks if o.completion_carve_silhouette else None,
                       other_inner_px=o.completion_other_inner_px,
                       other_mask_margin_m=(o.completion_other_mask_margin_m
                                            if o.completion_other_mask_margin_m >= 0
                                            else None))
            if o.completion_carve else None)
    cap, cap_src = np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    if o.completion_border_extent_m > 0:
        cap, cap_src = border_cap_points(pts, pix, cam.K, cam.world_from_camera, cam.width,
                                         cam.height, plane.point, plane.normal,
                                         max_extent_m=o.completion_border_extent_m,
                                         others_world=np.concatenate(others) if others
                                         else None)
    # the hidden top's points take their pixel (for colour and parts) from the nearest seen one
    own_top = (_with_hidden_top(np.zeros((0, 3)), tops, spec.id) if len(pts)
               else np.zeros((0, 3)))
    top_src = cKDTree(pts).query(own_top)[1] if len(own_top) else np.zeros(0, dtype=np.int64)
    try:
        both_pix = np.concatenate([pix, filled_pix, pix[cap_src], pix[top_src]])
        parts = part_labels(both_pix, own_px)[0] if o.completion_footprint_by_part else None
        shape = complete_from_points(np.concatenate([pts, filled, cap, own_top]), plane.point,
                                     plane.normal,
                                     colors=scene.rgb[both_pix[:, 0], both_pix[:, 1]],
                                     cell_m=o.completion_cell_m,
                                     below_points_world=others if stand_on_others else None,
                                     hull_margin_m=o.completion_hull_margin_px * pixel_m,
                                     view=view,
                                     extend_fraction=o.completion_extend_fraction,
                                     exclude=exclude,
                                     under_meshes_world=under if o.completion_rest_on_others
                                     else (), point_parts=parts,
                                     bridge_guards=bridge_guards)
    except ValueError as exc:
        raise StageError(f"object {spec.id}: completion failed ({exc})") from None
    return shape


def _clean_points(scene: InputScene, pts: np.ndarray, pix: np.ndarray, own_px: np.ndarray,
                  other_masks: np.ndarray, plane: PlaneFit, o: Options
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The object's observed points (N, 3) world and pixels (N, 2) without those that are
    not its own (bleed onto the table or a neighbour, flying pixels:
    geometry/point_cleanup.py), when ``completion_clean_points``. ``own_px`` (K, 2): its
    mask's pixels; ``other_masks`` (H, W) bool: the other objects' masks."""
    if not o.completion_clean_points:
        return pts, pix
    other_px = np.argwhere(other_masks)
    keep = object_point_mask(pts, pix, scene.depth_m[pix[:, 0], pix[:, 1]], plane.point,
                             plane.normal, neighbour_pixels=other_px,
                             neighbour_depth_m=scene.depth_m[other_px[:, 0], other_px[:, 1]],
                             mask_pixels=own_px if o.completion_parts_by_mask else None)
    return pts[keep], pix[keep]


class ObservedPoints(dict):
    """id -> (points (N, 3) world, pixels (N, 2) row, col) of every object, as
    :func:`_object_points` gives them, and ``hidden_tops``: carrier id -> the hidden top
    under what it carries (:func:`_hidden_tops`), made once for every completion."""

    def __init__(self, points: dict[int, tuple[np.ndarray, np.ndarray]]) -> None:
        super().__init__(points)
        self.hidden_tops: dict[int, HiddenTop] = {}


def _hidden_tops(scene: InputScene, observed: dict, plane: PlaneFit, o: Options
                 ) -> dict[int, HiddenTop]:
    """Carrier id -> the hidden top under what it carries (geometry/hidden_carrier.py),
    for objects completed from the observation (a registered prior keeps its shape). Made
    once from the observed points as they are: the mixed pixels where two masks meet are
    part of the evidence that one object touches the other (measured: with the points as
    a completion cleans them, a cup standing on a can whose lid it hides was no longer
    found; docs/completion.md)."""
    if not o.completion_hidden_tops:
        return {}
    return hidden_tops({i: p for i, (p, _) in observed.items()}, plane.point, plane.normal,
                       scene.camera.world_from_camera[:3, 3], cell_m=o.completion_cell_m,
                       carriers={s.id for s in scene.objects if s.prior_mesh is None})


def _extend_hidden_supports(scene: InputScene, observed: ObservedPoints,
                            shapes: dict[int, tuple], plane: PlaneFit, o: Options
                            ) -> dict[int, int]:
    """Per completed object whose centre of mass is not over what its base touches, the
    least continuation of one completed carrier's top under it
    (geometry/hidden_support.py), added to ``observed.hidden_tops`` (a carrier with a
    hidden top already keeps it); the carriers are completed again with it, in place in
    ``shapes``. Judged on the first completions, so the result does not depend on the
    order of the objects. Returns carried id -> carrier id."""
    if not o.completion_hidden_supports:
        return {}
    posed = {i: _posed(mesh, pose) for i, (mesh, pose, _) in shapes.items()
             if mesh is not None}
    completed = sorted(i for i in posed if shapes[i][2] is None)
    priors = {i: m for i, m in posed.items() if i not in completed}
    added: dict[int, HiddenTop] = {}
    found: dict[int, int] = {}
    for b in completed:
        carriers = {a: posed[a] for a in completed if a != b and a not in observed.hidden_tops}
        ext = support_extension(posed[b], carriers, priors, plane.point, plane.normal,
                                carried_id=b)
        if ext is None:
            continue
        found[b] = ext.carrier_id
        before = added.get(ext.carrier_id)
        added[ext.carrier_id] = ext if before is None else HiddenTop(
            before.carrier_id, before.carried_id, before.height_m,
            np.concatenate([before.points_world, ext.points_world]))
    if not added:
        return found
    observed.hidden_tops = {**observed.hidden_tops, **added}
    specs = {spec.id: spec for spec in scene.objects}
    for a in sorted(added):
        mesh, world_from_object = _complete(scene, specs[a], observed, plane, o)
        shapes[a] = (mesh, world_from_object, None)
    return found


def _with_hidden_top(points: np.ndarray, tops: dict[int, HiddenTop], obj_id: int
                     ) -> np.ndarray:
    """(N + M, 3) ``points`` and object ``obj_id``'s hidden top points, if it has any."""
    if obj_id not in tops:
        return points
    return np.concatenate([points, tops[obj_id].points_world])


def _final_shapes(ctx: StageContext, scene: InputScene, observed: dict,
                  shapes: dict[int, tuple], plane: PlaneFit, o: Options,
                  table_alternates: bool = True
                  ) -> tuple[dict[int, dict], dict[int, tuple]]:
    """In place in ``shapes``, the last changes once every object has its shape: hidden
    space shared by completed objects, hidden overlaps of priors, then the completed
    outlines snapped onto the masks. Returns the priors' hidden-overlap records (by id)
    and id -> (mesh, world_from_object, kind) of the completed objects' second completions
    (:func:`_partition_hidden`, and with ``table_alternates`` :func:`_table_alternates`),
    snapped the same way."""
    bridged = {}
    if o.completion_partition_hidden:
        ctx.progress("hidden space shared by completed objects", 0.9)
        bridged = _partition_hidden(scene, observed, shapes, plane, o)
    if o.completion_table_alternative and table_alternates:
        bridged.update(_table_alternates(scene, observed, shapes, plane, o, skip=set(bridged)))
    if o.completion_deepened_alternative and table_alternates:
        bridged.update(_deepened_alternates(scene, observed, shapes, plane, o,
                                            skip=set(bridged)))
    yielded = {}
    if o.prior_yield_hidden_overlap or o.prior_lift_below_table:  # only where priors overlap
        ctx.progress("hidden overlaps of priors", 0.92)
        yielded = _yield_prior_overlaps(observed, shapes, plane, o)
    if o.completion_snap_outline_px > 0:
        ctx.progress("outlines of completed objects", 0.93)
        _snap_completions(scene, shapes, plane, o.completion_snap_outline_px)
        for i, (mesh, pose, kind) in list(bridged.items()):
            alone = {**shapes, i: (mesh, pose, None)}
            _snap_completions(scene, alone, plane, o.completion_snap_outline_px, only=i)
            bridged[i] = (*alone[i][:2], kind)
    return yielded, bridged


def _finished_alternates(ctx: StageContext, scene: InputScene, observed: dict,
                         shapes: dict[int, tuple], alternates: dict[int, tuple],
                         plane: PlaneFit, o: Options) -> dict[int, tuple]:
    """The completions of the priors kept (``alternates``: id -> (mesh, world_from_object)),
    finished as if init had chosen every one of them: :func:`_final_shapes` on a copy of
    ``shapes`` with each kept prior replaced by its completion (hidden space shared among
    them, outlines snapped). physopt swaps several of them in together, where the priors
    could rest only turned from where they were seen; raw, the seed demo's fruit
    completions did not rest on the plate's (docs/physopt.md)."""
    if not alternates:
        return alternates
    together = {i: ((*alternates[i], None) if i in alternates else shape)
                for i, shape in shapes.items()}
    _final_shapes(ctx, scene, observed, together, plane, o, table_alternates=False)
    return {i: together[i][:2] for i in alternates}


def _snap_completions(scene: InputScene, shapes: dict[int, tuple], plane: PlaneFit,
                      max_shift_px: float, only: Optional[int] = None) -> None:
    """In place in ``shapes``: every completed object's mesh with its outer silhouette
    moved onto its mask's outline (:func:`r2s.geometry.silhouette_snap.snap_outline`),
    keeping out of every other object (in their final shapes as they are snapped). The
    last step before saving, so that no decision above (the partition of hidden space,
    resting on others, the prior-or-completion choice) depends on it. ``only``: snap that
    object alone, keeping out of the others as they stand."""
    cam = scene.camera
    posed = {}
    for obj_id, (mesh, world_from_object, _) in shapes.items():
        if mesh is not None:
            posed[obj_id] = trimesh.Trimesh(transform_points(world_from_object, mesh.vertices),
                                            mesh.faces, process=False)
    for obj_id, (mesh, world_from_object, reg) in shapes.items():
        if reg is not None or mesh is None or (only is not None and obj_id != only):
            continue
        snapped, _ = snap_outline(posed[obj_id], scene.masks == obj_id, scene.masks,
                                  scene.depth_m, cam.K, cam.world_from_camera, plane.normal,
                                  max_shift_px=max_shift_px,
                                  others=[m for j, m in posed.items() if j != obj_id])
        posed[obj_id] = snapped  # the objects after it keep out of its new surface
        out = mesh.copy()  # keeps the vertex colours: the same vertices, moved
        out.vertices = transform_points(np.linalg.inv(world_from_object), snapped.vertices)
        shapes[obj_id] = (out, world_from_object, None)


def _save_object(spec: ObjectSpec, shape: tuple, pts: np.ndarray, out: Path, o: Options,
                 table_extent_m: float, extra: Optional[dict] = None
                 ) -> tuple[ObjectState, trimesh.Trimesh, float, list[str]]:
    """Write one object's mesh and points; its state entry, world-frame mesh, fit RMSE
    and warning lines. ``shape`` = (mesh (object frame), world_from_object, registration
    or None for a completed object); ``extra``: more keys of its state entry."""
    mesh, world_from_object, reg = shape
    if reg is not None:
        source, fitness, rmse, scale = "prior", reg.fitness, reg.rmse_m, reg.scale
    else:
        source, scale = "completed", 1.0
        mesh_w = mesh.copy()
        mesh_w.apply_transform(world_from_object)
        fitness, rmse = surface_fit(mesh_w, pts, o.icp_inlier_m, seed=o.seed)
    flags = _result_flags(spec.id, float(fitness), mesh, table_extent_m)
    save_mesh(mesh, out / "meshes" / f"{spec.id}.glb")
    np.save(out / "points" / f"{spec.id}.npy", pts.astype(np.float32))
    mesh_w = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    mesh_w.apply_transform(world_from_object)
    state = ObjectState(
        id=spec.id, label=spec.label, mesh=f"meshes/{spec.id}.glb",
        world_from_object=world_from_object.tolist(), source=source,
        icp_fitness=round(float(fitness), 6),
        icp_rmse_m=float(rmse) if np.isfinite(rmse) else None, scale=float(scale),
        observed_points=f"points/{spec.id}.npy", num_observed_points=int(len(pts)),
        **(extra or {}))
    return state, mesh_w, float(rmse), flags


def _partition_hidden(scene: InputScene, observed: dict, shapes: dict[int, tuple],
                      plane: PlaneFit, o: Options) -> dict[int, tuple]:
    """Complete again, in place in ``shapes``, every completed object whose first
    completion overlaps another object, without the hidden space that the other owns
    (:mod:`r2s.geometry.hidden_partition`); the overlaps are judged on the first
    completions, so the split does not depend on the order of the objects.

    An object completed again may lie across the others (its base on their tops). Where
    the strict guards refuse that and the looser ones
    (:data:`r2s.geometry.completion.RELAXED_BRIDGE`, with ``completion_bridge_alternative``)
    accept it, the loosely bridged completion is returned; where the strict guards bridge
    it, the completion not bridged (its free columns reaching down to the table: a ball
    carried by a drill's sloping side in the grid rolls off it, where the truth rests on
    something hidden); id -> (mesh, world_from_object, kind). physopt swaps it in only where
    the first cannot rest near where it was seen."""
    posed = {}
    for obj_id, (mesh, world_from_object, _) in shapes.items():
        m = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        posed[obj_id] = m.apply_transform(world_from_object)
    tops = getattr(observed, "hidden_tops", {})
    claimant = {j: Claimant(posed[j], _with_hidden_top(observed[j][0], tops, j),
                            shapes[j][2] is not None)
                for j in shapes}
    redo, bridged = {}, {}
    for spec in scene.objects:
        if shapes[spec.id][2] is not None:
            continue  # a registered prior keeps its shape
        claimants = [claimant[j] for j in shapes if j != spec.id]
        if claimants and overlaps(posed[spec.id], claimants):
            redo[spec.id] = exclusion(observed[spec.id][0], claimants)
    for spec in scene.objects:
        if spec.id not in redo:
            continue
        under = [posed[j] for j in shapes if j != spec.id]
        shape = _complete_shape(scene, spec, observed, plane, o, exclude=redo[spec.id],
                                under=under)
        shapes[spec.id] = (shape.mesh, shape.world_from_object, None)
        if not (o.completion_bridge_alternative and under):
            continue
        other = _complete_shape(scene, spec, observed, plane, o, exclude=redo[spec.id],
                                under=under, bridge_guards=(NO_BRIDGE if shape.bridged
                                                            else RELAXED_BRIDGE))
        if other.bridged != shape.bridged:
            bridged[spec.id] = (other.mesh, other.world_from_object,
                                "bridged completion" if other.bridged
                                else "unbridged completion")
    return bridged


TABLE_ALTERNATIVE_MIN_BASE_M = 0.010
"""A completed object whose base is this far above the table or more stands on others; its
completion down to the table is kept as an alternative when that base is lower by at least
as much."""


def _base_height_m(mesh: trimesh.Trimesh, world_from_object: np.ndarray, plane: PlaneFit) -> float:
    """Lowest point of the posed ``mesh`` above the support plane (metres)."""
    return float(np.min(signed_distance(transform_points(world_from_object, mesh.vertices),
                                        plane.point, plane.normal)))


def _table_alternates(scene: InputScene, observed: dict, shapes: dict[int, tuple],
                      plane: PlaneFit, o: Options, skip: set[int]) -> dict[int, tuple]:
    """id -> (mesh, world_from_object, "completion to the table") of every completed object
    (not in ``skip``) whose base rests on others, completed again without the others' points
    as what it stands on, where that brings its base down by ``TABLE_ALTERNATIVE_MIN_BASE_M``
    or more. Found on the piles set's scene_00: a flat object standing on the table behind
    a leaning jenga block shows its top above the block and was completed lying on it.
    Completed from the object's own view alone: the hidden space the partition gave others
    (:func:`_partition_hidden`) is not kept out, and physopt cuts what overlaps."""
    out = {}
    for spec in scene.objects:
        mesh, pose, reg = shapes[spec.id]
        if reg is not None or spec.id in skip or mesh is None:
            continue
        base = _base_height_m(mesh, pose, plane)
        if base < TABLE_ALTERNATIVE_MIN_BASE_M:
            continue
        try:
            other = _complete_shape(scene, spec, observed, plane, o, stand_on_others=False)
        except StageError:
            continue
        if _base_height_m(other.mesh, other.world_from_object, plane) <= base - TABLE_ALTERNATIVE_MIN_BASE_M:
            out[spec.id] = (other.mesh, other.world_from_object, "completion to the table")
    return out


def _deepened_alternates(scene: InputScene, observed: dict, shapes: dict[int, tuple],
                         plane: PlaneFit, o: Options, skip: set[int]) -> dict[int, tuple]:
    """id -> (mesh, world_from_object, "deepened completion") of every completed object
    (not in ``skip``, without an inferred top) that stands on the table and was seen only
    as a face: completed again with a hidden back as deep as the face is wide
    (:mod:`r2s.geometry.hidden_back`), kept where that makes it at least
    ``hidden_back.MIN_DEEPER_M`` deeper along the view. Found on the piles set's scene_01:
    a box whose top a can lying over it hides was completed as a slab, and toppled with
    the can."""
    out = {}
    tops = getattr(observed, "hidden_tops", {})
    eye = scene.camera.world_from_camera[:3, 3]
    for spec in scene.objects:
        mesh, pose, reg = shapes[spec.id]
        if reg is not None or spec.id in skip or spec.id in tops or mesh is None:
            continue
        if _base_height_m(mesh, pose, plane) >= TABLE_ALTERNATIVE_MIN_BASE_M:
            continue
        back = hidden_back(observed[spec.id][0], plane.point, plane.normal, eye,
                           cell_m=o.completion_cell_m)
        if back is None:
            continue
        deeper = ObservedPoints(dict(observed))
        height = float(signed_distance(back[:1], plane.point, plane.normal)[0])
        deeper.hidden_tops = {**tops, spec.id: HiddenTop(spec.id, -1, height, back)}
        try:
            other = _complete_shape(scene, spec, deeper, plane, o)
        except StageError:
            continue
        if _view_depth_m(other.mesh, other.world_from_object, plane, eye) >= \
                _view_depth_m(mesh, pose, plane, eye) + MIN_DEEPER_M:
            out[spec.id] = (other.mesh, other.world_from_object, "deepened completion")
    return out


def _view_depth_m(mesh: trimesh.Trimesh, world_from_object: np.ndarray, plane: PlaneFit,
                  eye_world: np.ndarray) -> float:
    """Extent of the posed ``mesh`` along the horizontal direction from the camera centre
    ``eye_world`` (3,) to its vertices' mean (metres; 0 with the camera straight above)."""
    plane_from_world = np.linalg.inv(world_from_plane(plane.point, plane.normal))
    verts = transform_points(plane_from_world @ world_from_object, mesh.vertices)
    axes = view_axes(verts, transform_points(plane_from_world, eye_world[None])[0])
    if axes is None:
        return 0.0
    along = verts[:, :2] @ axes[0]
    return float(along.max() - along.min())


def _yield_prior_overlaps(observed: dict, shapes: dict[int, tuple], plane: PlaneFit,
                          o: Options) -> dict[int, dict]:
    """Where the registered priors overlap by at least ``SHAPE_ERROR_M`` somewhere (their
    hidden sides are single-image guesses), move, in place in ``shapes``, each prior's
    surface out of the table (``prior_lift_below_table``) and out of the priors that own
    the space it overlaps (``prior_yield_hidden_overlap``;
    :mod:`r2s.geometry.hidden_overlap`); a record per prior changed. Completions are left
    alone (they were built on the table and outside the priors), and so is a prior
    registered more than 5 mm into the table (a pose error)."""
    priors = {i: s for i, s in shapes.items() if s[2] is not None}
    posed, lifted = {}, {}
    for i, (mesh, pose, _) in priors.items():
        verts = transform_points(pose, mesh.vertices)
        if sunk_too_far(verts, plane.point, plane.normal):
            continue  # registered too low: a pose error, for geomopt
        if o.prior_lift_below_table:
            verts, n_below = lift_onto_plane(verts, plane.point, plane.normal)
            if n_below:
                lifted[i] = n_below
        posed[i] = trimesh.Trimesh(verts, mesh.faces, process=False)
    if len(posed) < 2:
        return {}
    new, reports, _ = yield_hidden_overlaps(posed, {i: observed[i][0] for i in posed})
    if not new:
        return {}  # the priors agree: exact shapes, nothing to give up or lift
    if not o.prior_yield_hidden_overlap:
        new, reports = {}, {}
    records = {}
    for i in sorted(set(lifted) | set(new)):
        mesh, pose, reg = shapes[i]
        moved = mesh.copy()
        moved.vertices = transform_points(np.linalg.inv(pose), new.get(i, posed[i].vertices))
        shapes[i] = (moved, pose, reg)
        records[i] = ({"below_table_vertices": lifted[i]} if i in lifted else {}) | (
            reports[i].as_dict() if i in reports else {})
    return records


def _with_silhouettes(scene: InputScene, plane: PlaneFit, o: Options, out: Path,
                      objects: list[ObjectState], posed: list[trimesh.Trimesh], flags: list[str]
                      ) -> tuple[list[ObjectState], list[trimesh.Trimesh]]:
    """``objects`` and their world-frame meshes ``posed`` with an object built from its
    silhouette for each of ``scene.skipped_objects`` that gives one (the measured objects
    own their inside), sorted by id; a warning line for each in ``flags``."""
    seen = [Claimant(mesh_w, np.zeros((0, 3)), is_prior=True) for mesh_w in posed]
    objects, posed = list(objects), list(posed)
    for spec in scene.skipped_objects:
        built = _from_silhouette(scene, spec, plane, o, out, seen)
        if isinstance(built, str):
            flags.append(built)
            continue
        objects.append(built[0])
        posed.append(built[1])
        flags.append(f"object {spec.id}: its mask read no depth; its shape is a guess from "
                     "its silhouette standing on the table (source 'silhouette')")
    order = np.argsort([ob.id for ob in objects], kind="stable")
    return [objects[k] for k in order], [posed[k] for k in order]


def _from_silhouette(scene: InputScene, spec: ObjectSpec, plane: PlaneFit, o: Options,
                     out: Path, seen: Sequence[Claimant]
                     ) -> tuple[ObjectState, trimesh.Trimesh] | str:
    """An object for an instance whose mask read (almost) no depth, built from its
    silhouette (:mod:`r2s.geometry.silhouette_completion`) outside the objects that were
    seen (``seen``: they own all of their inside): its state entry and world-frame mesh,
    with its mesh and (empty) points written; or the warning line why not."""
    cam = scene.camera
    mask = scene.masks == spec.id
    if o.silhouette_min_px <= 0 or mask.sum() < o.silhouette_min_px:
        return f"object {spec.id}: its mask read no depth and is too small to guess a shape from"
    view = carve_view(cam.K, cam.world_from_camera, scene.depth_m, np.argwhere(mask),
                      hole_fill_px=0, plane=(plane.point, plane.normal))
    try:
        shape = complete_from_silhouette(mask, cam.K, cam.world_from_camera, plane.point,
                                         plane.normal, view=view, cell_m=o.completion_cell_m,
                                         color=np.median(scene.rgb[mask], axis=0),
                                         exclude=_inside_any(seen))
    except ValueError as exc:
        return f"object {spec.id}: its mask read no depth and its silhouette gives no shape ({exc})"
    save_mesh(shape.mesh, out / "meshes" / f"{spec.id}.glb")
    np.save(out / "points" / f"{spec.id}.npy", np.zeros((0, 3), dtype=np.float32))
    state = ObjectState(id=spec.id, label=spec.label, mesh=f"meshes/{spec.id}.glb",
                        world_from_object=shape.world_from_object.tolist(), source="silhouette",
                        observed_points=f"points/{spec.id}.npy", num_observed_points=0)
    mesh_w = shape.mesh.copy()
    mesh_w.apply_transform(shape.world_from_object)
    return state, mesh_w


def _inside_any(claimants: Sequence[Claimant]) -> Optional[Callable[[np.ndarray], np.ndarray]]:
    """``f(points (M, 3) world) -> (M,) bool``, inside any of ``claimants``' meshes; None
    for none."""
    if not claimants:
        return None
    return lambda pts: np.any([c.inside(pts) for c in claimants], axis=0)


def _result_flags(obj_id: int, fitness: float, mesh: trimesh.Trimesh,
                  table_extent_m: float) -> list[str]:
    """Warnings about one object's fit: too few observed points explained, larger than
    the visible table (see :mod:`r2s.geometry.sanity`)."""
    problems = (sanity.low_fitness(fitness),
                sanity.larger_than_table(sanity.mesh_extent_m(mesh), table_extent_m))
    return [f"object {obj_id}: {p}" for p in problems if p]


def _png_bytes(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


def _register_or_complete(scene: InputScene, observed: dict, plane: PlaneFit, o: Options,
                          flags: list[str], progress
                          ) -> tuple[dict[int, tuple[trimesh.Trimesh, RefinedPose]], dict]:
    """Register every object with a prior (id -> (prior, registered pose)) and complete the
    others; ``shapes``: id -> (mesh (object frame), world_from_object, registration or
    None), the priors' meshes left None for :func:`_fit_priors`."""
    n = len(scene.objects)
    priors: dict[int, tuple[trimesh.Trimesh, RefinedPose]] = {}
    shapes: dict[int, tuple] = {}
    with_prior = [spec for spec in scene.objects if spec.prior_mesh is not None]
    if with_prior:
        progress(f"registering {len(with_prior)} priors", 0.0)

    def register_one(spec: ObjectSpec) -> tuple[tuple, list[str]]:
        notes: list[str] = []
        return _register(scene, spec, observed[spec.id][0], plane, o, notes), notes

    # independent fits, each seeding its own sampling: side by side on the cores there are
    registered = dict(zip([spec.id for spec in with_prior],
                          forked_map(register_one, with_prior)))
    for k, spec in enumerate(scene.objects):
        if spec.prior_mesh is not None:
            (prior, pose, reg), notes = registered[spec.id]
            flags.extend(notes)
            priors[spec.id] = (prior, pose)
            shapes[spec.id] = (None, None, reg)
        else:
            progress(f"object {spec.id}", 0.4 + 0.4 * k / max(n, 1))
            mesh, world_from_object = _complete(scene, spec, observed, plane, o)
            shapes[spec.id] = (mesh, world_from_object, None)
    return priors, shapes


def run(ctx: StageContext) -> dict:
    o: Options = ctx.options
    # the observation as the scene's model corrects it (depth bias, camera rotation kept by
    # 'r2s diagnose --set apply=true'); input/ itself is never changed
    scene = corrected_input(load_input(ctx.paths.root), ctx.manifest.model)
    cam = scene.camera
    ctx.progress("support plane", 0.0)
    plane, plane_points = _fit_support(scene, o)
    out = ctx.out_dir
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    (out / "points").mkdir(parents=True, exist_ok=True)

    support = plane_points[plane.inliers]
    if len(support) > o.support_points_max:
        rng = np.random.default_rng(o.seed)
        support = support[np.sort(rng.choice(len(support), o.support_points_max, replace=False))]
    np.save(out / "support_points.npy", support.astype(np.float32))

    observed = ObservedPoints({spec.id: _object_points(scene, spec.id, o, plane)
                               for spec in scene.objects})
    observed.hidden_tops = _hidden_tops(scene, observed, plane, o)
    # probably-wrong inputs and results, one line each
    flags: list[str] = (list(scene.warnings) + _support_flags(plane, observed, o)
                        + _prior_size_flags(scene, observed))
    unsegmented, unmasked = _unsegmented(scene, plane, observed, o, flags)
    table_extent_m = sanity.robust_extent_m(support)
    priors, shapes = _register_or_complete(scene, observed, plane, o, flags, ctx.progress)
    ctx.progress("fit priors to the view", 0.8)
    ious = _fit_priors(scene, priors, shapes, plane, o)
    _fallback_to_completion(scene, observed, shapes, ious, plane, o, flags)
    supports = _extend_hidden_supports(scene, observed, shapes, plane, o)
    ctx.progress("prior or completion", 0.85)
    choices, alternates, replaced = _choose_prior_or_completion(scene, observed, shapes, plane,
                                                                o, flags)
    _save_shapes(out / INIT_REPLACED_PRIORS_DIR, replaced, scene, plane, source="prior")
    alternates = _finished_alternates(ctx, scene, observed, shapes, alternates, plane, o)
    yielded, bridged = _final_shapes(ctx, scene, observed, shapes, plane, o)
    _save_alternates(out, alternates, scene, plane, bridged)
    objects: list[ObjectState] = []
    posed: list[trimesh.Trimesh] = []
    rmses: list[float] = []
    for spec in scene.objects:
        extra = _state_extras(spec.id, choices, yielded, observed, shapes)
        state, mesh_w, rmse, more = _save_object(spec, shapes[spec.id], observed[spec.id][0],
                                                 out, o, table_extent_m, extra or None)
        objects.append(state)
        posed.append(mesh_w)
        flags += more
        if state.source == "prior":
            rmses.append(rmse)

    if scene.skipped_objects:
        objects, posed = _with_silhouettes(scene, plane, o, out, objects, posed, flags)

    ctx.progress("overlay", 0.95)
    rendered = render_instances(posed, cam.K, cam.world_from_camera, cam.width, cam.height)
    picture = fit_overlay(scene.rgb, rendered, scene.masks, [ob.id for ob in objects],
                          zoom_to_px=1000, labels={ob.id: ob.label for ob in objects},
                          unmasked=unmasked)
    atomic_write_bytes(out / "init.png", _png_bytes(picture))
    write_state(out, SceneState(stage="init", gravity=list(DEFAULT_GRAVITY),
                                support=_support_plane(plane), objects=objects, **unsegmented))
    ctx.progress("done", 1.0)
    summary = _summary(objects, rmses, choices, plane, unsegmented, scene)
    return {**summary, "hidden_supports": {str(b): a for b, a in sorted(supports.items())},
            "flags": flags}


def _state_extras(obj_id: int, choices: dict, yielded: dict, observed: dict,
                  shapes: dict[int, tuple]) -> dict:
    """More keys of an object's init/state.json entry: ``prior_choice`` (the scores of
    prior and completion), ``hidden_overlap`` (what a prior yielded) and, for a completed
    object whose top under another was inferred (a hidden top or a continuation under
    what it carries), ``hidden_top``: the id it carries, the top's height over the table
    (m) and the number of points it added."""
    extra: dict = {}
    if obj_id in choices:
        extra["prior_choice"] = choices[obj_id]
    if obj_id in yielded:
        extra["hidden_overlap"] = yielded[obj_id]
    top = getattr(observed, "hidden_tops", {}).get(obj_id)
    if top is not None and shapes[obj_id][2] is None:
        extra["hidden_top"] = {"carries": top.carried_id, "height_m": round(top.height_m, 4),
                               "points": len(top.points_world)}
    return extra


def _summary(objects: list[ObjectState], rmses: list[float], choices: dict, plane: PlaneFit,
             unsegmented: dict, scene: InputScene) -> dict:
    """The stage summary's figures on the objects saved."""
    finite = [r for r in rmses if np.isfinite(r)]
    fitnesses = [float(ob.icp_fitness) for ob in objects if ob.source != "silhouette"]
    return {
        "objects": len(objects),
        "completed": sum(1 for ob in objects if ob.source == "completed"),
        "from_silhouette": [ob.id for ob in objects if ob.source == "silhouette"],
        "prior_choice": {str(i): c["chosen"] for i, c in sorted(choices.items())},
        "mean_icp_rmse_mm": round(1000 * float(np.mean(finite)), 3) if finite else None,
        "min_fitness": round(min(fitnesses), 4) if fitnesses else None,
        "support_inlier_fraction": round(float(plane.inliers.mean()), 4),
        "unsegmented_regions": len(unsegmented.get(UNSEGMENTED_KEY, [])),
        "skipped": [i for i in scene.skipped_ids if i not in {ob.id for ob in objects}],
    }


STAGE = StageSpec("init", Options, inputs, run, uses_model=frozenset({"input"}))
