"""The world the UAVs fly in: the configuration, the road and the target's track, the terrain and its polytopes,
line of sight and shadows (eqs. 6-9), the scene generator, its families and the task suite, scenarios and scene
sets, trajectories and their metrics (eqs. 2-3, 16-18), and the single-scene :class:`~covert_env.world.engine.Engine`.

It builds on :mod:`covert_env.geometry` and never imports the environments (``tests/test_imports.py``).
"""
