"""`python -m taichi_anim` is the `taichi-anim` command."""

import sys

from .cli import main

sys.exit(main())
