"""Write the generated pages of the documentation into ``docs/_generated``.

* ``api/``: one page per public module of :mod:`jaxnav` (autodoc), found by walking the package, so a
  new module gets its page without editing the docs; one page per group of modules (:data:`API_GROUPS`:
  core, models, simulators, …, and the internals last), each module in the group of its subpackage; and
  the index of the groups;
* ``reproductions/``: one page per registered experiment, its table and figure made from
  ``benchmarks/results/experiments/NAME.json`` by the experiment's own ``markdown`` and ``plot``,
  with a count of where the thesis value falls against our 95 % interval, and the hand-written
  notes of ``docs/reproductions/notes/NAME.md`` where there are any; and the page "Where we differ from
  the theses" (``docs/differences.py``), its numbers and verdicts read from the same results;
* ``benchmarks/``: the tables (:func:`benchmarks.markdown.tables`) and plots
  (:func:`benchmarks.plot.plot_all`) of every results file in ``benchmarks/results/``.

Run by ``conf.py`` before every build; ``python docs/generate.py`` runs it alone.
"""

from __future__ import annotations

import importlib
import json
import os
import pkgutil
import re
import shutil
import sys

# Results files shown on the benchmark page, in order, with the title of their section.
BENCHMARK_FILES = (
    ("speed/rng_after.json", "MCL and SLAM steps: W2, W2b, S2"),
    ("speed/rng_w1_after.json", "Resampling at N = 10³ and 10⁴: W1"),
    ("speed/after_w4.json", "Linear Kalman filter: W4"),
    ("classical.json", "Classical filters: W3 and W4"),
    ("hf_slam.json", "HF-RFID SLAM: S1 and S2"),
    ("uhf.json", "UHF-RFID tag filter: U1"),
    ("w1.json", "Resampling, all schemes and sizes: W1"),
)


