"""Evaluation of policies on held-out scenes, shared by ``covert-env evaluate`` and ``covert-env benchmark``.

* :mod:`covert_env.evaluation.registry` -- the policies a spec can name: the entry point group
  ``covert_env.policies``, which the packages providing policies (the planners, the learned teams) fill.
* :mod:`covert_env.evaluation.specs` -- policy specs ``SPEC[@MODE][+shield]`` and seed groups, resolved to a policy
  and its env settings.
* :mod:`covert_env.evaluation.episodes` -- a policy flown through held-out scenes (or a scene set), one row of
  metrics per episode (:func:`~covert_env.evaluation.episodes.run_episode`, ``evaluate``, ``summarise``, ``COLUMNS``).
* :mod:`covert_env.evaluation.evaluate` -- ``covert-env evaluate``: the harness, a leaderboard of policies on the
  same held-out scenes.
* :mod:`covert_env.evaluation.benchmark` -- ``covert-env benchmark``: the task suite's protocol (normalised scores,
  IQM with intervals, profiles).
* :mod:`covert_env.evaluation.tiers` -- the leaderboards' tiers, declared by each policy's factory.
* :mod:`covert_env.evaluation.stats` -- IQM, stratified bootstrap, probability of improvement (rliable's methods).
* :mod:`covert_env.evaluation.leaderboard` -- the suite's leaderboard published into the README and the docs.
* :mod:`covert_env.evaluation.provenance` -- where scores were measured: platform, library versions, commit.

This package imports no package above covert_env: it reaches policies only through the registry.
"""
