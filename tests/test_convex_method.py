"""export/physopt's convex_method option: CoACD is really used when chosen, V-HACD keeps
its cache keys, and both decompose an L-shaped block into pieces whose volume is the
block's (analytic: 2 boxes of 4x2x2 cm and 2x2x2 cm -> 24 cm^3)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from r2s.geometry.convex_cache import cached_convex_decomposition, mesh_key
from r2s.geometry.convex_params import DEFAULT_CONVEX, ConvexParams
from r2s.sim.export_scene import BodyParams


def l_block() -> trimesh.Trimesh:
    a = trimesh.creation.box((0.04, 0.02, 0.02))
    b = trimesh.creation.box((0.02, 0.02, 0.02))
    b.apply_translation((0.01, 0.0, 0.02))
    return trimesh.boolean.union([a, b], engine="manifold")


def test_default_keys_unchanged_and_method_named_otherwise():
    assert "method" not in DEFAULT_CONVEX.as_kwargs()
    assert ConvexParams(method="coacd").as_kwargs()["method"] == "coacd"
    assert BodyParams(convex_method="coacd").convex.method == "coacd"
    mesh = l_block()
    assert mesh_key(mesh, **DEFAULT_CONVEX.as_kwargs(), seed=0) != mesh_key(
        mesh, **ConvexParams(method="coacd").as_kwargs(), seed=0)


@pytest.mark.parametrize("method", ["vhacd", "coacd"])
def test_each_method_decomposes_the_l_block(method, tmp_path):
    mesh = l_block()
    assert mesh.volume == pytest.approx(24e-6, rel=1e-6)
    params = ConvexParams(method=method)
    pieces = cached_convex_decomposition(mesh, tmp_path, **params.as_kwargs())
    assert len(pieces) >= 2  # concave: not its hull
    total = sum(p.volume for p in pieces)
    assert total == pytest.approx(24e-6, rel=0.2)
    assert len(list(tmp_path.glob("*.npz"))) == 1
    again = cached_convex_decomposition(mesh, tmp_path, **params.as_kwargs())
    assert [np.allclose(p.vertices, q.vertices) for p, q in zip(pieces, again)] == [True] * len(pieces)


def test_the_methods_give_different_pieces():
    mesh = l_block()
    vhacd = cached_convex_decomposition(mesh, None, **ConvexParams(method="vhacd").as_kwargs())
    coacd = cached_convex_decomposition(mesh, None, **ConvexParams(method="coacd").as_kwargs())
    same = len(vhacd) == len(coacd) and all(
        p.vertices.shape == q.vertices.shape and np.allclose(p.vertices, q.vertices)
        for p, q in zip(vhacd, coacd))
    assert not same  # the option reaches the decomposition
