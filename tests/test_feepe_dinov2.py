"""The DINOv2 backbone's loading and layer code, on tiny randomly initialised models of the same
architecture (no weights can be downloaded here)."""

import numpy as np
import pytest
import torch

from feepe.backbones import get_backbone
from feepe.backbones.dinov2 import Dinov2Backbone, convert_hub_state_dict, load_model
from feepe.crop import Crop
from syneepose.errors import UserError


def _tiny(registers=False, swiglu=False):
    from transformers import Dinov2Config, Dinov2Model, Dinov2WithRegistersConfig, Dinov2WithRegistersModel

    kw = dict(hidden_size=32, num_hidden_layers=4, num_attention_heads=2, patch_size=14, image_size=70,
              use_swiglu_ffn=swiglu)
    torch.manual_seed(0)
    if registers:
        return Dinov2WithRegistersModel(Dinov2WithRegistersConfig(num_register_tokens=4, **kw)).eval()
    return Dinov2Model(Dinov2Config(**kw)).eval()


def _to_hub(model) -> dict:
    """Our model's weights under the original DINOv2 (torch hub) names: the inverse of the converter."""
    s = model.state_dict()
    out = {"cls_token": s["embeddings.cls_token"], "pos_embed": s["embeddings.position_embeddings"],
           "mask_token": s["embeddings.mask_token"].reshape(1, 1, -1),
           "patch_embed.proj.weight": s["embeddings.patch_embeddings.projection.weight"],
           "patch_embed.proj.bias": s["embeddings.patch_embeddings.projection.bias"],
           "norm.weight": s["layernorm.weight"], "norm.bias": s["layernorm.bias"]}
    if "embeddings.register_tokens" in s:
        out["register_tokens"] = s["embeddings.register_tokens"]
    for i in range(model.config.num_hidden_layers):
        a, b = f"encoder.layer.{i}.", f"blocks.{i}."
        for p in ("weight", "bias"):
            out[b + f"attn.qkv.{p}"] = torch.cat([s[a + f"attention.{n}.{p}"] for n in ("q_proj", "k_proj", "v_proj")])
            out[b + f"attn.proj.{p}"] = s[a + f"attention.o_proj.{p}"]
            out[b + f"norm1.{p}"], out[b + f"norm2.{p}"] = s[a + f"norm1.{p}"], s[a + f"norm2.{p}"]
            if model.config.use_swiglu_ffn:
                out[b + f"mlp.w12.{p}"] = torch.cat([s[a + f"mlp.gate_proj.{p}"], s[a + f"mlp.up_proj.{p}"]])
                out[b + f"mlp.w3.{p}"] = s[a + f"mlp.down_proj.{p}"]
            else:
                out[b + f"mlp.fc1.{p}"], out[b + f"mlp.fc2.{p}"] = s[a + f"mlp.fc1.{p}"], s[a + f"mlp.fc2.{p}"]
        out[b + "ls1.gamma"], out[b + "ls2.gamma"] = s[a + "layer_scale1.lambda1"], s[a + "layer_scale2.lambda1"]
    return out


def test_layer_counts_blocks_from_one_and_matches_hidden_states():
    model = _tiny()
    net = Dinov2Backbone("dinov2_vits14", layer=3, crop_size=70, model=model)
    rgb = np.random.default_rng(0).integers(0, 255, (70, 70, 3), dtype=np.uint8)
    tokens = net.patch_tokens(rgb)
    x = torch.from_numpy(((rgb / 255.0 - [0.485, 0.456, 0.406]) / [0.229, 0.224, 0.225]).transpose(2, 0, 1)[None]).float()
    with torch.inference_mode():
        ref = model.layernorm(model(x, output_hidden_states=True).hidden_states[3])[0, 1:]
    assert tokens.shape == (5, 5, 32)
    np.testing.assert_allclose(tokens.reshape(25, 32), ref.numpy(), atol=1e-5)


@pytest.mark.parametrize("registers,swiglu", [(False, False), (True, False), (False, True)])
def test_hub_checkpoint_loads_to_the_same_network(tmp_path, registers, swiglu):
    model = _tiny(registers, swiglu)
    path = tmp_path / "dinov2_vits14_pretrain.pth"
    torch.save(_to_hub(model), path)
    name = "dinov2_vits14_reg" if registers else "dinov2_vits14"
    state = convert_hub_state_dict(torch.load(path, weights_only=True), 4)
    assert set(state) == set(model.state_dict())
    # the real architecture table has 12 blocks for ViT-S: load the tiny file through a patched table
    import feepe.backbones.dinov2 as d

    saved = d.ARCH["s"]
    d.ARCH["s"] = ("small", 32, 4, 2, swiglu)
    try:
        loaded = load_model(name, path)
    finally:
        d.ARCH["s"] = saved
    x = torch.randn(1, 3, 70, 70)
    with torch.inference_mode():
        np.testing.assert_allclose(loaded(x).last_hidden_state.numpy(), model(x).last_hidden_state.numpy(), atol=1e-5)


def test_hugging_face_folder_and_features_inside_mask(tmp_path):
    model = _tiny()
    model.save_pretrained(tmp_path / "tiny")
    net = get_backbone("dinov2_vits14", weights=str(tmp_path / "tiny"), layer=2, crop_size=70)
    mask = np.zeros((70, 70), bool)
    mask[10:60, 20:50] = True
    crop = Crop(np.zeros((70, 70, 3), np.uint8), np.zeros((70, 70)), mask, np.eye(3), np.eye(3))
    feats = net.extract(crop)
    assert len(feats.uv) > 0 and feats.desc.shape == (len(feats.uv), 32)
    assert np.all((feats.uv[:, 0] > 20) & (feats.uv[:, 0] < 50) & (feats.uv[:, 1] > 10) & (feats.uv[:, 1] < 60))
    np.testing.assert_allclose(np.linalg.norm(feats.desc, axis=1), 1.0, atol=1e-5)
    assert net.options()["layer"] == 2


def test_missing_weights_say_how_to_provide_them(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    with pytest.raises(UserError, match="no local weights for dinov2_vitl14.*sift\\+normals\\+color"):
        get_backbone("dinov2_vitl14")
    with pytest.raises(UserError, match="unknown"):
        get_backbone("dinov2_vitx14")
    with pytest.raises(UserError, match="layer 9 does not exist"):
        Dinov2Backbone("dinov2_vits14", layer=9, crop_size=70, model=_tiny())
