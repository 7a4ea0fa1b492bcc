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
    """The PNGs the demo wrote since the last call, copied where the gallery wants them."""
    out = _output(block_vars["src_file"])
    shown = block_vars.setdefault("artifem_shown", set())
    pictures = sorted(p for p in out.rglob("*.png") if p not in shown)
    targets = []
    for picture, target in zip(pictures, block_vars["image_path_iterator"]):
        shutil.copyfile(picture, target)
        shown.add(picture)
        targets.append(target)
    return figure_rst(targets, gallery_conf["src_dir"])
