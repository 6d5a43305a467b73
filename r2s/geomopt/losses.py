"""The terms of L_geom as pure torch functions on signed distances (metres).

``d`` below is a (Q, N) tensor: signed distances of the N surface samples of one object
to another object's surface (or the support plane), one row per query. Geometric terms
are divided by ``length_scale_m`` so that their values read in millimetres.
"""

from __future__ import annotations

import torch


def penetration_term(d: torch.Tensor, length_scale_m: float = 1e-3) -> torch.Tensor:
    """(Q,) mean over samples of max(0, -d): the paper's non-penetration term."""
    return torch.relu(-d).mean(dim=-1) / length_scale_m


def contact_term(d: torch.Tensor, k: int, length_scale_m: float = 1e-3) -> torch.Tensor:
    """(Q,) max(0, mean of the k smallest d): the paper's TopK-min multi-point contact term.

    Zero once the k closest samples are on average touching (or inside) the surface.
    """
    k = max(1, min(int(k), d.shape[-1]))
    smallest = torch.topk(d, k, dim=-1, largest=False).values
    return torch.relu(smallest.mean(dim=-1)) / length_scale_m


def anchor_term(rotation_m: torch.Tensor, trans: torch.Tensor, sigma_rotation_m: float,
                sigma_translation_m: float, rays: torch.Tensor | None = None,
                sideways_ratio: float = 1.0) -> torch.Tensor:
    """(M,) squared pose deviation from the init pose, each part over its scale squared.

    ``rotation_m`` (M, 3) is the rotation vector times the object's radius (how far the
    rotation moves the object's farthest point); ``trans`` (M, 3) the translation.

    Image-space anchor: with ``rays`` (M, 3), unit viewing rays from the camera through
    each object's centre, the translation splits into its part along the ray (scale
    ``sigma_translation_m``) and its part across it (scale ``sigma_translation_m /
    sideways_ratio``). A move across the ray shifts the object's silhouette by
    f |t_perp| / z pixels, one along it only rescales the silhouette (f r |t_along| / z^2
    at its rim, r / z times less) and changes the observed depth: the prior the camera
    gives. ``sideways_ratio`` = 1 is the isotropic anchor.
    """
    cost = (trans * trans).sum(-1)
    if rays is not None and sideways_ratio != 1.0:
        along = (trans * rays).sum(-1)
        cost = cost + (sideways_ratio**2 - 1.0) * (cost - along * along)
    return (rotation_m * rotation_m).sum(-1) / sigma_rotation_m**2 + cost / sigma_translation_m**2
