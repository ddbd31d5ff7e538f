"""The DINOv2 backbone's loading and layer code, on tiny random models of the same architecture (no weights
can be downloaded here), checked against DINOv2's architecture written out in the test."""

import numpy as np
import pytest
import torch

from feepe.backbones import get_backbone
from feepe.backbones.dinov2 import Dinov2Backbone, convert_hub_state_dict, load_model
from feepe.crop import Crop
from kernel.errors import UserError


def _tiny():
    from transformers import Dinov2Config, Dinov2Model

    torch.manual_seed(0)
    return Dinov2Model(Dinov2Config(hidden_size=32, num_hidden_layers=4, num_attention_heads=2, patch_size=14,
                                    image_size=70)).eval()


DIM, DEPTH, HEADS, GRID = 32, 4, 2, 5  # a tiny ViT: 4 blocks on a 70 px image (5 x 5 patches)
MEAN, STD = [0.485, 0.456, 0.406], [0.229, 0.224, 0.225]


def _hub_state(registers: bool, swiglu: bool) -> dict:
    """Random weights under the original DINOv2 (torch hub) names and shapes, made without transformers."""
    g = torch.Generator().manual_seed(1)

    def r(*shape, scale=0.2):
        return scale * torch.randn(*shape, generator=g)

    hidden = (int(4 * DIM * 2 / 3) + 7) // 8 * 8 if swiglu else 4 * DIM  # DINOv2's SwiGLUFFNFused rounding
    s = {"cls_token": r(1, 1, DIM), "pos_embed": r(1, 1 + GRID * GRID, DIM), "mask_token": r(1, DIM),
         "patch_embed.proj.weight": r(DIM, 3, 14, 14, scale=0.05), "patch_embed.proj.bias": r(DIM),
         "norm.weight": 1 + r(DIM), "norm.bias": r(DIM)}
    if registers:
        s["register_tokens"] = r(1, 4, DIM)
    for i in range(DEPTH):
        b = f"blocks.{i}."
        mlp = ({"mlp.w12": (2 * hidden, DIM), "mlp.w3": (DIM, hidden)} if swiglu
               else {"mlp.fc1": (hidden, DIM), "mlp.fc2": (DIM, hidden)})
        for name, (n_out, n_in) in {"attn.qkv": (3 * DIM, DIM), "attn.proj": (DIM, DIM), **mlp}.items():
            s[b + name + ".weight"], s[b + name + ".bias"] = r(n_out, n_in, scale=n_in**-0.5), r(n_out)
        for name in ("norm1", "norm2"):
            s[b + name + ".weight"], s[b + name + ".bias"] = 1 + r(DIM), r(DIM)
        s[b + "ls1.gamma"], s[b + "ls2.gamma"] = 1 + r(DIM), 1 + r(DIM)
    return s