def _write(path: str, text: str) -> None:
    """Write ``text`` unless the file already holds it (an unchanged page is not rebuilt)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    if os.path.exists(path):
        with open(path) as f:
            if f.read() == text:
                return
    with open(path, "w") as f:
        f.write(text)


def public_modules() -> list[str]:
    """Every module of :mod:`jaxnav` whose dotted name has no part starting with ``_``."""
    import jaxnav

    names = ["jaxnav"]
    for info in pkgutil.walk_packages(jaxnav.__path__, "jaxnav."):
        if not any(part.startswith("_") for part in info.name.split(".")):
            names.append(info.name)
    return sorted(names)


def _defines(module_name: str, member: str) -> bool:
    """Whether the source of ``module_name`` assigns ``member`` at its top level (``X = Y``, ``X: T = Y``)."""
    import ast
    import inspect

    try:
        tree = ast.parse(inspect.getsource(importlib.import_module(module_name)))
    except (OSError, TypeError):
        return False
    for node in tree.body:
        targets = (
            node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        )
        if any(isinstance(t, ast.Name) and t.id == member for t in targets):
            return True
    return False


def documented_elsewhere(name: str, modules: set[str]) -> list[str]:
    """The names ``name`` exports (``__all__``) that another public module defines, and documents.

    A class or function is at home in its ``__module__``; an alias (``KalmanParams = LandmarkMapParams``,
    re-exported by another filter) in the public module that assigns it under that name and exports it.
    """
    module = importlib.import_module(name)
    out = []
    for member in getattr(module, "__all__", ()):
        obj = getattr(module, member, None)
        if home_of(name, member, obj, modules) != name:
            out.append(member)
    return out


def home_of(name: str, member: str, obj, modules: set[str]) -> str:
    """The public module that documents ``member`` (the object ``obj``) of module ``name``: ``name`` itself
    unless another public module defines it."""
    home = getattr(obj, "__module__", None) if callable(obj) else None  # a constant's is its type's
    if home != name and home in modules and getattr(importlib.import_module(home), member, None) is obj:
        return home
    if isinstance(obj, type) and obj.__name__ != member and not _defines(name, member):  # an imported alias
        for other in sorted(modules - {name}):
            mod = importlib.import_module(other)
            if vars(mod).get(member) is obj and member in getattr(mod, "__all__", ()) and _defines(other, member):
                return other
    return name


# The groups of the API reference, in order: (key, title, what it holds). A module belongs to the group of
# the subpackage it is in (``jaxnav.slam.fastslam``: ``slam``), a module directly under ``jaxnav`` to
# ``tools``; a new subpackage with no group here gets a group of its own, so that every public module
# has its page and its place in the index without editing the docs. ``jaxnav`` itself is under ``core``.
API_GROUPS = (
    (
        "core",
        "Core",
        "The package, and the engine every filter is built on: log-weights, resampling, the filter "
        "skeleton, Kalman primitives, random numbers, batch Monte Carlo, sharding.",
    ),
    ("models", "Models", "Motion models and sensor models: landmarks, range-only beacons, HF- and UHF-RFID, IR."),
    ("sim", "Simulators", "Simulated worlds and hardware that produce the data the filters read."),
    (
        "localization",
        "Localization",
        "Filters that estimate the robot's pose (or a tag's position) with a "
        "known map: MCL and its variants, EKF, UKF, grid, RFID.",
    ),
    (
        "slam",
        "SLAM",
        "Filters that estimate the robot's path and the map together: EKF-SLAM, FastSLAM, PF-SLAM, PS-SLAM.",
    ),
    (
        "experiments",
        "Experiments",
        "The reproduction studies and the real-data experiments, and the machinery "
        "that runs them (registry, sweeps, statistics, reports).",
    ),
    ("io", "IO", "Dataset loaders and their conversion to filter steps."),
    ("tools", "Calibration, metrics and demo", "Fitting parameters to data, scoring estimates, and the demo."),
)

# Modules the library uses itself and a user does not call; their names may change without notice. They
# keep their pages (other pages link to their functions) under the group ``internals``, listed last.
INTERNAL_MODULES = re.compile(
    r"jaxnav\.(cli|core\.(u64|fastmath|host_checks|integer_cdf)|experiments\.\w+\.(figures|tables))"
)
INTERNALS = (
    "internals",
    "Internals",
    "Modules the library uses itself, not meant to be called: the command line's implementation, the exact "
    "integer arithmetic under resampling, the host-side checks of the filters, and the experiments' "
    "registrations of tables and figures (run them by name with {mod}`jaxnav.experiments.registry`). Their "
    "names may change without notice.",
)


def is_internal(name: str) -> bool:
    """Whether module ``name`` is one of the internals (:data:`INTERNAL_MODULES`)."""
    return INTERNAL_MODULES.fullmatch(name) is not None


def api_group(name: str, modules: list[str] | set[str]) -> str:
    """The key of the group module ``name`` is listed under (see :data:`API_GROUPS`)."""
    if is_internal(name):
        return INTERNALS[0]
    parts = name.split(".")
    if len(parts) == 1:
        return "core"
    package = ".".join(parts[:2])
    known = {key for key, *_ in API_GROUPS} - {"tools"}
    if parts[1] in known or len(parts) > 2 or any(m.startswith(package + ".") for m in modules):
        return parts[1]  # the subpackage's group: one of API_GROUPS, or a new one
    return "tools"  # a module directly under jaxnav


def api_groups(modules: list[str]) -> list[tuple[str, str, str, list[str]]]:
    """``(key, title, blurb, modules)`` of every non-empty group, in the order of the index: the groups of
    :data:`API_GROUPS`, then any subpackage with no group there, then the internals."""
    members: dict[str, list[str]] = {}
    for name in modules:
        members.setdefault(api_group(name, modules), []).append(name)
    new = [(key, f"`jaxnav.{key}`", "") for key in members if key not in {k for k, *_ in API_GROUPS} | {INTERNALS[0]}]
    return [(key, title, blurb, members[key]) for key, title, blurb in [*API_GROUPS, *new, INTERNALS] if key in members]


def short_title(name: str, group: str) -> str:
    """The module's title in the sidebar, under its group's heading: its name inside the group's package
    (``mcl`` for ``jaxnav.localization.mcl``), inside ``jaxnav`` for the tools, and for the internals
    inside ``jaxnav`` or ``jaxnav.experiments`` (``core.u64``, ``hf_slam.figures``). Short, so that the
    sidebar, which breaks a name too long for it anywhere, need not break it."""
    if name == f"jaxnav.{group}":
        return group
    for prefix in (f"jaxnav.{group}.", "jaxnav.experiments." if group == INTERNALS[0] else "jaxnav.", "jaxnav."):
        if name.startswith(prefix):
            return name.removeprefix(prefix)
    return name


def write_api(out: str) -> None:
    modules = public_modules()
    for name in modules:
        body = f"# `{name}`\n\n"
        if is_internal(name):
            body += (
                "```{note}\nAn internal module: the library uses it itself, and its names may change without "
                "notice. It is documented for the pages that link to it.\n```\n\n"
            )
        body += f"```{{eval-rst}}\n.. automodule:: {name}\n   :members:\n"
        elsewhere = documented_elsewhere(name, set(modules))
        if elsewhere:
            body += f"   :exclude-members: {', '.join(elsewhere)}\n"
        body += "```\n"
        if elsewhere:
            module = importlib.import_module(name)
            body += (
                "\nAlso exported here, documented where they are defined: "
                + ", ".join(f"{{py:obj}}`~{home_of(name, n, module.__dict__[n], set(modules))}.{n}`" for n in elsewhere)
                + ".\n"
            )
        _write(os.path.join(out, "api", f"{name}.md"), body)
    groups = api_groups(modules)
    lines = [
        "# API reference\n\n",
        "Every public module, with the docstrings of its functions and classes, grouped by what it is for. "
        "The internals, last, are modules the library uses itself.\n",
    ]
    for key, title, blurb, names in groups:
        lines.append(f"\n## [{title}](group-{key}.md)\n\n")
        if blurb:
            lines.append(blurb + "\n\n")
        lines += [f"- [`{n}`]({n}.md)\n" for n in names]
        page = [f"# {title}\n\n", blurb + "\n\n" if blurb else ""]
        page += [f"- [`{n}`]({n}.md)\n" for n in names]
        page.append("\n```{toctree}\n:hidden:\n\n")
        page += [f"{short_title(n, key)} <{n}>\n" for n in names]
        page.append("```\n")
        _write(os.path.join(out, "api", f"group-{key}.md"), "".join(page))
    lines.append("\n```{toctree}\n:hidden:\n\n" + "".join(f"group-{key}\n" for key, *_ in groups) + "```\n")
    _write(os.path.join(out, "api", "index.md"), "".join(lines))


def _thesis_checks(obj, found: list[tuple[float, float, float]]) -> None:
    """Collect ``(mean, low, high)`` triples' positions against the thesis value (``paper``)."""
    if isinstance(obj, dict):
        if {"mean", "ci95", "paper"} <= obj.keys() and obj["paper"] is not None and obj["ci95"] is not None:
            low, high = obj["ci95"]
            if None not in (low, high, obj["mean"]):
                found.append((float(obj["paper"]), float(low), float(high)))
            return
        for v in obj.values():
            _thesis_checks(v, found)
    elif isinstance(obj, list):
        for v in obj:
            _thesis_checks(v, found)


