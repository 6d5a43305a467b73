"""Adam with ``torch.optim.Adam``'s CPU update, bit for bit, without its start-up cost.

Creating any ``torch.optim`` optimiser imports ``torch._dynamo`` (about 1.1 s of CPU, once
per process, measured on the 2-core development machine); physopt and texture only need
plain Adam. This is the update of ``torch.optim.Adam``'s single-tensor path (the one it
takes for CPU tensors; no AMSGrad, no weight decay, not maximising), the same tensor
operations in the same order, so results are identical
(``tests/test_adam.py`` checks equality with ``torch.optim.Adam``).
"""

from __future__ import annotations

from typing import Iterable, Union

import torch

ParamGroups = Union[Iterable[torch.Tensor], Iterable[dict]]


class Adam:
    """``Adam(params, lr, betas, eps)`` with ``zero_grad()`` and ``step()``.

    ``params``: tensors, or parameter groups ``{"params": [...], "lr": ...}`` as for
    ``torch.optim.Adam`` (a group without ``lr`` takes the default). Parameters whose
    ``grad`` is None are skipped by a step, as torch skips them.
    """

    def __init__(self, params: ParamGroups, lr: float = 1e-3,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        items = list(params)
        groups = items if items and isinstance(items[0], dict) else [{"params": items}]
        self.groups = [{"params": list(g["params"]), "lr": float(g.get("lr", lr))}
                       for g in groups]
        self.beta1, self.beta2 = (float(b) for b in betas)
        self.eps = float(eps)
        self.state: dict[int, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}

    def zero_grad(self, set_to_none: bool = True) -> None:
        for group in self.groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                if set_to_none:
                    p.grad = None
                else:
                    p.grad.detach_()
                    p.grad.zero_()

    @torch.no_grad()
    def step(self) -> None:
        beta1, beta2, eps = self.beta1, self.beta2, self.eps
        for group in self.groups:
            lr = group["lr"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                grad = p.grad
                if id(p) not in self.state:
                    self.state[id(p)] = (
                        torch.tensor(0.0, dtype=torch.float64 if torch.get_default_dtype()
                                     == torch.float64 else torch.float32),
                        torch.zeros_like(p, memory_format=torch.preserve_format),
                        torch.zeros_like(p, memory_format=torch.preserve_format))
                step_t, exp_avg, exp_avg_sq = self.state[id(p)]
                step_t += 1
                exp_avg.lerp_(grad, 1 - beta1)
                exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
                step = step_t.item()
                bias_correction1 = 1 - beta1**step
                bias_correction2 = 1 - beta2**step
                step_size = lr / bias_correction1
                bias_correction2_sqrt = bias_correction2**0.5
                denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(eps)
                p.addcdiv_(exp_avg, denom, value=-step_size)
