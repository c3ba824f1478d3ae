"""The batched learner's K Q-networks as stacked tensors: their initial parameters (those of
SB3's DQN for each member's seed), the layout they are stacked in, one forward pass of all K
MLPs, and the device they live on."""

from __future__ import annotations

import torch


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
