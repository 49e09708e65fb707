"""RIFT: an implicit neural representation trained through the GRT with optax.

The scene is a `Field` (an INR plus a global complex gain) rendered on the operator's
points; its signals are the GRT of that rendering, and the loss compares them with the
data. The signal's cotangent reaches ρ through `realified`, i.e. through the hand-written
adjoint kernel: JAX's own transpose of the forward kernel is exact but ~12x slower
(measured, docs/benchmarks.md).

- `recipe`: how an INR is trained (`Recipe`, `RECIPES`).
- `solver`: `rift`, the entry point: a training run, its collapse check and retries.
- `training`: one run, epoch by epoch on the shared `iterate`, and its jitted step.
- `active_set`: where a run trains (``prune``): candidate points and the active set.
- `optimizer`: AdamW, its learning-rate schedule and what it decays.
- `collapse`: the ways an INR fails without a non-finite value (`diagnose`).
"""

from .collapse import CollapseWarning as CollapseWarning
from .collapse import diagnose as diagnose
from .recipe import RECIPES as RECIPES
from .recipe import Recipe as Recipe
from .solver import rift as rift
