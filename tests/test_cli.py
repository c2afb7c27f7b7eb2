"""The ``covert-env`` command line: ``covert-env scene`` writes a picture of one slot."""

from __future__ import annotations

import argparse
import json
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
from covert_env.world.config import Config  # noqa: E402

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


def test_animate_default_out_is_not_the_tracked_gif():
    """`covert-env animate` alone writes into the git-ignored outputs/, not over the README's docs/dp_team.gif."""
    from baselines.animate import build_parser as animate_parser

    args = animate_parser().parse_args([])
    assert args.out == "outputs/dp_team.gif"


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
        "scene config /dev/zero": (["scene", "--config", "/dev/zero"],
                                   "--config /dev/zero: is a character device, expected a Config JSON file"),
        "scene config /dev/null": (["scene", "--config", "/dev/null"],
                                   "--config /dev/null: is a character device, expected a Config JSON file"),
        "scene config fifo": (["scene", "--config", str(tmp / "fifo")],
                              f"--config {tmp / 'fifo'}: is a named pipe, expected a Config JSON file"),
        "animate config fifo": (["animate", "--config", str(tmp / "fifo")], "is a named pipe"),
        "reproduce config /dev/zero": (["reproduce", "--out", str(tmp / "r"), "--config", "/dev/zero"],
                                       "is a character device"),
        "scene out is a fifo": (["scene", "--out", str(tmp / "fifo.png")],
                                f"--out {tmp / 'fifo.png'}: is a named pipe, expected a regular file name"),
        "reproduce out holds a folder where a file goes": (
            ["reproduce", "--quick", "--out", str(tmp / "full")],
            f"--out {tmp / 'full'}: {tmp / 'full' / 'metrics.md'} is a directory, but the command writes the file "
            "metrics.md there"),
        "reproduce out holds a folder where a figure goes": (
            ["reproduce", "--quick", "--out", str(tmp / "figs")], "fig_heldout.png is a directory"),
        "evaluate out holds a folder where a file goes": (
            ["evaluate", "--policies", "random", "--out", str(tmp / "full")],
            f"{tmp / 'full' / 'leaderboard.md'} is a directory, but the command writes the file leaderboard.md"),
        "evaluate cache is a file": (["evaluate", "--policies", "random", "--out", str(tmp / "cached")],
                                     f"{tmp / 'cached' / 'cache'} is a file, but the command writes into a folder"),
    }


@pytest.fixture
def error_dir(tmp_path):
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "a_dir").mkdir()
    (tmp_path / "bad.json").write_text("{not json")
    (tmp_path / "bad_value.json").write_text('{"n_uavs": -1}')
    for name in ("fifo", "fifo.png"):
        os.mkfifo(tmp_path / name)
    for name in ("full/metrics.md", "full/leaderboard.md", "figs/fig_heldout.png"):
        (tmp_path / name).mkdir(parents=True)
    (tmp_path / "cached").mkdir()
    (tmp_path / "cached" / "cache").write_text("x")
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


READ_ONLY_OUTS = {
    "scene in /proc": (["scene", "--out", "/proc/covert_env_test.png"], "cannot write in /proc"),
    "scene in /sys": (["scene", "--out", "/sys/covert_env_test.png"], "cannot write in /sys"),
    "scene in a new folder in /proc": (["scene", "--out", "/proc/covert_env_test/x.png"], "cannot create the folder"),
    "animate in /sys": (["animate", "--out", "/sys/covert_env_test.gif"], "cannot write in /sys"),
    "reproduce into /proc": (["reproduce", "--out", "/proc"], "cannot write in /proc"),
    "reproduce into a new folder in /sys": (["reproduce", "--out", "/sys/covert_env_test"],
                                            "cannot create the folder"),
    "evaluate into /proc": (["evaluate", "--policies", "dp", "--out", "/proc"], "cannot write in /proc"),
    "evaluate into a new folder in /sys": (["evaluate", "--policies", "dp", "--out", "/sys/covert_env_test"],
                                           "cannot write in /sys"),
}


