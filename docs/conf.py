"""Sphinx configuration of the huefringe manual.

Build: ``./run python -m sphinx -W --keep-going docs build/manual`` (the page lands in
``build/manual/index.html``); ``tests/test_docs.py`` builds it the same way in the suite. Nothing
is fetched at build time: no intersphinx, an offline theme (furo), and with
``HUEFRINGE_DOCS_OFFLINE=1`` (the test sets it) any socket connection fails the build.
"""

from __future__ import annotations

import os
import socket
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
REPO = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(REPO / "src"))

if os.environ.get("HUEFRINGE_DOCS_OFFLINE"):

    def _no_network(*args: object, **kwargs: object) -> None:
        raise OSError("the huefringe manual is built offline: a socket connection was attempted")

    socket.socket.connect = _no_network  # type: ignore[method-assign]
    socket.socket.connect_ex = _no_network  # type: ignore[method-assign]
    socket.getaddrinfo = _no_network  # type: ignore[assignment]

import huefringe  # noqa: E402

project = "huefringe"
author = "the huefringe developers"
copyright = "the huefringe developers, MIT licence"
release = version = huefringe.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "huefringe_docs",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_templates", "Thumbs.db", ".DS_Store"]
templates_path = ["_templates"]

# Markdown pages (MyST): "#heading" anchors for the measured pages' cross-links, $...$ maths.
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# API reference: autosummary writes one stub per module into api/ (generated, git-ignored) from
# _templates/autosummary/module.rst; numpydoc renders the docstrings.
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "member-order": "bysource", "show-inheritance": True}
autodoc_typehints = "signature"
autodoc_typehints_format = "short"
autodoc_preserve_defaults = True
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# maths in the browser; MathJax is loaded by the reader's browser, not at build time
html_theme = "furo"
html_title = f"huefringe {release}"
html_static_path: list[str] = []
html_show_sourcelink = False

# pages of the manual in the order of the contents; a page of docs/ that no pattern names
# lands under "More" (huefringe_docs.contents), so pages added by later work always appear
huefringe_sections = [
    ("Using huefringe", ["guide", "capture*", "rig*", "spec/capture-session", "spec/results",
                         "spec/structured-light-session", "spec/results-structured-light", "outputs",
                         "configuration", "cluster*", "archives*", "x3p*", "api"]),
    ("Method and design", ["method", "design*"]),
    ("Measured", ["demo", "accuracy", "accuracy-texture", "accuracy-cameras", "accuracy-*", "uncertainty*", "noise*",
                  "table1*", "hue-models*", "throughput*", "real-captures*"]),
]
