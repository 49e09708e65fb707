"""rift_jax: learning radar scenes from radar signals (RIFT, in JAX).

Data's path through the package: geometry (`Radar`, `Viewpoints`, `antennas_at`) →
scene (`Scene`, `rift_jax.scenes`) → GRT kernel (`rift_jax.grt`) → operator
(`grt_operator`; on a support, `estimate_support`) → solvers and INRs (`rift_jax.solvers`,
`RiftN`, `RiftS`, `Field`, `rift_jax.losses`) → `fit` → metrics (`rift_jax.metrics`). In and
out of files: `save`, `load`, `load_rift_public` (the RIFT authors' NPZ layout), `export_ply`
(a point cloud for 3-D viewers).
"""

import os as _os


def _use_every_cpu_core() -> None:
    """Give JAX one CPU device per core (unless the user chose a number, or JAX has already
    started). XLA runs one small computation on about one core; rift_jax spreads independent
    viewpoints over devices, so this is what makes both cores of a small machine work.
    Set ``RIFT_JAX_CPU_DEVICES=1`` to opt out."""
    import jax

    wanted = _os.environ.get("RIFT_JAX_CPU_DEVICES")
    if "xla_force_host_platform_device_count" in _os.environ.get("XLA_FLAGS", ""):
        return
    try:
        n = int(wanted) if wanted else len(_os.sched_getaffinity(0))
    except (ValueError, AttributeError):
        n = _os.cpu_count() or 1
    if n > 1 and jax.config.jax_num_cpu_devices == -1:  # -1: nobody has chosen
        try:
            jax.config.update("jax_num_cpu_devices", n)
        except RuntimeError:  # JAX's backends are already up: keep what the user has
            pass


_use_every_cpu_core()

from . import grt as grt  # noqa: E402
from . import losses as losses  # noqa: E402
from . import metrics as metrics  # noqa: E402
from . import scenes as scenes  # noqa: E402
from . import solvers as solvers  # noqa: E402
from ._checks import FitWarning as FitWarning  # noqa: E402
from ._checks import recorded_failures as recorded_failures  # noqa: E402
from ._fit import FitResult as FitResult  # noqa: E402
from ._fit import fit as fit  # noqa: E402
from ._geometry import C0 as C0  # noqa: E402
from ._geometry import Radar as Radar  # noqa: E402
from ._geometry import Viewpoints as Viewpoints  # noqa: E402
from ._geometry import antenna_positions as antenna_positions  # noqa: E402
from ._geometry import antennas_at as antennas_at  # noqa: E402
from ._io import export_ply as export_ply  # noqa: E402
from ._io import load as load  # noqa: E402
from ._io import load_rift_public as load_rift_public  # noqa: E402
from ._io import save as save  # noqa: E402
from ._models import AbstractINR as AbstractINR  # noqa: E402
from ._models import Field as Field  # noqa: E402
from ._models import HashGrid as HashGrid  # noqa: E402
from ._models import RiftN as RiftN  # noqa: E402
from ._models import RiftS as RiftS  # noqa: E402
from ._operator import GRT as GRT  # noqa: E402
from ._operator import GRTOperator as GRTOperator  # noqa: E402
from ._operator import grt_operator as grt_operator  # noqa: E402
from ._scenes import GridWarning as GridWarning  # noqa: E402
from ._scenes import Scene as Scene  # noqa: E402
from ._scenes import grid_points as grid_points  # noqa: E402
from ._support import estimate_support as estimate_support  # noqa: E402
from ._synthesis import PointScatterers as PointScatterers  # noqa: E402
from ._synthesis import RadarData as RadarData  # noqa: E402
from ._synthesis import synthesize as synthesize  # noqa: E402
from ._version import __version__ as __version__  # noqa: E402
