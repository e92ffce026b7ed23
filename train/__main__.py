"""``python -m train``: the same as ``snake-train``."""

import sys

from train.train import main

sys.exit(main())
