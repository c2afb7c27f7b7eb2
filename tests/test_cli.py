"""The ``covert-env`` command line: ``covert-env scene`` writes a picture of one slot."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402
from _extras import needs  # noqa: E402

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
def test_invalid_slot_names_the_option(tmp_path, slot, capsys):
    out = tmp_path / "x.png"
    with pytest.raises(SystemExit) as exc:
        main(["scene", "--seed", "0", "--slot", slot, "--out", str(out)])
    assert exc.value.code == 2
    assert "--slot" in capsys.readouterr().err
    assert not out.exists()


def test_invalid_slot_subprocess_exit_status(tmp_path):
    res = subprocess.run([sys.executable, "-m", "covert_env.cli", "scene", "--paper", "--slot", "999",
                          "--out", str(tmp_path / "x.png")], capture_output=True, text=True,
                         env=dict(os.environ, MPLBACKEND="Agg"), timeout=120)
    assert res.returncode == 2
    assert "--slot" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "x.png").exists()


def test_slot_range_follows_the_config_file(tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    Config(n_slots=6).to_json(cfg)
    out = tmp_path / "ok.png"
    assert main(["scene", "--config", str(cfg), "--slot", "6", "--out", str(out), "--dpi", "30"]) == 0
    assert out.read_bytes()[:8] == PNG_SIGNATURE
    with pytest.raises(SystemExit) as exc:
        main(["scene", "--config", str(cfg), "--slot", "7", "--out", str(tmp_path / "no.png")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--slot" in err and "[0, 6]" in err
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
    """`covert-env reproduce/evaluate ...` hand every argument, --help included, to their own parser, which
    names itself `covert-env <command>`."""
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: covert-env {command} ")
    assert "python -m" not in out.split("\n")[0]
    assert expected in out


# ---------------------------------------------------------------------- user errors: one line, exit 2
def _user_error_cases(tmp: Path) -> dict[str, tuple[list[str], str]]:
    """name -> (argv, text the error line must contain). ``tmp`` holds a file, a folder and bad configs."""
    f, d = tmp / "a_file", tmp / "a_dir"
    bad_json, bad_value = tmp / "bad.json", tmp / "bad_value.json"
    return {
        "scene out is a folder": (["scene", "--out", str(d)], "is a folder"),
        "scene out under a file": (["scene", "--out", str(f / "x.png")], "is a file, not a folder"),
        "scene out unknown type": (["scene", "--out", str(tmp / "x.foo")], "unknown file type"),
        "scene negative seed": (["scene", "--seed", "-5"], "--seed: must be an integer >= 0, got -5"),
        "scene seed not a number": (["scene", "--seed", "x"], "--seed"),
        "scene slot too big": (["scene", "--slot", "71"], "--slot must be in [0, 70]"),
        "scene negative slot": (["scene", "--slot", "-1"], "--slot"),
        "scene dpi zero": (["scene", "--dpi", "0"], "--dpi: must be an integer in [10, 1000]"),
        "scene dpi huge": (["scene", "--dpi", "100000"], "--dpi"),
        "scene missing config": (["scene", "--config", str(tmp / "missing.json")], "missing.json: no such file"),
        "scene config is a folder": (["scene", "--config", str(d)], "is a directory"),
        "scene invalid config json": (["scene", "--config", str(bad_json)], "invalid JSON"),
        "scene invalid config value": (["scene", "--config", str(bad_value)], "Config.n_uavs"),
        "reproduce out is a file": (["reproduce", "--out", str(f), "--quick"], "is a file, expected a folder"),
        "reproduce negative scenes": (["reproduce", "--out", str(tmp / "r"), "--scenes", "-2"],
                                      "--scenes: must be an integer in [0, 100000], got -2"),
        "reproduce zero jobs": (["reproduce", "--out", str(tmp / "r"), "--jobs", "0"], "--jobs"),
        "reproduce too many jobs": (["reproduce", "--out", str(tmp / "r"), "--jobs", "100000"], "--jobs"),
        "reproduce zero slots": (["reproduce", "--out", str(tmp / "r"), "--slots", "0"], "--slots"),
        "reproduce too many slots": (["reproduce", "--out", str(tmp / "r"), "--slots", "71"],
                                     "--slots must be in [1, 70]"),
        "reproduce missing config": (["reproduce", "--out", str(tmp / "r"), "--config", str(tmp / "no.json")],
                                     "no such file"),
        "reproduce invalid config": (["reproduce", "--out", str(tmp / "r"), "--config", str(bad_json)],
                                     "invalid JSON"),
        "reproduce no out": (["reproduce"], "--out"),
        "reproduce quick scenes beyond its pool": (["reproduce", "--out", str(tmp / "r"), "--quick", "--scenes", "21"],
                                                   "--scenes must be in [0, 20] with --quick"),
        "animate out not a gif": (["animate", "--out", str(tmp / "x.png")], "unknown file type '.png'"),
        "animate out is a folder": (["animate", "--out", str(d)], "is a folder"),
        "animate zero uavs": (["animate", "--uavs", "0"], "--uavs: must be an integer in [1, 3], got 0"),
        "animate four uavs": (["animate", "--uavs", "4"], "--uavs"),
        "animate too many slots": (["animate", "--slots", "71"], "--slots must be in [1, 70], got 71"),
        "animate unknown method": (["animate", "--method", "psychic"], "--method"),
        "animate zero frames per slot": (["animate", "--frames-per-slot", "0"], "--frames-per-slot"),
        "evaluate unknown policy": (["evaluate", "--policies", "nonsense", "--out", str(tmp / "e")],
                                    "unknown policy 'nonsense'"),
        "evaluate unknown mode": (["evaluate", "--policies", "random@hover", "--out", str(tmp / "e")],
                                  "unknown action mode 'hover'"),
        "evaluate missing sb3 path": (["evaluate", "--policies", "random", f"sb3:{tmp / 'nothing'}",
                                       "--out", str(tmp / "e")], "no SB3 model"),
        "evaluate missing rllib path": (["evaluate", "--policies", f"rllib:{tmp / 'nothing'}",
                                         "--out", str(tmp / "e")], "no RLlib checkpoint"),
        "evaluate out is a file": (["evaluate", "--policies", "random", "--out", str(f)],
                                   "is a file, expected a folder"),
        "evaluate zero episodes": (["evaluate", "--episodes", "0"], "--episodes"),
        "evaluate zero uavs": (["evaluate", "--n-uavs", "0"], "--n-uavs: must be an integer >= 1"),
        "evaluate negative seed offset": (["evaluate", "--seed-offset", "-1"], "--seed-offset"),
        "scene empty out": (["scene", "--out", ""], "--out '': empty; give a path"),
        "reproduce empty out": (["reproduce", "--quick", "--out", ""], "--out '': empty; give a path"),
        "reproduce blank out": (["reproduce", "--quick", "--out", "  "], "--out '  ': empty"),
        "evaluate empty out": (["evaluate", "--policies", "random", "--out", ""], "--out '': empty; give a path"),
    }


@pytest.fixture
def error_dir(tmp_path):
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "a_dir").mkdir()
    (tmp_path / "bad.json").write_text("{not json")
    (tmp_path / "bad_value.json").write_text('{"n_uavs": -1}')
    return tmp_path


@pytest.mark.parametrize("case", list(_user_error_cases(Path("/tmp"))))
def test_user_errors_print_one_line_and_exit_2(case, error_dir, capsys, monkeypatch):
    monkeypatch.chdir(error_dir)                          # default --out paths land in tmp
    argv, expected = _user_error_cases(error_dir)[case]
    before = sorted(p.name for p in error_dir.rglob("*"))
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"covert-env {argv[0]}: error: "), lines[0]
    assert expected in lines[0], lines[0]
    assert err.startswith("usage: covert-env") and "Traceback" not in err
    assert sorted(p.name for p in error_dir.rglob("*")) == before        # nothing written


@pytest.mark.parametrize("argv", [["scene", "--seed", "-5"], ["reproduce", "--out", "{f}"],
                                  ["evaluate", "--policies", "nonsense"], ["scene", "--config", "missing.json"]])
def test_user_errors_from_the_console_have_no_traceback(argv, error_dir):
    argv = [a.replace("{f}", str(error_dir / "a_file")) for a in argv]
    res = subprocess.run([sys.executable, "-m", "covert_env.cli", *argv], capture_output=True, text=True,
                         cwd=error_dir, env=dict(os.environ, MPLBACKEND="Agg",
                                                 PYTHONPATH=os.pathsep.join(sys.path)), timeout=120)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    assert len([ln for ln in res.stderr.splitlines() if "error:" in ln]) == 1
    assert res.stdout == ""


def test_genuine_bugs_keep_their_traceback(tmp_path, monkeypatch):
    """Only UsageError is turned into an error line: an unexpected ValueError inside a command propagates."""
    import covert_env.render

    def broken(*a, **k):
        raise ValueError("a bug, not a user error")

    monkeypatch.setattr(covert_env.render, "scene_figure", broken)
    with pytest.raises(ValueError, match="a bug"):
        main(["scene", "--out", str(tmp_path / "x.png")])


def test_reproduce_accepts_zero_scenes(tmp_path):
    """--scenes 0 is in range: the paper scenario only (the boundary of the checked range works)."""
    from baselines.reproduce import build_parser as reproduce_parser

    args = reproduce_parser().parse_args(["--out", str(tmp_path), "--scenes", "0", "--jobs", "1"])
    assert (args.scenes, args.jobs) == (0, 1)


# ---------------------------------------------------------------------- --help: each default once, the true one
def _option_blocks(help_text: str) -> dict[str, str]:
    """Option string -> its help text (wrapped lines joined), from an argparse --help."""
    blocks: dict[str, str] = {}
    current = None
    for line in help_text.split("options:", 1)[1].splitlines():
        m = re.match(r"^  (-{1,2}[\w-]+)", line)
        if m:
            current = m.group(1)
            blocks[current] = line
        elif current and line.startswith("   "):
            blocks[current] += " " + line.strip()
        elif not line.strip():
            current = None
    return blocks


def _parsers():
    from baselines.reproduce import build_parser as reproduce_parser
    from training.evaluate import build_parser as evaluate_parser

    yield "scene", build_parser()._subparsers._group_actions[0].choices["scene"]
    yield "animate", build_parser()._subparsers._group_actions[0].choices["animate"]
    yield "reproduce", reproduce_parser()
    yield "evaluate", evaluate_parser()


@pytest.mark.parametrize("name", ["scene", "animate", "reproduce", "evaluate"])
def test_cli_help_prints_each_default_once(name):
    parser = dict(_parsers())[name]
    blocks = _option_blocks(parser.format_help())
    assert len(blocks) >= 5
    for opt, text in blocks.items():
        assert text.lower().count("default") <= 1, (opt, text)
        assert "default: None" not in text, (opt, text)
    for action in parser._actions:                       # the printed default is the parser's own default
        opt = action.option_strings[-1] if action.option_strings else None
        if opt in blocks and action.default not in (None, False, argparse.SUPPRESS):
            shown = " ".join(map(str, action.default)) if isinstance(action.default, list) else str(action.default)
            m = re.search(r"default: ([^;)]*)", blocks[opt])
            if m and not isinstance(action.default, list):
                assert m.group(1).strip() == shown, (opt, blocks[opt])


TRAINING_SCRIPTS = ["ppo_multi", "ppo_single", "sac_single", "maskable_ppo_single", "rllib_ppo", "mappo"]


@pytest.mark.parametrize("script", TRAINING_SCRIPTS)
def test_training_help_prints_each_true_default_once(script):
    """The training scripts used to print `(default: 0) (default: None)`; now one default, the dataclass's."""
    import dataclasses
    import importlib

    from training.common import _show_default
    from training.common import build_parser as dataclass_parser

    module = importlib.import_module(f"training.{script}")
    parser = dataclass_parser(module.Args, "x", getattr(module, "RECIPES", None) if script == "ppo_multi" else None)
    blocks = _option_blocks(parser.format_help())
    for f in dataclasses.fields(module.Args):
        text = blocks["--" + f.name.replace("_", "-")]
        assert text.count("default:") == 1, text
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        assert f"default: {_show_default(default)})" in text, text
    assert parser.prog == f"python -m training.{script}"


