"""Adam for the stage-2 trainers: torch's fused CPU kernel, without ``torch.optim``.

``torch.optim.Optimizer.step`` imports ``torch._dynamo`` on its first call: about 2.7 s of CPU per
process on this project's machines (``python -c "import torch._dynamo"`` against ``import
torch``), paid again by every stage-2 job of a run (25 in the default one), for no work: 3DGS, the grid NeRF
and the MLP NeRF use this class instead.
:class:`FusedAdam` calls the kernel that ``torch.optim.Adam(..., fused=True)`` calls,
``torch._fused_adam_``, with the same arguments, so every update is bit-identical to it
(``tests/test_adam.py``). It keeps the parts of the ``torch.optim`` interface the trainers and
density control use: ``param_groups`` (dicts with ``params``, ``lr``, ``betas``, ``eps`` and any
extra key such as ``name``), ``state`` (per parameter: ``step``, ``exp_avg``, ``exp_avg_sq``, made
on the parameter's first gradient), ``step``, ``zero_grad``, and ``state_dict`` /
``load_state_dict`` in torch's layout (so either optimizer reads the other's checkpoints).
"""

from __future__ import annotations

import torch
from torch import Tensor

# The rest of torch.optim.Adam's group settings, as this class fixes them: written into state_dict()
# so that torch.optim.Adam can load it (it takes the saved groups' settings wholesale).
TORCH_GROUP = {
    "weight_decay": 0.0,
    "amsgrad": False,
    "maximize": False,
    "foreach": None,
    "capturable": False,
    "differentiable": False,
    "fused": True,
    "decoupled_weight_decay": False,
}


class FusedAdam:
    """Adam (no weight decay, no AMSGrad) over parameter groups, as ``torch.optim.Adam(fused=True)``
    (CPU, or CUDA where the NeRFs train on a GPU)."""

    def __init__(
        self, groups: list[dict], lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8
    ):
        self.defaults = {"lr": lr, "betas": tuple(betas), "eps": eps}
        self.param_groups = [self.defaults | g | {"params": list(g["params"])} for g in groups]
        self.state: dict[Tensor, dict[str, Tensor]] = {}
        for p in self.params():
            if not p.dtype.is_floating_point:
                raise ValueError(f"FusedAdam: parameters must be floating-point tensors, got {p.dtype} on {p.device}")

    def params(self) -> list[Tensor]:
        return [p for g in self.param_groups for p in g["params"]]

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self.params():
            if set_to_none:
                p.grad = None
            elif p.grad is not None:
                p.grad.zero_()

    @torch.no_grad()
    def step(self) -> None:
        for group in self.param_groups:
            params = [p for p in group["params"] if p.grad is not None]
            if not params:
                continue
            state = [self._state(p) for p in params]
            steps = [s["step"] for s in state]
            torch._foreach_add_(steps, 1)
            beta1, beta2 = group["betas"]
            torch._fused_adam_(
                params,
                [p.grad for p in params],
                [s["exp_avg"] for s in state],
                [s["exp_avg_sq"] for s in state],
                [],
                steps,
                amsgrad=False,
                lr=group["lr"],
                beta1=beta1,
                beta2=beta2,
                weight_decay=0.0,
                eps=group["eps"],
                maximize=False,
                grad_scale=None,
                found_inf=None,
            )

    def _state(self, p: Tensor) -> dict[str, Tensor]:
        """p's moments, zero on its first step; ``step`` a float32 scalar on p's device (as torch's
        fused path: the kernel runs where the parameters are, CPU or GPU)."""
        if p not in self.state:
            self.state[p] = {
                "step": torch.zeros((), dtype=torch.float32, device=p.device),
                "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
                "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format),
            }
        return self.state[p]

    def state_dict(self) -> dict:
        """torch.optim's layout: parameters numbered in group order."""
        index = {id(p): i for i, p in enumerate(self.params())}
        groups = [
            TORCH_GROUP
            | {k: v for k, v in g.items() if k != "params"}
            | {"params": [index[id(p)] for p in g["params"]]}
            for g in self.param_groups
        ]
        state = {index[id(p)]: dict(s) for p, s in self.state.items()}
        return {"state": state, "param_groups": groups}

    def load_state_dict(self, saved: dict) -> None:
        """Moments and hyper-parameters of ``state_dict()`` (this class's or torch.optim.Adam's) for
        parameters of the same groups and shapes."""
        groups = saved["param_groups"]
        if [len(g["params"]) for g in groups] != [len(g["params"]) for g in self.param_groups]:
            raise ValueError("FusedAdam.load_state_dict: the saved groups do not match this optimizer's parameters")
        self.state = {}
        for group, old in zip(self.param_groups, groups):
            group.update({k: v for k, v in old.items() if k in ("lr", "betas", "eps")})
            for p, i in zip(group["params"], old["params"]):
                s = saved["state"].get(i)
                if s is None:
                    continue
                if s["exp_avg"].shape != p.shape:
                    raise ValueError(
                        f"FusedAdam.load_state_dict: saved moments {tuple(s['exp_avg'].shape)} for a "
                        f"parameter of shape {tuple(p.shape)}"
                    )
                self.state[p] = {
                    "step": torch.as_tensor(s["step"], dtype=torch.float32).clone().reshape(()).to(p.device),
                    "exp_avg": s["exp_avg"].detach().clone().to(p.device, p.dtype),
                    "exp_avg_sq": s["exp_avg_sq"].detach().clone().to(p.device, p.dtype),
                }
