"""Reference solver: the official formulation, Adam on (d, u) with PyTorch autograd (Rossi et al. 2020).

Learning rate ``lr`` decays x0.1 every ceil(iters / lr_slots) steps (StepLR); d is clamped to
[d_min, d_max] after every step; float32 as the official default.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from engine.core.interrupt import check_interrupt
from engine.refinement.energy import ScaleProblem

SMALL_PROBLEM = 65536  # pixels below which Adam runs single-threaded


class TorchEnergy:
    """E(d, u) of one scale as a differentiable torch function (float32 unless told)."""

    def __init__(self, problem: ScaleProblem, dtype: torch.dtype = torch.float32):
        g = problem.graph
        self.n = problem.size
        self.neighbors = torch.from_numpy(g.neighbors.astype(np.int64))
        self.weights = torch.from_numpy(g.weights).to(dtype)
        self.offsets = torch.from_numpy(g.offsets).to(dtype)
        self.data = torch.from_numpy(np.asarray(problem.data, np.float32)).to(dtype)
        self.fidelity = torch.from_numpy(np.asarray(problem.fidelity, np.float32)).to(dtype)
        self.lambda_data, self.lambda_reg, self.gamma = problem.lambda_data, problem.lambda_reg, problem.gamma

    def __call__(self, d: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        nb = self.neighbors
        data = torch.sum(self.fidelity * torch.abs(d - self.data))
        res = self.weights * (d[:, None] - d[nb] - torch.einsum("ic,ikc->ik", u, self.offsets))
        plane = torch.sum(torch.linalg.vector_norm(res, dim=1))
        tv = torch.sum(self.weights * torch.linalg.vector_norm(u[:, None, :] - u[nb], dim=2))
        return (self.lambda_data * data + self.lambda_reg * (plane + self.gamma * tv)) / self.n


def solve_adam(problem: ScaleProblem, d0: np.ndarray, u0: np.ndarray, iters: int, lr: float,
               lr_slots: int = 1) -> tuple[np.ndarray, np.ndarray, int]:
    """Minimise E from (d0 (N,), u0 (N, 2)); returns (d, u, iterations done) as float32 arrays."""
    f = TorchEnergy(problem)
    d = torch.tensor(np.asarray(d0, np.float32).ravel(), requires_grad=True)
    u = torch.tensor(np.asarray(u0, np.float32).reshape(-1, 2), requires_grad=True)
    if iters <= 0:
        return d.detach().numpy().copy(), u.detach().numpy().copy(), 0
    opt = torch.optim.Adam([d, u], lr=lr)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=max(1, math.ceil(iters / lr_slots)), gamma=0.1)
    threads = torch.get_num_threads()
    if problem.size < SMALL_PROBLEM:  # intra-op threads only add synchronisation on small maps
        torch.set_num_threads(1)
    try:
        with torch.no_grad():
            d.clamp_(problem.d_min, problem.d_max)
        for _ in range(iters):
            check_interrupt()  # between steps (engine/core/interrupt.py)
            opt.zero_grad(set_to_none=True)
            f(d, u).backward()
            opt.step()
            sched.step()
            with torch.no_grad():
                d.clamp_(problem.d_min, problem.d_max)
    finally:
        torch.set_num_threads(threads)
    return d.detach().numpy().copy(), u.detach().numpy().copy(), iters
