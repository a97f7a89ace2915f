"""Adam (Kingma & Ba 2015) for the project's training loops, without ``torch.optim``.

``torch.optim``'s optimisers import ``torch._dynamo`` the first time one is built (its methods are
wrapped to keep ``torch.compile`` out of them), which costs about 1.1 s per process on the 2-core VM:
every conversion's worker and every measuring worker of a ``--network scene`` run paid it. This
class computes what ``torch.optim.Adam`` computes with ``amsgrad``, weight decay and ``maximize`` off
(the only form the project uses), update for update: the test beside it checks the parameters
bit for bit against ``torch.optim.Adam`` over steps with changing learning rates and missing gradients.

Update for a parameter ``p`` with gradient ``g`` at step ``t`` (1-based), per element::

    m = beta1 m + (1 - beta1) g          (lerp)
    v = beta2 v + (1 - beta2) g^2
    p = p - lr / (1 - beta1^t) * m / (sqrt(v) / sqrt(1 - beta2^t) + eps)

The state dict has ``torch.optim``'s layout (``state``: per parameter index ``step``, ``exp_avg``,
``exp_avg_sq``; ``param_groups``: ``lr``, ``betas``, ``eps``, ``params``), so checkpoints written by
either load into the other.
"""

from __future__ import annotations

import math

import torch


def cosine_lr(start: float, end: float, step: int, steps: int) -> float:
    """The learning rate of step ``step`` (0-based) of a ``steps``-step run: a half cosine from ``start`` at step 0
    down to ``end`` at step ``steps`` (and after it), the schedule of every training loop of the project."""
    t = min(1.0, step / max(1, steps))
    return end + 0.5 * (start - end) * (1.0 + math.cos(math.pi * t))


class Adam:
    """Adam over ``params`` (tensors, or one dict ``{"params": [...], ...}`` per group), learning rate
    ``lr`` (each group's ``"lr"`` may be changed between steps), ``betas`` and ``eps`` as in the paper."""

    def __init__(self, params, lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        params = list(params)
        groups = params if params and isinstance(params[0], dict) else [{"params": params}]
        self.param_groups = [{"lr": lr, "betas": tuple(betas), "eps": eps, **g, "params": list(g["params"])}
                             for g in groups]
        self.state: dict[torch.Tensor, dict] = {}

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Clear every parameter's gradient (None, or zeros with ``set_to_none=False``)."""
        for group in self.param_groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                if set_to_none:
                    p.grad = None
                else:
                    p.grad.detach_().zero_()

    @torch.no_grad()
    def step(self) -> None:
        """One update of every parameter that has a gradient (module docstring)."""
        for group in self.param_groups:
            beta1, beta2 = group["betas"]
            lr, eps = group["lr"], group["eps"]
            params = [p for p in group["params"] if p.grad is not None]
            if not params:
                continue
            states = [self._state(p) for p in params]
            grads = [p.grad for p in params]
            exp_avgs = [s["exp_avg"] for s in states]
            exp_avg_sqs = [s["exp_avg_sq"] for s in states]
            for s in states:
                s["step"] += 1
            torch._foreach_lerp_(exp_avgs, grads, 1 - beta1)
            torch._foreach_mul_(exp_avg_sqs, beta2)
            torch._foreach_addcmul_(exp_avg_sqs, grads, grads, value=1 - beta2)
            # One step count per parameter (all equal unless a parameter missed steps): group by it.
            for t in sorted({float(s["step"]) for s in states}):
                idx = [i for i, s in enumerate(states) if float(s["step"]) == t]
                step_size = lr / (1 - beta1 ** t)
                correction = (1 - beta2 ** t) ** 0.5
                denom = torch._foreach_sqrt([exp_avg_sqs[i] for i in idx])
                torch._foreach_div_(denom, correction)
                torch._foreach_add_(denom, eps)
                torch._foreach_addcdiv_([params[i] for i in idx], [exp_avgs[i] for i in idx], denom,
                                        value=-step_size)

    def _state(self, p: torch.Tensor) -> dict:
        state = self.state.get(p)
        if state is None:
            state = self.state[p] = {"step": torch.tensor(0.0), "exp_avg": torch.zeros_like(p),
                                     "exp_avg_sq": torch.zeros_like(p)}
        return state

    def state_dict(self) -> dict:
        """``torch.optim``'s layout (module docstring): parameters by their index over the groups."""
        index, groups, state = 0, [], {}
        for group in self.param_groups:
            ids = []
            for p in group["params"]:
                if p in self.state:
                    state[index] = dict(self.state[p])
                ids.append(index)
                index += 1
            groups.append({**{k: v for k, v in group.items() if k != "params"}, "params": ids})
        return {"state": state, "param_groups": groups}

    def load_state_dict(self, state_dict: dict) -> None:
        """Restore a :meth:`state_dict` (or ``torch.optim.Adam``'s) made for groups of the same sizes."""
        groups = state_dict["param_groups"]
        if [len(g["params"]) for g in groups] != [len(g["params"]) for g in self.param_groups]:
            raise ValueError("the optimiser state was saved for other parameter groups")
        saved = state_dict["state"]
        self.state = {}
        for group, stored in zip(self.param_groups, groups):
            for key in ("lr", "betas", "eps"):
                if key in stored:
                    group[key] = tuple(stored[key]) if key == "betas" else stored[key]
            for p, i in zip(group["params"], stored["params"]):
                if i in saved:
                    s = saved[i]
                    self.state[p] = {"step": torch.as_tensor(s["step"], dtype=torch.float32).clone(),
                                     "exp_avg": s["exp_avg"].to(p.device, p.dtype).clone(),
                                     "exp_avg_sq": s["exp_avg_sq"].to(p.device, p.dtype).clone()}
