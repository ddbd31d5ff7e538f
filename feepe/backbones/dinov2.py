"""DINOv2 patch features (the paper's backbone), from local weights only.

Layers count transformer blocks from 0, as FoundPose does (its extractor hooks `blocks[layer]`, and its
ViT-L last layer is 23): "layer 19" of ViT-L/14 is the output of `blocks[19]`, the 20th of 24 blocks, so
the paper's ablation {11, 19, 23} ends at the last block. The final LayerNorm is applied to that output,
as FoundPose does with `norm=1` (its default and its configurations); only blocks 0..layer are run.
Without a layer, the paper's relative depth 19 of 0..23 is used (ViT-S/B: 9 of 0..11, FoundPose's ViT-S
choice; ViT-G: 32 of 0..39).

Weights come from, in order: an explicit path (a Hugging Face model folder, or an original torch-hub
`.pth` checkpoint), the Hugging Face cache (`facebook/dinov2-large`, ...), the torch-hub checkpoint cache
(`$TORCH_HOME/hub/checkpoints/dinov2_vitl14_pretrain.pth`, ...). Nothing is ever downloaded.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from feepe.backbones.base import PatchFeatures, eroded, unit_rows
from feepe.crop import Crop
from kernel.errors import UserError

# name -> (HF repo id, hidden size, blocks, heads, swiglu)
ARCH = {"s": ("small", 384, 12, 6, False), "b": ("base", 768, 12, 12, False),
        "l": ("large", 1024, 24, 16, False), "g": ("giant", 1536, 40, 24, True)}
PATCH = 14
MEAN = np.array([0.485, 0.456, 0.406])
STD = np.array([0.229, 0.224, 0.225])


def parse_name(name: str) -> tuple[str, bool]:
    size, registers = name[len("dinov2_vit")], name.endswith("_reg")
    return size, registers


def hf_repo(name: str) -> str:
    size, registers = parse_name(name)
    return f"facebook/dinov2{'-with-registers' if registers else ''}-{ARCH[size][0]}"


def hub_checkpoint(name: str) -> Path:
    size, registers = parse_name(name)
    torch_home = Path(os.environ.get("TORCH_HOME", Path.home() / ".cache" / "torch"))
    stem = f"dinov2_vit{size}14{'_reg4' if registers else ''}_pretrain.pth"
    return torch_home / "hub" / "checkpoints" / stem


def default_layer(name: str) -> int:
    return round(19 / 23 * (ARCH[parse_name(name)[0]][2] - 1))


def hf_config(name: str, image_size: int = 518):
    from transformers import Dinov2Config, Dinov2WithRegistersConfig

    size, registers = parse_name(name)
    _, hidden, blocks, heads, swiglu = ARCH[size]
    kw = dict(hidden_size=hidden, num_hidden_layers=blocks, num_attention_heads=heads, patch_size=PATCH,
              image_size=image_size, use_swiglu_ffn=swiglu, layerscale_value=1.0)
    return Dinov2WithRegistersConfig(num_register_tokens=4, **kw) if registers else Dinov2Config(**kw)


def convert_hub_state_dict(state: dict, num_blocks: int) -> dict:
    """Original DINOv2 (torch hub) parameter names -> transformers' Dinov2Model names."""
    out = {"embeddings.cls_token": state["cls_token"], "embeddings.position_embeddings": state["pos_embed"],
           "embeddings.patch_embeddings.projection.weight": state["patch_embed.proj.weight"],
           "embeddings.patch_embeddings.projection.bias": state["patch_embed.proj.bias"],
           "layernorm.weight": state["norm.weight"], "layernorm.bias": state["norm.bias"]}
    out["embeddings.mask_token"] = state["mask_token"].reshape(1, -1)
    if "register_tokens" in state:
        out["embeddings.register_tokens"] = state["register_tokens"]
    for i in range(num_blocks):
        src, dst = f"blocks.{i}.", f"encoder.layer.{i}."
        q, k, v = state[src + "attn.qkv.weight"].chunk(3, 0)
        qb, kb, vb = state[src + "attn.qkv.bias"].chunk(3, 0)
        for n, w, b in (("q_proj", q, qb), ("k_proj", k, kb), ("v_proj", v, vb)):
            out[dst + f"attention.{n}.weight"], out[dst + f"attention.{n}.bias"] = w, b
        pairs = {"norm1": "norm1", "norm2": "norm2", "attn.proj": "attention.o_proj"}
        if src + "mlp.w12.weight" in state:
            gate, up = state[src + "mlp.w12.weight"].chunk(2, 0)
            gate_b, up_b = state[src + "mlp.w12.bias"].chunk(2, 0)
            out.update({dst + "mlp.gate_proj.weight": gate, dst + "mlp.gate_proj.bias": gate_b,
                        dst + "mlp.up_proj.weight": up, dst + "mlp.up_proj.bias": up_b})
            pairs["mlp.w3"] = "mlp.down_proj"
        else:
            pairs.update({"mlp.fc1": "mlp.fc1", "mlp.fc2": "mlp.fc2"})
        for a, b in pairs.items():
            out[dst + b + ".weight"], out[dst + b + ".bias"] = state[src + a + ".weight"], state[src + a + ".bias"]
        out[dst + "layer_scale1.lambda1"] = state[src + "ls1.gamma"]
        out[dst + "layer_scale2.lambda1"] = state[src + "ls2.gamma"]
    return out


