"""GV presets are registry entries (named configurations merged over a default), not an if/elif chain."""

from __future__ import annotations

import pytest

from vpr_uncertainty.geometric import GV_PRESETS, GeometricVerifier, GVPreset, register_preset
from vpr_uncertainty.geometric.local_features import NearestNeighborMatcher


def test_presets_are_declared_entries():
    assert GV_PRESETS.names() == ["GV-SIFT", "GV-DISK-LG", "GV-XFEAT", "GV-SP-SG", "GV-SP-LG"]
    sift = GV_PRESETS.get("GV-SIFT")
    assert sift.extra == "opencv" and sift.requires == ("images",)
    assert sift.merged_options() == {"extractor": {"max_keypoints": 4096}, "matcher": {"ratio": 0.8, "mutual": True}}
    assert sift.merged_options({"matcher": {"ratio": 0.9}})["matcher"] == {"ratio": 0.9, "mutual": True}
    with pytest.raises(ValueError, match=r"has no option 'ratoi' \(valid options: extractor, matcher\)"):
        sift.merged_options({"ratoi": 0.9})


def test_unknown_preset_is_an_error_listing_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown geometric-verification preset 'GV-SIFF'; did you mean 'GV-SIFT'\?"):
        GeometricVerifier.from_preset("GV-SIFF")


class _Extractor:
    def __init__(self, *, max_side: int, scale: float = 1.0) -> None:
        self.max_side, self.scale = max_side, scale


def test_a_new_preset_is_one_registration():
    preset = GVPreset(
        "GV-TEST",
        "a test extractor + mutual NN",
        extractor=f"{__name__}:_Extractor",
        matcher="vpr_uncertainty.geometric.local_features:NearestNeighborMatcher",
        options={"extractor": {"scale": 2.0}, "matcher": {"ratio": None}},
        modules=(),
    )
    register_preset(preset)
    try:
        verifier = GeometricVerifier.from_preset("GV-TEST", max_side=320, workers=1)
    finally:
        GV_PRESETS.unregister("GV-TEST")
    assert isinstance(verifier.extractor, _Extractor) and verifier.extractor.scale == 2.0
    assert verifier.extractor.max_side == 320 and isinstance(verifier.matcher, NearestNeighborMatcher)
    assert verifier.matcher.ratio is None
