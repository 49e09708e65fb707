"""How an INR is trained: the `Recipe`, its named presets, and resolving a method's
``recipe`` and per-field overrides into one."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ..._losses import LOSSES
from ..._validation import check_nonnegative_int, check_positive, check_positive_int


@dataclasses.dataclass(frozen=True)
class Recipe:
    """How an INR is trained. ``Recipe()`` is the default; ``RECIPES["paper"]`` the paper's.

    - `loss`: ``"mse"`` (default: complex MSE), ``"robust"`` (the default until complex
      MSE did better on the stress grid: docs/rift.md), ``"paper"`` (see
      `rift_jax.losses`), or a callable ``loss(pred, target) -> scalar``.
    - `epochs`: how many epochs, each one or more passes over the training viewpoints
      (`epoch_views`).
    - `learning_rate`, `weight_decay`, `adam_eps`: `optax.adamw`'s (weight decay applies to
      the INR, not to the gain). ``learning_rate=None`` takes the model's own default
      (`AbstractINR.learning_rate`: 1e-2 for RiftN and HashGrid, 1e-3 for RiftS).
    - `halve_every`: halve the learning rate every this many epochs, a fraction allowed
      (counted in optimizer steps, at least one; None: constant).
    - `batch_views`: viewpoints per optimizer step (None: all, one step per pass). Each pass
      visits the viewpoints in a fresh seeded order; when the batch does not divide an
      epoch's views, the last batch is filled up with the epoch's first ones.
    - `epoch_views`: an epoch visits at least this many viewpoints: from n fewer, it passes
      over them ⌈epoch_views / n⌉ times (`passes`), each pass in a fresh order, so that
      `epochs`, `halve_every`, `patience` and `recheck_every` mean about as many optimizer
      steps from 10 or 30 views as from 100 (docs/rift.md, "Few viewpoints"). None: one
      pass per epoch, as the paper.
    - `clip_norm`: clip the gradient to this global norm (None: no clipping).
    - `gain`: learn the global complex gain, started where the initial field's signals have
      the data's energy (False: fixed where it starts, 1 as in the paper, or an `init`
      field's own).
    - `patience`: stop early once this many epochs in a row have not lowered the epoch's
      mean training loss below ``1 - min_improvement`` times its value at the last epoch
      that did (`rift_jax.solvers` `Patience`, the least-squares solvers' rule; default 10, so that
      `epochs` is a budget: "until converged, at most N"; None: run every epoch, as the
      paper). The run then ends with ``Outcome.CONVERGED``, as the least-squares solvers
      do, and keeps the best parameters. At the paper's scale the loss is flat after ~20 of
      100 epochs, so a `patience` of 10 can save most of a run. Where `rift` is told the
      data's `noise`, progress is measured on the loss above the noise's share
      (`Patience`'s ``floor``).
    - `min_improvement`: see `patience`.
    - `prune`: train only an *active set* of the operator's points: those where |ρ| is at
      least ``prune`` times its largest value, and their neighbours (within √3 point
      spacings). The set is chosen from the field itself every `recheck_every` epochs (the
      first time after `recheck_every` epochs, or at once from an `init` field), and grows
      back wherever the field has risen since; each step's cost follows the active points.
      The result is what was trained: the best epoch's field on that epoch's active set,
      zero elsewhere. Default 0.05: RIFT trains where the field lives (on the paper's cube,
      the same m-SSIM in a fraction of the time: docs/rift.md). None: train every point.
    - `recheck_every`: see `prune`.
    - `holdout`: hold out this many of the training viewpoints (evenly spread in their
      order) and never train on them. Each epoch then measures their relative residual
      ‖y − Aρ‖/‖y‖ (``stats["holdout_residual"]``), and the best parameters and `patience`
      follow it instead of the training loss: early stopping on unseen data. 0: none.
    - `sparsity`: weight of a sparsity prior added to the loss: ‖ρ‖₁ / (√k‖ρ‖₂) over the
      k trained points, which ignores scale (1 for a flat field, 1/√k for one point), so
      that the weight means the same on any data (an active set's k is the stage's
      candidate points, so the term does not jump when the set changes). The loss that
      picks the best epoch and drives `patience` includes it. 0 (default): none, as the
      paper.
    - `retries`: how many times a collapsed run is retried from a fresh start at half the
      learning rate (see `rift`, "Collapse"). 0: never.
    """

    loss: str | Callable = "mse"
    epochs: int = 100
    learning_rate: float | None = None
    weight_decay: float = 1e-2
    halve_every: float | None = 25
    batch_views: int | None = 10
    epoch_views: int | None = 100
    clip_norm: float | None = 1.0
    gain: bool = True
    adam_eps: float = 1e-8
    patience: int | None = 10
    min_improvement: float = 1e-3
    prune: float | None = 0.05
    recheck_every: int = 10
    holdout: int = 0
    retries: int = 2
    sparsity: float = 0.0

    def __post_init__(self):
        if not callable(self.loss) and self.loss not in LOSSES:
            raise ValueError(
                f"Recipe: unknown `loss` {self.loss!r}; choose one of {sorted(LOSSES)} or pass "
                "a callable loss(pred, target)."
            )
        check_positive_int("Recipe: `epochs`", self.epochs)
        if self.learning_rate is not None:
            check_positive("Recipe: `learning_rate` (or None)", self.learning_rate)
        check_positive("Recipe: `adam_eps`", self.adam_eps)
        if not isinstance(self.weight_decay, int | float | np.number) or not self.weight_decay >= 0:
            raise ValueError(f"Recipe: `weight_decay` must be ≥ 0, got {self.weight_decay!r}.")
        if self.halve_every is not None:
            check_positive("Recipe: `halve_every` (or None)", self.halve_every)
        if self.batch_views is not None:
            check_positive_int("Recipe: `batch_views` (or None)", self.batch_views)
        if self.epoch_views is not None:
            check_positive_int("Recipe: `epoch_views` (or None)", self.epoch_views)
        if self.clip_norm is not None:
            check_positive("Recipe: `clip_norm` (or None)", self.clip_norm)
        if not isinstance(self.gain, bool):
            raise ValueError(f"Recipe: `gain` must be True or False, got {self.gain!r}.")
        if self.patience is not None:
            check_positive_int("Recipe: `patience` (or None)", self.patience)
        if self.prune is not None and not 0 < self.prune < 1:
            raise ValueError(f"Recipe: `prune` must be in (0, 1) or None, got {self.prune!r}.")
        check_positive_int("Recipe: `recheck_every`", self.recheck_every)
        check_nonnegative_int("Recipe: `holdout`", self.holdout)
        check_nonnegative_int("Recipe: `retries`", self.retries)
        if not isinstance(self.sparsity, int | float | np.number) or not self.sparsity >= 0:
            raise ValueError(f"Recipe: `sparsity` must be ≥ 0, got {self.sparsity!r}.")
        if not 0 <= self.min_improvement < 1:
            raise ValueError(
                f"Recipe: `min_improvement` must be in [0, 1), got {self.min_improvement!r}."
            )

    def passes(self, n_views: int) -> int:
        """Passes over ``n_views`` training viewpoints per epoch: enough to visit
        `epoch_views` of them (1 when that is None or the views are at least as many)."""
        if self.epoch_views is None:
            return 1
        return max(1, -(-self.epoch_views // n_views))

    @property
    def loss_fn(self) -> Callable:
        return self.loss if callable(self.loss) else LOSSES[self.loss]


RECIPES = {
    "default": Recipe(),
    # Appendix "Optimization Details": AdamW 1e-2, weight decay 1e-2, 500 epochs, learning
    # rate halved every 100, lowest-loss parameters kept; magnitude + phase L1 with α2 = 1000
    # α1. The batch is not stated: one step per epoch over all viewpoints.
    "paper": Recipe(
        loss="paper",
        epochs=500,
        learning_rate=1e-2,
        halve_every=100,
        batch_views=None,
        epoch_views=None,  # one pass over the viewpoints per epoch
        clip_norm=None,
        gain=False,
        patience=None,  # the paper trains every epoch
        prune=None,  # ... on every point
    ),
}


def resolve(where: str, recipe, overrides) -> Recipe:
    if isinstance(recipe, str):
        if recipe not in RECIPES:
            raise ValueError(
                f"{where}: unknown `recipe` {recipe!r}; choose one of {sorted(RECIPES)} or pass "
                "a rift_jax.solvers.Recipe."
            )
        recipe = RECIPES[recipe]
    if not isinstance(recipe, Recipe):
        raise ValueError(f"{where}: `recipe` must be a name or a Recipe, got {recipe!r}.")
    fields = {f.name for f in dataclasses.fields(Recipe)}
    if unknown := set(overrides) - fields:
        raise ValueError(
            f"{where}: unknown option(s) {sorted(unknown)}; the Recipe's fields are "
            f"{sorted(fields)}, besides model, recipe, width, depth, init, extent, fine_points, "
            "fine_epochs, seed and progress."
        )
    return dataclasses.replace(recipe, **overrides)
