"""Learned MAPPO/IPPO teams without torch: the actor's forward pass in numpy, its weights in ``.npz``, a loader.

:mod:`training.mappo` trains the actor in torch; this module is what runs it everywhere else (the harness's
``mappo:PATH`` and ``pretrained:NAME`` policy specs), so that evaluating a learned team needs neither torch nor
pickle. The same :func:`node_features` feed the actor in training and here: one definition of its inputs.

Files (no pickle anywhere: ``np.load(..., allow_pickle=False)`` and JSON):

* ``NAME.npz``: the actor's parameters, named as in the torch module (``trunk.0.weight``, ``node_obs.weight``, ...);
* ``NAME.json``: the model card: ``actor`` (the architecture fields below), ``env_kwargs`` (``n_uavs``,
  ``action_mode``, ...), and for the shipped weights the algorithm, recipe, commit and scores.

The actor (parameter-shared: one network for every UAV, eq. numbers of docs/paper_to_code.md):

* trunk: the agent's observation (the parallel env's table), with ``agent_id`` followed by the one-hot of the
  agent's index, through ``Linear + tanh`` layers;
* waypoint mode, ``head = "node"``: each lattice node l is scored from the trunk's output and the node's geometry
  relative to the UAV and its teammates (:func:`node_features`): ``logit_l = w . relu(A h + F f_l + b) + c``;
  masked nodes get -inf (a masked categorical). ``head = "flat"``: one logit per node from ``Linear(h)``;
* unicycle mode: a Gaussian whose mean is ``Linear(h)``; the env clips actions to [-1, 1] (no tanh squashing).

Deterministic acting (the harness) takes the most likely node, or the clipped mean.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from baselines.policies import parallel_env_of
from covert_env.envs.observation import field_slices
from covert_env.evaluation.cards import check_env_kwargs, weights_and_card
from covert_env.geometry.angles import wrap_angle
from covert_env.geometry.dynamics import solve_manoeuvre
from covert_env.geometry.ties import first_argmax
from training.runs import run_env
from training.shield import SeparationShield

__all__ = ["node_features", "map_at", "manoeuvre_features", "n_node_features", "NumpyActor", "LearnedPolicy",
           "load_learned", "as_flown", "check_weights", "PRETRAINED_DIR", "pretrained_names", "N_OWN_FEATURES",
           "N_MAP_FEATURES", "N_MANOEUVRE_FEATURES", "MASKED_LOGIT"]

#: The logit of a node outside the action mask (training.mappo's masked categorical): finite, so a log-probability
#: stays a number, and far below any node's score.
MASKED_LOGIT = -1e8

PRETRAINED_DIR = Path(__file__).resolve().parent
#: The largest weights file :func:`load_learned` unpacks (bytes of arrays): the shipped actor holds well under 1 MB.
MAX_WEIGHTS_BYTES = 256 * 2**20
#: Features per (agent, node) besides the U - 1 teammate distances (see :func:`node_features`).
N_OWN_FEATURES = 9
#: The map features :func:`node_features` adds with ``map_offsets`` (the actor's ``node_map``).
N_MAP_FEATURES = 2
#: The manoeuvre features :func:`node_features` adds with ``w_max`` (the actor's ``node_manoeuvre``).
N_MANOEUVRE_FEATURES = 6


def n_node_features(n_uavs: int, spec: dict) -> int:
    """How many features per node the node head of an actor ``spec`` (its ``node_map``, ``node_manoeuvre``) reads
    with ``n_uavs`` UAVs: the width of ``node_feat.weight``."""
    return (N_OWN_FEATURES + n_uavs - 1 + (N_MAP_FEATURES if spec.get("node_map") else 0)
            + (N_MANOEUVRE_FEATURES if spec.get("node_manoeuvre") else 0))


def node_features(obs: np.ndarray, lattice: np.ndarray, n_uavs: int, *, r2: float, v_max: float, delta: float,
                  d_safe1: float, map_offsets: np.ndarray | None = None, w_max: float | None = None) -> np.ndarray:
    """Per-node inputs of the actor's waypoint head, ``(..., L, 9 + U - 1)`` float32 from observations ``(..., D)``
    (2 more with ``map_offsets``, then 6 more with ``w_max``: :func:`n_node_features`).

    Everything is read from the agent's own observation (no extra information): its offset from the target
    (field ``offset``, in units of R2), the target's displacement to the next slot (``target_displacement``, in units
    of V_max delta) and the teammates' offsets (``teammates``), read by name from the observation layout. The
    lattice lives in the target's frame at slot k+1; the UAV and its teammates are moved into that frame by
    subtracting the displacement (the target's turn within one slot is neglected).
    For node l at ``p_l`` (units of R2) and the UAV at ``o``:

    * ``p_l`` (2) and ``p_l - o`` (2);
    * ``|p_l - o| R2 / (V_max delta)``: the fraction of a slot's maximal path (energy, eq. 15);
    * the bearing and range changes the move makes, ``wrap(alpha_l - alpha_o) / pi`` and ``|p_l| - |o|``, and their
      absolute values: the disguise kappa of eq. 11 is ``eta |d alpha| + |d d|``;
    * per teammate j, ``min(|p_l - o_j| R2 / (2 d_safe1), 3)``: how close the node is to where j is now (eq. 2);
    * with ``map_offsets`` (the env's map cell centres, ``(S * S, 2)`` m, row-major with +y on top): the observation's
      ``map_next`` (1 where the cell is in the eroded zone with clear LoS at slot k+1) read at the node and at the
      midpoint of the move (with ``o`` moved as above: off by the target's turn in the slot, up to about 6 m on
      the winding family), each at the nearest cell (0 outside the map). The shadows are in the observation's
      maps; these two inputs put them under the node the head scores, so that a team whose mask allows shadowed
      nodes (``mask_mode="kinematic"``) can learn to avoid them (docs/decisions/learning.md, "Learned teams across the
      suite");
    * with ``w_max`` (the turn-rate limit W_max, rad/s): the manoeuvre that flies the UAV there
      (:func:`manoeuvre_features`): whether one exists, its length and the heading the UAV arrives with. The
      heading at a node sets which nodes the next slot reaches, so these inputs tell two nodes apart by what they
      leave open (docs/decisions/learning.md, "The arrival heading in the node head").
    """
    obs = np.asarray(obs, np.float32)
    # The fields read here come before the maps, so the maps' size (0 here) does not move them.
    field = field_slices(n_uavs, map_size=0)
    own = obs[..., field["offset"]]
    disp = obs[..., field["target_displacement"]] * (v_max * delta / r2)
    o = own - disp
    mates = obs[..., field["teammates"]].reshape(*obs.shape[:-1], n_uavs - 1, 2) - disp[..., None, :]
    p = (np.asarray(lattice, np.float32) / r2)                          # (L, 2)
    shape = (*obs.shape[:-1], len(p))
    n_map, n_man = (2 if map_offsets is not None else 0), (6 if w_max is not None else 0)
    # Each feature is written into its float32 column as computed (the float64 -> float32 rounding of a cast),
    # and the squares of 2-vectors are summed as x^2 + y^2 (what a sum over their length-2 axis computes).
    out = np.empty((*shape, 9 + n_uavs - 1 + n_map + n_man), np.float32)
    out[..., 0:2] = p
    rel = out[..., 2:4]
    np.subtract(p, o[..., None, :], out=rel)                           # (..., L, 2)
    out[..., 4] = np.sqrt(rel[..., 0] ** 2 + rel[..., 1] ** 2) * (r2 / (v_max * delta))
    d_alpha = wrap_angle(np.arctan2(p[:, 1], p[:, 0]) - np.arctan2(o[..., 1], o[..., 0])[..., None]) / np.pi
    out[..., 5] = d_alpha
    out[..., 6] = np.abs(d_alpha)
    d_range = np.hypot(p[:, 0], p[:, 1]) - np.hypot(o[..., 0], o[..., 1])[..., None]
    out[..., 7] = d_range
    out[..., 8] = np.abs(d_range)
    col = 9
    for j in range(n_uavs - 1):
        gx = p[:, 0] - mates[..., j, None, 0]                           # (..., L)
        gy = p[:, 1] - mates[..., j, None, 1]
        out[..., col] = np.minimum(np.sqrt(gx ** 2 + gy ** 2) * (r2 / (2 * d_safe1)), 3.0)
        col += 1
    if map_offsets is not None:
        cells = np.asarray(map_offsets, np.float64) / r2                  # (S * S, 2), units of R2
        size = int(round(np.sqrt(len(cells))))
        grid = obs[..., field_slices(n_uavs, size)["map_next"]]           # (..., S * S)
        out[..., col] = map_at(grid, cells, p)
        out[..., col + 1] = map_at(grid, cells, 0.5 * (p + o[..., None, :]))
        col += 2
    if w_max is not None:
        # The target turns by about twice its displacement's bearing in its own frame (a chord of an arc of
        # constant curvature); the manoeuvre needs it, since a node 100 m away moves 28 m under a 0.28 rad turn.
        turn = 2.0 * np.arctan2(disp[..., 1], disp[..., 0])
        c, s = np.cos(turn)[..., None], np.sin(turn)[..., None]
        start = np.concatenate([c * o[..., :1] + s * o[..., 1:], -s * o[..., :1] + c * o[..., 1:]], axis=-1)
        heading = obs[..., field["heading"]]
        out[..., col:] = manoeuvre_features(start * r2, np.arctan2(heading[..., 1], heading[..., 0]) - turn, p * r2,
                                            v_max=v_max, w_max=w_max, delta=delta)
    return out


def manoeuvre_features(start: np.ndarray, theta: np.ndarray, nodes: np.ndarray, *, v_max: float, w_max: float,
                       delta: float) -> np.ndarray:
    """The turn-then-straight manoeuvre (eqs. 22-29) from each start pose to each node, as node-head inputs:
    ``(..., L, 6)`` float32 from starts ``(..., 2)`` m, headings ``(...)`` rad and nodes ``(L, 2)`` m, all in the
    target's frame (the actor's frame: the heading is the observation's, relative to the target's).

    Per node: 1 if a manoeuvre reaches it in one slot, else 0; its length as a fraction of ``v_max * delta``
    (eq. 15); the cos and sin of the heading it arrives with; the cos and sin of that heading relative to the
    node's bearing from the target (1, 0: flying straight away from the target). Where no manoeuvre reaches the
    node, the straight line's length and heading stand in (the env then flies its best effort, or masks it).
    Only nodes within ``v_max * delta`` of the start are solved: no manoeuvre reaches farther."""
    start, theta, nodes = np.asarray(start, np.float64), np.asarray(theta, np.float64), np.asarray(nodes, np.float64)
    rel = nodes - start[..., None, :]                                                 # (..., L, 2)
    length = np.hypot(rel[..., 0], rel[..., 1])
    head = np.arctan2(rel[..., 1], rel[..., 0])
    ok = np.zeros(length.shape, bool)
    near = np.nonzero(length <= v_max * delta)
    if len(near[0]):
        th = np.broadcast_to(theta[..., None], length.shape)[near]
        m = solve_manoeuvre(start[near[:-1]], th, nodes[near[-1]], v_max=v_max, w_max=w_max, delta=delta)
        ok[near] = m.feasible
        length[near] = np.where(m.feasible, m.length, length[near])
        head[near] = np.where(m.feasible, m.heading_after, head[near])
    rel_head = head - np.arctan2(nodes[:, 1], nodes[:, 0])
    return np.stack([ok, length / (v_max * delta), np.cos(head), np.sin(head), np.cos(rel_head), np.sin(rel_head)],
                    axis=-1).astype(np.float32)


def map_at(grid: np.ndarray, cells: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Values of S x S maps ``grid`` ``(..., S * S)`` (row-major, +y on top, cell centres ``cells`` ``(S * S, 2)``)
    at the nearest cell of each of ``points`` ``(..., L, 2)`` (the same units as ``cells``), 0 outside the map:
    ``(..., L)``."""
    size = int(round(np.sqrt(len(cells))))
    x0, y_top = cells[0]
    dx, dy = cells[1, 0] - cells[0, 0], cells[0, 1] - cells[size, 1]  # cell sides (> 0)
    col = np.floor((points[..., 0] - x0) / dx + 0.5).astype(np.int64)
    row = np.floor((y_top - points[..., 1]) / dy + 0.5).astype(np.int64)
    inside = (col >= 0) & (col < size) & (row >= 0) & (row < size)
    idx = np.where(inside, row * size + col, 0)
    idx = np.broadcast_to(idx, (*grid.shape[:-1], idx.shape[-1]))
    return np.where(inside, np.take_along_axis(grid, idx, axis=-1), 0.0)


class NumpyActor:
    """The actor of :mod:`training.mappo` in numpy (same parameter names, same outputs as the torch module)."""

    def __init__(self, params: dict[str, np.ndarray], spec: dict):
        self.p = {k: np.asarray(v, np.float64) for k, v in params.items()}
        self.spec = dict(spec)
        self.head = spec["head"]
        self.trunk = sorted({int(k.split(".")[1]) for k in self.p if k.startswith("trunk.")})
        for need in {"node": ("node_obs.weight", "node_feat.weight", "node_out.weight"), "flat": ("flat.weight",),
                     "gaussian": ("mean.weight",)}[self.head]:
            if need not in self.p:
                raise ValueError(f"actor weights lack {need!r} for head {self.head!r}")

    def _trunk(self, obs: np.ndarray) -> np.ndarray:
        h = np.asarray(obs, np.float64)
        for i in self.trunk:
            h = np.tanh(h @ self.p[f"trunk.{i}.weight"].T + self.p[f"trunk.{i}.bias"])
        return h

    def logits(self, obs: np.ndarray, feats: np.ndarray | None = None) -> np.ndarray:
        """Unmasked node logits ``(N, L)`` (waypoint heads) for observations ``(N, D)``."""
        h = self._trunk(obs)
        if self.head == "flat":
            return h @ self.p["flat.weight"].T + self.p["flat.bias"]
        a = h @ self.p["node_obs.weight"].T + self.p["node_obs.bias"]             # (N, H)
        z = np.maximum(a[:, None, :] + feats @ self.p["node_feat.weight"].T, 0.0)  # (N, L, H)
        return z @ self.p["node_out.weight"][0] + self.p["node_out.bias"][0]

    def mean(self, obs: np.ndarray) -> np.ndarray:
        """Gaussian mean ``(N, 2)`` (unicycle head), before the env's clipping."""
        return self._trunk(obs) @ self.p["mean.weight"].T + self.p["mean.bias"]


class LearnedPolicy:
    """A learned team behind the harness's policy interface (``reset(env, seed)``, ``act(observations, env)``):
    the agents still flying act at once (one batch), deterministically."""

    def __init__(self, actor: NumpyActor, card: dict, name: str):
        self.actor, self.card, self.name = actor, card, name
        ekw = card["env_kwargs"]
        #: The separation shield's distance (m) if the team was trained with it (:mod:`training.shield`).
        self.shield_distance = card.get("separation_shield")
        #: The shield the team acts through (None without one); its ``fallbacks`` count the slots where some UAV
        #: was left with no separated node.
        self.shield = (None if self.shield_distance is None else
                       SeparationShield(float(self.shield_distance), float(card.get("shield_end_margin") or 0.0),
                                        lookahead=bool(card.get("shield_lookahead", False)),
                                        min_reach=int(card.get("viability_min_reach") or 1)))
        #: The viability rule of the shield (a UAV avoids nodes from which it could reach no node next slot).
        self.viability = bool(card.get("viability_shield", False)) and self.shield is not None
        self.env_settings = {"n_uavs": int(ekw["n_uavs"]), "action_mode": ekw["action_mode"],
                             "map_size": int(ekw.get("map_size", 8))}
        if ekw.get("target_path", 0):
            # A team that reads the target's predicted path (the env's target_path), checked by run_env.
            self.env_settings["target_path"] = int(ekw["target_path"])
        if ekw["action_mode"] == "waypoint":
            # The mask the team was trained with (cards before mask modes: the visible-zone mask).
            self.env_settings["mask_mode"] = ekw.get("mask_mode", "visible")

    def reset(self, env, seed: int | None = None) -> None:
        pass

    def act(self, observations, env):
        par, single = parallel_env_of(env)
        agents = [a for a in par.possible_agents if a in par.agents]
        obs_d = observations if single is None else {single: observations}
        obs = np.stack([np.asarray(obs_d[a], np.float32) for a in agents])
        x = obs
        if self.actor.spec.get("agent_id"):
            u = len(par.possible_agents)
            x = np.concatenate([obs, np.eye(u)[[par.possible_agents.index(a) for a in agents]]], axis=1)
        if self.actor.head == "gaussian":
            act = np.clip(self.actor.mean(x), -1.0, 1.0).astype(np.float32)
            out = {a: act[i] for i, a in enumerate(agents)}
        else:
            c = par.config
            feats = node_features(obs, par.lattice, len(par.possible_agents), r2=c.r2, v_max=c.v_max, delta=c.delta,
                                  d_safe1=c.d_safe1,
                                  map_offsets=par.map_offsets if self.actor.spec.get("node_map") else None,
                                  w_max=c.w_max if self.actor.spec.get("node_manoeuvre") else None
                                  ) if self.actor.head == "node" else None
            logits = self.actor.logits(x, feats)
            mask = np.stack([par.action_mask(a) for a in agents]).astype(bool)
            #: The node logits of the last ``act`` (U, L): a safety filter around the team orders its
            #: alternatives by them (:class:`covert_env.envs.safety_filter.ShieldedPolicy`). A team trained with
            #: the filter ordering by its logits (the card's ``filter_scores``) saw the masked nodes' at
            #: MASKED_LOGIT (training.mappo scores the allowed nodes only): so here, so that it flies as it trained.
            self.last_logits = np.where(mask, logits, MASKED_LOGIT) if self.card.get("filter_scores") else logits
            if self.shield is not None:
                act, _ = self.shield.choose(mask[None], lambda n: par.waypoint_paths(n[0])[None],
                                            lambda k, m: first_argmax(np.where(m, logits[k], -np.inf), axis=-1),
                                            (lambda xy, th: par.onward_reach(xy[0], th[0])[None]) if self.viability
                                            else None)
                out = {a: int(act[0, i]) for i, a in enumerate(agents)}
            else:
                out = {a: first_argmax(np.where(mask[i], logits[i], -np.inf)) for i, a in enumerate(agents)}
        return out[single] if single is not None else out


#: The fields of a MAPPO card's ``env_kwargs`` (what :mod:`training.mappo` writes) and of its ``actor``.
MAPPO_ENV_KWARGS = ("n_uavs", "action_mode", "max_cycles", "scene_pool", "map_size", "mask_mode", "target_path")
ACTOR_FIELDS = ("head", "hidden", "node_hidden", "n_feat", "obs_dim", "n_actions", "agent_id", "node_map",
                "node_manoeuvre")


def pretrained_path(name) -> Path:
    """The weights of ``pretrained:NAME``; a ``ValueError`` unless NAME is one of :func:`pretrained_names` (so no
    path, ``../`` or other, leaves this folder)."""
    names = pretrained_names()
    if name not in names:
        raise ValueError(f"no pretrained weights {name!r} (shipped: {', '.join(names) or 'none'})")
    return PRETRAINED_DIR / f"{name}.npz"


def pretrained_names() -> list[str]:
    """Names of the weights shipped in this folder (``NAME.npz`` with its card ``NAME.json``)."""
    return sorted(p.stem for p in PRETRAINED_DIR.glob("*.npz") if p.with_suffix(".json").is_file())


def as_flown(pol: LearnedPolicy):
    """The policy as its card says it flies: a team trained through the safety filter flies through it
    (:class:`~covert_env.envs.safety_filter.ShieldedPolicy`), its alternatives ordered as in training (by its
    logits where the card says ``filter_scores``, else by the distance to the proposal, as
    :class:`~covert_env.envs.safety_filter.SafetyFilteredVectorEnv` orders them by default) and with the card's
    viability rule (``viability_min_reach``, 1 if null); a team that also has a separation shield proposes through
    it, as in training; any other team as it is. The one rule of ``covert-env evaluate`` and of the cards'
    scores."""
    if not pol.card.get("safety_filter"):
        return pol
    from covert_env.envs.safety_filter import ShieldedPolicy

    min_reach = (pol.card.get("viability_min_reach") or 1) if pol.card.get("viability_shield") else 0
    return ShieldedPolicy(pol, use_scores=bool(pol.card.get("filter_scores")), min_reach=min_reach)


def load_learned(path: str | Path) -> LearnedPolicy:
    """A :class:`LearnedPolicy` from weights (``.npz``) and their card (the ``.json`` beside), or a run folder of
    :mod:`training.mappo` (its ``model.npz``/``model.json``). Raises ``ValueError`` naming the file and the field on
    a missing or malformed file: the card's fields, the env its ``env_kwargs`` build, and every weight's shape
    against that env's observation and action sizes (:func:`check_weights`), so that a wrong file fails here and
    not inside an episode."""
    path = Path(path)
    npz, card_path, card = weights_and_card(path, "learned actor", "training.mappo")
    try:
        spec, ekw = card["actor"], card["env_kwargs"]
        if not isinstance(spec, dict) or spec.get("head") not in ("node", "flat", "gaussian") \
                or not isinstance(ekw, dict) or ekw.get("action_mode") not in ("unicycle", "waypoint"):
            raise KeyError("actor.head / env_kwargs.action_mode")
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{card_path}: not a model card of training.mappo ({exc})") from None
    check_env_kwargs(ekw, MAPPO_ENV_KWARGS, card_path)
    unknown = sorted(set(spec) - set(ACTOR_FIELDS))
    if unknown:
        raise ValueError(f"{card_path}: actor has unknown fields {unknown}; an actor's fields are {list(ACTOR_FIELDS)}")
    for key in ("hidden", "node_hidden", "n_feat", "obs_dim", "n_actions"):
        v = spec.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 1_000_000):
            raise ValueError(f"{card_path}: actor.{key} must be an integer in [1, 1000000], got {v!r}")
    for key in ("node_map", "node_manoeuvre", "agent_id"):
        if not isinstance(spec.get(key, False), bool):
            raise ValueError(f"{card_path}: actor.{key} must be true or false, got {spec[key]!r}")
    if not isinstance(card.get("viability_shield", False), bool):
        raise ValueError(f"{card_path}: viability_shield must be true or false, got {card['viability_shield']!r}")
    if not isinstance(card.get("safety_filter", False), bool):
        raise ValueError(f"{card_path}: safety_filter must be true or false, got {card['safety_filter']!r}")
    if not isinstance(card.get("filter_scores", False), bool):
        raise ValueError(f"{card_path}: filter_scores must be true or false, got {card['filter_scores']!r}")
    if card.get("filter_scores") and not card.get("safety_filter"):
        raise ValueError(f"{card_path}: filter_scores orders the safety filter's alternatives, but safety_filter is "
                         "false")
    if not isinstance(card.get("shield_lookahead", False), bool):
        raise ValueError(f"{card_path}: shield_lookahead must be true or false, got {card['shield_lookahead']!r}")
    reach = card.get("viability_min_reach")
    if reach is not None and (isinstance(reach, bool) or not isinstance(reach, int) or not 1 <= reach <= 100_000):
        raise ValueError(f"{card_path}: viability_min_reach must be null or an integer in [1, 100000], got {reach!r}")
    if reach is not None and not card.get("viability_shield"):
        raise ValueError(f"{card_path}: viability_min_reach is a bar of the viability rule, but viability_shield "
                         "is false")
    if card.get("shield_lookahead") and card.get("separation_shield") is None:
        raise ValueError(f"{card_path}: shield_lookahead is a rule of the separation shield, but separation_shield "
                         "is null")
    if card.get("viability_shield") and card.get("separation_shield") is None and not card.get("safety_filter"):
        raise ValueError(f"{card_path}: viability_shield is a rule of the separation shield or the safety filter, "
                         "but separation_shield is null and safety_filter false")
    for key, lo in (("separation_shield", 0.0), ("shield_end_margin", 0.0)):
        v = card.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v)
                              or v < lo or (key == "separation_shield" and v == 0)):
            allowed = "a number > 0" if key == "separation_shield" else "a number >= 0"
            raise ValueError(f"{card_path}: {key} must be null or {allowed}, got {v!r}")
    _, env = run_env(ekw, str(card_path))
    try:
        with zipfile.ZipFile(npz) as z:                         # sizes from the zip's directory, nothing unpacked
            unpacked = sum(info.file_size for info in z.infolist())
    except (OSError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{npz}: not a weights file ({exc})") from None
    if unpacked > MAX_WEIGHTS_BYTES:
        raise ValueError(f"{npz}: {unpacked} bytes of arrays, more than the {MAX_WEIGHTS_BYTES} a weights file may "
                         "hold")
    try:
        with np.load(npz, allow_pickle=False) as data:
            params = {k.removeprefix("actor."): data[k] for k in data.files if k.startswith("actor.")}
    except (OSError, ValueError, EOFError) as exc:
        raise ValueError(f"{npz}: not a weights file ({exc})") from None
    agent = env.possible_agents[0]
    obs_dim = env.observation_space(agent).shape[0]
    if spec.get("obs_dim") is not None and spec["obs_dim"] != obs_dim:
        env.close()
        raise ValueError(f"{card_path}: actor.obs_dim is {spec['obs_dim']}, but env_kwargs {ekw} give observations of "
                         f"{obs_dim} values (n_uavs, map_size and target_path set their size); the card contradicts "
                         "itself")
    check_weights(params, spec, obs_dim=env.observation_space(agent).shape[0], n_uavs=len(env.possible_agents),
                  n_actions=int(getattr(env.action_space(agent), "n", 2)), where=str(npz))
    env.close()
    actor = NumpyActor(params, spec)
    label = card.get("algorithm", "mappo")
    return LearnedPolicy(actor, card, name=f"{label} ({path.stem if not path.is_dir() else path.name})")


def check_weights(params: dict[str, np.ndarray], spec: dict, *, obs_dim: int, n_uavs: int, n_actions: int,
                  where: str) -> None:
    """``ValueError`` naming ``where`` and the parameter unless ``params`` form the actor of ``spec`` (its ``head``
    and ``agent_id``) for an env with observations of ``obs_dim``, ``n_uavs`` UAVs and ``n_actions`` lattice nodes
    (waypoint mode; 2 in unicycle mode): real finite arrays, each layer's input the previous layer's output."""
    for k, v in params.items():
        if v.dtype.kind not in "fiu":
            raise ValueError(f"{where}: actor.{k} must hold numbers, got dtype {v.dtype}")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{where}: actor.{k} holds non-finite values")

    def need(key: str, shape: tuple, why: str) -> np.ndarray:
        if key not in params:
            raise ValueError(f"{where}: actor.{key} is missing ({spec['head']} head)")
        got = params[key].shape
        if len(got) != len(shape) or any(e is not None and g != e for g, e in zip(got, shape, strict=False)):
            text = "(" + ", ".join("*" if e is None else str(e) for e in shape) + ("," if len(shape) == 1 else "") + ")"
            raise ValueError(f"{where}: actor.{key} has shape {got}, expected {text} ({why})")
        return params[key]

    width = obs_dim + (n_uavs if spec.get("agent_id") else 0)
    why = f"observations of {obs_dim} values" + (f" + {n_uavs} agent-id inputs" if spec.get("agent_id") else "")
    for i in sorted({int(k.split(".")[1]) for k in params if k.startswith("trunk.") and k.split(".")[1].isdigit()}):
        w = need(f"trunk.{i}.weight", (None, width), why)
        need(f"trunk.{i}.bias", (w.shape[0],), f"trunk.{i}.weight has {w.shape[0]} outputs")
        width, why = w.shape[0], f"trunk.{i} has {w.shape[0]} outputs"
        if spec.get("hidden") is not None and width != spec["hidden"]:
            raise ValueError(f"{where}: actor.trunk.{i}.weight has {width} outputs, but the card's actor.hidden is "
                             f"{spec['hidden']!r}; the card does not describe these weights")
    if spec["head"] == "node":
        n_feat = n_node_features(n_uavs, spec)
        h = need("node_obs.weight", (None, width), why).shape[0]
        if spec.get("node_hidden") is not None and h != spec["node_hidden"]:
            raise ValueError(f"{where}: actor.node_obs.weight has {h} outputs, but the card's actor.node_hidden is "
                             f"{spec['node_hidden']!r}; the card does not describe these weights")
        need("node_obs.bias", (h,), f"node_obs.weight has {h} outputs")
        extra = [w for w, key in (("the map's", "node_map"), ("the manoeuvre's", "node_manoeuvre")) if spec.get(key)]
        need("node_feat.weight", (h, n_feat), f"{n_feat} node features for {n_uavs} UAVs"
             + (" with " + " and ".join(extra) if extra else "") + f", node_obs has {h} outputs")
        need("node_out.weight", (1, h), f"node_obs has {h} outputs")
        need("node_out.bias", (1,), "one logit per node")
    else:
        key, n = ("flat", n_actions) if spec["head"] == "flat" else ("mean", 2)
        what = f"{n} lattice nodes" if key == "flat" else "2 action components (v, omega)"
        need(f"{key}.weight", (n, width), f"{what}; {why}")
        need(f"{key}.bias", (n,), what)
