"""Pick bodies from the catalogue and place them into a verified clutter.

:func:`place` drops the requested number of bodies (replacing the ones that do not come
to rest), re-drops them until enough of them touch, applies the ``com_offset_m`` effect
and runs a last rest check in id order, the order in which the judge loads them.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from r2s.console import ProgressFn
from r2s.errors import R2SError
from r2s.synth import catalog, physics
from r2s.synth.collision import collision_pieces
from r2s.synth.effects import Effects
from r2s.synth.files import write_piece_objs
from r2s.synth.options import SynthOptions

STRAY_M = 0.12
"""Bodies whose COM ends farther than the drop disc's radius plus this from its centre have
rolled or slid away from the clutter: they are removed (and replaced)."""

PLACEMENT_TRIALS = 3
"""Drops of the same bodies tried to reach :func:`wanted_contacts` touching pairs."""


@dataclass(frozen=True)
class Placed:
    """A verified scene: bodies (id = index + 1) and their (N, 4, 4) world_from_object."""

    bodies: list[physics.Body]
    poses: np.ndarray


# ---- bodies -------------------------------------------------------------------------------
def _make_body(entry: catalog.CatalogEntry, mesh: trimesh.Trimesh, uid: int,
               options: SynthOptions, effects: Effects, rng: np.random.Generator,
               work: Path, cache_dir: Optional[Path]) -> physics.Body:
    pieces = collision_pieces(mesh, cache_dir)
    files = write_piece_objs(work / "pieces", f"b{uid}", pieces)
    density = float(rng.uniform(*entry.density_kg_m3))
    friction = float(effects.friction) if effects.friction is not None else float(
        rng.uniform(*options.friction_range))
    return physics.Body(
        name=entry.name, mesh=mesh, pieces=pieces, piece_files=files,
        mass_kg=float(density * mesh.volume), com_in_object=np.asarray(mesh.center_mass),
        friction=friction, extra={"density_kg_m3": density, "source": entry.source},
    )


def body_stream(entries: list[catalog.CatalogEntry], options: SynthOptions, effects: Effects,
                rngs: dict[str, np.random.Generator], work: Path,
                cache_dir: Optional[Path]) -> Iterator[physics.Body]:
    """Endless bodies: the entries in random order, reshuffled when exhausted."""
    uid = 0
    while True:
        usable = 0
        for index in rngs["select"].permutation(len(entries)):
            entry = entries[int(index)]
            mesh = catalog.load_object_mesh(entry.name)
            if mesh is None:
                continue
            usable += 1
            uid += 1
            yield _make_body(entry, mesh, uid, options, effects, rngs["body"], work, cache_dir)
        if usable == 0:
            raise R2SError(f"no usable object mesh in set {options.objects!r}")


def make_support(options: SynthOptions, effects: Effects, rng: np.random.Generator
                 ) -> tuple[physics.Support, dict]:
    """The support plane through the origin (tilted by ``table_tilt_deg`` about a random
    horizontal axis) and the effect's record (empty when not tilted)."""
    normal = np.array([0.0, 0.0, 1.0])
    record: dict = {}
    if effects.table_tilt_deg:
        a = rng.uniform(0, 2 * np.pi)
        axis = np.array([np.cos(a), np.sin(a), 0.0])
        normal = Rotation.from_rotvec(np.radians(effects.table_tilt_deg) * axis).apply(normal)
        record = {"value": effects.table_tilt_deg, "axis": axis, "normal": normal}
    return physics.Support(point=np.zeros(3), normal=normal,
                           friction=float(options.support_friction)), record


# ---- placement ----------------------------------------------------------------------------
def drop_radius(count: int) -> float:
    """Radius of the disc objects drop over, metres."""
    return 0.03 + 0.01 * count


def _fill(placed: Placed, stream: Iterator[physics.Body], count: int, support: physics.Support,
          options: SynthOptions, rngs: dict[str, np.random.Generator], progress: ProgressFn,
          attempts: int) -> Placed:
    """Drop new bodies until ``count`` are verified at rest (or ``attempts`` run out)."""
    bodies, poses = list(placed.bodies), placed.poses
    radius = drop_radius(count)
    for attempt in range(attempts):
        need = count - len(bodies)
        if need <= 0:
            break
        progress(f"loading {need} objects", 0.05)
        new = [next(stream) for _ in range(need)]
        size = np.array([np.log(b.mesh.volume) for b in new])
        new = [new[k] for k in np.argsort(-(size + rngs["place"].normal(0, 0.7, len(new))))]
        progress(f"dropping {need} objects (attempt {attempt + 1})", 0.2)
        start: list[Optional[np.ndarray]] = list(poses) + [None] * need
        everyone = bodies + new
        dropped = physics.drop_bodies(everyone, start, support, rngs["place"], radius,
                                      options.stack_probability, options.adjacent_probability)
        progress("verifying rest", 0.35)
        bodies, poses = physics.settle_and_verify(
            everyone, dropped, support, options.verify_duration_s, options.verify_translation_m,
            options.verify_rotation_deg, radius + STRAY_M)
    return Placed(bodies, poses)


