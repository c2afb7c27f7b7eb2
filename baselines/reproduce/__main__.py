"""``python -m baselines.reproduce``: :func:`baselines.reproduce.main`."""

import sys

from baselines.reproduce import main

sys.exit(main())
