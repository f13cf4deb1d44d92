"""Appearance seeds: the same world under another light with a few props moved, as the paper's
navigation ran at other times than its mapping."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sim.world_spec import LightSpec, PropSpec, WorldSpec

#: largest shift and turn that an appearance seed gives a movable prop
MAX_PROP_SHIFT_M = 0.20
MAX_PROP_TURN_DEG = 20.0


def apply_appearance(spec: WorldSpec, appearance_seed: int) -> WorldSpec:
    """The same world under another appearance: light jittered, about half the movable props moved.

    Seed 0 returns ``spec`` unchanged. Other seeds are deterministic: the light direction turns
    by up to 60 deg in azimuth with an elevation of 30..75 deg, its colour gets a warm or cool
    tint of up to 10%, the ambient/diffuse coefficients move by up to 0.12 and the specular one
    by up to 0.05; ceil(n/2) of the n movable props shift by 0.05..MAX_PROP_SHIFT_M and turn by
    up to MAX_PROP_TURN_DEG. Walls, decals and routes never change.
    """
    if appearance_seed < 0:
        raise ValueError(f"appearance_seed must be >= 0, got {appearance_seed}")
    if appearance_seed == 0:
        return spec
    rng = np.random.default_rng([appearance_seed, 0x5EED])
    return dataclasses.replace(spec, light=_jitter_light(spec.light, rng), props=_move_props(spec.props, rng))


def _jitter_light(light: LightSpec, rng: np.random.Generator) -> LightSpec:
    d = np.asarray(light.direction, dtype=float)
    azimuth = math.atan2(d[1], d[0]) + math.radians(rng.uniform(-60.0, 60.0))
    elevation = math.radians(rng.uniform(30.0, 75.0))
    direction = (math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                 math.sin(elevation))
    tint = rng.uniform(-1.0, 1.0)
    gain = rng.uniform(0.92, 1.0)
    color = np.clip(np.asarray(light.color) * gain * (1.0 + 0.1 * np.array([tint, 0.0, -tint])), 0.0, 1.0)
    return dataclasses.replace(
        light,
        direction=tuple(round(v, 6) for v in direction),
        color=tuple(float(round(v, 6)) for v in color),
        ambient=float(np.clip(light.ambient + rng.uniform(-0.12, 0.12), 0.25, 0.95)),
        diffuse=float(np.clip(light.diffuse + rng.uniform(-0.12, 0.12), 0.1, 0.8)),
        specular=float(np.clip(light.specular + rng.uniform(-0.05, 0.05), 0.0, 0.3)),
    )


def _move_props(props: tuple[PropSpec, ...], rng: np.random.Generator) -> tuple[PropSpec, ...]:
    movable = [i for i, p in enumerate(props) if p.movable]
    if not movable:
        return props
    chosen = set(rng.choice(movable, size=(len(movable) + 1) // 2, replace=False).tolist())
    out = list(props)
    for i in sorted(chosen):
        x, y, yaw = props[i].pose
        r = rng.uniform(0.05, MAX_PROP_SHIFT_M)
        a = rng.uniform(0.0, 2.0 * math.pi)
        turn = rng.uniform(-MAX_PROP_TURN_DEG, MAX_PROP_TURN_DEG)
        out[i] = dataclasses.replace(props[i], pose=(x + r * math.cos(a), y + r * math.sin(a), yaw + turn))
    return tuple(out)
