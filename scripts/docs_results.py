"""The results' pages, for scripts/gen_docs.py: docs/results.md (the benchmark's chart and
tables, results/benchmark.json by tendon2r_gym.app.report), docs/studies/<name>.md (each
study's own Markdown, research/results/<name>.md, as the study writes it: no research code is
imported) and docs/reports/<name>.md (each own-arm report, results/<name>/benchmark.json).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gen_figures
from docs_common import ROOT, asset, benchmark_reports, figure, header, relative_paths

from tendon2r_gym.app import report
from tendon2r_gym.app.markdown import code, indented, page, table
from tendon2r_gym.evaluation.metrics import smoothness_x_pd

#: The studies whose results have a page (``research/results/<name>.md``, where it exists),
#: linked from the results page in this order.  A study that writes its Markdown there needs
#: only its name here.
STUDIES = ("ten_seeds", "scale_up", "realism", "identification", "identification_out_of_sample",
           "envelope", "envelope_generalists", "clients")  # fmt: skip


#: A benchmark row's plots (tendon2r_gym.app.plots.plot_trace), by the link's label.
PLOTS = {"tracking": "tracking.png", "tensions": "forces.png", "path": "effector_path.png"}


def plot_links(root: Path, plots_dir: str, prefix: str = "") -> Callable[[dict[str, Any]], str]:
    """Returns the function that gives a row of a report its plots' links: the files that the
    benchmark wrote under ``plots_dir/<env>/<policy>/`` (links from a page ``prefix`` deep)."""

    def links(row: dict[str, Any]) -> str:
        folder = f"{plots_dir}/{row['env']}/{row['policy'].replace(' ', '_')}"
        return " · ".join(
            f"[{label}]({asset(f'{folder}/{file}', prefix)})"
            for label, file in PLOTS.items()
            if (root / folder / file).is_file()
        )

    return links


#: The results page's "how to read", above its chart; the rest is in a collapsed note.
HOW_TO_READ = [
    "PD, computed torque (CT) and PPO, plain and residual on PD, on the same episodes of each",
    "bundled preset: RMS tracking error per joint, lower is better (log scale; dots: each",
    "training seed). Each table row links its tracking, tension and path plots.",
]


#: The class of the block that holds a report's tables of figures: its cells do not wrap
#: (docs/stylesheets/extra.css), so that 4.4e-10 never breaks at its exponent's minus sign.
FIGURES = "figures"


def figures_block(lines: list[str]) -> list[str]:
    """Returns a report's sections inside a block of class FIGURES (md_in_html)."""
    return [f'<div class="{FIGURES}" markdown>', "", *lines, "", "</div>"]


def bundled_section(root: Path, result: dict[str, Any]) -> list[str]:
    """Returns the bundled presets' section (``tendon2r-benchmark``, results/benchmark.json)."""
    result = {**result, "rows": relative_paths(result["rows"])}
    return [
        "## The bundled presets",
        "",
        f"`results/benchmark.json`, produced by `{result['command']}` (`make benchmark`); the",
        "rows marked *quoted* are the [lab reports'](background.md) own figures.",
        "",
        *figures_block(
            report.bundled_sections(
                result, level=3, notes=[], plots=plot_links(root, "results/plots")
            )
        ),
        *profile_block(result["rows"]),
    ]


def profile_block(rows: list[dict[str, Any]]) -> list[str]:
    """Returns the performance profile of the learned rows over their seeds (if any)."""
    if not gen_figures.profile_ratios(rows):
        return []
    return [
        "",
        "### Performance profile",
        "",
        "Each learned policy's training seeds on every preset: the fraction whose worse joint's",
        "RMS error is at most tau times PD's (left of 1: better than PD on both joints), with",
        "stratified bootstrap bands, the presets as strata.",
        "",
        figure(gen_figures.PROFILE_FIGURE, "Performance profile of plain and residual PPO"),
    ]


def ten_seeds_section(root: Path) -> list[str]:
    """Returns the default preset's rows over ten training seeds (research/results/
    ten_seeds.json), if that study has run."""
    path = root / "research" / "results" / "ten_seeds.json"
    if not path.is_file():
        return []
    result = json.loads(path.read_text())
    return [
        "",
        "### Over ten training seeds",
        "",
        f"The `{result['preset']}` preset's two recipes, trained on {len(result['seeds'])} seeds "
        "each and evaluated on the same episodes as above",
        f"([the study](studies/ten_seeds.md), `{result['command']}`):",
        "",
        *report.seeds_table(result["rows"]),
    ]


