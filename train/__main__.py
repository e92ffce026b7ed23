"""``python -m snake_env.train``: the same as ``snake-train``."""

import sys

from snake_env.train.train import main

sys.exit(main())
