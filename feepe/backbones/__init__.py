"""Backbones by name (`get_backbone`): weight-free dense descriptors built from parts joined with '+' -
`sift`, `normals`, `color` (dense.py) and OpenCV-contrib's `vgg`, `boost`, `beblid`, `teblid`, `daisy`,
`latch` (contrib.py); default `sift+normals+color` - and DINOv2 (`dinov2_vits14`, `dinov2_vitl14`, ... with
`_reg` variants; dinov2.py) from local weights only. The interface is base.py."""

from __future__ import annotations

from kernel.errors import UserError

DEFAULT = "sift+normals+color"  # chosen by measurement on mini (docs/feepe.md, "Weight-free backbone")
DINOV2_NAMES = tuple(f"dinov2_vit{s}14{r}" for s in "sblg" for r in ("", "_reg"))


def get_backbone(name: str, **kwargs):
    if name.startswith("dinov2"):
        from feepe.backbones.dinov2 import Dinov2Backbone

        if name not in DINOV2_NAMES:
            raise UserError(f"backbone {name!r} unknown; DINOv2 backbones: {', '.join(DINOV2_NAMES)}")
        return Dinov2Backbone(name, **kwargs)
    from feepe.backbones.dense import PARTS, DenseBackbone

    parts = tuple(p for p in name.split("+") if p)
    if not parts or set(parts) - set(PARTS):
        raise UserError(f"backbone {name!r} unknown; use parts of {'+'.join(PARTS)} (e.g. sift+normals) "
                        f"or one of {', '.join(DINOV2_NAMES)}")
    return DenseBackbone(parts, **kwargs)
