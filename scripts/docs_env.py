"""The env card (docs/env.md) and the changelog page (docs/changelog.md), for
scripts/gen_docs.py.

The card: the Tendon2REnv docstring's sections, its observation and reward tables
(tendon2r_gym.task.observation, tendon2r_gym.task.rewards.TERMS), every argument with its
description (the ``#:`` comment above its EnvConfig field; the docstring's ``Args:`` for the
env's own: the preset and rendering) and default, the registered ids and one line per version
(tendon2r_gym.VERSIONS, CHANGELOG.md's entries).
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import re
import string
from pathlib import Path
from typing import Any

import gymnasium as gym
from docs_common import (
    ARM_PICTURE,
    ENV_NAME,
    ROOT,
    asset,
    env_contract_hash,
    env_ids,
    header,
    newest_id,
    quiet,
    shown,
)
from markdown.extensions.toc import slugify

import tendon2r_gym
from tendon2r_gym.app.field_docs import class_node, docstring_args, field_comments
from tendon2r_gym.app.markdown import code, code_block, page, table
from tendon2r_gym.envs.env import CARD_SECTIONS, Tendon2REnv
from tendon2r_gym.envs.env_config import EnvConfig, arguments
from tendon2r_gym.task import observation
from tendon2r_gym.task.rewards import MULTISCALE, TERMS

#: The env card's sections, in Gymnasium's order (the Tendon2REnv docstring's ``##`` headings).
ENV_SECTIONS = CARD_SECTIONS


def docstring_template(cls: type) -> str:
    """Returns a class's docstring as its source writes it (before any ``str.format`` that
    fills tables into it), dedented."""
    node = class_node(Path(inspect.getsourcefile(cls)).read_text(), cls.__name__)
    return ast.get_docstring(node, clean=True) or ""


def sections(text: str) -> tuple[str, dict[str, str]]:
    """Splits Markdown at its ``## `` headings: (the text before them, heading -> body)."""
    parts = re.split(r"^## +(.+?) *$", text, flags=re.M)
    return parts[0].strip(), {
        h: body.strip() for h, body in zip(parts[1::2], parts[2::2], strict=True)
    }


def markdown_indent(text: str) -> str:
    """Returns docstring text with its indentation doubled: a docstring nests lists by two
    spaces, Markdown by four."""
    return re.sub(r"^( +)", lambda m: m.group(1) * 2, text, flags=re.M)


def own_arguments(template: str) -> tuple[str, dict[str, str]]:
    """Returns the docstring with its Google-style ``Args:`` block (the env's own arguments:
    the preset and rendering) replaced by ``{arguments}``, and that block's descriptions
    (read by tendon2r_gym.app.field_docs, as the commands' --help reads them)."""
    found, described = docstring_args(template)
    if found is None:
        raise ValueError("the Tendon2REnv docstring has no Args: block for its own arguments")
    return template[: found.start()] + "{arguments}\n\n" + template[found.end() :], described