@pytest.mark.parametrize("script", TRAINING_SCRIPTS)
def test_every_numeric_training_flag_is_range_checked(script, capsys):
    import dataclasses
    import importlib
    import typing

    from training.common import _ranges, parse_args

    module = importlib.import_module(f"training.{script}")
    ranges = _ranges()
    hints = typing.get_type_hints(module.Args)
    for f in dataclasses.fields(module.Args):
        if hints[f.name] in (int, float) or typing.get_origin(hints[f.name]) is tuple:
            assert f.name in ranges, f"{script}.Args.{f.name} has no range in training.common._ranges"
            flag = "--" + f.name.replace("_", "-")
            with pytest.raises(SystemExit) as exc:
                parse_args(module.Args, [flag, "-1000000" if f.name != "log_std_init" else "100"])
            assert exc.value.code == 2
            err = capsys.readouterr().err
            assert f"argument {flag}" in err and "must be" in err and "Traceback" not in err
            with pytest.raises(SystemExit):
                parse_args(module.Args, [flag, "nan"])
            capsys.readouterr()
    assert parse_args(module.Args, []) == module.Args()     # the defaults are in range


#: Packages of the extras that no training script's ``--help`` (nor ``import training.common``) may need.
OPTIONAL_PACKAGES = ("stable_baselines3", "sb3_contrib", "torch", "tensorboard", "tqdm", "rich", "ray", "torchrl",
                     "tensordict", "benchmarl", "tianshou")


def test_training_help_needs_no_optional_package():
    """Every training script's ``--help`` runs with the optional packages made unimportable (``None`` in
    ``sys.modules``), whether or not they are installed here."""
    code = f"""
import runpy, sys
sys.modules.update(dict.fromkeys({OPTIONAL_PACKAGES!r}))
import training.common
for script in {TRAINING_SCRIPTS!r}:
    sys.argv = [script, "--help"]
    try:
        runpy.run_module("training." + script, run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        print(script, "exit", exc.code)
"""
    root = Path(__file__).resolve().parents[1]
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    for script in TRAINING_SCRIPTS:
        assert f"usage: python -m training.{script}" in res.stdout, res.stdout[-2000:]
        assert f"{script} exit 0" in res.stdout, res.stdout[-2000:]


def test_evaluate_sb3_file_that_is_not_a_model_is_one_line(error_dir, capsys, monkeypatch):
    needs("stable_baselines3")
    monkeypatch.chdir(error_dir)
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--policies", "sb3:a_file", "--episodes", "1", "--n-uavs", "1", "--no-progress",
              "--out", "o"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "--policies: sb3:a_file: a_file is not a loadable PPO model" in lines[0], lines[0]
