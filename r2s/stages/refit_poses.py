"""The support tree and geomopt's poses again, for a scene whose shapes physopt changed.

physopt solves a scene a second time with init's completions in place of some priors
(r2s/stages/physopt.py, ``swap_to_completion``). The completions have other undersides and
other extents than the priors the contact graph and geomopt saw: a banana completed down to
the table rests on the table, not on the plate its prior lay across. The graph and geomopt
run again first, as ``r2s run`` would have run them had init chosen the completions, with
the options those stages last ran with (the manifest's; their defaults where a stage never
ran). On the seed demo the second solve is then the very solve of
``init.prior_choice=completion``: the same support tree, geomopt moves and result (IoU
0.950; the priors' solution 0.761).

Frames: poses are (4, 4) ``world_from_object``; meshes are in their object frames.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from r2s.graph.build import build_contact_graph
from r2s.io.mesh_io import load_mesh
from r2s.io.recorded_options import recorded_options
from r2s.physopt.hierarchy import parents_of
from r2s.runner.base import StageContext
from r2s.io.state import SceneState
from r2s.stages import geomopt as geomopt_stage
from r2s.stages import graph as graph_stage


def refit_poses(ctx: StageContext, state: SceneState, files: dict[int, Path],
                with_geomopt: bool) -> tuple[SceneState, Optional[dict[int, int]], dict]:
    """The contact graph of ``state`` (objects at their poses, ``files``: id -> its mesh
    file, object frame, loaded as the graph and geomopt stages load it: not welded), then,
    ``with_geomopt``, geomopt's optimisation of its poses along that graph (the SDFs of
    meshes geomopt already saw reused from ``geomopt/sdf/``).

    Returns the state with the new poses, the support tree (child id -> parent id, 0 = the
    table; None without support edges) and a record for physopt/log.json (the parents, and
    each object's geomopt move in mm and deg).
    """
    meshes = {i: load_mesh(f) for i, f in files.items()}
    graph_opts = recorded_options(ctx.manifest, "graph", graph_stage.Options)
    graph = build_contact_graph(graph_stage.posed_objects(state, meshes),
                                np.asarray(state.gravity), np.asarray(state.support.point),
                                np.asarray(state.support.normal), graph_opts.params())
    parents = parents_of(graph)
    record: dict = {"parents": {str(k): v for k, v in sorted((parents or {}).items())}}
    if not with_geomopt:
        return state, parents, record
    opts = recorded_options(ctx.manifest, "geomopt", geomopt_stage.Options)
    ordered = [meshes[o.id] for o in state.objects]
    sdf_dir = ctx.paths.stage_dir("geomopt") / "sdf"
    grids = [geomopt_stage.sdf_of_file(sdf_dir, o.id, meshes[o.id], files[o.id].read_bytes(),
                                       opts)[0] for o in state.objects]
    problem, result = geomopt_stage.solve_poses(ctx.paths, ctx.manifest.model, state, ordered,
                                                grids, graph, opts, lambda *_: None)
    objects = [o.model_copy(update={"world_from_object": result.world_from_object[k].tolist()})
               for k, o in enumerate(state.objects)]
    moved_mm, turned_deg = geomopt_stage.pose_moves(problem, result)
    record["geomopt"] = {str(o.id): [round(float(m), 2), round(float(d), 2)]
                         for o, m, d in zip(state.objects, moved_mm, turned_deg)}
    return state.model_copy(update={"objects": objects}), parents, record
