"""What the envs and the planners compute stays the same: seeded digests of every env kind's arrays (six families,
unicycle and waypoint mode, both masks, the prediction error, the target's flown path, 6 UAVs) and the planner
variants' chosen nodes, against ``tests/data/fingerprints.json`` (see ``tests/fingerprints.py``)."""

from __future__ import annotations

import json

import pytest
from fingerprints import REFERENCE, collect, digest, same


@pytest.fixture(scope="module")
def arrays():
    return collect()


def test_every_case_is_recorded(arrays):
    assert sorted(arrays) == sorted(json.loads(REFERENCE.read_text()))


def test_fingerprints_unchanged(arrays):
    ref = json.loads(REFERENCE.read_text())
    changed = [k for k in sorted(arrays) if k in ref and not same(digest(arrays[k]), ref[k])]
    assert not changed, f"{len(changed)} of {len(ref)} arrays changed, e.g. {changed[:8]}"


def test_digest_sees_a_small_change(arrays):
    """The float tolerance is far below a real change: one observation moved by 1e-3 is caught."""
    key = "paper/unicycle/obs"
    a = arrays[key].copy()
    ref = digest(a)
    a.reshape(-1)[a.size // 2] += 1e-3
    assert not same(digest(a), ref)
    mask = arrays["paper/waypoint-visible/mask"].copy()
    ref = digest(mask)
    mask.reshape(-1)[0] ^= 1
    assert not same(digest(mask), ref)
