"""The demos in the gallery: each writes its outputs into the directory given as its
first argument, and its pictures are the PNGs it wrote there (sphinx-gallery's image
scraper interface: ``scraper(block, block_vars, gallery_conf) -> rst``)."""

import shutil
from pathlib import Path

from sphinx_gallery.scrapers import figure_rst

#: where each demo writes, under the build's output
OUTPUT = Path(__file__).resolve().parents[1] / "_build" / "demo_output"


def _output(src_file) -> Path:
    return OUTPUT / Path(src_file).stem


def demo_arguments(gallery_conf, script_vars):
    """sys.argv[1:] of a demo: its output directory (emptied first)."""
    out = _output(script_vars["src_file"])
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    return [str(out)]


def demo_pictures(block, block_vars, gallery_conf):
    """The PNGs the demo wrote, copied where the gallery wants them (a demo is one block:
    this runs once, after the whole script)."""
    pictures = sorted(_output(block_vars["src_file"]).rglob("*.png"))
    targets = [str(target) for _, target in zip(pictures, block_vars["image_path_iterator"])]
    for picture, target in zip(pictures, targets):
        shutil.copyfile(picture, target)
    return figure_rst(targets, gallery_conf["src_dir"])
