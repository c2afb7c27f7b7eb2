"""One-off conversion of VecNormalize statistics pickled by older covert_env versions to the JSON the scripts write.

    python -m training.sb3.convert_vecnormalize --trust-checkpoint runs/<run>   # every .pkl of the run, its checkpoints
    python -m training.sb3.convert_vecnormalize --trust-checkpoint runs/<run>/vecnormalize.pkl

Unpickling a file can run any code it contains: the files are unpickled only with ``--trust-checkpoint``
(``trust_checkpoint=True`` in :func:`convert`), for files you made yourself or otherwise trust.
Nothing else in covert_env loads a ``.pkl`` (training resumes and ``evaluate --policies sb3:...`` read the
``.json`` written here, :func:`training.sb3.vec_env.read_vecnormalize`). Each ``X.pkl`` gives ``X.json`` beside it;
the ``.pkl`` is left in place.
"""

from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

from training.trust import require_trust


def convert(pkl: Path, *, trust_checkpoint: bool = False) -> Path:
    """Unpickle the trusted VecNormalize file ``pkl`` and write its statistics to ``pkl.with_suffix('.json')``.
    Refused (:func:`training.trust.require_trust`) unless ``trust_checkpoint=True``."""
    from training.sb3.vec_env import save_vecnormalize  # needs SB3 (the [train] extra)

    require_trust(pkl, "a pickled VecNormalize file", trust_checkpoint)
    with open(pkl, "rb") as f:
        vn = pickle.load(f)  # noqa: S301 -- explicit, documented one-off on a file the user trusts
    if not all(hasattr(vn, a) for a in ("norm_obs", "ret_rms", "clip_obs", "epsilon")):
        raise ValueError(f"{pkl}: not a pickled VecNormalize ({type(vn).__name__})")
    return save_vecnormalize(vn, pkl.with_suffix(".json"))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m training.sb3.convert_vecnormalize", description=__doc__.split("\n")[0])
    p.add_argument("paths", nargs="+", help="a pickled VecNormalize file (.pkl) or a run folder (all its .pkl)")
    p.add_argument("--trust-checkpoint", action="store_true",
                   help="unpickle the files (required): unpickling runs any code a file carries, so pass this only "
                        "for files you made yourself or otherwise trust")
    args = p.parse_args(argv)
    files: list[Path] = []
    for s in args.paths:
        path = Path(s)
        if path.is_dir():
            found = sorted(path.glob("vecnormalize.pkl")) + sorted(path.glob("checkpoints/*_vecnormalize_*.pkl"))
            if not found:
                p.error(f"{s}: no vecnormalize .pkl files in this folder")
            files += found
        elif path.suffix == ".pkl" and path.is_file():
            files.append(path)
        else:
            p.error(f"{s}: expected a .pkl file or a run folder")
    if not args.trust_checkpoint:
        p.error(f"{files[0]} is a pickled VecNormalize file: unpickling runs any code it carries. Pass "
                "--trust-checkpoint only if you made it yourself or otherwise trust it")
    for pkl in files:
        try:
            out = convert(pkl, trust_checkpoint=True)
        except ValueError as exc:
            p.error(str(exc))
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