def thesis_counts(result: dict) -> tuple[int, int, int, int]:
    """``(values, inside, above, below)``: the thesis values of ``result`` against our 95 % intervals."""
    found: list[tuple[float, float, float]] = []
    _thesis_checks(result.get("rows", result.get("curves", [])), found)
    inside = sum(low <= p <= high for p, low, high in found)
    above = sum(p > high for p, low, high in found)
    below = sum(p < low for p, low, high in found)
    return len(found), inside, above, below


def thesis_summary(result: dict) -> str:
    """One sentence: how many thesis values lie inside, below or above our 95 % intervals."""
    n, inside, above, below = thesis_counts(result)
    if not n:
        return ""
    return (
        f"Of the {n} values the thesis reports, {inside} lie inside our 95 % interval, "
        f"{above} above it (the thesis's error is larger than ours) and {below} below it "
        "(the thesis's error is smaller)."
    )


def runs_needed(name: str, result: dict) -> int:
    """Runs per setting a reproduction page should rest on: 50 per point of a figure, 100 per table cell."""
    return 50 if "curves" in result or name.startswith("fig-") else 100


def write_reproductions(out: str, root: str, docs: str) -> list[tuple[str, str, int, str]]:
    import matplotlib

    matplotlib.use("Agg")
    from jaxnav.experiments import registry

    results_dir = os.path.join(root, "benchmarks", "results", "experiments")
    notes_dir = os.path.join(docs, "reproductions", "notes")
    index = []
    for name, exp in registry.experiments().items():
        path = os.path.join(results_dir, f"{name}.json")
        if not os.path.exists(path):
            raise FileNotFoundError(f"{path}: no committed result for the registered experiment {name!r}")
        with open(path) as f:
            result = json.load(f)
        png = os.path.join(out, "reproductions", f"{name}.png")
        os.makedirs(os.path.dirname(png), exist_ok=True)
        if not os.path.exists(png) or os.path.getmtime(png) < os.path.getmtime(path):
            exp.plot(result, png)
        summary = thesis_summary(result)
        needed = runs_needed(name, result)
        lines = [
            f"# {name}\n\n",
            f"{exp.title}.\n\n",
            f"`jaxnav experiments run {name} --runs {result['runs']} --out DIR` reruns it; this page is made "
            f"from the committed `benchmarks/results/experiments/{name}.json` ({result['runs']} runs per "
            "setting).\n\n",
        ]
        if result["runs"] < needed:
            lines.append(
                f"```{{warning}}\nThese results rest on {result['runs']} runs per setting, fewer than the "
                f"{needed} this page is meant to show: the intervals are wide, and a difference from the "
                "thesis inside them is not evidence of one.\n```\n\n"
            )
        if summary:
            lines.append(summary + "\n\n")
        note = os.path.join(notes_dir, f"{name}.md")
        if os.path.exists(note):
            with open(note) as f:
                lines.append(f.read().strip() + "\n\n")
        lines.append(f"![{name}]({name}.png)\n\n")
        lines.append(exp.markdown(result).strip() + "\n")
        _write(os.path.join(out, "reproductions", f"{name}.md"), "".join(lines))
        index.append((name, exp.title, int(result["runs"]), thesis_counts(result)))
    return index


