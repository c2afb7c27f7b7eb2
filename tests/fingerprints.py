"""Seeded fingerprints of what the envs and the planners compute, for refactors that must not change a number.

:func:`collect` runs fixed, seeded cases and returns every array they produce: the vector env of each scene family
in unicycle mode, waypoint mode with both masks, and with the target's prediction error; the parallel env (B = 1)
with the target's flown path; and the planner variants' chosen nodes on two scenes. ``tests/test_fingerprints.py``
compares their digests (:func:`digest`) with ``tests/data/fingerprints.json``.

A digest is exact for booleans and integers (masks, flags, chosen nodes: a hash), and for floats a few fixed
random projections compared to 1e-7 of the array's L1 norm: a changed flag or a value moved beyond rounding shows,
while a last-bit difference between CPUs (another SIMD path for sin or arctan2) does not. Bit-for-bit identity
between two commits on one machine is ``--dump`` then ``--compare``.

    python -m tests.fingerprints --write        # record the digests (after a change that is meant to change them)
    python -m tests.fingerprints --dump F.npz   # every array, to compare two commits bit for bit (--compare F.npz)
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np

import covert_env
from covert_env.world.tasks import FAMILIES

REFERENCE = Path(__file__).parent / "data" / "fingerprints.json"
STEPS = 12           # steps per env case (max_cycles 8: every case crosses an automatic reset)
PROJECTIONS = 4


def _env_cases() -> dict[str, dict]:
    cases = {}
    for fam in FAMILIES:
        cases[f"{fam}/unicycle"] = dict(family=fam, n_uavs=3)
        cases[f"{fam}/waypoint-visible"] = dict(family=fam, n_uavs=3, action_mode="waypoint")
        cases[f"{fam}/waypoint-kinematic"] = dict(family=fam, n_uavs=3, action_mode="waypoint", mask_mode="kinematic")
    cases["paper/prediction-error"] = dict(family="paper", n_uavs=3, config={"prediction_error": 2.0})
    cases["paper/waypoint-prediction-error"] = dict(family="paper", n_uavs=3, action_mode="waypoint",
                                                    config={"prediction_error": 2.0})
    cases["downtown/6uav-target-path"] = dict(family="downtown", n_uavs=6, action_mode="waypoint", target_path=4)
    return cases


def _run_vector(kw: dict, num_envs: int = 3) -> dict[str, np.ndarray]:
    venv = covert_env.vector_env(num_envs=num_envs, max_cycles=8, **kw)
    rng = np.random.default_rng(5)
    obs, infos = venv.reset(seed=3)
    out = {"obs": [obs], "state": [venv.state()]}
    for _ in range(STEPS):
        if venv.action_mode == "waypoint":
            mask = venv.action_masks()
            out.setdefault("mask", []).append(mask)
            # A uniformly random allowed node per UAV, vectorised: the first allowed node at or after a random one.
            start = rng.integers(0, mask.shape[-1], mask.shape[:2])
            order = (np.arange(mask.shape[-1]) - start[..., None]) % mask.shape[-1]
            act = np.argmin(np.where(mask > 0, order, mask.shape[-1]), axis=-1)
        else:
            act = rng.uniform(-1.0, 1.0, (venv.num_envs, len(venv.possible_agents), 2)).astype(np.float32)
        obs, rew, term, trunc, infos = venv.step(act)
        out["obs"].append(obs)
        out["state"].append(venv.state())
        out.setdefault("reward", []).append(rew)
        out.setdefault("done", []).append(np.stack([term, trunc]))
        for key, val in infos.items():
            if isinstance(val, np.ndarray) and not key.startswith("_") and val.dtype != object:
                out.setdefault(f"info/{key}", []).append(val)
    venv.close()
    return {k: np.stack(v) for k, v in out.items()}


def _run_planners() -> dict[str, np.ndarray]:
    from baselines.policies import POLICIES, make_policy

    out = {}
    scenes = {"paper-3uav": dict(task="paper-3uav"), "downtown-3uav": dict(task="downtown-3uav"),
              # the planner's line of sight to every possible true target (PossibleTargets)
              "paper-prediction-error": dict(family="paper", n_uavs=3, config={"prediction_error": 2.0})}
    for task, kw in scenes.items():
        for name in POLICIES:
            if not name.startswith("dp"):
                continue
            env = covert_env.parallel_env(**kw, action_mode="waypoint", max_cycles=4)
            pol = make_policy(name)
            obs, _ = env.reset(seed=21, options={"scene_seed": 21})
            pol.reset(env, 21)
            nodes = []
            while env.agents:
                act = pol.act(obs, env)
                nodes.append([int(act[a]) for a in env.possible_agents])
                obs, *_ = env.step(act)
            out[f"plan/{task}/{name}"] = np.array(nodes)
            env.close()
    return out


def collect() -> dict[str, np.ndarray]:
    """Every array of every case, keyed ``case/array``."""
    arrays = {}
    for case, kw in _env_cases().items():
        for key, val in _run_vector(kw).items():
            arrays[f"{case}/{key}"] = val
    arrays.update(_run_planners())
    return arrays


def digest(a: np.ndarray) -> dict:
    """An exact hash (booleans, integers) or projections and the L1 norm (floats), see the module docstring."""
    a = np.asarray(a)
    if a.dtype.kind in "biu":
        return {"sha256": hashlib.sha256(np.ascontiguousarray(a.astype(np.int64)).tobytes()).hexdigest(),
                "shape": list(a.shape)}
    x = np.nan_to_num(a.astype(np.float64).reshape(-1), nan=7.0, posinf=11.0, neginf=-13.0)
    w = np.random.default_rng(0).standard_normal((PROJECTIONS, x.size))
    return {"proj": [float(f"{v:.15g}") for v in w @ x], "l1": float(f"{np.abs(x).sum():.15g}"),
            "shape": list(a.shape)}


def same(d: dict, ref: dict) -> bool:
    """Whether a digest matches the reference (see the module docstring for the float tolerance)."""
    if d["shape"] != ref["shape"]:
        return False
    if "sha256" in ref:
        return d.get("sha256") == ref["sha256"]
    tol = 1e-7 * ref["l1"] + 1e-12
    return bool(np.all(np.abs(np.asarray(d["proj"]) - np.asarray(ref["proj"])) <= tol))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.fingerprints", description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help=f"record the digests in {REFERENCE}")
    parser.add_argument("--dump", type=Path, help="save every array (.npz) to compare commits bit for bit")
    parser.add_argument("--compare", type=Path, help="compare every array with a --dump file, bit for bit")
    args = parser.parse_args(argv)
    arrays = collect()
    if args.write:
        REFERENCE.parent.mkdir(exist_ok=True)
        REFERENCE.write_text(json.dumps({k: digest(v) for k, v in sorted(arrays.items())}) + "\n")
        print(f"wrote {len(arrays)} digests to {REFERENCE}")
    if args.dump:
        np.savez_compressed(args.dump, **arrays)
        print(f"saved {len(arrays)} arrays to {args.dump}")
    if args.compare:
        ref = np.load(args.compare)
        diff = sorted(k for k in set(ref.files) | set(arrays)
                      if k not in arrays or k not in ref.files or not np.array_equal(ref[k], arrays[k], equal_nan=True))
        same_n = len(arrays) - len(diff)
        print(f"{same_n} of {len(arrays)} arrays bit-identical" + (f"; differ: {diff}" if diff else ""))
        return int(bool(diff))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
