"""How much a scene's rest depends on the order its bodies are made in PyBullet.

The judge rolls the export out with the bodies made in the export's order, forwards and
backwards; Bullet's solver visits contacts in that order, so a marginal configuration can
rest in one and slide in the other. This takes a stage's state (default geomopt), builds
the collision pieces as physopt does (decomposition, trimming against the neighbours, the
cut where pieces overlap), and prints each object's drift (mm, deg) in physopt's check,
forwards and backwards; with ``--contacts ID``, also the contacts on that object during
the backward rollout (count, the summed contact force from each other body, N).

    python scripts/check_body_order.py SCENE [--stage geomopt] [--contacts 5]

Read-only: the scene is not written to (the decompositions are cached in a temporary
folder).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import pybullet as pb

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.geometry.collision_trim import trim_scene_pieces  # noqa: E402
from r2s.geometry.convex_cache import cached_convex_decomposition  # noqa: E402
from r2s.geometry.convex_params import ConvexParams  # noqa: E402
from r2s.io.mesh_io import load_mesh, welded  # noqa: E402
from r2s.io.state import read_state  # noqa: E402
from r2s.physopt.hierarchy import (lowest_points_m, order_root_to_leaves,  # noqa: E402
                                   parents_from_graph)
from r2s.physopt.params import initial_params  # noqa: E402
from r2s.physopt.piece_overlap import shave_overlaps  # noqa: E402
from r2s.physopt.repair import check, world_factory  # noqa: E402
from r2s.stages.physopt import Options, trimmed_objects  # noqa: E402

SAMPLED_STEPS = (1, 60, 240, 480, 1200)


def _contacts(world, oid: int, start: dict, steps: int) -> None:
    """Print the contacts on body ``oid`` at a few steps of a rollout from ``start``."""
    world.set_poses(start)
    names = {b: i for i, b in world.body_ids.items()}
    body = world.body_ids[oid]
    for k in range(1, steps + 1):
        pb.stepSimulation(physicsClientId=world.client)
        if k not in SAMPLED_STEPS:
            continue
        force: dict = {}
        for c in pb.getContactPoints(bodyA=body, physicsClientId=world.client):
            other = names.get(c[2], "table")
            n, f = force.get(other, (0, np.zeros(3)))
            force[other] = (n + 1, f + np.asarray(c[7]) * c[9])
        print(f"  step {k}: " + ", ".join(f"{o}: {n} contacts, {np.linalg.norm(f):.1f} N"
                                          for o, (n, f) in force.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("scene", type=Path)
    ap.add_argument("--stage", default="geomopt")
    ap.add_argument("--contacts", type=int, default=None, metavar="ID")
    args = ap.parse_args()
    opt = Options()
    folder = args.scene / args.stage
    state = read_state(folder)
    meshes = {o.id: welded(load_mesh(folder / o.mesh)) for o in state.objects}
    ids = [o.id for o in state.objects]
    parents = parents_from_graph(args.scene / "graph" / "contact_graph.json")
    order = order_root_to_leaves(ids, parents, lowest_points_m(state.objects, meshes))
    poses = {o.id: np.asarray(o.pose) for o in state.objects}
    convex = ConvexParams(opt.convex_threshold, opt.max_convex_pieces, opt.convex_method)
    with tempfile.TemporaryDirectory() as cache:
        pieces = {i: cached_convex_decomposition(meshes[i], Path(cache), **convex.as_kwargs())
                  for i in ids}
    pieces, _ = trim_scene_pieces(pieces, meshes, poses, only=trimmed_objects(state),
                                  max_split_depth=opt.trim_split_levels)
    support = (np.asarray(state.support.point), np.asarray(state.support.normal))
    pieces, _ = shave_overlaps(pieces, meshes, poses, order, support)
    params = initial_params(state, meshes, pieces, opt.density_kg_m3, opt.mass_bounds,
                            opt.friction_init, {})
    make_world = world_factory(pieces, state, order, opt)
    for name, body_order in (("forwards", ids), ("backwards", ids[::-1])):
        drift = check(make_world, params, [body_order], opt.verify_duration_s)
        print(f"{name}: " + ", ".join(f"{i}: {1000 * t:.1f} mm {r:.1f} deg"
                                      for i, (t, r) in sorted(drift.items())))
    if args.contacts is not None:
        print(f"contacts on object {args.contacts}, backwards:")
        world = make_world(params, ids[::-1])
        try:
            _contacts(world, args.contacts, poses,
                      int(round(opt.verify_duration_s * 240)))
        finally:
            world.close()


if __name__ == "__main__":
    main()
