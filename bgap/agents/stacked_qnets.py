"""The batched learner's K Q-networks as stacked tensors: their initial parameters (those of
SB3's DQN for each member's seed), the layout they are stacked in, one forward pass of all K
MLPs, the device they live on, and Adam on the stacked parameters."""

from __future__ import annotations

import numpy as np
import torch
from torch.optim.adam import adam


def default_device() -> torch.device:
    """CUDA when torch sees a GPU, else the CPU (no code change between them)."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def initial_parameters(seed: int, sizes: list[int]) -> list[torch.Tensor]:
    """The Q-network SB3's ``DQN(..., seed=seed)`` starts from: ``nn.Linear`` layers made in
    order under ``torch.manual_seed(seed)`` (SB3's ``create_mlp``), as [W, b, W, b, ...];
    the global torch stream is left as it was."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        layers = [torch.nn.Linear(i, o) for i, o in zip(sizes[:-1], sizes[1:], strict=True)]
    return [t.detach().clone() for layer in layers for t in (layer.weight, layer.bias)]


def stacking_layout(tensors: list[torch.Tensor]) -> list[torch.Tensor]:
    """nn.Linear's [W (out, in), b, ...] <-> the learner's [W (in, out), b, ...]."""
    return [t.t() if t.dim() == 2 else t for t in tensors]


def q_values(params: list[torch.Tensor], x: torch.Tensor) -> torch.Tensor:
    """K MLPs at once: ``x`` (K, B, inputs) -> (K, B, actions); params stacked
    [W (K, in, out), b (K, out), ...] (nn.Linear's weights transposed, with a member axis:
    contiguous operands and gradients are faster), ReLU between layers (SB3's MlpPolicy)."""
    n = len(params) // 2
    for i in range(n):
        w, b = params[2 * i], params[2 * i + 1]
        x = torch.baddbmm(b.unsqueeze(1), x, w)
        if i < n - 1:
            x = torch.relu(x)
    return x


class StackedAdam:
    """torch.optim.Adam (betas 0.9, 0.999, eps 1e-8: SB3's optimizer) on stacked parameters
    with one step count per member; members outside ``mask`` keep their parameters and
    moments unchanged.

    When all members share a step count (the lock step of a training), the update is
    torch's single-tensor Adam (``torch.optim.adam._single_tensor_adam``) written out in
    place on buffers kept between steps: torch's foreach path, equal to it bit for bit,
    allocates four tensors of every parameter's size per step, and on a CPU those
    allocations (fresh pages each time) cost more than the arithmetic
    (``python tools/bench.py learn``). A test holds it to torch's ``adam`` bit for bit.
    Members at different counts take torch's functional update per count."""

    def __init__(self, params: list[torch.Tensor], lr: float, betas=(0.9, 0.999), eps=1e-8):
        self.lr, (self.beta1, self.beta2), self.eps = lr, betas, eps
        self.steps = np.zeros(params[0].shape[0], dtype=np.int64)
        self.exp_avg = [torch.zeros_like(p) for p in params]
        self.exp_avg_sq = [torch.zeros_like(p) for p in params]
        self._denom = [torch.empty_like(p) for p in params]

    def step(self, params: list[torch.Tensor], grads: list[torch.Tensor], mask: np.ndarray):
        on = np.flatnonzero(mask)
        counts = np.unique(self.steps[on])
        if len(on) == len(self.steps) and len(counts) == 1:
            self._step_all(params, grads, int(counts[0]) + 1)
            self.steps += 1
            return
        for count in counts:
            members = on[self.steps[on] == count]
            idx = torch.as_tensor(members, device=params[0].device)
            p, m, v = ([t[idx] for t in ts] for ts in (params, self.exp_avg, self.exp_avg_sq))
            step = [torch.tensor(float(count)) for _ in p]
            with torch.no_grad():
                adam(
                    p,
                    [g[idx] for g in grads],
                    m,
                    v,
                    [],
                    step,
                    foreach=True,
                    amsgrad=False,
                    beta1=self.beta1,
                    beta2=self.beta2,
                    lr=self.lr,
                    weight_decay=0.0,
                    eps=self.eps,
                    maximize=False,
                )
                for full, sub in zip(
                    (*params, *self.exp_avg, *self.exp_avg_sq), (*p, *m, *v), strict=True
                ):
                    full[idx] = sub
            self.steps[members] += 1

    def _step_all(self, params: list[torch.Tensor], grads: list[torch.Tensor], step: int):
        """Step ``step`` (1-based) of every member: _single_tensor_adam's lines, in place."""
        bias_correction1 = 1 - self.beta1**step
        bias_correction2_sqrt = (1 - self.beta2**step) ** 0.5
        step_size = self.lr / bias_correction1
        with torch.no_grad():
            for p, g, m, v, denom in zip(
                params, grads, self.exp_avg, self.exp_avg_sq, self._denom, strict=True
            ):
                m.lerp_(g, 1 - self.beta1)
                v.mul_(self.beta2).addcmul_(g, g, value=1 - self.beta2)
                torch.sqrt(v, out=denom).div_(bias_correction2_sqrt).add_(self.eps)
                p.addcdiv_(m, denom, value=-step_size)
