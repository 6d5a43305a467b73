"""Photometric texture refinement with an isotropic total-variation prior (the paper's stage d).

With geometry and poses fixed, every observed pixel of an object reads a fixed bilinear
footprint of four texels of that object's texture (:mod:`r2s.render.texel`). The textures
``T_i`` (S, S, 3) minimise, summed over objects i,

    lambda_photo / |Omega_i| * sum_{p in Omega_i} mean_c |I_r(p) - I_t(p)|
  + lambda_tv / N * sum_{texels} sqrt(|grad_x D_i|^2 + |grad_y D_i|^2 + eps)

(``Omega_i``: the object's pixels where the render and the instance mask agree; N = S * S;
the gradient norm is taken over the three channels together), by Adam, with the texels
kept in [0, 1]. ``D_i = T_i - R_i``: with no reference (``R_i = 0``, the paper's form) the
TV term spreads colour from seen texels into texels no pixel reads and smooths them; with
the initial texture as reference (a foundation model's texture worth keeping) it is the
*change* that is kept smooth and spread, so unseen texels keep the initial pattern and
take on the colour shift of their seen neighbours. (Adam scales each texel's step by its
own gradient history, so texels that only the TV term touches move at about ``lr`` per
iteration however small ``lambda_tv`` is: plain TV would flatten an unseen pattern.)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import torch

from r2s.console import ProgressFn, silent_progress
from r2s.sim.adam import Adam


@dataclass(frozen=True)
class RefineOptions:
    """Optimiser settings (see the module docstring for the objective)."""

    iterations: int = 200
    lr: float = 0.02
    lambda_photo: float = 1.0
    lambda_tv: float = 0.5
    tv_eps: float = 1e-6
    seed: int = 0
    threads: int = 1
    """Torch CPU threads during the loop (restored after); one thread is fastest on a busy
    2-core machine, where extra threads mostly spin."""


@dataclass(frozen=True)
class PixelSamples:
    """The observed pixels of one object and the texels they read.

    Attributes
    ----------
    index : (P, 4) int64 flat texel indices into that object's (S, S) texture.
    weight : (P, 4) float32 bilinear weights.
    observed : (P, 3) float32 observed RGB in [0, 1].
    """

    index: np.ndarray
    weight: np.ndarray
    observed: np.ndarray

    @property
    def count(self) -> int:
        return int(len(self.index))


@dataclass
class RefineResult:
    """Refined textures (list of (S, S, 3) float32) and the loss per iteration."""

    textures: list[np.ndarray]
    loss: list[float] = field(default_factory=list)
    photo_l1: list[float] = field(default_factory=list)


class _IsotropicTV(torch.autograd.Function):
    """Mean isotropic TV per texture with a hand-written backward (fewer passes over memory)."""

    @staticmethod
    def forward(ctx, textures: torch.Tensor, eps: float) -> torch.Tensor:  # noqa: ANN001
        dx = torch.zeros_like(textures)
        dy = torch.zeros_like(textures)
        torch.sub(textures[:, :, 1:], textures[:, :, :-1], out=dx[:, :, :-1])
        torch.sub(textures[:, 1:], textures[:, :-1], out=dy[:, :-1])
        norm = torch.sqrt(dx.square().sum(dim=-1) + dy.square().sum(dim=-1) + eps)
        ctx.save_for_backward(dx, dy, norm)
        return norm.mean(dim=(1, 2))

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):  # noqa: ANN001, ANN205
        dx, dy, norm = ctx.saved_tensors
        texels = norm.shape[1] * norm.shape[2]
        scale = (grad_out[:, None, None] / texels / norm)[..., None]
        gx = dx * scale
        gy = dy * scale
        grad = -(gx + gy)
        grad[:, :, 1:] += gx[:, :, :-1]
        grad[:, 1:] += gy[:, :-1]
        return grad, None


def isotropic_tv(textures: torch.Tensor, eps: float) -> torch.Tensor:
    """Mean over texels of sqrt(|dT/dx|^2 + |dT/dy|^2 + eps), forward differences.

    ``textures`` is (n, S, S, C); the difference across the last row / column is zero and
    the norm is taken over the C channels together. Returns (n,), one mean per texture.
    """
    return _IsotropicTV.apply(textures, eps)


def seen_texels(samples: PixelSamples, texture_shape: tuple[int, int]) -> np.ndarray:
    """(S, S) bool: texels with a non-zero weight in some observed pixel's footprint."""
    seen = np.zeros(texture_shape[0] * texture_shape[1], bool)
    seen[samples.index[samples.weight > 0]] = True
    return seen.reshape(texture_shape)