@pytest.mark.skipif(not (Path("/proc/self").is_dir() and Path("/sys/kernel").is_dir()), reason="needs /proc and /sys")
@pytest.mark.parametrize("case", list(READ_ONLY_OUTS))
def test_unwritable_out_fails_before_the_run(case, capsys, monkeypatch):
    """/proc and /sys refuse new files even to root, for whom os.access says yes: the output folder is probed by
    writing a temporary file, before any planning or evaluation runs (those are replaced by a failure here)."""
    import baselines.reproduce
    import baselines.reproduce.command
    import covert_env.evaluation.evaluate

    def ran(*a, **k):
        raise AssertionError("the run started before --out was checked")

    monkeypatch.setattr(baselines.reproduce.command, "run_all", ran)
    monkeypatch.setattr(baselines.reproduce, "write_gif", ran)
    monkeypatch.setattr(covert_env.evaluation.evaluate, "evaluate", ran)
    argv, expected = READ_ONLY_OUTS[case]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1 and "Traceback" not in err, err
    out = argv[argv.index("--out") + 1]
    assert re.fullmatch(rf"covert-env {argv[0]}: error: --out {re.escape(out)}: {expected}( in /\w+)? \(.+\)",
                        lines[0]), lines[0]


def test_output_checks_leave_nothing_behind(tmp_path):
    from covert_env.cli import output_dir, output_file

    output_dir(tmp_path / "a", create=False)
    assert list(tmp_path.iterdir()) == []
    assert output_dir(tmp_path / "a" / "b") == tmp_path / "a" / "b"
    assert [p.relative_to(tmp_path) for p in tmp_path.rglob("*")] == [Path("a"), Path("a/b")]
    f = tmp_path / "x.png"
    f.write_bytes(b"old")
    assert output_file(f, suffixes=("png",)) == f
    assert f.read_bytes() == b"old"                        # opened for writing, not changed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "x.png"]


