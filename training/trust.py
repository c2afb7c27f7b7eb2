"""Pickled checkpoints load only when the user says so: ``--trust-checkpoint`` / ``trust_checkpoint=True``.

SB3 model files (``model.zip``, ``{algo}_{steps}_steps.zip``) keep the spaces, schedules and policy class as
cloudpickle in their ``data`` entry, and RLlib checkpoints are pickled too: loading one runs whatever code it
carries. So every loader of such a file (``evaluate --policies sb3:/rllib:``, the training scripts' ``--resume``,
:mod:`training.sb3.convert_vecnormalize`) refuses unless asked, as ``torch.load`` now loads weights only by default.
What the project writes itself needs no opt-in: JSON (configs, args, VecNormalize statistics, model cards) and
``.npz`` weights read with ``allow_pickle=False`` (``mappo:PATH``, ``pretrained:NAME``, MAPPO's ``--resume``).

Kept free of heavy imports, so that a refusal comes before torch, SB3 or Ray load.
"""

from __future__ import annotations

from pathlib import Path

from covert_env.command_line import UsageError

__all__ = ["TRUST_FLAG", "require_trust"]

TRUST_FLAG = "--trust-checkpoint"


def require_trust(path: str | Path, what: str, trust_checkpoint: bool) -> None:
    """Return if ``trust_checkpoint`` is True; else a :class:`~covert_env.command_line.UsageError` saying that
    ``path`` (``what``: "an SB3 model", "an RLlib checkpoint" ...) is pickled and naming the opt-in. A non-bool
    ``trust_checkpoint`` is a TypeError (a string such as ``"no"`` must not count as yes)."""
    if not isinstance(trust_checkpoint, bool):
        raise TypeError(f"trust_checkpoint must be True or False, got {trust_checkpoint!r}")
    if trust_checkpoint:
        return

    raise UsageError(f"{path} is {what}, which holds pickled Python objects: loading it runs any code they carry. "
                     f"Pass {TRUST_FLAG} (trust_checkpoint=True in Python) only if it comes from a source you trust")