def _intro(docs: str, name: str) -> str:
    """The hand-written text that opens a generated index page (``docs/NAME.md``)."""
    with open(os.path.join(docs, name)) as f:
        return f.read().strip() + "\n\n"


def write_differences(out: str, root: str, docs: str) -> None:
    """``reproductions/differences.md``: the claims the experiments do not reproduce (``docs/differences.py``)."""
    sys.path.insert(0, docs)
    try:
        differences = importlib.import_module("differences")
    finally:
        sys.path.remove(docs)
    results = {}
    files = [(n, f"{n}.json") for n in differences.needed_experiments()]
    files += [(f"{n}.runs", f"{n}.runs.json") for n in differences.RUNS_NEEDED]
    experiments = os.path.join(root, "benchmarks", "results", "experiments")
    files += [
        (n, f"{n}.json")
        for n in differences.OPTIONAL_EXPERIMENTS
        if os.path.exists(os.path.join(experiments, f"{n}.json"))
    ]
    for key, file in files:
        with open(os.path.join(experiments, file)) as f:
            results[key] = json.load(f)
    _write(os.path.join(out, "reproductions", "differences.md"), differences.page(results))


def write_reproduction_index(out: str, docs: str, index) -> None:
    lines = [
        _intro(docs, "reproductions/intro.md"),
        "Where our results and the theses' part, and what the experiments say about why: "
        "[Where we differ from the theses](differences.md).\n\n",
        "| experiment | what | runs per setting | thesis values inside / above / below our interval |\n",
        "| --- | --- | --- | --- |\n",
    ]
    for name, title, runs, (n, inside, above, below) in index:
        counts = f"{inside} / {above} / {below} of {n}" if n else "–"
        lines.append(f"| [{name}]({name}.md) | {title} | {runs} | {counts} |\n")
    lines.append("\n```{toctree}\n:hidden:\n\ndifferences\n" + "".join(f"{n}\n" for n, *_ in index) + "```\n")
    _write(os.path.join(out, "reproductions", "index.md"), "".join(lines))


def _without_provenance(text: str, rel: str) -> str:
    """The tables' header names the machine and versions; drop the source revision and the path the run
    wrote to (a results file is committed as ``benchmarks/results/REL``)."""
    text = re.sub(r"jaxnav [0-9a-f]{7,40}(\+[^,]*)?, ", "", text)
    return re.sub(r"--out \S+?(`|\s)", lambda m: f"--out benchmarks/results/{rel}{m.group(1)}", text)


def write_benchmarks(out: str, root: str, docs: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from benchmarks import markdown, plot
    from benchmarks.workloads import discover

    workloads = discover()
    lines = [_intro(docs, "benchmarks/intro.md")]
    for rel, title in BENCHMARK_FILES:
        src = os.path.join(root, "benchmarks", "results", rel)
        with open(src) as f:
            payload = json.load(f)
        stem = rel.replace("/", "_").removesuffix(".json")
        copy = os.path.join(out, "benchmarks", stem + ".json")
        os.makedirs(os.path.dirname(copy), exist_ok=True)
        fresh = os.path.exists(copy) and os.path.getmtime(copy) >= os.path.getmtime(src)
        if not fresh:
            shutil.copyfile(src, copy)
        pngs = sorted(p for p in os.listdir(os.path.dirname(copy)) if p.startswith(stem + "_") and p.endswith(".png"))
        if not fresh or not pngs:
            pngs = [os.path.basename(p) for p in plot.plot_all(payload, copy, workloads)]
        lines.append(
            f"## {title}\n\nFrom `benchmarks/results/{rel}`. {_without_provenance(markdown.tables(payload), rel)}\n\n"
        )
        lines += [f"![{p}]({p})\n\n" for p in pngs]
    _write(os.path.join(out, "benchmarks", "index.md"), "".join(lines))


def main(docs: str, root: str) -> None:
    out = os.path.join(docs, "_generated")
    write_api(out)
    write_reproduction_index(out, docs, write_reproductions(out, root, docs))
    write_differences(out, root, docs)
    write_benchmarks(out, root, docs)


if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    sys.path[:0] = [os.path.dirname(here)]
    main(here, os.path.dirname(here))
