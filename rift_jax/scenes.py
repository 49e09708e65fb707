"""The paper's synthetic scenes, each a `rift_jax.Scene` built at a given granularity
(``__all__``), and `random_primitives`, a seeded family of scenes the paper never used."""

from ._scenes import cube as cube
from ._scenes import highway as highway
from ._scenes import parking_lot as parking_lot
from ._scenes import pyramid as pyramid
from ._scenes import random_primitives as random_primitives
from ._scenes import sphere as sphere
from ._scenes import weak_target as weak_target

__all__ = ["sphere", "cube", "pyramid", "parking_lot", "highway", "weak_target"]
