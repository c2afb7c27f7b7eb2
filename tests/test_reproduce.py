"""`covert-env reproduce`: the bootstrap CI, --quick's choice of scenes and slots, metrics.md, the GIF writer."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.reproduce import (
    HELDOUT_SEED_BASE,
    QUICK_POOL,
    QUICK_SCENES,
    QUICK_SLOTS,
    bootstrap_ci,
    figure_slot,
    make_scenario,
    most_shadowed_scenes,
    zone_shadow_shares,
)
from baselines.reproduce.report import aggregate, metrics_markdown
from covert_env.world.config import Config


# ---------------------------------------------------------------------- bootstrap
def test_bootstrap_ci_hand_computed_two_scenes():
    """Two scenes [0, 1]: a resample's mean is 0, 0.5 or 1 with probabilities 1/4, 1/2, 1/4. The 2.5 % and
    97.5 % percentiles are therefore 0 and 1; the 30 % and 70 % ones (a 40 % interval) are both 0.5."""
    assert bootstrap_ci([0.0, 1.0]) == (0.0, 1.0)
    assert bootstrap_ci([0.0, 1.0], level=0.4) == (0.5, 0.5)


def test_bootstrap_ci_degenerate_cases():
    assert bootstrap_ci([0.25, 0.25, 0.25]) == (0.25, 0.25)      # no spread: the interval is the value
    assert bootstrap_ci([0.3]) == (0.3, 0.3)                      # one scene: no interval to estimate
    assert all(np.isnan(bootstrap_ci([])))
    with pytest.raises(ValueError, match="level"):
        bootstrap_ci([1.0, 2.0], level=1.0)


def test_bootstrap_ci_is_deterministic_and_brackets_the_mean():
    x = np.random.default_rng(5).exponential(size=20)
    lo, hi = bootstrap_ci(x)
    assert (lo, hi) == bootstrap_ci(x)                            # fixed seed
    assert lo < x.mean() < hi
    assert bootstrap_ci(x, seed=1) != (lo, hi)


def test_bootstrap_ci_paired_rows_resampled_together():
    """Rows stay whole: a ratio of the column means of identical columns is exactly 1 in every resample."""
    x = np.random.default_rng(0).uniform(1, 2, size=12)
    pairs = np.column_stack([x, x])
    assert bootstrap_ci(pairs, lambda b: b[..., 0].mean(axis=1) / b[..., 1].mean(axis=1)) == (1.0, 1.0)


def test_bootstrap_ci_matches_scipy_percentile_bootstrap():
    stats = pytest.importorskip("scipy.stats")
    x = np.random.default_rng(1).beta(0.5, 4.0, size=20)          # skewed, like per-scene occlusion rates
    lo, hi = bootstrap_ci(x)
    ref = stats.bootstrap((x,), np.mean, n_resamples=10_000, method="percentile", confidence_level=0.95,
                          random_state=np.random.default_rng(2)).confidence_interval
    width = ref.high - ref.low
    assert abs(lo - ref.low) < 0.05 * width + 1e-12
    assert abs(hi - ref.high) < 0.05 * width + 1e-12


# ---------------------------------------------------------------------- --quick's scenes and slots
def test_quick_paper_slots_have_shadow_inside_the_zone():
    """--quick flies QUICK_SLOTS slots of the paper scene: some of them have a shadow covering a real part of the
    zone (checked on the geometry: the visible zone is smaller than the feasible zone)."""
    from covert_env.render import zones_at

    sc = make_scenario("paper", 0, 1)
    shares = zone_shadow_shares(sc, range(1, QUICK_SLOTS + 1))
    k = int(np.argmax(shares)) + 1
    zone, shadows, visible = zones_at(sc, k)
    inside = sum(zone.intersection(s).area for s in shadows if not s.is_empty)
    assert shares.max() > 0.08
    assert zone.area - visible.area > 0.08 * zone.area
    assert inside >= zone.area - visible.area - 1e-6            # the lost area is in the shadows


def test_quick_scenes_are_the_most_shadowed_of_the_pool():
    cfg = Config()
    seeds = most_shadowed_scenes(QUICK_SCENES, QUICK_SLOTS, cfg)
    assert len(seeds) == QUICK_SCENES and all(HELDOUT_SEED_BASE <= s < HELDOUT_SEED_BASE + QUICK_POOL for s in seeds)
    mean_share = {s: zone_shadow_shares(make_scenario("random", s, 1, cfg), range(1, QUICK_SLOTS + 1)).mean()
                  for s in range(HELDOUT_SEED_BASE, HELDOUT_SEED_BASE + QUICK_POOL)}
    chosen = min(mean_share[s] for s in seeds)
    assert chosen > 0.03                                         # a few % of the zone on average, not a sliver
    assert all(mean_share[s] <= chosen for s in mean_share if s not in seeds)


def test_figure_slot_prefers_blocked_then_shadowed():
    los = np.ones((6, 2), bool)
    shares = np.array([0.0, 0.3, 0.1, 0.1, 0.0, 0.2])
    assert figure_slot(los, shares) == 2                          # nothing blocked: the most shadowed slot
    los[2, 0] = los[3, 0] = los[3, 1] = False
    assert figure_slot(los, shares) == 4                          # most UAVs blocked
    los[3, 1] = True
    assert figure_slot(los, shares) == 3                          # tie (1 UAV each): shares equal, first slot


# ---------------------------------------------------------------------- metrics.md
def _records(method, scene, u, seeds, blocked):
    out = []
    for s, b in zip(seeds, blocked, strict=True):
        for i in range(u):
            out.append({"run": f"{scene}{s}-{u}-{method}", "scene": scene, "seed": s, "n_uavs": u, "method": method,
                        "uav": i, "slots": 10, "blocked_slots": b, "blocked_unflagged": b, "lost_between_slots": 1,
                        "blocked_path_slots": b + 1, "blocked_path_unflagged": b + 1, "infeasible_slots": 0,
                        "truncated_slots": 0, "zone_violation_rate": 0.0, "mean_disguise": 40.0 + b,
                        "path_length": 500.0, "objective": -4000.0, "min_separation": None,
                        "separation_violations": 0, "terrain_violations": 0, "speed_violations": 0,
                        "team_time_ms_median": 10.0, "team_time_ms_p90": 20.0, "negotiation_rounds": 0,
                        "unresolved_conflicts": 0})
    return out


def test_metrics_md_has_a_confidence_interval_for_every_held_out_rate():
    seeds = [HELDOUT_SEED_BASE + i for i in range(4)]
    records = (_records("aware", "paper", 1, [0], [0]) + _records("blind", "paper", 1, [0], [2])
               + _records("aware", "heldout", 1, seeds, [0, 0, 0, 0])
               + _records("blind", "heldout", 1, seeds, [0, 1, 2, 5]))
    rows = aggregate(records)
    blind = next(r for r in rows if r["scene"] == "heldout" and r["method"] == "blind")
    assert blind["rate_occlusion"] == pytest.approx(0.2)         # (0 + 1 + 2 + 5) / 40 UAV-slots
    assert blind["rate_occlusion_ci"] == bootstrap_ci([0.0, 0.1, 0.2, 0.5])
    text = metrics_markdown(rows, records, Config(), 1.0, False, [], (0.0, 0.0))
    line = next(ln for ln in text.splitlines() if ln.startswith("| heldout | 1 | blind |"))
    lo, hi = blind["rate_occlusion_ci"]
    assert f"0.200 [{lo:.3f}, {hi:.3f}]" in line
    assert line.count("[") == 7                                  # every rate of the table has its interval
    assert "95 % percentile bootstrap" in text
    assert "disguise aware / blind = **" in text and "] (>= 0.8" in text    # the paired ratio's interval


def test_cli_run_writes_metrics_md_with_cis(tmp_path):
    """End to end on a cut-down --quick (2 held-out scenes, 2 slots, no figures): metrics.md has the intervals."""
    from baselines.reproduce import main

    assert main(["--out", str(tmp_path), "--quick", "--slots", "2", "--jobs", "1", "--path-uavs",
                 "--no-figures"]) == 0
    text = (tmp_path / "metrics.md").read_text()
    assert "QUICK" in text and "95 % percentile bootstrap" in text
    held = [ln for ln in text.split("## Counts")[0].splitlines() if ln.startswith("| heldout |")]
    assert len(held) == 4 and all(ln.count("[") == 7 for ln in held)


def test_quick_scenes_show_the_blind_planner_losing_los():
    """On --quick's held-out scenes the 1-UAV shadow-blind planner loses LoS at a slot time; the aware one does
    not (on slots it did not flag infeasible)."""
    from baselines.reproduce import rollout
    from covert_env.world.metrics import slot_quantities

    cfg = Config()
    blocked = {"blind": 0, "aware": 0}
    for seed in most_shadowed_scenes(QUICK_SCENES, QUICK_SLOTS, cfg):
        sc = make_scenario("random", seed, 1, cfg)
        for name in blocked:
            traj = rollout(sc, shadow_aware=name == "aware", n_slots=QUICK_SLOTS)["trajectory"]
            q = slot_quantities(traj, sc.terrain, cfg, path_los=False)
            blocked[name] += int((~q.los & ~traj.infeasible).sum())
    assert blocked["blind"] > 0 and blocked["aware"] == 0


# ---------------------------------------------------------------------- the animation
def test_episode_gif_from_a_tiny_episode(tmp_path):
    from PIL import Image

    from baselines.reproduce import rollout
    from covert_env.render import episode_frames, save_episode_gif

    sc = make_scenario("paper", 0, 2)
    traj = rollout(sc, n_slots=2)["trajectory"]
    frames = episode_frames(sc, traj, frames_per_slot=2, size=(200, 200), dpi=50)
    assert len(frames) == 2 * 2 + 1 and frames[0].shape == (200, 200, 3)
    assert not np.array_equal(frames[0], frames[-1])
    path = tmp_path / "ep.gif"
    save_episode_gif(frames, path, fps=5)
    assert path.read_bytes()[:6] == b"GIF89a"
    with Image.open(path) as im:
        assert im.n_frames == len(frames)
        assert im.info["duration"] == 200 and im.info["loop"] == 0


# ---------------------------------------------------------------------- --sensitivity
def test_sensitivity_table_one_row_per_value():
    from baselines.reproduce import sensitivity

    text = sensitivity(Config(), jobs=1, scenes=2, n_slots=2, values={"r_u": (0.0, 2.0), "h_min": (None, 30.0)})
    rows = [ln for ln in text.splitlines() if ln.startswith("| r_u") or ln.startswith("| h_min")]
    assert [r.split("|")[1:3] for r in rows] == [[" r_u ", " 0 "], [" r_u ", " 2 * "], [" h_min ", " auto * "],
                                                 [" h_min ", " 30 "]]
    assert all(len(r.split("|")) == 12 for r in rows)
    # r_u = 2 and h_min = auto are both the default config: the same runs, the same numbers.
    assert rows[1].split("|")[3:] == rows[2].split("|")[3:]


# ---------------------------------------------------------------------- figures
def test_figures_are_written_from_tiny_runs(tmp_path):
    """Every figure of a 1-UAV paper pair and 2 held-out scenes (3 slots) is drawn and saved as a PNG."""
    from baselines.reproduce import RunSpec
    from baselines.reproduce.figures import write_figures
    from baselines.reproduce.runs import run_job

    cfg = Config()
    specs = [RunSpec("paper", 0, 1, m, 3) for m in ("aware", "blind")]
    specs += [RunSpec("random", HELDOUT_SEED_BASE + i, 1, m, 3) for i in (2, 18) for m in ("aware", "blind")]
    results = {(s.kind, s.seed, s.n_uavs, s.method): run_job((s, cfg.to_dict())) for s in specs}
    names = write_figures(tmp_path, results, cfg, jobs=1)
    assert names == ["fig08_trajectories_1uav.png", "fig09_los_1uav.png", "fig10_zones_1uav.png",
                     "fig11_disguise_1uav.png", "fig_heldout.png", "fig_los_between_slots.png"]
    for n in names:
        assert (tmp_path / n).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