def report_name(path: str) -> str:
    """Returns an own-arm report's name: its folder under results/."""
    return Path(path).parent.name


def own_arm_pages(root: Path = ROOT) -> dict[str, str]:
    """Returns docs/reports/<name>.md for each own-arm report results/<name>/benchmark.json
    (``tendon2r-benchmark --env-config FILE``): its tables, each row linking its plots."""
    out = {}
    for path, result in benchmark_reports(root).items():
        if path == "results/benchmark.json":
            continue
        result = {**result, "rows": relative_paths(result["rows"])}
        plots = plot_links(root, f"{Path(path).parent.as_posix()}/plots", "../")
        out[f"reports/{report_name(path)}.md"] = page(
            [
                header(path),
                "",
                f"# Your own arm: {report_name(path)}",
                "",
                f"`{path}`. How to read it: the [results](../results.md) page's note; the",
                "commands: [your own arm](../your_arm.md).",
                "",
                *figures_block(report.own_arm_sections(result, notes=[], plots=plots, level=2)),
            ]
        )
    return out


def study_pages(root: Path = ROOT) -> dict[str, str]:
    """Returns docs/studies/<name>.md for each study of STUDIES whose Markdown
    (research/results/<name>.md) exists: that file's text as the study wrote it."""
    out = {}
    for name in STUDIES:
        path = root / "research" / "results" / f"{name}.md"
        if path.is_file():
            text = path.read_text()
            out[f"studies/{name}.md"] = page(
                [header(f"research/results/{name}.md"), "", text, "", "[Results](../results.md)"]
            )
    return out


def study_title(text: str) -> str:
    """Returns a study page's title: its first ``#`` heading."""
    found = re.search(r"^# +(.+?) *$", text, flags=re.M)
    return found.group(1) if found else "(untitled)"


def studies_section(root: Path) -> list[str]:
    """Returns the results page's list of the studies' pages, each with the command its page
    says made it."""
    pages = study_pages(root)
    if not pages:
        return []
    rows = []
    for file, text in pages.items():
        # the command the page says made it (a study's arm set has its flag), else its module
        made = re.search(r"`(python -m research\.studies\.[^`]+)`", text)
        command = made.group(1) if made else f"python -m research.studies.{Path(file).stem}"
        rows.append((f"[{study_title(text)}]({file})", code(command)))
    return [
        "## Studies",
        "",
        "Each study's own report (`research/results/<name>.md`), on a page of its own:",
        "",
        *table(("study", "command"), rows),
    ]


def results_page(root: Path = ROOT) -> str:
    """Returns docs/results.md."""
    reports = benchmark_reports(root)
    main = reports.pop("results/benchmark.json", None)
    lines = [
        header("results/benchmark.json, results/*/benchmark.json and research/results/*.md"),
        "",
        "# Results",
        "",
        *HOW_TO_READ,
        "",
    ]
    if main is None:
        lines += ["`results/benchmark.json` is missing: `make benchmark` writes it."]
    else:
        lines += [
            figure(gen_figures.RESULTS_FIGURE, "RMS error per joint by policy and preset"),
            "",
            '??? note "How to read the tables"',
            "",
            *indented(report.NOTES),
            "",
            *bundled_section(root, main),
            *ten_seeds_section(root),
        ]
    lines += ["", *studies_section(root)]
    if reports:
        rows = [
            (f"[{report_name(path)}](reports/{report_name(path)}.md)", code(result["command"]))
            for path, result in reports.items()
        ]
        lines += [
            "",
            "## Your own arm",
            "",
            "`tendon2r-benchmark --env-config FILE` trains both PPO variants on an experiment",
            "file and compares them with PD, CT and the generalists ([Your own arm](your_arm.md)).",
            "The example arms' reports:",
            "",
            *table(("report", "command"), rows),
        ]
    return page(lines)


#: The ids the training page's clients summary covers, in its order.
CLIENT_IDS = ("Tendon2R-v2", "Tendon2RResidual-v2")