def argument_defaults() -> dict[str, Any]:
    """Returns the env's keyword arguments with their defaults: Tendon2REnv's own (the preset
    and rendering), then EnvConfig's (a field without a default comes from the preset)."""
    out = {
        k: p.default
        for k, p in inspect.signature(Tendon2REnv.__init__).parameters.items()
        if p.default is not inspect.Parameter.empty
    }
    fields = {f.name: f for f in dataclasses.fields(EnvConfig)}
    for name in arguments():
        f = fields[name]
        if f.default is not dataclasses.MISSING:
            out[name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[name] = f.default_factory()
        else:
            out[name] = None  # the preset's
    return out


def argument_descriptions(own: dict[str, str]) -> dict[str, str]:
    """Returns each argument's description, in the table's order: the preset, EnvConfig's
    fields, then rendering.  Raises naming an argument without one, or one that the env does
    not take."""
    comments = field_comments()
    config = {k: comments.get(k, "") for k in arguments()}
    rendering = {k: v for k, v in own.items() if k != "preset"}
    described = {"preset": own.get("preset", ""), **config, **rendering}
    defaults = argument_defaults()
    missing = sorted(k for k in defaults if not described.get(k))
    unknown = sorted(set(described) - set(defaults))
    if missing or unknown:
        raise ValueError(
            f"arguments without a description: {missing} (a #: comment above the EnvConfig "
            f"field, or the Tendon2REnv docstring's Args:); described but not taken: {unknown}"
        )
    return described


#: What the arguments table shows for a default that another table of the card holds.
DEFAULT_ELSEWHERE = {"reward_scales": "the [Rewards](#rewards) table's weights"}


def default_cell(name: str, value: Any) -> str:
    """Returns an argument's default as the arguments table shows it: the value, or for
    ``reward_scales`` (when it is the reward terms' default weights) a link to their table."""
    if name == "reward_scales" and value == {k: w for k, (w, _) in TERMS.items()}:
        return DEFAULT_ELSEWHERE[name]
    return code(shown(value))


def arguments_table(own: dict[str, str]) -> list[str]:
    """Returns the arguments table: every argument, its default and its description."""
    defaults = argument_defaults()
    rows = (
        (code(k), default_cell(k, defaults[k]), d) for k, d in argument_descriptions(own).items()
    )
    return table(("argument", "default", "description"), rows)


#: Each reward term as math (KaTeX): e_j the tracking error of joint j (deg), a_i the applied
#: command's entry i.  A term without a formula here shows "see below".
FORMULAS = {
    "tracking": rf"\frac{{1}}{{{len(MULTISCALE)}}}\sum_{{m}} k_{{m\sigma}}(e),\ m \in "
    rf"\{{{', '.join(f'{m:g}' for m in MULTISCALE)}\}}",
    "tracking_quadratic": r"-\sum_j e_j^2",
    "tracking_rate": r"\text{tracking}(e + h\,\dot e),\ h = \texttt{tracking\_horizon}",
    "ctrl": r"-\sum_i f_i^2",
    "action_rate": r"-\sum_i (a_i - a_i^{\text{last}})^2",
    "action_rate_need": r"-\sum_i \ln\!\left(1 + \left(\frac{a_i - a_i^{\text{last}}}{s_i}"
    r"\right)^2\right)",
    "divergence": r"-1 \text{ on the step that diverges, else } 0",
}  # fmt: skip
KERNEL = (
    r"k_\sigma(e) = -\frac{\sum_j \ln\left(1 + (e_j / \sigma)^2\right)}"
    r"{2 \ln\left(1 + (180 / \sigma)^2\right)}"
)


def reward_table() -> list[str]:
    """Returns the reward terms' table (weight and formula), the kernel they use, and below
    them each term's meaning (tendon2r_gym.task.rewards.TERMS)."""
    rows = (
        (code(k), f"{w:g}", f"${FORMULAS[k]}$" if k in FORMULAS else "see below")
        for k, (w, _) in TERMS.items()
    )
    return [
        *table(("term", "default weight", "unscaled term"), rows),
        "",
        "with e the joints' tracking errors (deg), sigma = `tracking_sigma_deg`, a the applied "
        "command (f and s: below), and the log kernel (quadratic below sigma, logarithmic far "
        "from it):",
        "",
        "$$",
        KERNEL,
        "$$",
        "",
        "What each term is for, and why its weight: [reward terms](rewards.md).",
    ]


def rewards_page(root: Path = ROOT) -> str:
    """Returns docs/rewards.md: what each reward term is for (tendon2r_gym.task.rewards.TERMS),
    the env card's Rewards table giving their weights and formulas."""
    return page([
        header("tendon2r_gym.task.rewards.TERMS"),
        "",
        "# Reward terms",
        "",
        "What each term of the reward is for. Their default weights and formulas are the env "
        "card's [Rewards](env.md#rewards) table; `reward_scales` sets the weights.",
        "",
        *(f"- `{k}`: {doc}." for k, (_, doc) in TERMS.items()),
    ])  # fmt: skip


def observation_table(config: EnvConfig) -> list[str]:
    """Returns the observation's entries in order (tendon2r_gym.task.observation): each one's
    index in ``config``'s layout (the newest id's), size, unit and, where its name does not
    say it, what it holds; the optional entries with the ``observe`` name that adds them."""
    index, start = {}, 0
    for name, n in config.observation.layout():
        index[name] = f"{start}-{start + n - 1}"
        start += n
    what = {
        "error_log": f"e log-scaled, linear below {observation.ERROR_LOG_SCALE:g} rad",
        "preview": "q_des(t + k preview_dt), k = 1..P, A then B",
        "last_action": "the command applied last (the rest command after a reset)",
        observation.ERROR_RATE[0]: "dq_des - dq log-scaled as `error_log`, linear below "
        f"{observation.ERROR_RATE_LOG_SCALE:g} rad/s",
        observation.FEEDFORWARD[0]: "the normalized joint torques for the reference's "
        "acceleration over the next step",
        observation.FORCE_LIMIT[0]: "ln of the force limit in N",
        "arm": "the drawn fields, normalized to [-1, 1]",
    }
    entries = [(name, name, str(n), unit) for name, n, unit in observation.FIXED]
    entries += [
        ("preview", "preview", "2P", "rad"),
        ("last_action", "last_action", "n_actions", "1"),
    ]
    entries += [(key, name, str(n), unit) for (name, n, unit), key in observation.OPTIONAL.items()]
    entries += [("arm", "arm", "one per drawn field", "1")]
    rows = []
    for key, name, size, unit in entries:
        optional = key in observation.OBSERVABLE
        label = f"{code(name)} (observe {code(key)})" if optional else code(name)
        label += f": {what[name]}" if name in what else ""
        rows.append((index.get(name, index.get(key, "-")), label, size, unit))
    return table((f"index in {code(newest_id())}", "entry", "size", "unit"), rows)


def newest_config() -> EnvConfig:
    """Returns the config that ``gym.make`` of the newest id builds."""
    with quiet():
        env = gym.make(newest_id())
    config = env.unwrapped.config
    env.close()
    return config


def ids_table() -> list[str]:
    """Returns the table of the registered ids: spaces of the default env, contract hash (the
    action space in a line above it when every id has the same)."""
    rows = []
    for env_id in env_ids():
        with quiet():
            env = gym.make(env_id)
        rows.append(
            (
                code(env_id),
                code(repr(env.action_space)),
                code(env.observation_space.shape),
                code(env_contract_hash(env_id)),
            )
        )
        env.close()
    head = ("id", "action space", "observation shape", "env contract")
    if len({r[1] for r in rows}) > 1:
        return table(head, rows)
    return [
        f"Every id's action space is {rows[0][1]}; its observations are float64.",
        "",
        *table(head[:1] + head[2:], (r[:1] + r[2:] for r in rows)),
    ]


def changelog_headings(root: Path) -> list[str]:
    """Returns CHANGELOG.md's ``##`` headings."""
    path = root / "CHANGELOG.md"
    return re.findall(r"^## +(.+?) *$", path.read_text(), flags=re.M) if path.is_file() else []


def version_lines(root: Path) -> list[str]:
    """Returns one line per version of tendon2r_gym.VERSIONS: its id, contract, what its
    defaults change over the version before, and its changelog entry."""
    headings = changelog_headings(root)
    rows, before = [], None
    for version, defaults in tendon2r_gym.VERSIONS.items():
        env_id = f"{ENV_NAME}-{version}"
        config = EnvConfig.make("default", **defaults)
        if before is None:
            change = "the first id: each preset's values"
        else:
            changed = [
                f"{code(k)} {shown(getattr(before, k))} → {shown(getattr(config, k))}"
                for k in defaults
                if getattr(before, k) != getattr(config, k)
            ]
            change = ", ".join(changed) or "no default changed"
        entry = next((h for h in headings if re.search(rf"\b{re.escape(env_id)}\b", h)), None)
        name = f"[{code(env_id)}](changelog.md#{slugify(entry, '-')})" if entry else code(env_id)
        rows.append((name, change))
        before = config
    return table(("version (its changelog entry)", "defaults over the version before"), rows)


def env_page(root: Path = ROOT) -> str:
    """Returns docs/env.md."""
    template, own = own_arguments(docstring_template(Tendon2REnv))
    fields = {f for _, f, _, _ in string.Formatter().parse(template) if f}
    fills = {
        "obs_table": "\n".join(observation_table(newest_config())),
        "rewards": "\n".join(reward_table()),
        "arguments": "\n".join(arguments_table(own)),
    }
    if unknown := fields - set(fills):
        raise ValueError(f"the Tendon2REnv docstring has fields {sorted(unknown)} to fill")
    summary, found = sections(markdown_indent(template).format(**fills))
    if missing := [s for s in ENV_SECTIONS if s not in found]:
        raise ValueError(f"the Tendon2REnv docstring misses the sections {missing}")
    found["Version History"] = "\n".join(
        [
            "Each id's contract is pinned (tendon2r_gym.envs.contract): a change that can "
            "change learning results is a new version. The [changelog](changelog.md) has each "
            "release's details.",
            "",
            *version_lines(root),
            "",
            "Which PPO settings learn each id, and what to expect of them: "
            "[your own PPO settings](training.md#your-own-ppo-settings).",
        ]
    )
    lines = [
        header("the Tendon2REnv docstring, EnvConfig, tendon2r_gym.task and tendon2r_gym.VERSIONS"),
        "",
        "# The env: Tendon2R",
        "",
        f"![The default arm, rendered by MuJoCo]({asset(ARM_PICTURE)}){{ width=480 }}",
        "",
        summary,
        "",
        *code_block(
            [
                "import gymnasium as gym",
                "import tendon2r_gym  # registers the ids",
                "",
                f'env = gym.make("{newest_id()}")  # or preset="my_arm.yaml"',
            ],
            "python",
        ),
        "",
        "The registered ids, each made with its default arguments. Env contract: the hash of "
        "the env config that `gym.make(id)` builds, which a training run records and each "
        "[shipped model](models.md) names.",
        "",
        *ids_table(),
    ]
    for name in (*ENV_SECTIONS, *(s for s in found if s not in ENV_SECTIONS)):
        lines += ["", f"## {name}", "", found[name]]
    return page(lines)


def changelog_page(root: Path = ROOT) -> str:
    """Returns docs/changelog.md: CHANGELOG.md as it is."""
    path = root / "CHANGELOG.md"
    text = path.read_text() if path.is_file() else "# Changelog\n\nNo CHANGELOG.md yet.\n"
    return page([header("CHANGELOG.md"), "", text])
