"""Sphinx configuration of the jaxnav documentation.

Build: ``sphinx-build -W --keep-going -n -b html docs docs/_build/html`` (the ``docs`` extra).
Before reading the sources, :mod:`generate` writes the API pages, the reproduction pages and the
benchmark pages into ``docs/_generated`` from the package and the committed JSON results, so every
table and figure there comes from ``benchmarks/results/``.
"""

from __future__ import annotations

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path[:0] = [ROOT, HERE]  # the package and the benchmark harness from this checkout; generate.py

import importlib  # noqa: E402
import re  # noqa: E402
import typing  # noqa: E402

import generate  # noqa: E402
import jax  # noqa: E402

import jaxnav  # noqa: E402

project = "jaxnav"
author = "jaxnav developers"
copyright = "2026, jaxnav developers"
release = jaxnav.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",  # MathJax copied into the site: its maths render without a network
    "myst_nb",
    "sphinx_copybutton",
]

myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
# The notebooks of notebooks/ are committed with their outputs (and executed by the test suite); the family
# guides are executed pages (MyST notebooks: ``execution_mode: cache`` in their front matter), run by the
# build and cached under _build/.jupyter_cache, so a build fails when one of their cells does.
nb_execution_mode = "off"
nb_execution_raise_on_error = True
nb_execution_show_tb = True
nb_execution_timeout = 600  # s per cell
nb_merge_streams = True

autodoc_member_order = "bysource"
autodoc_typehints = "signature"
# Defaults as written (``dtype=jnp.float32``), not as their repr, which Sphinx cannot parse.
autodoc_preserve_defaults = True
autodoc_default_options = {"members": True, "show-inheritance": True}
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
napoleon_attr_annotations = True

# Every cross-reference inside jaxnav must resolve (-n). References to other projects' objects are not
# checked: the build runs without a network, so their inventories cannot be fetched.
nitpicky = True
nitpick_ignore_regex = [
    (r"py:.*", r"(jax|jaxlib|numpy|np|jnp|chex|optax|matplotlib|collections|typing|types|enum|dataclasses)(\..*)?"),
    (r"py:.*", r"(Array|ArrayLike|PRNGKeyArray|PyTree|Any|Callable|Sequence|Mapping|Iterable|Iterator|NamedTuple)"),
    (r"py:.*", r"(int|float|bool|str|bytes|dict|list|tuple|object|None|type|complex|Ellipsis)"),
    (r"py:.*", r"(ValueError|TypeError|KeyError|FileNotFoundError|RuntimeError|OSError|ImportError)"),
    (r"py:.*", r"(os|pathlib)(\..*)?"),
    (r"py:.*", r"jaxnav(\.\w+)*\._\w+"),  # private names (type variables such as memory._F) are not documented
]

# reproductions/ and benchmarks/ hold the texts generate.py puts into the generated pages.
exclude_patterns = ["_build", "**.ipynb_checkpoints", "jupyter_execute", "reproductions", "benchmarks"]
source_suffix = {".md": "myst-nb", ".ipynb": "myst-nb", ".rst": "restructuredtext"}

html_theme = "furo"
html_title = f"jaxnav {release}"
html_static_path = []
html_theme_options = {
    "source_repository": "",
    "navigation_with_keys": True,
}
suppress_warnings = ["myst.header"]


def _document_custom_derivatives() -> None:
    """Document functions wrapped in ``jax.custom_jvp``/``custom_vjp`` (``fastmath.sincos``, …) as functions.

    autodoc does not see them as routines and leaves them out of the module pages. The hook it asks is
    private to Sphinx 9; with another version the build goes on without it (those few functions are
    then missing from the API pages, and the references to them fail the build).
    """
    try:
        from sphinx.ext.autodoc._dynamic import _member_finder
    except ImportError:
        return
    best = _member_finder._best_object_type_for_member

    def with_custom_derivatives(member, member_name, is_attr, *, parent_obj_type, parent_props):
        if parent_obj_type == "module" and isinstance(member, (jax.custom_jvp, jax.custom_vjp)):
            return "function"
        return best(member, member_name, is_attr, parent_obj_type=parent_obj_type, parent_props=parent_props)

    _member_finder._best_object_type_for_member = with_custom_derivatives


_document_custom_derivatives()


def _resolve_namedtuple_annotations(app) -> None:
    """A NamedTuple's generated ``__new__`` keeps its string annotations unresolved (``lm.RangeBearingObs``,
    ``tuple[int, ...]``), so the class signature would show text, not links: give it the resolved ones."""
    for name in generate.public_modules():
        module = importlib.import_module(name)
        for obj in vars(module).values():
            if isinstance(obj, type) and issubclass(obj, tuple) and hasattr(obj, "_fields") and obj.__module__ == name:
                try:
                    obj.__new__.__annotations__ = typing.get_type_hints(obj)
                except (NameError, TypeError):  # an annotation that cannot be evaluated stays text
                    continue


def _skip_namedtuple_fields(app, what, name, obj, skip, options):
    """NamedTuple fields are documented by their class's ``Attributes:`` section, not again as members; so
    are dataclass fields whose default is a function of another name (``FilterSpec.prepare``), which
    autodoc would otherwise take for a method."""
    doc = getattr(obj, "__doc__", None) or ""
    if what == "class" and doc.startswith("Alias for field number"):
        return True
    if what == "class" and callable(obj) and getattr(obj, "__name__", name) != name:
        return True
    return None


_SENSOR_DEFAULT = re.compile(r"\('(\w+)'(?:, <function \w+>)+\)")


def _short_sensor_defaults(app, what, name, obj, options, signature, return_annotation):
    """A default that is a sensor object (a NamedTuple of functions, e.g. ``MCLConfig.sensor``) is shown as
    its repr, ``ParticleSensor('range_bearing')``, not as the tuple of its functions, which the signature
    parser cannot read."""
    if signature:
        signature = _SENSOR_DEFAULT.sub(r"ParticleSensor('\1')", signature)
    return _public_array_signature(app, what, name, obj, options, signature, return_annotation)


# ``jax.Array`` is defined in a private module, and autodoc names a class by its module and qualified name:
# ``jax.jaxlib._jax.Array``. Users write, and the docs show, the public name.
_PRIVATE_ARRAY = re.compile(r"\b(?:jax\.)?jaxlib\._jax\.Array\b")


def _public_array_signature(app, what, name, obj, options, signature, return_annotation):
    """Signatures and return annotations show ``jax.Array``, not ``jax.jaxlib._jax.Array``. Called by
    :func:`_short_sensor_defaults`: Sphinx takes the first answer of the ``autodoc-process-signature``
    handlers, so there is one."""
    if signature:
        signature = _PRIVATE_ARRAY.sub("jax.Array", signature)
    if return_annotation:
        return_annotation = _PRIVATE_ARRAY.sub("jax.Array", return_annotation)
    return signature, return_annotation


def _public_array_docstring(app, what, name, obj, options, lines):
    """The types napoleon writes for a class's attributes (``:type:``) show ``jax.Array`` too."""
    lines[:] = [_PRIVATE_ARRAY.sub("jax.Array", line) for line in lines]


def setup(app):
    app.connect("autodoc-process-signature", _short_sensor_defaults)
    app.connect("autodoc-process-docstring", _public_array_docstring, priority=600)  # after napoleon (500)
    app.connect("builder-inited", lambda app: generate.main(HERE, ROOT))
    app.connect("autodoc-skip-member", _skip_namedtuple_fields)
    app.connect("builder-inited", _resolve_namedtuple_annotations)
