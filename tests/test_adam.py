"""r2s.sim.adam.Adam takes exactly torch.optim.Adam's steps (bitwise), as physopt and
texture use it: parameter groups with their own rates, gradients that are sometimes
missing, float64 and float32."""

from __future__ import annotations

import pytest
import torch

from r2s.sim.adam import Adam


def _run(make_optimiser, dtype: torch.dtype, steps: int = 60) -> list[torch.Tensor]:
    gen = torch.Generator().manual_seed(0)
    params = [torch.zeros(3, dtype=dtype, requires_grad=True),
              torch.zeros((), dtype=dtype, requires_grad=True),
              (torch.rand(4, 5, 3, generator=gen, dtype=dtype)).requires_grad_(True)]
    target = [torch.randn(p.shape, generator=gen, dtype=dtype) for p in params]
    opt = make_optimiser(params)
    for it in range(steps):
        opt.zero_grad()
        loss = sum(((p - t) ** 2 * (1 + k)).sum() for k, (p, t) in enumerate(zip(params, target))
                   if not (k == 1 and it % 7 == 3))  # param 1 has no grad now and then
        loss.backward()
        if it % 5 == 0 and params[1].grad is not None:
            torch.nan_to_num_(params[1].grad, 0.0, 0.0, 0.0)
        opt.step()
        with torch.no_grad():
            params[2].clamp_(0.0, 1.0)
    return [p.detach().clone() for p in params]


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_adam_equals_torch_adam_bitwise(dtype):
    groups = lambda ps: [{"params": [ps[0]], "lr": 1e-3}, {"params": [ps[1]], "lr": 0.2},
                         {"params": [ps[2]]}]
    ours = _run(lambda ps: Adam(groups(ps), lr=0.05), dtype)
    theirs = _run(lambda ps: torch.optim.Adam(groups(ps), lr=0.05), dtype)
    for a, b in zip(ours, theirs):
        assert torch.equal(a, b)
    start = torch.zeros(3, dtype=dtype)
    assert not torch.equal(ours[0], start)  # it did move


def test_plain_parameter_list():
    ours = _run(lambda ps: Adam(ps, lr=0.01), torch.float32, steps=20)
    theirs = _run(lambda ps: torch.optim.Adam(ps, lr=0.01), torch.float32, steps=20)
    assert all(torch.equal(a, b) for a, b in zip(ours, theirs))
