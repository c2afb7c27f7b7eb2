"""The geometry of the model, scene-free: angles (eq. 11's bearings), separation (eq. 2), the feasible zone and its
lattice (eqs. 4-5), the unicycle and its turn-then-straight manoeuvre (eqs. 1, 22-29), the flight of a batch of
UAVs, the reach table of the waypoint masks, the stage cost (eqs. 11-15) and the one line-of-sight kernel.

Nothing here imports :mod:`covert_env.world` or the environments (``tests/test_imports.py``).
"""
