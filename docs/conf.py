"""Sphinx configuration of artifem's documentation site (``make docs``).

The pages are the Markdown files of docs/ (MyST), the API reference comes from the
docstrings (autodoc, napoleon for the Args: sections) and the demo gallery from demos/
(sphinx-gallery, every demo executed in its quick mode, its pictures shown). The build
runs with warnings as errors, so a broken reference or a failing demo fails it.
"""

import os
import sys
from pathlib import Path

import artifem  # first: orders MPI ahead of dolfinx (the demos and autodoc import both)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).parent / "_ext"))

os.environ.setdefault("ARTIFEM_QUICK", "1")  # the demos' quick mode: a few steps each

project = "artifem"
author = "the artifem developers"
copyright = "2026, the artifem developers"
release = version = artifem.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "sphinx_gallery.gen_gallery",
    "plain_math",  # docs/_ext: |x| in a docstring is a norm
]

templates_path = ["_templates"]  # a class page: its docstring, then its members
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "_ext", "img"]  # img/: pictures and a table airway.md quotes
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3

autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autosummary_generate = True
napoleon_google_docstring = True
napoleon_numpy_docstring = False

sphinx_gallery_conf = {
    "examples_dirs": "../demos",
    "gallery_dirs": "demos",
    "filename_pattern": r".*\.py",  # execute every demo, not only plot_*.py
    "reset_argv": "demo_pictures.demo_arguments",
    "image_scrapers": ("demo_pictures.demo_pictures",),
    "download_all_examples": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "within_subsection_order": "FileNameSortKey",
}

html_theme = "furo"
html_title = f"artifem {release}"
html_static_path = []
