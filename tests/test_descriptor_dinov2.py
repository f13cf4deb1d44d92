"""AnyLoc's DINOv2 backend with a random checkpoint of the official layout; no network.

The checkpoint is written key by key from the published layout of ``dinov2_vits14_pretrain.pth``
(not from the module's own table), saved to a real file and loaded strictly. Numerical checks
compare the network with plain numpy written from the architecture facts.
"""

from __future__ import annotations

import http.server
import math
import threading
from functools import partial
from pathlib import Path

import numpy as np
import pytest
import torch
from skimage import data

from descriptors import dinov2
from descriptors.base import DescriptorError
from descriptors.dinov2 import (
    Dinov2Extractor,
    DinoV2Vit,
    VitConfig,
    expected_shapes,
    interpolate_pos_embed,
    load_dinov2,
)
from descriptors.factory import descriptor_from_state, make_descriptor

D, DEPTH, HEADS = 384, 12, 6          # ViT-S/14
W_PX, H_PX = 224, 168                 # 16 x 12 patches: small enough for one core
MEAN = np.array([0.485, 0.456, 0.406])
STD = np.array([0.229, 0.224, 0.225])


def official_vits14_state(seed: int) -> dict[str, torch.Tensor]:
    """Random tensors under the official ViT-S/14 names and shapes, scaled like a trained net."""
    g = torch.Generator().manual_seed(seed)

    def rand(*shape, scale=1.0, offset=0.0):
        return torch.randn(*shape, generator=g) * scale + offset

    state = {"cls_token": rand(1, 1, D, scale=0.02), "pos_embed": rand(1, 1 + 37 * 37, D, scale=0.1),
             "mask_token": rand(1, D, scale=0.02),
             "patch_embed.proj.weight": rand(D, 3, 14, 14, scale=(3 * 14 * 14) ** -0.5),
             "patch_embed.proj.bias": rand(D, scale=0.02)}
    for i in range(DEPTH):
        p = f"blocks.{i}."
        state.update({p + "norm1.weight": rand(D, scale=0.1, offset=1.0), p + "norm1.bias": rand(D, scale=0.1),
                      p + "attn.qkv.weight": rand(3 * D, D, scale=D ** -0.5),
                      p + "attn.qkv.bias": rand(3 * D, scale=0.1),
                      p + "attn.proj.weight": rand(D, D, scale=D ** -0.5), p + "attn.proj.bias": rand(D, scale=0.02),
                      p + "ls1.gamma": rand(D, scale=0.05, offset=0.2),
                      p + "norm2.weight": rand(D, scale=0.1, offset=1.0), p + "norm2.bias": rand(D, scale=0.1),
                      p + "mlp.fc1.weight": rand(4 * D, D, scale=D ** -0.5), p + "mlp.fc1.bias": rand(4 * D, scale=0.1),
                      p + "mlp.fc2.weight": rand(D, 4 * D, scale=(4 * D) ** -0.5),
                      p + "mlp.fc2.bias": rand(D, scale=0.02),
                      p + "ls2.gamma": rand(D, scale=0.05, offset=0.2)})
    state.update({"norm.weight": rand(D, scale=0.1, offset=1.0), "norm.bias": rand(D, scale=0.1)})
    return state


@pytest.fixture(scope="module")
def state() -> dict[str, torch.Tensor]:
    return official_vits14_state(seed=0)


