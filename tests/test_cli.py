"""The ``covert-env`` command line: ``covert-env scene`` writes a picture of one slot."""

from __future__ import annotations

import os
import subprocess
import sys

import matplotlib

matplotlib.use("Agg")

import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from covert_env.cli import build_parser, main  # noqa: E402
from covert_env.config import Config  # noqa: E402

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def check_png(path, dpi):
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > 20_000
    img = mpimg.imread(path)
    # scene_figure is 15 x 6.5 inches.
    assert img.shape[:2] == (round(6.5 * dpi), round(15 * dpi))
    assert img.shape[2] in (3, 4)
    # Not a blank canvas: many distinct colours (terrain, zone, shadows, road, legend).
    flat = img[..., :3].reshape(-1, 3)
    assert flat.std(axis=0).max() > 0.05
    assert len({tuple(px) for px in (flat[:: 97] * 255).round().astype(int).tolist()}) > 20


def test_scene_random_in_process(tmp_path, capsys):
    out = tmp_path / "sub" / "scene.png"                      # the parent directory is created
    assert main(["scene", "--seed", "3", "--slot", "5", "--out", str(out), "--dpi", "60"]) == 0
    check_png(out, 60)
    msg = capsys.readouterr().out
    assert str(out) in msg and "random-3" in msg and "slot 5" in msg
    plt.close("all")


def test_scene_paper_in_process(tmp_path, capsys):
    out = tmp_path / "paper.png"
    assert main(["scene", "--paper", "--slot", "0", "--out", str(out), "--dpi", "60"]) == 0
    check_png(out, 60)
    assert "paper-3uav" in capsys.readouterr().out
    plt.close("all")


def test_scene_seeds_give_different_pictures(tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    main(["scene", "--seed", "1", "--slot", "2", "--out", str(a), "--dpi", "40"])
    main(["scene", "--seed", "2", "--slot", "2", "--out", str(b), "--dpi", "40"])
    assert a.read_bytes() != b.read_bytes()
    plt.close("all")


def test_scene_subprocess(tmp_path):
    out = tmp_path / "scene.png"
    env = dict(os.environ, MPLBACKEND="Agg")
    res = subprocess.run([sys.executable, "-m", "covert_env.cli", "scene", "--seed", "4", "--slot", "10",
                          "--out", str(out)], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    check_png(out, 110)                                       # the default dpi
    assert "wrote" in res.stdout


@pytest.mark.parametrize("slot", ["-1", "71", "1000"])
def test_invalid_slot_names_the_option(tmp_path, slot):
    out = tmp_path / "x.png"
    with pytest.raises(SystemExit) as exc:
        main(["scene", "--seed", "0", "--slot", slot, "--out", str(out)])
    assert exc.value.code not in (0, None)
    assert "--slot" in str(exc.value.code)
    assert not out.exists()


def test_invalid_slot_subprocess_exit_status(tmp_path):
    res = subprocess.run([sys.executable, "-m", "covert_env.cli", "scene", "--paper", "--slot", "999",
                          "--out", str(tmp_path / "x.png")], capture_output=True, text=True,
                         env=dict(os.environ, MPLBACKEND="Agg"), timeout=120)
    assert res.returncode != 0
    assert "--slot" in res.stderr
    assert not (tmp_path / "x.png").exists()


def test_slot_range_follows_the_config_file(tmp_path):
    cfg = tmp_path / "cfg.json"
    Config(n_slots=6).to_json(cfg)
    out = tmp_path / "ok.png"
    assert main(["scene", "--config", str(cfg), "--slot", "6", "--out", str(out), "--dpi", "30"]) == 0
    assert out.read_bytes()[:8] == PNG_SIGNATURE
    with pytest.raises(SystemExit) as exc:
        main(["scene", "--config", str(cfg), "--slot", "7", "--out", str(tmp_path / "no.png")])
    assert "--slot" in str(exc.value.code) and "6" in str(exc.value.code)
    plt.close("all")


def test_parser_defaults_and_usage_errors(capsys):
    args = build_parser().parse_args(["scene"])
    assert (args.seed, args.slot, args.paper, args.dpi, args.config) == (0, 0, False, 110, None)
    with pytest.raises(SystemExit) as exc:
        main([])                                              # a command is required
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        main(["scene", "--slot", "two"])
    assert exc.value.code == 2
    assert "--slot" in capsys.readouterr().err


def test_scene_does_not_leak_figures(tmp_path):
    plt.close("all")
    main(["scene", "--seed", "0", "--slot", "0", "--out", str(tmp_path / "a.png"), "--dpi", "30"])
    try:
        assert plt.get_fignums() == []
    finally:
        plt.close("all")


@pytest.mark.parametrize("command, expected", [("reproduce", "--quick"), ("evaluate", "--policies")])
def test_forwarded_subcommands_reach_their_parsers(command, expected, capsys):
    """`covert-env reproduce/evaluate ...` hand every argument, --help included, to their own parser."""
    from covert_env.cli import main

    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert f"usage: covert-env {command}" in out or "usage:" in out
    assert expected in out
