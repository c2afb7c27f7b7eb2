"""mkdocs hooks: the site's generated parts, made from the repository at build time (nothing here is hand-copied).

* ``<!-- generated: NAME -->`` on a page is replaced by the table or list NAME (:data:`GENERATED`): the suite's
  leaderboard from ``docs/results/suite.json`` (the run published by
  ``python -m covert_env.evaluation.leaderboard``), the shipped cards from ``training/pretrained/*.json``, the task
  list from ``covert_env.world.tasks``.
* Generated files: ``changelog.md`` (the repository's ``CHANGELOG.md``), ``images/families/<family>.png`` (one
  held-out scene of each family, drawn by ``covert_env.render.scene_figure``), ``images/suite_profile.png``
  (the published run's performance profiles, drawn by ``covert_env.evaluation.leaderboard.profile_figure``) and
  ``images/throughput.png`` (env-steps per second against B, from ``docs/results/throughput.json``, which
  ``benchmarks/vector_throughput.py --json`` writes).
"""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]
PLACEHOLDER = re.compile(r"<!-- generated: ([a-z_]+) -->")


def _suite() -> dict:
    return json.loads((ROOT / "docs" / "results" / "suite.json").read_text())


def _cards() -> str:
    from training.catalogue import weights_table

    return weights_table()


def _tasks() -> str:
    from covert_env.world.tasks import DEFAULT_TASKS, TASKS

    lines = ["| task | family | UAVs | target | core |", "|---|---|---|---|---|"]
    lines += [f"| `{t.name}` | {t.family} | {t.n_uavs} | {t.target} | {'yes' if t.name in DEFAULT_TASKS else ''} |"
              for t in TASKS.values()]
    return "\n".join(lines)


def _families() -> str:
    from covert_env.world.families import FAMILIES

    return "\n".join(f"### `{name}`\n\n{fam.description}.\n\n![A held-out scene of the {name} family]"
                     f"(images/families/{name}.png)\n" for name, fam in FAMILIES.items())


def _suite_tiers() -> str:
    from covert_env.evaluation.leaderboard import tier_table

    return tier_table(_suite())


def _suite_tiers_compact() -> str:
    from covert_env.evaluation.leaderboard import tier_table

    return tier_table(_suite(), compact=True)


def _suite_tasks() -> str:
    from covert_env.evaluation.leaderboard import task_table

    return task_table(_suite())


def _suite_caption() -> str:
    from covert_env.evaluation.leaderboard import caption

    return f"*{caption(_suite())}.*"


def _throughput() -> dict:
    return json.loads((ROOT / "docs" / "results" / "throughput.json").read_text())


def _throughput_caption() -> str:
    t = _throughput()
    return (f"*covert_env {t['covert_env']}, {t['date']}, {t['cpus']} CPUs (load average {t['load_average']} at the "
            f"end), CPU-time rates: `{t['command']}`.*")


def _throughput_figure():
    import matplotlib.pyplot as plt

    t = _throughput()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for config in dict.fromkeys(r["config"] for r in t["rows"]):
        rows = sorted((r for r in t["rows"] if r["config"] == config), key=lambda r: r["B"])
        ax.plot([r["B"] for r in rows], [r["steps_per_s_cpu"] for r in rows], "o-" if "vmas" not in config else "s--",
                label=config if "vmas" in config else f"covert_env, {config}")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("copies B (3 agents each)")
    ax.set_ylabel("env-steps per CPU-second")
    ax.set_title(f"Vector env throughput, covert_env {t['covert_env']} ({t['date']})", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


#: What a placeholder may name.
GENERATED = {"cards": _cards, "tasks": _tasks, "families": _families, "suite_tiers": _suite_tiers,
             "suite_tiers_compact": _suite_tiers_compact,
             "suite_tasks": _suite_tasks, "suite_caption": _suite_caption, "throughput_caption": _throughput_caption}


def on_page_markdown(markdown: str, page, config, files) -> str:
    def fill(m: re.Match) -> str:
        if m.group(1) not in GENERATED:
            raise KeyError(f"{page.file.src_uri}: no generated part named {m.group(1)!r} (docs/hooks.py: "
                           f"{', '.join(GENERATED)})")
        return GENERATED[m.group(1)]()

    return PLACEHOLDER.sub(fill, markdown)


#: A Sphinx role in a docstring (``:class:`~a.b.C```), as the Markdown renderer leaves it in the HTML.
SPHINX_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj):<code>(~?)([^<]*)</code>")


#: The single-UAV env's part of a page (its observation table is the single agent's).
SINGLE_ENV = 'id="covert_env.envs.single.'


def _observation_tables(html: str) -> str:
    """The env docstrings' ``{OBSERVATION_TABLE}``, which the env modules fill at import (the docstrings are read
    from the source here), as the tables ``observation_table`` makes."""
    import markdown

    from covert_env.envs.observation import observation_table

    def table(single: bool) -> str:
        return markdown.markdown(observation_table(single_agent=single), extensions=["tables"])

    head, sep, tail = html.partition(SINGLE_ENV)
    return head.replace("{OBSERVATION_TABLE}", table(False)) + sep + tail.replace("{OBSERVATION_TABLE}", table(True))


def on_page_content(html: str, page, config, files) -> str:
    """The docstrings' Sphinx roles as plain code (``~`` keeps the last name, as Sphinx shows it), and their
    observation tables."""
    html = SPHINX_ROLE.sub(lambda m: f"<code>{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}</code>",
                           html)
    return _observation_tables(html) if "{OBSERVATION_TABLE}" in html else html


def _png(draw) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = draw()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    return buf.getvalue()


def _family_figure(name: str):
    import covert_env
    from covert_env.render import scene_figure
    from covert_env.world.families import HELD_OUT_SEEDS

    env = covert_env.parallel_env(task=f"{name}-3uav")
    seed = HELD_OUT_SEEDS.start
    env.reset(seed=seed, options={"scene_seed": seed})
    fig = scene_figure(env.scenario, 10, uav_xy=None)
    fig.suptitle(f"{name}: held-out scene {seed}, slot 10 (covert_env {covert_env.__version__}; feasible zone black, "
                 "shadows red, visible zone green)", fontsize=9)
    env.close()
    return fig


def on_files(files, config):
    from covert_env.evaluation.leaderboard import profile_figure
    from covert_env.world.families import FAMILIES

    files.append(File.generated(config, "changelog.md", content=(ROOT / "CHANGELOG.md").read_text(encoding="utf-8")))
    for name in FAMILIES:
        files.append(File.generated(config, f"images/families/{name}.png",
                                    content=_png(lambda name=name: _family_figure(name))))
    files.append(File.generated(config, "images/throughput.png", content=_png(_throughput_figure)))
    buf = io.BytesIO()
    profile_figure(_suite(), buf)
    files.append(File.generated(config, "images/suite_profile.png", content=buf.getvalue()))
    return files
