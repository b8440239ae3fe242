"""Helpers of the documentation's tests: the scripts of ``docs/`` loaded as modules, and the Python
examples of documentation pages run as written (every ```python block and every ```{code-cell} python of
an executed page, in order, in one namespace per page, all pages in one child process).

The caller chooses the child's XLA flags: XLA's defaults for pages whose examples run long (the README's
study is 100 runs of 120 steps; ``xla_defaults_env`` of tests/conftest.py), the suite's compile-fast flags
for pages whose examples mostly compile. Blocks that need a dataset are written as ```{code-block} python
and are not run.
"""

from __future__ import annotations

import importlib.util
import json
import pathlib
import re
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def load_docs_script(name: str, module_name: str | None = None):
    """``docs/NAME.py`` (``generate``, ``check_links``) imported as a module, under ``module_name``."""
    spec = importlib.util.spec_from_file_location(module_name or name, DOCS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # a dataclass looks its module up while the module runs
    spec.loader.exec_module(module)
    return module


# A fenced Python block, or a code cell of an executed (myst-nb) page; its body is the group.
PYTHON_BLOCK = r"^```(?:python|\{code-cell\} python)\n(.*?)^```"

# Runs every page's Python blocks, one namespace per page, in one process, and prints one JSON line:
# {page: null, or the traceback of the block that failed}.
_RUN_EXAMPLES = """
import json, re, sys, traceback, types
from pathlib import Path
PATTERN = sys.argv[2]
outcomes = {}
for page in sys.argv[3:]:
    blocks = re.findall(PATTERN, (Path(sys.argv[1]) / page).read_text(), flags=re.S | re.M)
    module = types.ModuleType("docs_example")  # a real module: dataclasses look their class's module up
    sys.modules[module.__name__] = module
    try:
        for block in blocks:  # later blocks use what earlier ones defined
            exec(compile(block, page, "exec"), module.__dict__)
        outcomes[page] = None if blocks else "no Python example"
    except BaseException:
        outcomes[page] = traceback.format_exc()
print("OUTCOMES " + json.dumps(outcomes))
"""


def python_blocks(path: pathlib.Path) -> list[str]:
    """The ```python fenced blocks and ```{code-cell} python cells of a Markdown file (illustrations use
    ```text or ```{code-block})."""
    return re.findall(PYTHON_BLOCK, path.read_text(), flags=re.S | re.M)


def run_pages(pages: tuple[str, ...], cwd: pathlib.Path, env: dict[str, str]) -> dict[str, str | None]:
    """``{page: None, or the traceback of its block that failed}`` for ``pages`` (paths from the
    repository root), run in one child process in ``cwd`` with ``env`` (a non-interactive matplotlib)."""
    proc = subprocess.run(
        [sys.executable, "-c", _RUN_EXAMPLES, str(ROOT), PYTHON_BLOCK, *pages],
        cwd=cwd,
        env={**env, "MPLBACKEND": "Agg"},
        capture_output=True,
        text=True,
        timeout=1200,
    )
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("OUTCOMES ")]
    assert line, f"the examples' process printed no outcome (exit {proc.returncode}):\n{proc.stderr[-4000:]}"
    return json.loads(line[-1].removeprefix("OUTCOMES "))