def _model_class(name: str):
    from transformers import Dinov2Model, Dinov2WithRegistersModel

    return Dinov2WithRegistersModel if parse_name(name)[1] else Dinov2Model


def _from_hub_checkpoint(name: str, path: Path):
    import torch

    state = torch.load(path, map_location="cpu", weights_only=True)
    pos = state["pos_embed"].shape[1] - 1
    config = hf_config(name, image_size=int(round(pos**0.5)) * PATCH)
    model = _model_class(name)(config)
    model.load_state_dict(convert_hub_state_dict(state, config.num_hidden_layers))
    return model


def load_model(name: str, weights: str | Path | None = None):
    """The model in eval mode, from the first local source that has it; a UserError lists where it looked."""
    looked = []
    if weights:
        path = Path(weights)
        if path.is_file():
            return _from_hub_checkpoint(name, path).eval()
        if (path / "config.json").is_file():
            return _model_class(name).from_pretrained(path, local_files_only=True).eval()
        raise UserError(f"--backbone-weights {path}: neither a torch-hub .pth checkpoint nor a Hugging Face "
                        "model folder (config.json + weights)")
    try:
        return _model_class(name).from_pretrained(hf_repo(name), local_files_only=True).eval()
    except OSError:
        looked.append(f"the Hugging Face cache ({hf_repo(name)})")
    ckpt = hub_checkpoint(name)
    if ckpt.is_file():
        return _from_hub_checkpoint(name, ckpt).eval()
    looked.append(str(ckpt))
    raise UserError(f"no local weights for {name}; looked in {' and '.join(looked)}. On a machine with internet, "
                    f"fetch `{hf_repo(name)}` into the Hugging Face cache or the torch-hub checkpoint "
                    f"{ckpt.name} from dl.fbaipublicfiles.com/dinov2/, copy it here, or pass its path as the "
                    "backbone weights; or use the weight-free backbone `sift+normals+color`")


@dataclass
class Dinov2Backbone:
    variant: str = "dinov2_vitl14"
    layer: int | None = None
    crop_size: int = 420
    weights: str | None = None
    model: object = None  # a loaded transformers model (tests pass a tiny one)

    def __post_init__(self):
        if self.crop_size % PATCH:
            raise UserError(f"DINOv2 crop size {self.crop_size} must be a multiple of {PATCH}")
        if self.model is None:
            self.model = load_model(self.variant, self.weights)
        blocks = len(self.model.encoder.layer)
        if self.layer is None:
            self.layer = default_layer(self.variant)
        if not 0 <= self.layer < blocks:
            raise UserError(f"{self.variant} has blocks 0..{blocks - 1}; layer {self.layer} does not exist")

    @property
    def name(self) -> str:
        return self.variant

    def options(self) -> dict:
        cfg = self.model.config
        return {"backbone": self.variant, "layer": self.layer, "crop_size": self.crop_size,
                "hidden_size": cfg.hidden_size, "blocks": cfg.num_hidden_layers,
                "weights": str(self.weights or getattr(cfg, "_name_or_path", ""))}

    def patch_tokens(self, rgb: np.ndarray) -> np.ndarray:
        """(S/14, S/14, C) normalised tokens of block `layer` for a (S, S, 3) uint8 image."""
        import torch

        x = (rgb.astype(np.float32) / 255.0 - MEAN) / STD
        x = torch.from_numpy(x.transpose(2, 0, 1)[None].astype(np.float32))
        with torch.inference_mode():
            h = self.model.embeddings(x)
            for block in self.model.encoder.layer[: self.layer + 1]:
                h = block(h, None)
            h = self.model.layernorm(h)
        n = self.crop_size // PATCH
        return h[0, -n * n:].reshape(n, n, -1).numpy()  # registers and CLS lead the sequence

    def extract(self, crop: Crop) -> PatchFeatures:
        tokens = self.patch_tokens(crop.rgb)
        n = tokens.shape[0]
        centres = np.arange(n) * PATCH + (PATCH - 1) / 2.0
        gx, gy = np.meshgrid(centres, centres)
        uv = np.stack([gx.ravel(), gy.ravel()], 1)
        inside = eroded(crop.mask)[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)]
        return PatchFeatures(uv[inside], unit_rows(tokens.reshape(n * n, -1)[inside]))
