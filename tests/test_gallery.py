"""The gallery's shipped scenes (issue 26): each loads through ``mi.load_file`` in ``scalar_rgb`` and
``llvm_ad_rgb`` at its DEFAULT parameters (counts included: what ``motes render NAME`` gives) and renders
finite, non-black pixels at a tiny size; each says in its header what it shows and which figure it follows."""

from __future__ import annotations

import re

import numpy as np
import pytest

import motes
from motes.cli import shipped_scenes

GALLERY = {"lamp": "Fig. 10", "cornell": "Figs. 12 and 13", "bench": "Fig. 17", "staircase": "Fig. 18",
           "house": "Fig. 19", "limit": "Figs. 14 and 15", "footprint": "Fig. 16"}


def test_every_gallery_scene_ships_with_a_header_naming_its_figure():
    shipped = shipped_scenes()
    for name, figure in GALLERY.items():
        assert name in shipped, f"{name} is not shipped in motes/scenes"
        text = shipped[name].read_text()
        header = text[:text.index("<scene")]
        assert figure in header, f"{name}: header should name {figure}"
        assert "Parameters" in header and "Render:" in header
        # The preview knobs every scene takes.
        for param in ("spp", "res"):
            assert re.search(rf'<default name="{param}"', text), f"{name}: no ${param} parameter"


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
@pytest.mark.parametrize("name", sorted(GALLERY))
def test_gallery_scene_renders_at_its_defaults(name, variant):
    motes.set_variant(variant)
    import mitsuba as mi

    scene = mi.load_file(str(shipped_scenes()[name]), res="24", spp="2")
    img = np.asarray(mi.render(scene, spp=2), dtype=np.float64)
    assert img.shape[:2] == (24, 24)
    assert np.all(np.isfinite(img)), f"{name} ({variant}): non-finite pixels"
    assert img.mean() > 1e-5, f"{name} ({variant}): black image (mean {img.mean():.3g})"