def test_provided_commands_come_from_the_entry_points(monkeypatch, capsys):
    """A subcommand of the entry point group runs with the arguments after its name and our prog; a declared one
    missing from the installed metadata is one error line naming the group."""
    import types

    import covert_env.cli as cli

    seen = []

    def hello(argv, prog):
        seen.append((argv, prog))
        return 3

    monkeypatch.setattr(cli, "provided_commands", lambda: {"hello": types.SimpleNamespace(load=lambda: hello)})
    assert main(["hello", "--x", "1"]) == 3
    assert seen == [(["--x", "1"], "covert-env hello")]
    assert "hello" in build_parser().format_help()                       # listed by covert-env --help
    with pytest.raises(SystemExit) as exc:
        main(["reproduce", "--help"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "the reproduce command is not in the installed metadata (entry point group covert_env.commands has: " \
           "hello)" in err


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
    from baselines.animate import build_parser as animate_parser
    from baselines.reproduce import build_parser as reproduce_parser
    from covert_env.evaluation.benchmark import build_parser as benchmark_parser
    from covert_env.evaluation.evaluate import build_parser as evaluate_parser

    yield "scene", build_parser()._subparsers._group_actions[0].choices["scene"]
    yield "animate", animate_parser()
    yield "reproduce", reproduce_parser()
    yield "evaluate", evaluate_parser()
    yield "benchmark", benchmark_parser()


@pytest.mark.parametrize("name", ["scene", "animate", "reproduce", "evaluate", "benchmark"])
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


TRAINING_SCRIPTS = ["sb3.ppo_multi", "sb3.ppo_single", "sb3.sac_single", "sb3.maskable_ppo_single", "rllib_ppo",
                    "mappo", "imitation"]


@pytest.mark.parametrize("script", TRAINING_SCRIPTS)
def test_training_help_prints_each_true_default_once(script):
    """Each training flag's --help shows one default, the dataclass's (never `(default: 0) (default: None)`)."""
    import dataclasses
    import importlib

    from training.common import _show_default
    from training.common import build_parser as dataclass_parser

    module = importlib.import_module(f"training.{script}")
    parser = dataclass_parser(module.Args, "x", getattr(module, "RECIPES", None) if script == "sb3.ppo_multi" else None)
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
OPTIONAL_PACKAGES = ("stable_baselines3", "sb3_contrib", "torch", "tensorboard", "rich", "ray", "torchrl",
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
              "--out", "o", "--trust-checkpoint"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "--policies: sb3:a_file: a_file is not a loadable PPO model" in lines[0], lines[0]


# ---------------------------------------------------------------------- files evaluate reads: named with the field
def _evaluate_file_cases(tmp: Path) -> dict[str, tuple[list[str], str]]:
    """name -> (argv after `evaluate`, regex the one error line must match after `error: `); files under ``tmp``."""
    cache = tmp / "lb" / "cache" / "random__2__1000000__3.json"
    sb3, rllib = tmp / "sb3run", tmp / "rllibrun" / "checkpoint"
    base = ["--episodes", "2", "--n-uavs", "3", "--no-progress"]
    return {
        "truncated cache": (["--policies", "random", "--out", str(tmp / "lb"), "--reuse", *base],
                            rf"--reuse: cached results {re.escape(str(cache))}: invalid JSON \(.*\); "
                            r"delete it \(it is rewritten\) or run without --reuse"),
        "cache of other scenes": (["--policies", "random", "--out", str(tmp / "lb2"), "--reuse", *base],
                                  r"--reuse: cached results .*: row 0 has scene_seed 5, expected 1000000; delete it"),
        "cache with a text reward": (["--policies", "random", "--out", str(tmp / "lb3"), "--reuse", *base],
                                     r"--reuse: cached results .*: row 1 field reward must be a finite number, "
                                     r"got 'high'"),
        "sb3 args.json n_uavs three": (["--policies", f"sb3:{sb3}", "--trust-checkpoint", "--out", str(tmp / "o"),
                                        *base],
                                       rf"--policies: {re.escape(str(sb3 / 'args.json'))}: env_kwargs: n_uavs must "
                                       r"be an integer, got str 'three'"),
        "rllib args.json map_size": (["--policies", f"rllib:{rllib}", "--trust-checkpoint", "--out", str(tmp / "o"),
                                      *base],
                                     rf"--policies: {re.escape(str(rllib.parent / 'args.json'))}: env_kwargs: "
                                     r"map_size must be an integer in \[2, 64\], got 1"),
    }


@pytest.fixture
def evaluate_files(tmp_path):
    from covert_env.evaluation.evaluate import COLUMNS

    good = [{"scene_seed": 1_000_000 + i, **{k: 1.0 for k, _, _ in COLUMNS}} for i in range(2)]
    for out, text in [("lb", json.dumps(good)[:40]), ("lb2", json.dumps([{**good[0], "scene_seed": 5}, good[1]])),
                      ("lb3", json.dumps([good[0], {**good[1], "reward": "high"}]))]:
        cache = tmp_path / out / "cache" / "random__2__1000000__3.json"
        cache.parent.mkdir(parents=True)
        cache.write_text(text)
    (tmp_path / "sb3run").mkdir()
    (tmp_path / "sb3run" / "model.zip").write_bytes(b"never read: the settings fail first")
    (tmp_path / "sb3run" / "args.json").write_text(json.dumps({"env_kwargs": {"n_uavs": "three"}}))
    (tmp_path / "rllibrun" / "checkpoint" / "learner_group" / "learner" / "rl_module" / "shared_policy").mkdir(
        parents=True)
    (tmp_path / "rllibrun" / "args.json").write_text(json.dumps({"env_kwargs": {"n_uavs": 3, "map_size": 1}}))
    return tmp_path


@pytest.mark.parametrize("case", list(_evaluate_file_cases(Path("/tmp"))))
def test_evaluate_file_errors_name_the_file_and_field(case, evaluate_files, capsys, monkeypatch):
    import covert_env.evaluation.evaluate

    def ran(*a, **k):
        raise AssertionError("evaluation started before the files were checked")

    monkeypatch.setattr(covert_env.evaluation.evaluate, "evaluate", ran)
    argv, pattern = _evaluate_file_cases(evaluate_files)[case]
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert re.fullmatch(rf"covert-env evaluate: error: {pattern}.*", lines[0]), lines[0]


def test_resume_needs_the_run_folder_itself(tmp_path, capsys, monkeypatch):
    """A folder inside a run is not the run: its args.json must be in the folder itself (an RLlib checkpoint, with
    learner_group/, keeps it beside)."""
    from training.mappo import main as mappo_main

    (tmp_path / "run" / "sub").mkdir(parents=True)
    (tmp_path / "run" / "args.json").write_text("{}")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        mappo_main(["--resume", "run/sub"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert re.search(r"error: --resume run/sub: not a run folder \(no run/sub/args\.json\)", err), err


def test_evaluate_reuses_a_sound_cache(evaluate_files, capsys, monkeypatch):
    import covert_env.evaluation.evaluate

    monkeypatch.setattr(covert_env.evaluation.evaluate, "evaluate",
                        lambda *a, **k: (_ for _ in ()).throw(AssertionError("ran")))
    cache = evaluate_files / "lb3" / "cache" / "random__2__1000000__3.json"
    rows = json.loads(cache.read_text())
    rows[1]["reward"] = 2.0
    cache.write_text(json.dumps(rows))
    assert main(["evaluate", "--policies", "random", "--out", str(evaluate_files / "lb3"), "--reuse", "--episodes",
                 "2", "--no-progress"]) == 0
    assert "random" in (evaluate_files / "lb3" / "leaderboard.md").read_text()


def test_evaluate_names_a_built_in_policy_by_its_spec_as_the_suite_does(evaluate_files, monkeypatch):
    """leaderboard.md and suite.md name the paper's planner alike: dp (its planner label is dp-aware-inherited)."""
    import covert_env.evaluation.evaluate

    monkeypatch.setattr(covert_env.evaluation.evaluate, "evaluate",
                        lambda *a, **k: (_ for _ in ()).throw(AssertionError("ran")))
    rows = json.loads((evaluate_files / "lb3" / "cache" / "random__2__1000000__3.json").read_text())
    rows[1]["reward"] = 2.0
    cache = evaluate_files / "dp" / "cache" / "dp__2__1000000__3.json"
    cache.parent.mkdir(parents=True)
    cache.write_text(json.dumps(rows))
    assert main(["evaluate", "--policies", "dp", "--out", str(evaluate_files / "dp"), "--reuse", "--episodes", "2",
                 "--no-progress"]) == 0
    board = (evaluate_files / "dp" / "leaderboard.md").read_text()
    assert "| planner | dp | waypoint |" in board and "dp-aware-inherited" not in board
    assert set(json.loads((evaluate_files / "dp" / "results.json").read_text())) == {"dp"}


# ---------------------------------------------------------------------- training scripts: paths and saved arguments
def _training_path_cases(tmp: Path) -> dict[str, tuple[str, list[str], str]]:
    """name -> (script, argv, regex of the error line after `error: `); folders under ``tmp``."""
    return {
        "saved seed out of range": ("sb3.ppo_single", ["--resume", str(tmp / "neg_seed")],
                                    rf"--resume {re.escape(str(tmp / 'neg_seed'))}: .*args\.json: seed: must be an "
                                    r"integer >= 0, got -3"),
        "saved args not json": ("sb3.sac_single", ["--resume", str(tmp / "broken")],
                                r"--resume .*broken: .*args\.json: invalid JSON \(.*\)"),
        "saved args a list": ("sb3.ppo_multi", ["--resume", str(tmp / "listed")],
                              r"--resume .*listed: .*args\.json: must be a JSON object \(a run's arguments\), "
                              r"got list"),
        "saved net_arch of text": ("sb3.maskable_ppo_single", ["--resume", str(tmp / "net")],
                                   r"--resume .*net: .*args\.json: net_arch must be a list of int, got \[64, 'x'\]"),
        "saved algo of another script": ("mappo", ["--resume", str(tmp / "other")],
                                         r"--resume .*other: .*args\.json: algo must be one of mappo, ippo, got "
                                         r"'ppo_single'"),
        "run name with a folder where args.json goes": (
            "mappo", ["--runs-dir", str(tmp / "runs"), "--run-name", "taken"],
            rf"--run-name {re.escape(str(tmp / 'runs' / 'taken'))}: .*args\.json is a directory, but the command "
            r"writes the file args\.json there; move it away or choose another --run-name"),
        "runs dir under a file": ("sb3.ppo_single", ["--runs-dir", str(tmp / "a_file" / "runs")],
                                  r"--runs-dir .*: .*a_file is a file, not a folder"),
    }


@pytest.fixture
def training_dirs(tmp_path):
    for name, text in [("neg_seed", '{"seed": -3}'), ("broken", "{"), ("listed", "[1, 2]"),
                       ("net", '{"net_arch": [64, "x"]}'), ("other", '{"algo": "ppo_single"}')]:
        (tmp_path / name).mkdir()
        (tmp_path / name / "args.json").write_text(text)
    (tmp_path / "runs" / "taken" / "args.json").mkdir(parents=True)
    (tmp_path / "a_file").write_text("x")
    return tmp_path


@pytest.mark.parametrize("case", list(_training_path_cases(Path("/tmp"))))
def test_training_scripts_check_paths_and_saved_arguments_first(case, training_dirs, capsys):
    import importlib

    from training.common import parse_args

    script, argv, pattern = _training_path_cases(training_dirs)[case]
    module = importlib.import_module(f"training.{script}")
    with pytest.raises(SystemExit) as exc:
        parse_args(module.Args, argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert re.fullmatch(rf"python -m training\.{script}: error: {pattern}", lines[0]), lines[0]


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs /proc")
def test_training_runs_dir_on_a_read_only_filesystem(capsys):
    from training.common import parse_args
    from training.sb3 import ppo_multi

    with pytest.raises(SystemExit) as exc:
        parse_args(ppo_multi.Args, ["--runs-dir", "/proc/covert_env_runs"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "error: --runs-dir /proc/covert_env_runs: cannot write in /proc (" in err and "Traceback" not in err


@pytest.mark.parametrize("jobs", [1, 2])
def test_ordered_results_keep_the_order_and_raise_the_first_failure(jobs):
    """training.common.ordered_results: results in the order of the work, one callback per result, and a failing
    item raises its own error (in this process or from a spawned worker)."""
    from covert_env.command_line import ordered_results

    seen = []
    assert ordered_results(int, [("3",), ("1",), ("2",)], jobs, lambda: seen.append(1)) == [3, 1, 2]
    assert len(seen) == 3
    with pytest.raises(ValueError, match="invalid literal for int"):
        ordered_results(int, [("1",), ("x",), ("2",)], jobs)


def test_scene_set_refuses_scenes_beside_seeds(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["scene-set", "--scenes", "5", "--seeds", "1", "2", "--out", str(tmp_path / "s.json")])
    assert exc.value.code == 2 and not (tmp_path / "s.json").exists()
    assert "--scenes 5 and --seeds 1 2: give the number of held-out scenes or the seeds, not both" in \
        capsys.readouterr().err


def test_list_shows_what_the_commands_accept(capsys):
    """covert-env list: every task, family, built-in policy (dp-path too) and shipped weight with its tier."""
    from baselines.policies import POLICIES
    from covert_env.world.families import FAMILIES
    from covert_env.world.tasks import TASKS
    from training.pretrained import pretrained_names

    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert all(f" {t} " in out for t in TASKS) and all(f"  {f} " in out for f in FAMILIES)
    assert all(p in out for p in POLICIES) and "dp-path" in out and "hold-centre (or heuristic)" in out
    assert "SPEC+shield" in out and "random@waypoint+shield" in out
    assert "tier reference" not in out                       # no shipped weight can be a reference
    for name in pretrained_names():
        tier = "hybrid" if name.startswith("dp-cost") else "learned"
        assert re.search(rf"^  {re.escape(name)} +{tier} ", out, re.M), name
    assert main(["list", "families"]) == 0
    out = capsys.readouterr().out
    assert "towers" in out and "paper-3uav" not in out
    with pytest.raises(SystemExit) as exc:
        main(["list", "planets"])
    assert exc.value.code == 2 and "unknown section 'planets'" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["evaluate", "benchmark"])
def test_a_policy_given_twice_is_a_usage_error(command, capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main([command, "--policies", "dp", "random@waypoint", "dp", "--out", str(tmp_path / "out")])
    assert exc.value.code == 2
    assert "--policies: dp given twice; give each spec once" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
