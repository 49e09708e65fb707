"""``python -m rift_jax``: the command line (`rift_jax._cli`), as the ``rift-jax`` script."""

import sys

from ._cli import main

if __name__ == "__main__":
    sys.exit(main())
