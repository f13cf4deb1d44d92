"""AnyLoc's DINOv2 backend: a ViT's attention facet of one layer as dense local features, + VLAD.

The network is written here from the DINOv2 architecture (Oquab et al. 2023), with the parameter
names and shapes of the official backbone checkpoints ``dinov2_vit{s,b,l,g}14_pretrain.pth`` so
that they load with ``strict=True``:

- patch 14 px (``patch_embed.proj``: a 14x14 stride-14 convolution), a class token
  (``cls_token`` (1, 1, D)), learned positions for a 518 px training input (``pos_embed``
  (1, 1 + 37*37, D)), an unused ``mask_token`` (1, D), then pre-norm blocks
  ``x += ls1(attn(norm1(x))); x += ls2(mlp(norm2(x)))`` with LayerScale (``ls1.gamma`` (D,)),
  multi-head attention with one fused ``attn.qkv`` projection (rows: query, key, value, each
  with the heads side by side) and ``attn.proj``, and a final ``norm``. LayerNorm epsilon 1e-6.
- ViT-S/14: D 384, 12 blocks, 6 heads; ViT-B/14: 768, 12, 12; ViT-L/14: 1024, 24, 16 (all with
  a GELU MLP ``mlp.fc1`` / ``mlp.fc2``, hidden 4 D); ViT-g/14: 1536, 40, 24 with a SwiGLU MLP
  ``mlp.w12`` (both gates, 2 x 4096 rows) and ``mlp.w3``, hidden (int(4 D * 2/3) + 7) // 8 * 8.
- Positions for another patch grid are resampled bicubically as DINOv2 does it: with a scale
  factor of (grid + 0.1) / 37 per axis rather than a target size (this sets where the samples
  fall, so features match the reference implementation), and not at all for a 37 x 37 grid.

AnyLoc's features (Keetha et al. 2023): the image normalised with ImageNet mean / std, the
chosen layer's attention *value* facet (the value rows of ``qkv`` applied to that block's
``norm1`` output, heads concatenated), the class token dropped, each patch feature L2-normalised.
Layers count from 0 like ``blocks.N``: ViT-S and ViT-B layer 10 (AnyLoc's ablations), ViT-g
layer 31 (AnyLoc's default). Other facets: ``query``, ``key`` and ``token`` (the block output).

Weights: the ``weights`` path if given, else the torch hub cache file
``<torch.hub.get_dir()>/checkpoints/dinov2_vits14_pretrain.pth`` (and its siblings), downloaded
from :data:`CHECKPOINT_BASE_URL` only when that cache file is missing and the server answers.
They load on first use, so building a descriptor (e.g. from a map's state) is cheap.
"""

from __future__ import annotations

import math
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from core.atomic import AtomicFile
from descriptors.base import DescriptorError
from descriptors.preprocess import resize_rgb

PATCH_PX = 14
TRAIN_GRID = 37                      # 518 px / 14: the grid the checkpoints' pos_embed was learned for
LAYER_NORM_EPS = 1e-6
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
FACETS = ("value", "key", "query", "token")
CHECKPOINT_BASE_URL = "https://dl.fbaipublicfiles.com/dinov2"
DOWNLOAD_TIMEOUT_S = 10.0            # connect / read timeout: an offline machine fails fast


@dataclass(frozen=True)
class VitConfig:
    """Shape of one DINOv2 backbone. ``ffn`` is "mlp" (GELU) or "swiglu"."""

    embed_dim: int
    depth: int
    num_heads: int
    ffn: str = "mlp"
    default_layer: int = 0

    @property
    def ffn_hidden(self) -> int:
        hidden = 4 * self.embed_dim
        if self.ffn == "swiglu":      # DINOv2 shrinks SwiGLU's hidden size to keep its parameter count
            hidden = (int(hidden * 2 / 3) + 7) // 8 * 8
        return hidden