def wanted_contacts(count: int) -> int:
    """Touching object pairs a scene of ``count`` objects should have to count as clutter."""
    return min(count - 1, max(1, count // 2))


def _cluttered(stream: Iterator[physics.Body], options: SynthOptions,
               support: physics.Support, rngs: dict[str, np.random.Generator],
               progress: ProgressFn) -> Placed:
    """Verified bodies at rest; re-dropped (same bodies) up to PLACEMENT_TRIALS times until
    enough of them touch, keeping the trial with the most contacts."""
    best: Optional[Placed] = None
    best_score = (-1, -1)
    reuse: list[physics.Body] = []
    for trial in range(PLACEMENT_TRIALS):
        source = itertools.chain(reuse, stream)
        placed = _fill(Placed([], np.zeros((0, 4, 4))), source, options.count, support,
                       options, rngs, progress, attempts=4)
        contacts = physics.contact_summary(placed.bodies, placed.poses, support)
        score = (min(len(placed.bodies), options.count), len(contacts["pairs"])
                 + len(contacts["stacked"]))
        if score > best_score:
            best, best_score = placed, score
        if len(contacts["pairs"]) >= wanted_contacts(options.count):
            break
        progress(f"too few contacts ({len(contacts['pairs'])}), dropping again", 0.3)
        reuse = list(placed.bodies)
    assert best is not None
    return best


def _shift_com(body: physics.Body, pose: np.ndarray, distance_m: float,
               rng: np.random.Generator) -> dict:
    """Move the body's COM by ``distance_m`` in a random world-horizontal direction (kept
    inside the convex hull by halving); returns the record."""
    a = rng.uniform(0, 2 * np.pi)
    direction_world = np.array([np.cos(a), np.sin(a), 0.0])
    direction_object = pose[:3, :3].T @ direction_world
    hull = body.mesh.convex_hull
    used = float(distance_m)
    for _ in range(8):
        candidate = body.com_in_object + used * direction_object
        if hull.contains(candidate[None, :])[0]:
            break
        used *= 0.5
    original = body.com_in_object.copy()
    body.com_in_object = body.com_in_object + used * direction_object
    return {"name": body.name, "direction_world": direction_world,
            "offset_in_object": body.com_in_object - original, "distance_m": used,
            "original_com_in_object": original}


def place(stream: Iterator[physics.Body], options: SynthOptions, effects: Effects,
          support: physics.Support, rngs: dict[str, np.random.Generator],
          progress: ProgressFn) -> tuple[Placed, dict]:
    """The final verified clutter (body k has id k + 1) and the ``com_offset_m`` record.

    Raises :class:`R2SError` when no body could be brought to rest.
    """
    placed = _cluttered(stream, options, support, rngs, progress)
    record: dict = {}
    if effects.com_offset_m and placed.bodies:
        n = len(placed.bodies)
        targets = list(range(n)) if effects.com_offset_scope == "all" else [
            int(rngs["effect"].integers(n))]
        shifted = {id(placed.bodies[k]): _shift_com(placed.bodies[k], placed.poses[k],
                                                    effects.com_offset_m, rngs["effect"])
                   for k in targets}
        progress("verifying rest with the shifted centres of mass", 0.4)
        placed = Placed(*physics.settle_and_verify(
            placed.bodies, placed.poses, support, options.verify_duration_s,
            options.verify_translation_m, options.verify_rotation_deg,
            drop_radius(options.count) + STRAY_M))
        placed = _fill(placed, stream, options.count, support, options, rngs, progress,
                       attempts=3)
        record = {"value": effects.com_offset_m, "scope": effects.com_offset_scope,
                  "_shifted": shifted}
    # Final order = id order; verify once more in exactly the order the judge loads them.
    order = rngs["order"].permutation(len(placed.bodies))
    bodies = [placed.bodies[k] for k in order]
    poses = placed.poses[order] if len(order) else placed.poses
    progress("final rest check", 0.45)
    bodies, poses = physics.settle_and_verify(
        bodies, poses, support, options.verify_duration_s, options.verify_translation_m,
        options.verify_rotation_deg, drop_radius(options.count) + STRAY_M)
    if not bodies:
        raise R2SError("could not make a scene at rest with these options (try another seed)")
    return Placed(bodies, poses), record