def clients_block(root: Path = ROOT) -> list[str]:
    """Returns the training page's summary of the clients study
    (research/results/clients.json): per id and client, on how many seeds the trained policy
    is better than PD on both joints, the step it first was, and its tension rate against
    PD's (smoothness_x_pd)."""
    path = root / "research" / "results" / "clients.json"
    if not path.is_file():
        return ["The clients study has not run: `python -m research.studies.clients`."]
    result = json.loads(path.read_text())
    lines = []
    for setting in CLIENT_IDS:
        for client, what in result["clients"].items():
            runs = [r for r in result["runs"] if r["setting"] == setting and r["client"] == client]
            if not runs:
                continue
            steps = max(r["steps"] for r in runs)
            runs = [r for r in runs if r["steps"] == steps]
            wins = [r["first_beats_pd_steps"] for r in runs if r["final"]["beats_pd"]]
            rates = [smoothness_x_pd(r["final"], r["pd"])[1] for r in runs]
            first = f", first at {_span(wins, ',')} steps" if wins else ""
            lines.append(
                f"- `{setting}`, {what}: after {steps:,} steps, better than PD on both joints on "
                f"{len(wins)} of {len(runs)} seed{'s' * (len(runs) > 1)}{first}; tension rate "
                f"{_span(rates, '.1f')} times PD's."
            )
    source = "Generated by scripts/gen_docs.py from research/results/clients.json."
    return ["", *lines, "", f"_{source}_", ""]


def _span(values: list[float], spec: str) -> str:
    """Returns "x" or "x to y" for the least and largest of ``values``."""
    lo, hi = format(min(values), spec), format(max(values), spec)
    return lo if lo == hi else f"{lo} to {hi}"


#: The candidates study's rows, named on the real-tendons page (others: a candidate model).
REFERENCE_LABELS = {
    "ct": "CT: the nominal model's inverse dynamics, PD tuned's feedback",
    "ct_floor": "the floor: CT with no delays, motor lag or pulley friction",
}


def references_block(root: Path = ROOT) -> list[str]:
    """Returns the real-tendons page's comparison of the shipped realism models, the
    candidates tried for them and the classical references on the one-geometry arms of the
    envelope study (research/results/candidates.json, `python -m research.studies.candidates`)."""
    from tendon2r_gym.artifacts.bundle import bundle_names

    path = root / "research" / "results" / "candidates.json"
    if not path.is_file():
        return ["The candidates study has not run: `python -m research.studies.candidates`."]
    result = json.loads(path.read_text())
    shipped = set(bundle_names())
    floor = result["summary"]["ct_floor"]["one_geometry"]["median_ratio"]
    rows = []
    for name, kinds in result["summary"].items():
        s = kinds.get("one_geometry", {})
        if "median_ratio" not in s:
            continue
        label = REFERENCE_LABELS.get(name) or (
            f"`{name}` (shipped)" if name in shipped else f"`{name}` (a candidate, not shipped)"
        )
        to = s["median_ratio_to"]
        rows.append([
            label,
            f"{s['beats_pd_tuned']} of {s['arms'] - s['refused']}",
            f"{s['median_ratio']:.3f} / {s['max_ratio']:.3f}",
            f"{to['ct']:.3f} / {to['ct_floor']:.3f}",
            f"{s['median_tension_x']:.2f}",
            f"{s['median_rate_x']:.2f}",
            f"{(1 - s['median_ratio']) / (1 - floor):.2f}",
        ])  # fmt: skip
    head = [
        "controller",
        "<= PD tuned on both joints",
        "worst-joint ratio to PD tuned: median / largest",
        "median ratio to CT / to the floor",
        "RMS tension x PD tuned, median",
        "tension rate x PD tuned, median",
        "of the way from PD tuned (0) to the floor (1), medians",
    ]
    source = (f"Generated by scripts/gen_docs.py from research/results/candidates.json "
              f"(`{result['command']}`).")  # fmt: skip
    return ["", *table(head, rows), "", f"_{source}_", ""]


#: The identification study's arm sets on the identify page: its results' stem, and a label.
IDENTIFICATION_SETS = {
    "identification": "its own 16 arms",
    "identification_out_of_sample": "16 arms out of sample (wrong nominal motor mass, loop "
    "delay 0 to 3 ms)",
}
#: The summary lines of an identification study's page that the identify page quotes.
IDENTIFICATION_LINES = ("Unflagged fields", "PD: ", "residual: ", "CT: ", "The residual keeps")


def identification_block(root: Path = ROOT) -> list[str]:
    """Returns the identify page's summary of the identification study: for each arm set that
    has run, the summary lines of its page (research/results/<stem>.md), quoted as written."""
    out = []
    for stem, label in IDENTIFICATION_SETS.items():
        path = root / "research" / "results" / f"{stem}.md"
        if not path.is_file():
            continue
        quoted = [
            f"- {line}"
            for line in path.read_text().splitlines()
            if line.startswith(IDENTIFICATION_LINES)
        ]
        out += ["", f"On {label} ([its page](studies/{stem}.md)):", "", *quoted]
    if not out:
        return ["The identification study has not run: `python -m research.studies.identification`"]
    return [*out, "", "_Quoted by scripts/gen_docs.py from the study's pages._", ""]