def refine_textures(textures: Sequence[np.ndarray], samples: Sequence[PixelSamples],
                    options: RefineOptions = RefineOptions(),
                    progress: ProgressFn = silent_progress,
                    tv_reference: Optional[Sequence[bool]] = None) -> RefineResult:
    """Optimise the textures of several objects jointly.

    Parameters
    ----------
    textures : per object, (S, S, 3) float initial texture in [0, 1] (one common S).
    samples : per object, its :class:`PixelSamples` (an object with no pixel is only
        smoothed by the TV term).
    options : :class:`RefineOptions`.
    progress : called with (message, fraction) every few iterations.
    tv_reference : per object, True to regularise the change from the initial texture
        (``R_i = T_i(0)``) instead of the texture itself; default all False.

    Returns
    -------
    :class:`RefineResult` with the textures as (S, S, 3) float32.
    """
    if not textures:
        return RefineResult([])
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(max(int(options.threads), 1))
    try:
        return _refine(textures, samples, options, progress,
                       tv_reference or [False] * len(textures))
    finally:
        torch.set_num_threads(previous_threads)


def _refine(textures: Sequence[np.ndarray], samples: Sequence[PixelSamples],
            options: RefineOptions, progress: ProgressFn,
            tv_reference: Sequence[bool]) -> RefineResult:
    torch.manual_seed(options.seed)
    size = textures[0].shape[:2]
    if any(t.shape[:2] != size for t in textures):
        raise ValueError("all textures must have the same size")
    texels = size[0] * size[1]
    init = torch.as_tensor(np.stack([np.asarray(t, dtype=np.float32) for t in textures]))
    param = init.clone().requires_grad_(True)
    use_ref = torch.as_tensor([bool(r) for r in tv_reference], dtype=torch.float32)
    reference = init * use_ref[:, None, None, None]

    # all objects' pixels in one gather: offset each object's indices into the stack
    index = np.concatenate([s.index + k * texels for k, s in enumerate(samples)])
    weight = np.concatenate([s.weight for s in samples])
    observed = np.concatenate([s.observed for s in samples])
    per_pixel = np.concatenate([np.full(s.count, options.lambda_photo / max(s.count, 1))
                                for s in samples]).astype(np.float32)
    index_t = torch.as_tensor(index)
    weight_t = torch.as_tensor(weight)[..., None]
    observed_t = torch.as_tensor(observed, dtype=torch.float32)
    per_pixel_t = torch.as_tensor(per_pixel)
    n_obj_pixels = max(sum(1 for s in samples if s.count), 1)

    opt = Adam([param], lr=options.lr)  # torch.optim.Adam's steps (r2s.sim.adam)
    result = RefineResult([])
    report_every = max(options.iterations // 20, 1)
    for it in range(options.iterations):
        opt.zero_grad(set_to_none=True)
        flat = param.reshape(-1, 3)
        rendered = (flat[index_t] * weight_t).sum(dim=1)
        residual = (rendered - observed_t).abs().mean(dim=1)
        photo = (per_pixel_t * residual).sum()
        tv = isotropic_tv(param - reference, options.tv_eps).sum()
        loss = photo + options.lambda_tv * tv
        loss.backward()
        opt.step()
        with torch.no_grad():
            param.clamp_(0.0, 1.0)
        result.loss.append(float(loss.detach()))
        result.photo_l1.append(float(photo.detach()) / options.lambda_photo / n_obj_pixels
                               if options.lambda_photo else float("nan"))
        if it % report_every == 0:
            progress(f"texture refinement {it}/{options.iterations}", it / options.iterations)
    result.textures = [t.detach().numpy().astype(np.float32) for t in param]
    return result
