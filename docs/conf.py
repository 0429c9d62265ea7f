"""Sphinx configuration: MyST pages, references generated from the code (see _ext/)."""
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))  # the package from this tree, installed or not

from simlidar_mi._version import __version__  # noqa: E402

project = "simlidar-mi"
author = "simlidar-mi developers"
copyright = "simlidar-mi developers"
release = version = __version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",  # $...$ and $$...$$ (MyST dollarmath, amsmath) render as formulas
    "simlidar_ref",
]
source_suffix = {".md": "markdown"}
exclude_patterns = ["_build"]
myst_heading_anchors = 3  # GitHub-style ids on headings to level 3: links name a section
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_dmath_double_inline = True  # $$...$$ inside a paragraph is a displayed formula too
html_theme = "furo"
html_title = f"simlidar-mi {release}"
html_static_path = ["_static"]
html_css_files = ["simlidar.css"]  # long commands wrap in code blocks (see the file)
smartquotes = False  # TOML values, `--set` options and quotes are shown exactly as typed

# The API reference documents what `import simlidar_mi` exposes, in the source order.
autodoc_member_order = "bysource"
autodoc_typehints = "description"
napoleon_google_docstring = False
napoleon_numpy_docstring = True
