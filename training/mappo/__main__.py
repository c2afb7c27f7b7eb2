"""``python -m training.mappo``: :func:`training.mappo.main`."""

from training.mappo import main

main()