@pytest.fixture(scope="module")
def checkpoint(state, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("weights") / "dinov2_vits14_pretrain.pth"
    torch.save(state, path)
    return path


@pytest.fixture(scope="module")
def photos() -> list[np.ndarray]:
    return [data.chelsea(), data.astronaut(), data.coffee(), data.rocket(), data.chelsea()[40:260, 20:400]]


@pytest.fixture
def offline_hub(tmp_path, monkeypatch) -> Path:
    """An empty torch hub cache, and a download URL that is refused at once (nothing listens on port 9)."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.setattr(dinov2, "CHECKPOINT_BASE_URL", "http://127.0.0.1:9/dinov2")
    return tmp_path / "torch" / "hub" / "checkpoints"


# -- layout ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("model, dim, depth, hidden, params_m", [
    ("vits14", 384, 12, 1536, 21), ("vitb14", 768, 12, 3072, 86),
    ("vitl14", 1024, 24, 4096, 300), ("vitg14", 1536, 40, 4096, 1100)])
def test_layout_matches_the_official_checkpoints(model, dim, depth, hidden, params_m):
    """Names and shapes of the published backbones; parameter counts as published (21M ... 1.1B)."""
    shapes = expected_shapes(dinov2.MODELS[model])
    assert shapes["cls_token"] == (1, 1, dim) and shapes["mask_token"] == (1, dim)
    assert shapes["pos_embed"] == (1, 1 + 37 * 37, dim)
    assert shapes["patch_embed.proj.weight"] == (dim, 3, 14, 14)
    last = f"blocks.{depth - 1}."
    assert shapes[last + "attn.qkv.weight"] == (3 * dim, dim) and shapes[last + "ls2.gamma"] == (dim,)
    assert f"blocks.{depth}.norm1.weight" not in shapes
    if model == "vitg14":
        assert shapes[last + "mlp.w12.weight"] == (2 * hidden, dim) and shapes[last + "mlp.w3.weight"] == (dim, hidden)
    else:
        assert shapes[last + "mlp.fc1.weight"] == (hidden, dim) and shapes[last + "mlp.fc2.weight"] == (dim, hidden)
    assert len(shapes) == 7 + 14 * depth
    total = sum(math.prod(s) for s in shapes.values())
    assert abs(total / 1e6 - params_m) / params_m < 0.06, total


def test_random_official_checkpoint_loads_strictly(state, checkpoint):
    net = load_dinov2("vits14", checkpoint)
    loaded = net.state_dict()
    assert set(loaded) == set(state)
    assert all(torch.equal(loaded[k], state[k]) for k in state)


# -- features -------------------------------------------------------------------------------------
def test_value_facet_shape_unit_length_and_determinism(checkpoint, photos):
    ex = Dinov2Extractor("vits14", weights=checkpoint, input_width_px=W_PX, input_height_px=H_PX)
    assert ex.layer == 10 and ex.feature_dim == D
    maps = ex(photos[:2])
    assert maps.shape == (2, H_PX // 14, W_PX // 14, D) and maps.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(maps, axis=-1), 1.0, atol=1e-5)
    assert np.array_equal(maps, ex(photos[:2]))
    again = Dinov2Extractor("vits14", weights=checkpoint, input_width_px=W_PX, input_height_px=H_PX)
    assert np.array_equal(maps, again(photos[:2]))
    # Different images and different places within one image give different features.
    assert not np.allclose(maps[0], maps[1], atol=1e-3)
    assert float(np.einsum("d,d", maps[0, 0, 0], maps[0, -1, -1])) < 0.999


def _layer_norm(x, weight, bias, eps=1e-6):
    mu = x.mean(-1, keepdims=True)
    return (x - mu) / np.sqrt(((x - mu) ** 2).mean(-1, keepdims=True) + eps) * weight + bias


def _linear(x, s, name):
    return x @ s[name + ".weight"].T + s[name + ".bias"]


def _gelu(x):
    return 0.5 * x * (1.0 + np.vectorize(math.erf)(x / math.sqrt(2.0)))


def _hand_block(x, s, p, heads):
    """One pre-norm block in float64 numpy, written from the DINOv2 description."""
    n, d = x.shape
    qkv = _linear(_layer_norm(x, s[p + "norm1.weight"], s[p + "norm1.bias"]), s, p + "attn.qkv")
    hd = d // heads
    out = np.zeros((n, d))
    for h in range(heads):
        q, k, v = (qkv[:, part * d + h * hd: part * d + (h + 1) * hd] for part in range(3))
        logits = q @ k.T / math.sqrt(hd)
        att = np.exp(logits - logits.max(1, keepdims=True))
        out[:, h * hd:(h + 1) * hd] = (att / att.sum(1, keepdims=True)) @ v
    x = x + s[p + "ls1.gamma"] * _linear(out, s, p + "attn.proj")
    y = _layer_norm(x, s[p + "norm2.weight"], s[p + "norm2.bias"])
    if p + "mlp.w12.weight" in s:
        gate, val = np.split(_linear(y, s, p + "mlp.w12"), 2, axis=-1)
        y = _linear(gate / (1.0 + np.exp(-gate)) * val, s, p + "mlp.w3")     # silu(gate) * value
    else:
        y = _linear(_gelu(_linear(y, s, p + "mlp.fc1")), s, p + "mlp.fc2")
    return x + s[p + "ls2.gamma"] * y


def _hand_tokens(image_u8, s):
    """Input tokens of an image already at a multiple of 14 px, patch positions all equal."""
    img = (image_u8 / 255.0 - MEAN) / STD
    rows, cols = img.shape[0] // 14, img.shape[1] // 14
    patches = img.reshape(rows, 14, cols, 14, 3).transpose(0, 2, 4, 1, 3).reshape(rows * cols, 3 * 14 * 14)
    x = patches @ s["patch_embed.proj.weight"].reshape(D, -1).T + s["patch_embed.proj.bias"]
    x = x + s["pos_embed"][0, 1]
    cls = s["cls_token"][0] + s["pos_embed"][0, :1]
    return np.concatenate([cls, x], axis=0), rows, cols


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def test_facets_equal_a_hand_computation(state, tmp_path):
    """Value / key / query facets of layers 0 and 1, and the token facet, from the raw weights.

    Patch positions are made equal so that any grid gets the same positions (bicubic keeps a
    constant); a 56 x 42 image gives 4 x 3 patches plus the class token."""
    s = {k: v.clone() for k, v in state.items()}
    s["pos_embed"][:, 1:] = s["pos_embed"][:, 1:2]
    path = tmp_path / "flat_positions.pth"
    torch.save(s, path)
    s64 = {k: v.double().numpy() for k, v in s.items()}
    image = np.random.default_rng(5).integers(0, 256, size=(42, 56, 3), dtype=np.uint8)
    x0, rows, cols = _hand_tokens(image.astype(np.float64), s64)
    x1 = _hand_block(x0, s64, "blocks.0.", HEADS)
    for layer, x in ((0, x0), (1, x1)):
        p = f"blocks.{layer}."
        qkv = _linear(_layer_norm(x, s64[p + "norm1.weight"], s64[p + "norm1.bias"]), s64, p + "attn.qkv")
        for part, facet in enumerate(("query", "key", "value")):
            ex = Dinov2Extractor("vits14", layer=layer, facet=facet, weights=path,
                                 input_width_px=56, input_height_px=42)
            expected = _unit(qkv[1:, part * D:(part + 1) * D]).reshape(rows, cols, D)
            np.testing.assert_allclose(ex([image])[0], expected, atol=2e-4, err_msg=f"{facet} layer {layer}")
    token = Dinov2Extractor("vits14", layer=0, facet="token", weights=path, input_width_px=56, input_height_px=42)
    np.testing.assert_allclose(token([image])[0], _unit(x1[1:]).reshape(rows, cols, D), atol=2e-4)


@pytest.mark.parametrize("ffn, hidden", [("mlp", 192), ("swiglu", 128)])
def test_block_equals_a_hand_computation_in_double_precision(ffn, hidden):
    """A whole block, GELU MLP (S, B, L) or ViT-g's SwiGLU with its shrunk hidden size
    ((int(4 * 48 * 2 / 3) + 7) // 8 * 8 = 128), on a tiny stand-in configuration."""
    config = VitConfig(embed_dim=48, depth=1, num_heads=4, ffn=ffn)
    assert config.ffn_hidden == hidden
    torch.manual_seed(1)
    net = DinoV2Vit(config).double()
    with torch.no_grad():
        for t in net.parameters():
            t.copy_(torch.randn_like(t) * 0.5 + (0.5 if t.ndim == 1 else 0.0))
    x = torch.randn(1, 7, 48, dtype=torch.float64)
    s64 = {k: v.numpy() for k, v in net.state_dict().items()}
    with torch.inference_mode():
        got = net.blocks[0](x)[0].numpy()
    np.testing.assert_allclose(got, _hand_block(x[0].numpy(), s64, "blocks.0.", 4), atol=1e-9)


def _keys_cubic(t, a=-0.75):
    t = abs(t)
    if t <= 1:
        return (a + 2) * t ** 3 - (a + 3) * t ** 2 + 1
    return a * t ** 3 - 5 * a * t ** 2 + 8 * a * t - 4 * a if t < 2 else 0.0


def _resample_matrix(n_out, n_in=37):
    """Rows: bicubic weights over the n_in trained positions, scale (n_out + 0.1) / n_in, borders clamped."""
    m = np.zeros((n_out, n_in))
    for i in range(n_out):
        src = (i + 0.5) * n_in / (n_out + 0.1) - 0.5
        base = math.floor(src)
        for k in range(-1, 3):
            m[i, min(max(base + k, 0), n_in - 1)] += _keys_cubic(src - (base + k))
    return m


def test_position_interpolation_for_a_non_square_grid():
    rng = np.random.default_rng(2)
    pos = torch.from_numpy(rng.normal(size=(1, 1 + 37 * 37, 5)).astype(np.float32))
    rows, cols = 12, 17
    out = interpolate_pos_embed(pos, rows, cols)
    assert out.shape == (1, 1 + rows * cols, 5)
    assert torch.equal(out[:, 0], pos[:, 0])
    grid = pos[0, 1:].reshape(37, 37, 5).double().numpy()
    expected = np.einsum("ri,ijd,cj->rcd", _resample_matrix(rows), grid, _resample_matrix(cols))
    np.testing.assert_allclose(out[0, 1:].reshape(rows, cols, 5).numpy(), expected, atol=1e-4)
    assert interpolate_pos_embed(pos, 37, 37) is pos


# -- the descriptor ---------------------------------------------------------------------------------
def test_vlad_descriptor_through_the_factory(checkpoint, photos):
    d = make_descriptor("anyloc-dinov2", weights=str(checkpoint), input_width_px=W_PX, input_height_px=H_PX,
                        clusters=4)
    assert d.needs_fit
    d.fit(photos)
    full = d.describe(photos[:3])
    thirds = d.describe_thirds(photos[:3])
    assert full.shape == (3, 4 * D) and thirds.shape == (3, 4, 4 * D)
    np.testing.assert_allclose(np.linalg.norm(thirds, axis=2), 1.0, atol=1e-5)
    np.testing.assert_allclose(thirds[:, 0], full, atol=1e-6)
    assert d.identity.settings == {"model": "vits14", "layer": 10, "facet": "value", "input_width_px": W_PX,
                                   "input_height_px": H_PX, "weights": "dinov2_vits14_pretrain.pth",
                                   "clusters": 4, "seed": 0, "max_features": 100_000}
    rebuilt = descriptor_from_state(d.state_dict(), weights=str(checkpoint))
    assert rebuilt.identity == d.identity
    np.testing.assert_array_equal(rebuilt.describe(photos[:3]), full)


def test_weights_are_found_in_the_torch_hub_cache(checkpoint, photos, offline_hub):
    offline_hub.mkdir(parents=True)
    (offline_hub / "dinov2_vits14_pretrain.pth").symlink_to(checkpoint)
    d = make_descriptor("anyloc-dinov2", input_width_px=W_PX, input_height_px=H_PX, clusters=4)
    d.fit(photos)
    assert d.describe(photos[:1]).shape == (1, 4 * D)
    assert d.identity.settings["weights"] == "dinov2_vits14_pretrain.pth"


def test_offline_without_weights_says_where_to_put_the_file(photos, offline_hub):
    d = make_descriptor("anyloc-dinov2", model="vitb14")       # cheap: nothing is loaded yet
    with pytest.raises(DescriptorError) as err:
        d.fit(photos)
    message = str(err.value)
    assert str(offline_hub / "dinov2_vitb14_pretrain.pth") in message
    assert "--weights" in message and "dinov2_vitb14/dinov2_vitb14_pretrain.pth" in message
    assert not offline_hub.exists() or not any(offline_hub.iterdir())   # no partial file left behind


def test_online_the_checkpoint_is_downloaded_into_the_hub_cache(checkpoint, photos, offline_hub, tmp_path,
                                                                 monkeypatch):
    """A real HTTP server on the loopback interface stands in for the official host."""
    served = tmp_path / "served" / "dinov2_vits14"
    served.mkdir(parents=True)
    (served / "dinov2_vits14_pretrain.pth").symlink_to(checkpoint)

    class QuietHandler(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0),
                                             partial(QuietHandler, directory=str(tmp_path / "served")))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        monkeypatch.setattr(dinov2, "CHECKPOINT_BASE_URL", f"http://127.0.0.1:{server.server_address[1]}")
        ex = Dinov2Extractor("vits14", input_width_px=W_PX, input_height_px=H_PX)
        maps = ex(photos[:1])
    finally:
        server.shutdown()
        server.server_close()
    cached = offline_hub / "dinov2_vits14_pretrain.pth"
    assert cached.read_bytes() == checkpoint.read_bytes()
    assert sorted(p.name for p in offline_hub.iterdir()) == ["dinov2_vits14_pretrain.pth"]
    direct = Dinov2Extractor("vits14", weights=checkpoint, input_width_px=W_PX, input_height_px=H_PX)
    assert np.array_equal(maps, direct(photos[:1]))


# -- bad input --------------------------------------------------------------------------------------
def test_a_checkpoint_that_does_not_fit_names_the_keys(state, tmp_path):
    bad = dict(state)
    bad["blocks.3.attn.qkvx.weight"] = bad.pop("blocks.3.attn.qkv.weight")
    bad["norm.weight"] = torch.zeros(383)
    path = tmp_path / "bad.pth"
    torch.save(bad, path)
    with pytest.raises(DescriptorError) as err:
        load_dinov2("vits14", path)
    message = str(err.value)
    for part in (str(path), "missing keys (1): blocks.3.attn.qkv.weight",
                 "unexpected keys (1): blocks.3.attn.qkvx.weight", "norm.weight (383,) instead of (384,)"):
        assert part in message


def test_a_checkpoint_of_another_size_or_with_registers_gets_a_hint(state, checkpoint, tmp_path):
    with pytest.raises(DescriptorError, match="looks like a vits14 checkpoint"):
        load_dinov2("vitb14", checkpoint)
    path = tmp_path / "reg.pth"
    torch.save({**state, "register_tokens": torch.zeros(1, 4, D)}, path)
    with pytest.raises(DescriptorError, match="unexpected keys.*register_tokens.*reg4"):
        load_dinov2("vits14", path)


def test_unreadable_or_missing_weights_are_named(tmp_path):
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(DescriptorError, match=f"cannot read DINOv2 checkpoint {junk}"):
        load_dinov2("vits14", junk)
    missing = tmp_path / "nowhere.pth"
    with pytest.raises(DescriptorError, match=f"weights file not found: {missing}"):
        make_descriptor("anyloc-dinov2", weights=str(missing))


@pytest.mark.parametrize("settings, match", [
    ({"model": "vith14"}, "unknown DINOv2 model 'vith14'"),
    ({"layer": 12}, r"layer must be in 0\.\.11, got 12"),
    ({"model": "vitg14", "layer": -1}, r"0\.\.39"),
    ({"facet": "values"}, "facet must be one of value, key, query, token"),
    ({"input_width_px": 320}, "input_width_px must be a multiple of 14.*use 308 or 322"),
    ({"input_height_px": 7}, "input_height_px must be a multiple of 14.*at least 14"),
    ({"layer": 2.5}, "layer must be an integer"),
])
def test_bad_settings_are_named(settings, match):
    with pytest.raises(DescriptorError, match=match):
        make_descriptor("anyloc-dinov2", **settings)
