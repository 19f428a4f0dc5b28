"""The regression loop both learned policies train with: AdamW, a cosine schedule, seeded
minibatches, MSE on standardised actions, and a history row every 1/20 of the run."""

from __future__ import annotations

import time
from collections.abc import Callable

import torch


def fit(model: torch.nn.Module, batch_loss: Callable[[torch.Tensor], torch.Tensor], n: int, config,
        log: Callable[[dict], None] | None = None) -> list[dict]:
    """Train ``model`` for ``config.steps`` steps; ``batch_loss(indices)`` is the loss on those
    of the ``n`` samples. Rows: step, loss, smoothed loss, seconds."""
    optimiser = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, config.steps, eta_min=config.lr * 0.05)
    gen = torch.Generator().manual_seed(config.seed)
    history, t0, every, running = [], time.perf_counter(), max(1, config.steps // 20), None
    model.train()
    for step in range(1, config.steps + 1):
        loss = batch_loss(torch.randint(0, n, (min(config.batch_size, n),), generator=gen))
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        schedule.step()
        running = loss.item() if running is None else 0.9 * running + 0.1 * loss.item()
        if step == 1 or step % every == 0 or step == config.steps:
            record = {"step": step, "loss": float(loss.item()), "smoothed_loss": float(running),
                      "seconds": round(time.perf_counter() - t0, 3)}
            history.append(record)
            if log:
                log(record)
    model.eval()
    return history
