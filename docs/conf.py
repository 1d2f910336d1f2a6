"""Sphinx configuration of hilbench's documentation site (``make docs``).

The pages are Markdown (MyST-Parser); the API reference (``api/``) is generated from the docstrings by
autosummary, one page per module, into ``api/_generated/`` (git-ignored, rebuilt on every run). The
build runs with ``-W -n``: every warning, a cross-reference that resolves to nothing too, fails it.
There is no intersphinx (the build needs no network): names of the standard library and of
third-party packages are let through by ``nitpick_ignore_regex`` below instead of being linked.
"""

import importlib
import importlib.metadata
import re
import sys
import types
from pathlib import Path

import sphinx.ext.autosummary

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "docs" / "_ext"))
# autosummary imports every submodule to list it, and importing hilbench.cli.__main__ runs the command
# (with sphinx's arguments): an empty stand-in is imported instead (a private module: no page).
sys.modules.setdefault("hilbench.cli.__main__", types.ModuleType("hilbench.cli.__main__"))

import labgrid_stand_ins  # noqa: E402 (docs/_ext, on the path just above)

project = "hilbench"
author = "the hilbench authors"
copyright = "the hilbench authors"

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.viewcode",
    "myst_parser",
    "pyrefs",  # docs/_ext/pyrefs.py: names in docstrings and signatures resolved as Python resolves them
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
templates_path = ["_templates"]
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

html_theme = "furo"
html_title = "hilbench"
# The table of contents lists pages and their sections, not every class and function of the reference
# (the module page lists them): with ~230 module pages a toctree of every object makes each page's
# navigation, and the build, many times slower.
toc_object_entries = False


def _navigation_but_on_source_pages(context):
    """furo builds the whole site's navigation tree for every page, the ~230 highlighted module sources
    (viewcode's ``_modules/``) too: a fifth of the build. Those pages get none (their "[docs]" links lead
    back); every other page keeps it."""
    if str(context.get("pagename", "")).startswith("_modules/"):
        return ""
    return _furo_navigation(context)


try:
    import furo

    _furo_navigation = furo._compute_navigation_tree
    furo._compute_navigation_tree = _navigation_but_on_source_pages
except (ImportError, AttributeError):  # another furo: the full navigation everywhere, a slower build
    pass

# Markdown: GitHub-style heading anchors (so `page.md#a-heading` links work as they do on GitHub and are
# checked), and the fences and roles the pages use.
myst_heading_anchors = 6
myst_enable_extensions = ["colon_fence", "deflist"]

# API reference: one page per module (docs/_templates/autosummary/module.rst), members defined in that
# module only (a re-export is documented where it is defined, so nothing is described twice).
autosummary_generate = True
autosummary_generate_overwrite = True
autodoc_default_options = {
    "members": True,
    "undoc-members": True,
    "show-inheritance": True,
    "ignore-module-all": True,
}
autodoc_member_order = "bysource"


def _modules_first(name, grouped_exception=True):
    """A hilbench name that is a module is that module. ``hilbench.monitor.can`` imports the function
    ``summary`` from its module ``summary``: the package's attribute hides the module, and autosummary
    (which follows attributes) would make the module's page the function's."""
    if name.startswith("hilbench.") and "__main__" not in name:
        try:
            return importlib.import_module(name), None, name
        except ImportError:
            pass
    return _import_by_name(name, grouped_exception)


_import_by_name = sphinx.ext.autosummary._import_by_name
sphinx.ext.autosummary._import_by_name = _modules_first
autodoc_typehints = "signature"
# Optional packages the reference does not install: labgrid (it has a venv of its own, see the Makefile),
# with attrs and pexpect, gets stand-ins (docs/_ext/labgrid_stand_ins.py), the rest autodoc's mocks.
labgrid_stand_ins.install()
autodoc_mock_imports = ["atheris"]

# README's output examples are abbreviated JSON (``...``), which Pygments cannot lex: shown unhighlighted.
suppress_warnings = ["misc.highlighting_failure"]

nitpicky = True
# Outside names (standard library, third-party packages): not linked (no intersphinx), not errors. A
# reference reaches this list only when docs/_ext/pyrefs.py found no hilbench object for it. Outside
# names are every top-level name of the standard library and of the installed distributions but
# hilbench, plus `np` (numpy imported as np, in string annotations); a bare name that is also the name
# of a hilbench module (`can`, `profile`, `serial`...) is not let through: it means the module.
_OUTSIDE = (set(sys.stdlib_module_names) | set(importlib.metadata.packages_distributions())
            | {"np", "labgrid", "attr", "pexpect"} | set(autodoc_mock_imports)) - {"hilbench"}
_OWN_MODULES = {p.stem for p in (ROOT / "hilbench").rglob("*.py")} | {
    p.name for p in (ROOT / "hilbench").rglob("*") if p.is_dir()}


def _alternatives(names):
    return "|".join(sorted(map(re.escape, names)))


nitpick_ignore_regex = [
    (r"py:.*", rf"(?:{_alternatives(_OUTSIDE)})\..+"),
    (r"py:.*", rf"(?:{_alternatives(_OUTSIDE - _OWN_MODULES)})"),
    # Type variables (a one-letter name in a module) have no page of their own.
    (r"py:(?:class|obj)", r"hilbench\..+\.[A-Z]"),
]


_UNPARSABLE_DEFAULT = re.compile(r"=\s*<[^<>]*>")


def _parsable_signature(app, what, name, obj, options, signature, return_annotation):
    """A dataclass field's default shows as ``<factory>``, which Sphinx cannot parse as Python: it then
    splits the signature at every comma (``dict[str`` and ``int]`` become two broken references)."""
    if signature and "<" in signature:
        signature = _UNPARSABLE_DEFAULT.sub("= ...", signature)
    return signature, return_annotation


def setup(app):
    app.connect("autodoc-process-signature", _parsable_signature)
