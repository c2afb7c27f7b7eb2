"""The learned policies the evaluation harness loads from files: the factories of the spec prefixes ``sb3:``,
``rllib:``, ``mappo:`` and ``pretrained:`` (entry point group ``covert_env.policies``,
:mod:`covert_env.evaluation.registry`).

* ``sb3:PATH``: an SB3 model (PPO, SAC, MaskablePPO) -- a run folder (its ``model.zip``) or a ``.zip``
  checkpoint; its ``args.json`` gives the env settings and the VecNormalize statistics beside the model
  (``vecnormalize.json``, read without pickle; older ``.pkl`` statistics are refused, see
  :mod:`training.sb3.convert_vecnormalize`) are applied. Single-UAV models act for every UAV independently (each sees
  its own observation), so they need ``--n-uavs 1`` unless they were trained with the same team size.
* ``rllib:PATH``: an RLlib checkpoint of :mod:`training.rllib_ppo`; inference runs in plain torch, no Ray
  cluster is started.
* SB3 ``.zip`` files and RLlib checkpoints hold pickles, which run any code they carry when loaded: ``sb3:`` and
  ``rllib:`` specs are refused unless ``trust_checkpoint=True`` (``--trust-checkpoint``), only for files from a
  source you trust (:mod:`training.trust`).
* ``mappo:PATH``: a MAPPO/IPPO actor of :mod:`training.mappo` -- a run folder (its ``model.npz`` and
  ``model.json``) or ``NAME.npz`` with its card ``NAME.json``; ``pretrained:NAME``: the weights shipped in
  ``training/pretrained/``. Both run in numpy (no torch, no pickle): :mod:`training.pretrained`. A card of ``kind``
  ``dp-cost`` is the planner with a learned cost (:mod:`baselines.learned_cost`): it plans for any team
  size in waypoint mode.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

import numpy as np

from baselines.learned_cost import is_cost_planner_card, load_cost_planner
from baselines.policies import parallel_env_of
from covert_env.command_line import UsageError, read_run_json
from training.pretrained import PRETRAINED_DIR, as_flown, load_learned, pretrained_names
from training.rllib_ppo import load_policy as load_rllib
from training.runs import run_env
from training.trust import require_trust

__all__ = ["SB3Policy", "load_sb3", "mappo_policy", "pretrained_policy", "rllib_policy", "sb3_policy",
           "vecnormalize_path"]


class SB3Policy:
    """An SB3 model behind the common policy interface (``reset(env, seed)``, ``act(observations, env)``).

    Observations of the agents still flying are stacked, normalised with the saved VecNormalize statistics and
    passed to ``model.predict(deterministic=True)`` in one batch (parameter sharing); MaskablePPO also gets the
    env's action masks.
    """

    def __init__(self, model, norm=None, *, name: str = "sb3", env_settings: dict | None = None,
                 deterministic: bool = True):
        self.model = model
        self.norm = norm                        # training.sb3.vec_env.NormStats or None
        self.name = name
        self.env_settings = env_settings or {}
        self.deterministic = deterministic
        self.masked = type(model).__name__ == "MaskablePPO"

    def reset(self, env, seed: int | None = None) -> None:
        pass

    def _par(self, env):
        return parallel_env_of(env)

    def act(self, observations, env):
        par, single = self._par(env)
        agents = [a for a in par.possible_agents if a in par.agents]
        obs_d = observations if single is None else {single: observations}
        obs = np.stack([np.asarray(obs_d[a], np.float32) for a in agents])
        if self.norm is not None:
            obs = self.norm.normalize_obs(obs)
        kw = {}
        if self.masked:
            kw["action_masks"] = np.stack([par.action_mask(a).astype(bool) for a in agents])
        actions, _ = self.model.predict(obs, deterministic=self.deterministic, **kw)
        out = {a: (int(actions[i]) if np.ndim(actions[i]) == 0 else np.asarray(actions[i]))
               for i, a in enumerate(agents)}
        return out[single] if single is not None else out


def _space_text(space) -> str:
    return f"Discrete({space.n})" if hasattr(space, "n") else f"a Box of shape {tuple(space.shape)}"


def _find_args_json(path: Path) -> Path | None:
    for d in [path if path.is_dir() else path.parent, *(path if path.is_dir() else path.parent).parents][:3]:
        if (d / "args.json").exists():
            return d / "args.json"
    return None


def vecnormalize_path(model_path: Path) -> Path:
    """The VecNormalize statistics beside an SB3 model: ``vecnormalize.json`` of a run folder's ``model.zip``, or
    ``{algo}_vecnormalize_{steps}_steps.json`` of a ``CheckpointCallback`` checkpoint ``{algo}_{steps}_steps.zip``."""
    name = model_path.name
    if name.endswith("_steps.zip"):                              # CheckpointCallback naming
        head, steps = name[: -len("_steps.zip")].rsplit("_", 1)
        return model_path.parent / f"{head}_vecnormalize_{steps}_steps.json"
    return model_path.parent / "vecnormalize.json"


def load_sb3(path: str | Path, *, trust_checkpoint: bool = False) -> SB3Policy:
    """Load an SB3 run folder or checkpoint (.zip) with its VecNormalize statistics (JSON) and env settings.

    The model ``.zip`` is loaded by SB3, which unpickles parts of it: without ``trust_checkpoint=True`` it is
    refused (:func:`training.trust.require_trust`) before anything is read. Statistics pickled by older versions
    (``.pkl``) are refused with the command that converts them.
    """
    path = Path(path)
    model_path = path / "model.zip" if path.is_dir() else path
    if not model_path.is_file():
        raise UsageError(f"no SB3 model at {model_path} (expected a run folder holding model.zip, or a .zip)")
    require_trust(model_path, "an SB3 model", trust_checkpoint)
    vn_path = vecnormalize_path(model_path)
    if not vn_path.exists() and vn_path.with_suffix(".pkl").exists():
        vn_path = vn_path.with_suffix(".pkl")                    # refused below, with the conversion command
    args_json = _find_args_json(path)
    meta = read_run_json(args_json, "run arguments") if args_json else {}
    if not isinstance(meta, dict):
        raise UsageError(f"{args_json}: must be a JSON object (a run's arguments), got {type(meta).__name__}")
    cls_name = meta.get("sb3_class", "PPO")
    if cls_name not in ("PPO", "SAC", "MaskablePPO"):
        raise UsageError(f"{args_json}: unknown sb3_class {cls_name!r} (PPO, SAC or MaskablePPO)")
    settings, env = run_env(meta.get("env_kwargs", {}), str(args_json or f"sb3:{path} (no args.json)"))

    from training.sb3.vec_env import read_vecnormalize

    norm = None
    if vn_path.exists():
        try:
            norm = read_vecnormalize(vn_path)
        except (OSError, ValueError) as exc:
            raise UsageError(str(exc)) from None
        norm = norm if norm.norm_obs else None

    import torch

    torch.set_num_threads(1)
    if cls_name == "MaskablePPO":
        from sb3_contrib import MaskablePPO as cls
    else:
        import stable_baselines3

        cls = getattr(stable_baselines3, cls_name)
    try:
        model = cls.load(str(model_path), device="cpu")
    except (ValueError, KeyError, OSError, EOFError, AssertionError) as exc:
        # Not a zip, or a zip that is not an SB3 model (SB3 asserts "No data found in the saved file").
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        reason = first.removeprefix("Error: ")
        raise UsageError(f"sb3:{path}: {model_path} is not a loadable {cls_name} model ({reason})") from None
    if norm is not None and norm.obs_mean.shape != model.observation_space.shape:
        raise UsageError(f"{vn_path}: statistics of observations of shape {norm.obs_mean.shape}, but {model_path} "
                         f"takes observations of shape {model.observation_space.shape}")
    agent = env.possible_agents[0]
    for kind, space, wanted in (("observations", model.observation_space, env.observation_space(agent)),
                                ("actions", model.action_space, env.action_space(agent))):
        if _space_text(space) != _space_text(wanted):
            raise UsageError(f"sb3:{path}: {model_path} takes {kind} as {_space_text(space)}, but the env of its "
                             f"settings ({args_json or 'defaults, no args.json'}: n_uavs={settings['n_uavs']}, "
                             f"action_mode={settings['action_mode']}, map_size={settings['map_size']}) has "
                             f"{_space_text(wanted)}")
    env.close()
    label = meta.get("algo", cls_name.lower())
    if path.is_dir():
        name = f"{label} ({path.name})"
    elif path.parent.name == "checkpoints":
        steps = path.stem.rsplit("_", 2)[-2] if path.stem.endswith("_steps") else path.stem
        name = f"{label} ({path.parent.parent.name} @ {steps} steps)"
    else:
        name = f"{label} ({path.parent.name}/{path.name})"
    return SB3Policy(model, norm, name=name, env_settings=settings)


@contextlib.contextmanager
def _extra(module: str, extra: str):
    """A missing optional dependency ``module`` as a :class:`~covert_env.command_line.UsageError` naming the extra."""
    try:
        yield
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split(".")[0] != module:
            raise

        raise UsageError(f"this policy needs {module}, which is not installed: pip install -e \".[{extra}]\"") \
            from None


# ---------------------------------------------------------------------- the factories of the spec prefixes
def sb3_policy(spec: str, n_uavs: int, *, trust_checkpoint: bool = False) -> tuple[Any, dict]:
    """``sb3:PATH``: an SB3 model and the env settings of its run."""
    with _extra("stable_baselines3", "train"), _extra("sb3_contrib", "train"), _extra("torch", "train"):
        pol = load_sb3(spec[len("sb3:"):], trust_checkpoint=trust_checkpoint)
    return pol, dict(pol.env_settings)


def rllib_policy(spec: str, n_uavs: int, *, trust_checkpoint: bool = False) -> tuple[Any, dict]:
    """``rllib:PATH``: an RLlib checkpoint of :mod:`training.rllib_ppo` (run in plain torch)."""
    path = spec[len("rllib:"):]
    if not (Path(path) / "learner_group").is_dir():
        raise UsageError(f"no RLlib checkpoint at {path} (expected a training.rllib_ppo checkpoint folder)")
    require_trust(path, "an RLlib checkpoint", trust_checkpoint)
    with _extra("ray", "rllib"):
        pol = load_rllib(path, trust_checkpoint=True)
    return pol, dict(pol.env_settings)


def mappo_policy(spec: str, n_uavs: int, *, trust_checkpoint: bool = False) -> tuple[Any, dict]:
    """``mappo:PATH``: a run folder of :mod:`training.mappo` or :mod:`training.dp_cost`, or ``NAME.npz`` with its
    card."""
    return _numpy_policy(spec, Path(spec[len("mappo:"):]), n_uavs)


def pretrained_policy(spec: str, n_uavs: int, *, trust_checkpoint: bool = False) -> tuple[Any, dict]:
    """``pretrained:NAME``: weights shipped in ``training/pretrained/``."""
    name = spec[len("pretrained:"):]
    if name not in pretrained_names():
        shipped = ", ".join(pretrained_names()) or "none"
        raise UsageError(f"no pretrained weights {name!r} (shipped: {shipped})")
    return _numpy_policy(spec, PRETRAINED_DIR / f"{name}.npz", n_uavs)


def card_tier(path: Path) -> str:
    """The tier of the weights at ``path`` (:mod:`covert_env.evaluation.tiers`): ``hybrid`` for the planner with a
    learned cost, ``learned`` for an actor that acts from observations."""
    return "hybrid" if is_cost_planner_card(path) else "learned"


sb3_policy.argument = rllib_policy.argument = mappo_policy.argument = "PATH"
pretrained_policy.argument = "NAME"
# A seed group's tier is its first run's.
sb3_policy.tier = rllib_policy.tier = "learned"
mappo_policy.tier = lambda spec: card_tier(Path(spec[len("mappo:"):].split(",")[0]))
pretrained_policy.tier = lambda spec: card_tier(PRETRAINED_DIR / f"{spec[len('pretrained:'):].split(',')[0]}.npz")


def _numpy_policy(spec: str, path: Path, n_uavs: int) -> tuple[Any, dict]:
    """The weights at ``path`` run in numpy: a learned actor (through the safety filter if its card says it was
    trained through it), or the planner with a learned cost."""
    try:
        if is_cost_planner_card(path):
            # The planner with a learned cost: it plans for any team size, like the planners.
            pol = load_cost_planner(path)
            return pol, {"n_uavs": n_uavs, **pol.env_settings}
        pol = load_learned(path)
        return as_flown(pol), dict(pol.env_settings)
    except ValueError as exc:
        raise UsageError(f"{spec}: {exc}") from None