# Default layers: S and B 10 (AnyLoc's ablations), g 31 (AnyLoc's default). For L (24 blocks) no
# AnyLoc result is known to us; 20 sits between the relative depths of the others (10/11, 31/39).
MODELS: dict[str, VitConfig] = {
    "vits14": VitConfig(384, 12, 6, "mlp", default_layer=10),
    "vitb14": VitConfig(768, 12, 12, "mlp", default_layer=10),
    "vitl14": VitConfig(1024, 24, 16, "mlp", default_layer=20),
    "vitg14": VitConfig(1536, 40, 24, "swiglu", default_layer=31),
}


# -- the network ----------------------------------------------------------------------------------
class PatchEmbed(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.proj = nn.Conv2d(3, dim, kernel_size=PATCH_PX, stride=PATCH_PX)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x).flatten(2).transpose(1, 2)       # (B, rows*cols, D), row-major


class Attention(nn.Module):
    def __init__(self, dim: int, num_heads: int):
        super().__init__()
        self.num_heads = num_heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, n, d = x.shape
        q, k, v = self.qkv(x).view(b, n, 3, self.num_heads, d // self.num_heads).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(q, k, v)        # softmax(q k^T / sqrt(d_head)) v
        return self.proj(out.transpose(1, 2).reshape(b, n, d))


class LayerScale(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.gamma = nn.Parameter(torch.ones(dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.gamma


class Mlp(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(F.gelu(self.fc1(x)))


class SwiGlu(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.w12 = nn.Linear(dim, 2 * hidden)
        self.w3 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        gate, value = self.w12(x).chunk(2, dim=-1)
        return self.w3(F.silu(gate) * value)


class Block(nn.Module):
    def __init__(self, config: VitConfig):
        super().__init__()
        d = config.embed_dim
        self.norm1 = nn.LayerNorm(d, eps=LAYER_NORM_EPS)
        self.attn = Attention(d, config.num_heads)
        self.ls1 = LayerScale(d)
        self.norm2 = nn.LayerNorm(d, eps=LAYER_NORM_EPS)
        self.mlp = SwiGlu(d, config.ffn_hidden) if config.ffn == "swiglu" else Mlp(d, config.ffn_hidden)
        self.ls2 = LayerScale(d)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.ls1(self.attn(self.norm1(x)))
        return x + self.ls2(self.mlp(self.norm2(x)))


class DinoV2Vit(nn.Module):
    """A DINOv2 backbone; :meth:`facet` gives one layer's tokens (class token first)."""

    def __init__(self, config: VitConfig):
        super().__init__()
        d = config.embed_dim
        self.config = config
        self.cls_token = nn.Parameter(torch.zeros(1, 1, d))
        self.pos_embed = nn.Parameter(torch.zeros(1, 1 + TRAIN_GRID * TRAIN_GRID, d))
        self.mask_token = nn.Parameter(torch.zeros(1, d))     # training only; kept so the checkpoint loads strictly
        self.patch_embed = PatchEmbed(d)
        self.blocks = nn.ModuleList(Block(config) for _ in range(config.depth))
        self.norm = nn.LayerNorm(d, eps=LAYER_NORM_EPS)

    def tokens(self, images: torch.Tensor) -> torch.Tensor:
        """(B, 1 + rows*cols, D) input tokens of normalised (B, 3, 14 rows, 14 cols) images."""
        rows, cols = images.shape[2] // PATCH_PX, images.shape[3] // PATCH_PX
        x = self.patch_embed(images)
        x = torch.cat([self.cls_token.expand(x.shape[0], -1, -1), x], dim=1)
        return x + interpolate_pos_embed(self.pos_embed, rows, cols)

    def facet(self, images: torch.Tensor, layer: int, facet: str = "value") -> torch.Tensor:
        """(B, 1 + rows*cols, D): ``facet`` of block ``layer`` (0-based); blocks after it do not run."""
        x = self.tokens(images)
        for block in self.blocks[:layer]:
            x = block(x)
        block = self.blocks[layer]
        if facet == "token":
            return block(x)
        d = self.config.embed_dim
        part = {"query": 0, "key": 1, "value": 2}[facet]
        return block.attn.qkv(block.norm1(x))[..., part * d:(part + 1) * d]


def interpolate_pos_embed(pos_embed: torch.Tensor, rows: int, cols: int) -> torch.Tensor:
    """(1, 1 + rows*cols, D) positions for a rows x cols patch grid from the 37 x 37 trained ones.

    Bicubic (PyTorch's, a = -0.75, borders clamped) with the scale factor (n + 0.1) / 37 per
    axis as DINOv2 does; the class token's position is kept; a 37 x 37 grid is returned as is."""
    side = int(round(math.sqrt(pos_embed.shape[1] - 1)))
    if (rows, cols) == (side, side):
        return pos_embed
    d = pos_embed.shape[2]
    grid = pos_embed[:, 1:].reshape(1, side, side, d).permute(0, 3, 1, 2)
    grid = F.interpolate(grid.float(), scale_factor=((rows + 0.1) / side, (cols + 0.1) / side),
                         mode="bicubic", align_corners=False)
    if grid.shape[2:] != (rows, cols):   # cannot happen for n >= 1; guards the +0.1 rounding argument
        raise DescriptorError(f"position interpolation gave a {tuple(grid.shape[2:])} grid, not {rows}x{cols}")
    grid = grid.permute(0, 2, 3, 1).reshape(1, rows * cols, d).to(pos_embed.dtype)
    return torch.cat([pos_embed[:, :1], grid], dim=1)


# -- checkpoints ----------------------------------------------------------------------------------
def model_config(model: str) -> VitConfig:
    """The :class:`VitConfig` of ``model`` ("vits14", "vitb14", "vitl14", "vitg14")."""
    try:
        return MODELS[model]
    except KeyError:
        raise DescriptorError(f"unknown DINOv2 model {model!r}; choose one of {', '.join(MODELS)}") from None


def checkpoint_file_name(model: str) -> str:
    return f"dinov2_{model}_pretrain.pth"


def checkpoint_url(model: str) -> str:
    return f"{CHECKPOINT_BASE_URL}/dinov2_{model}/{checkpoint_file_name(model)}"


def hub_checkpoint_path(model: str) -> Path:
    """Where torch hub keeps the official checkpoint (``TORCH_HOME`` moves it)."""
    return Path(torch.hub.get_dir()) / "checkpoints" / checkpoint_file_name(model)


def expected_shapes(config: VitConfig) -> dict[str, tuple[int, ...]]:
    """Parameter name -> shape of a checkpoint for ``config`` (built on the meta device: no memory)."""
    with torch.device("meta"):
        net = DinoV2Vit(config)
    return {name: tuple(t.shape) for name, t in net.state_dict().items()}


def locate_checkpoint(model: str, weights: str | Path | None) -> Path:
    """The checkpoint file to load: ``weights``, else the hub cache file (downloaded if online)."""
    if weights is not None:
        path = Path(weights).expanduser()
        if not path.is_file():
            raise DescriptorError(f"DINOv2 weights file not found: {path}")
        return path
    path = hub_checkpoint_path(model)
    if not path.is_file():
        download_checkpoint(model, path)
    return path


def download_checkpoint(model: str, dest: Path) -> None:
    """Fetch the official checkpoint to ``dest`` (via a partial file); offline -> DescriptorError
    saying where to put the file by hand."""
    from tqdm import tqdm
    url = checkpoint_url(model)
    part = None
    try:
        with urllib.request.urlopen(url, timeout=DOWNLOAD_TIMEOUT_S) as response:
            total = int(response.headers.get("Content-Length") or 0) or None
            part = AtomicFile(dest, binary=True)
            with tqdm(total=total, unit="B", unit_scale=True, desc=f"downloading {dest.name}") as bar:
                while chunk := response.read(1 << 20):
                    part.write(chunk)
                    bar.update(len(chunk))
        part.commit()
    except (urllib.error.URLError, OSError, ValueError) as exc:   # offline, refused, timed out, disk full
        if part is not None:
            part.discard()
        reason = getattr(exc, "reason", exc)
        raise DescriptorError(
            f"DINOv2 {model} weights are missing: no file {dest}, and downloading {url} failed ({reason}). "
            f"Download that URL on a machine with internet and put the file at {dest} "
            f"(the torch hub cache; TORCH_HOME moves it), or pass its path with --weights PATH "
            f"(the 'weights' setting of the anyloc-dinov2 descriptor).") from None


def read_state_dict(path: Path) -> dict[str, torch.Tensor]:
    """The checkpoint's tensors as float32 (memory-mapped when the file format allows)."""
    try:
        try:
            state = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
        except RuntimeError:          # an old (non-zip) torch.save file cannot be memory-mapped
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:          # a corrupt or foreign file: say which one
        raise DescriptorError(f"cannot read DINOv2 checkpoint {path}: {exc}") from None
    if not isinstance(state, Mapping) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise DescriptorError(f"DINOv2 checkpoint {path} is not a state dict of tensors "
                              f"(got {type(state).__name__})")
    return {k: (v.float() if v.is_floating_point() and v.dtype != torch.float32 else v) for k, v in state.items()}


def check_state_dict(state: Mapping[str, torch.Tensor], model: str, path: Path) -> None:
    """Raise DescriptorError naming missing, unexpected and wrong-shape keys (first few of each)."""
    expected = expected_shapes(model_config(model))
    missing = [k for k in expected if k not in state]
    unexpected = [k for k in state if k not in expected]
    wrong = [f"{k} {tuple(state[k].shape)} instead of {expected[k]}"
             for k in expected if k in state and tuple(state[k].shape) != expected[k]]
    if not (missing or unexpected or wrong):
        return
    problems = [f"{label} ({len(keys)}): {', '.join(keys[:4])}{', ...' if len(keys) > 4 else ''}"
                for label, keys in (("missing keys", missing), ("unexpected keys", unexpected),
                                    ("wrong shapes", wrong)) if keys]
    raise DescriptorError(f"DINOv2 checkpoint {path} does not fit model {model!r}: {'; '.join(problems)}"
                          f"{_checkpoint_hint(state, model)}")


def _checkpoint_hint(state: Mapping[str, torch.Tensor], model: str) -> str:
    if "register_tokens" in state:
        return (". It holds register tokens (a *_reg4 checkpoint); use the plain "
                f"{checkpoint_file_name(model)}")
    cls = state.get("cls_token")
    depth = len({k.split(".")[1] for k in state if k.startswith("blocks.")})
    for name, config in MODELS.items():
        if name != model and cls is not None and cls.shape[-1] == config.embed_dim and depth == config.depth:
            return f". It looks like a {name} checkpoint: set model={name!r}"
    return ""


def load_dinov2(model: str, path: str | Path) -> DinoV2Vit:
    """The network ``model`` in eval mode with the checkpoint at ``path`` (checked, then strict)."""
    path = Path(path)
    state = read_state_dict(path)
    check_state_dict(state, model, path)
    with torch.device("meta"):        # no random init: parameters are the checkpoint's tensors
        net = DinoV2Vit(model_config(model))
    net.load_state_dict(state, strict=True, assign=True)
    return net.eval()


# -- the extractor --------------------------------------------------------------------------------
class Dinov2Extractor:
    """Callable: list of RGB uint8 images -> (N, rows, cols, D) float32 unit-length patch features.

    Every image is resized (aspect not kept) to ``input_width_px`` x ``input_height_px``, both
    multiples of 14, so a batch is one tensor and every frame sees the same patch grid."""

    def __init__(self, model: str = "vits14", layer: int | None = None, facet: str = "value",
                 weights: str | Path | None = None, input_width_px: int = 322, input_height_px: int = 238,
                 batch_size: int = 8):
        model = str(model).removeprefix("dinov2_")
        self.config = model_config(model)
        self.model = model
        self.layer = self.config.default_layer if layer is None else _integer("layer", layer)
        if not 0 <= self.layer < self.config.depth:
            raise DescriptorError(f"DINOv2 {model} layer must be in 0..{self.config.depth - 1}, got {layer}")
        if facet not in FACETS:
            raise DescriptorError(f"DINOv2 facet must be one of {', '.join(FACETS)}, got {facet!r}")
        self.facet = facet
        self.input_size = (_patch_multiple("input_width_px", input_width_px),
                           _patch_multiple("input_height_px", input_height_px))
        self.batch_size = max(1, int(batch_size))
        self.weights = Path(weights).expanduser() if weights is not None else None
        if self.weights is not None and not self.weights.is_file():
            raise DescriptorError(f"DINOv2 weights file not found: {self.weights}")
        self._net: DinoV2Vit | None = None

    @property
    def feature_dim(self) -> int:
        return self.config.embed_dim

    @property
    def settings(self) -> dict:
        """What changes the features: model, layer, facet, input size and the weights file name."""
        name = self.weights.name if self.weights is not None else checkpoint_file_name(self.model)
        return {"model": self.model, "layer": self.layer, "facet": self.facet,
                "input_width_px": self.input_size[0], "input_height_px": self.input_size[1], "weights": name}

    def grid_shape(self) -> tuple[int, int]:
        """(rows, columns) of the feature map."""
        w, h = self.input_size
        return h // PATCH_PX, w // PATCH_PX

    def network(self) -> DinoV2Vit:
        """The loaded network (first call finds, maybe downloads, and loads the checkpoint)."""
        if self._net is None:
            net = load_dinov2(self.model, locate_checkpoint(self.model, self.weights))
            net.blocks = net.blocks[:self.layer + 1]   # later blocks never run; free their memory
            self._net = net
        return self._net

    def to_tensor(self, images: Sequence[np.ndarray]) -> torch.Tensor:
        """(N, 3, H, W) ImageNet-normalised tensor of already-checked RGB uint8 images."""
        w, h = self.input_size
        batch = np.stack([resize_rgb(img, w, h) for img in images]).astype(np.float32) / 255.0
        batch = (batch - np.asarray(IMAGENET_MEAN, np.float32)) / np.asarray(IMAGENET_STD, np.float32)
        return torch.from_numpy(batch).permute(0, 3, 1, 2).contiguous()

    @torch.inference_mode()
    def __call__(self, images: Sequence[np.ndarray]) -> np.ndarray:
        net = self.network()
        rows, cols = self.grid_shape()
        out = []
        for start in range(0, len(images), self.batch_size):
            x = self.to_tensor(images[start:start + self.batch_size])
            patches = net.facet(x, self.layer, self.facet)[:, 1:]          # drop the class token
            out.append(F.normalize(patches, dim=-1).reshape(x.shape[0], rows, cols, -1).numpy())
        return np.concatenate(out, axis=0)


def _integer(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise DescriptorError(f"DINOv2 {name} must be an integer, got {value!r}")
    return int(value)


def _patch_multiple(name: str, value: object) -> int:
    px = _integer(name, value)
    if px < PATCH_PX or px % PATCH_PX:
        upper = (px // PATCH_PX + 1) * PATCH_PX
        hint = f"{px // PATCH_PX * PATCH_PX} or {upper}" if px > PATCH_PX else f"at least {PATCH_PX}"
        raise DescriptorError(f"DINOv2 {name} must be a multiple of {PATCH_PX} px (the patch size), "
                              f"got {value}; use {hint}")
    return px


def make_anyloc_dinov2(model: str = "vits14", layer: int | None = None, facet: str = "value",
                       weights: str | Path | None = None, input_width_px: int = 322,
                       input_height_px: int = 238, clusters: int = 32, seed: int = 0,
                       max_features: int = 100_000, batch_size: int = 8):
    """AnyLoc: DINOv2 ``model`` facet of ``layer`` (None: the model's default) + VLAD-``clusters``.

    322 x 238 px (23 x 17 patches) is the multiple-of-14 size nearest to the 320 x 240 frames used
    elsewhere in this project: a 1% stretch instead of AnyLoc's crop, so the whole field of view
    is kept. ``weights``: a checkpoint path (default: the torch hub cache file)."""
    from descriptors.dense import DenseVlad
    extractor = Dinov2Extractor(model, layer, facet, weights, input_width_px, input_height_px, batch_size)
    return DenseVlad("anyloc-dinov2", extractor, clusters, seed, max_features)
