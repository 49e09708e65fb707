"""Data in and out, one idea per module:

- `native`: `save` and `load`, rift_jax's own files (NPZ or HDF5, exact bit for bit);
- `codec`: objects to those files' record (JSON header and named arrays) and back;
- `public`: `load_rift_public`, the RIFT authors' NPZ layout;
- `ply`: `export_ply`, a point cloud for 3-D viewers;
- `atomic`: `write_atomic`, which every writer here (and the experiments' run store) uses.
"""

from .atomic import write_atomic as write_atomic
from .native import load as load
from .native import save as save
from .ply import export_ply as export_ply
from .public import load_rift_public as load_rift_public