def _plain_forward(s: dict, x: torch.Tensor) -> list[torch.Tensor]:
    """Every block's output tokens: DINOv2's VisionTransformer (prepare_tokens, Block, Attention, Mlp /
    SwiGLUFFN, LayerNorm eps 1e-6) written out from its state dict, independently of transformers."""
    F = torch.nn.functional

    def ln(t, p):
        return F.layer_norm(t, t.shape[-1:], s[p + ".weight"], s[p + ".bias"], eps=1e-6)

    def lin(t, p):
        return F.linear(t, s[p + ".weight"], s[p + ".bias"])

    t = F.conv2d(x, s["patch_embed.proj.weight"], s["patch_embed.proj.bias"], stride=14).flatten(2).transpose(1, 2)
    t = torch.cat([s["cls_token"].expand(len(t), -1, -1), t], 1) + s["pos_embed"]
    if "register_tokens" in s:
        t = torch.cat([t[:, :1], s["register_tokens"].expand(len(t), -1, -1), t[:, 1:]], 1)
    outs = []
    for i in range(DEPTH):
        b = f"blocks.{i}."
        B, N, C = t.shape
        qkv = lin(ln(t, b + "norm1"), b + "attn.qkv").reshape(B, N, 3, HEADS, C // HEADS).permute(2, 0, 3, 1, 4)
        attn = ((qkv[0] * (C // HEADS) ** -0.5) @ qkv[1].transpose(-2, -1)).softmax(-1)
        t = t + s[b + "ls1.gamma"] * lin((attn @ qkv[2]).transpose(1, 2).reshape(B, N, C), b + "attn.proj")
        h = ln(t, b + "norm2")
        if b + "mlp.w12.weight" in s:
            x1, x2 = lin(h, b + "mlp.w12").chunk(2, -1)
            h = lin(F.silu(x1) * x2, b + "mlp.w3")
        else:
            h = lin(F.gelu(lin(h, b + "mlp.fc1")), b + "mlp.fc2")
        t = t + s[b + "ls2.gamma"] * h
        outs.append(t)
    return outs


def _load_hub(tmp_path, monkeypatch, registers: bool, swiglu: bool):
    import feepe.backbones.dinov2 as d

    state = _hub_state(registers, swiglu)
    path = tmp_path / "dinov2_vits14_pretrain.pth"
    torch.save(state, path)
    monkeypatch.setitem(d.ARCH, "s", ("small", DIM, DEPTH, HEADS, swiglu))  # the real table has ViT-S's 12 blocks
    return state, load_model("dinov2_vits14_reg" if registers else "dinov2_vits14", path)


@pytest.mark.parametrize("registers,swiglu", [(False, False), (True, False), (False, True)])
def test_hub_checkpoint_computes_the_original_network(tmp_path, monkeypatch, registers, swiglu):
    """The converted checkpoint in transformers' model gives the original architecture's output."""
    state, model = _load_hub(tmp_path, monkeypatch, registers, swiglu)
    assert set(convert_hub_state_dict(state, DEPTH)) == set(model.state_dict())
    x = torch.randn(2, 3, 70, 70, generator=torch.Generator().manual_seed(2))
    with torch.inference_mode():
        ours = model(x).last_hidden_state
        ref = torch.nn.functional.layer_norm(_plain_forward(state, x)[-1], (DIM,), state["norm.weight"],
                                             state["norm.bias"], eps=1e-6)
    assert ours.shape == ref.shape == (2, 1 + 4 * registers + GRID * GRID, DIM)
    np.testing.assert_allclose(ours.numpy(), ref.numpy(), atol=1e-4)


@pytest.mark.parametrize("registers", [False, True])
def test_layer_is_foundposes_block_index_with_the_final_norm(tmp_path, monkeypatch, registers):
    """Layer L = the output of blocks[L] (FoundPose's hook index), final LayerNorm applied, patch tokens
    only; the same as transformers' hidden_states[L + 1] (hidden_states[0] is the embedding)."""
    state, model = _load_hub(tmp_path, monkeypatch, registers, False)
    rgb = np.random.default_rng(0).integers(0, 255, (70, 70, 3), dtype=np.uint8)
    x = torch.from_numpy(((rgb / 255.0 - MEAN) / STD).transpose(2, 0, 1)[None]).float()
    with torch.inference_mode():
        blocks = _plain_forward(state, x)
        hidden = [model.layernorm(h) for h in model(x, output_hidden_states=True).hidden_states]
    for layer in range(DEPTH):
        tokens = Dinov2Backbone("dinov2_vits14", layer=layer, crop_size=70, model=model).patch_tokens(rgb)
        assert tokens.shape == (GRID, GRID, DIM)
        ref = torch.nn.functional.layer_norm(blocks[layer], (DIM,), state["norm.weight"], state["norm.bias"], eps=1e-6)
        np.testing.assert_allclose(tokens.reshape(-1, DIM), ref[0, -GRID * GRID:].numpy(), atol=1e-4)
        np.testing.assert_allclose(tokens.reshape(-1, DIM), hidden[layer + 1][0, -GRID * GRID:].numpy(), atol=1e-4)
    assert not np.allclose(blocks[2].numpy(), blocks[3].numpy(), atol=1e-2)  # neighbouring layers differ


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
    with pytest.raises(UserError, match="blocks 0..3; layer 4 does not exist"):
        Dinov2Backbone("dinov2_vits14", layer=4, crop_size=70, model=_tiny())
    assert Dinov2Backbone("dinov2_vits14", layer=0, crop_size=70, model=_tiny()).layer == 0
