"""Labelled street scenes for detection (issue 19; the paper's Sec. 6.1 automotive task).

No street dataset can be downloaded here, so scenes are drawn: sky, a row of building
facades with windows, a road with a dashed centre line, dead-leaves clutter (the texture
model of scenes/procedural.py) on facades and road, and objects of four classes standing on
the ground plane: vehicles (side or rear view), pedestrians, bikes and traffic lights on
poles. An object's size follows where it stands (a pinhole camera over a flat road: the
height in pixels is proportional to its base's distance below the horizon), from about 8 px
to a third of the frame; nearer objects are drawn later and so occlude farther ones, and each
box is the extent of the object's *visible* pixels (COCO's convention).

Light varies inside a frame: cast shadows (hard-edged, with a short penumbra) and dusk
gradients leave regions with 10-100x less light than the sunlit ones (never less than 1/100),
so photon noise decides what can be seen there. A lit traffic-light lamp emits, whatever the shadow.

``street_scene`` returns linear radiance (sunlit white reflectance = ``level``), the light
map, the boxes, the class labels and per-object light; everything is a function of ``seed``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError

#: COCO categories of the scenes (ids as written in COCO JSON; 0 is left for "background")
CATEGORIES = (
    {"id": 1, "name": "vehicle"},
    {"id": 2, "name": "pedestrian"},
    {"id": 3, "name": "bike"},
    {"id": 4, "name": "traffic light"},
)
CLASS_IDS = {c["name"]: c["id"] for c in CATEGORIES}

_CAR_COLOURS = np.array(
    [
        [0.55, 0.05, 0.04],
        [0.05, 0.12, 0.45],
        [0.75, 0.75, 0.72],
        [0.04, 0.04, 0.05],
        [0.38, 0.40, 0.42],
        [0.70, 0.55, 0.05],
        [0.10, 0.30, 0.12],
    ],
    np.float32,
)
_CLOTHES = np.array(
    [
        [0.60, 0.08, 0.08],
        [0.08, 0.15, 0.50],
        [0.05, 0.05, 0.06],
        [0.55, 0.50, 0.35],
        [0.15, 0.40, 0.20],
        [0.70, 0.65, 0.10],
        [0.45, 0.20, 0.45],
    ],
    np.float32,
)
_SKIN = np.array([[0.62, 0.42, 0.32], [0.45, 0.28, 0.18], [0.25, 0.15, 0.10]], np.float32)
_FACADES = np.array(
    [[0.45, 0.42, 0.38], [0.55, 0.45, 0.35], [0.35, 0.33, 0.32], [0.60, 0.58, 0.52], [0.42, 0.28, 0.22]], np.float32
)
_LAMPS = {"red": (1.0, 0.08, 0.04), "yellow": (1.0, 0.65, 0.02), "green": (0.08, 1.0, 0.45)}


@dataclass
class StreetScene:
    radiance: torch.Tensor  # [3, H, W] linear radiance (a sunlit white surface = level)
    light: torch.Tensor  # [H, W] illumination relative to sunlight (1 = sunlit)
    boxes: torch.Tensor  # [N, 4] visible extent, x0, y0, x1, y1 in pixels (x1, y1 exclusive)
    labels: torch.Tensor  # [N] COCO category ids (CATEGORIES)
    object_light: torch.Tensor  # [N] mean illumination over each object's visible pixels
    object_index: list[int]  # [N] each labelled object's index among the scene's objects (for ``hide``)
    owner: np.ndarray  # [H, W] index of the object a pixel shows (-1: background)


def _grid(y0: int, x0: int, h: int, w: int, H: int, W: int):
    """Pixel-centre coordinates of the box's part inside the frame, in the box's units
    (u across, v down, both 0..1), and the slices they fill."""
    ya, yb, xa, xb = max(y0, 0), min(y0 + h, H), max(x0, 0), min(x0 + w, W)
    if ya >= yb or xa >= xb:
        return None
    v = (np.arange(ya, yb, dtype=np.float32)[:, None] + 0.5 - y0) / h
    u = (np.arange(xa, xb, dtype=np.float32)[None, :] + 0.5 - x0) / w
    return (
        np.broadcast_to(u, (yb - ya, xb - xa)),
        np.broadcast_to(v, (yb - ya, xb - xa)),
        (slice(ya, yb), slice(xa, xb)),
    )


def _rect(u, v, u0, u1, v0, v1):
    return (u >= u0) & (u < u1) & (v >= v0) & (v < v1)


def _disc(u, v, cu, cv, r, aspect):
    """A disc of radius r (in units of the box height) centred at (cu, cv); aspect = w / h."""
    return ((u - cu) * aspect) ** 2 + (v - cv) ** 2 <= r * r


def _segment(u, v, a, b, half_width, aspect):
    """Pixels within half_width (box heights) of the segment a-b (box units)."""
    pu, pv = (u - a[0]) * aspect, v - a[1]
    du, dv = (b[0] - a[0]) * aspect, b[1] - a[1]
    t = np.clip((pu * du + pv * dv) / max(du * du + dv * dv, 1e-12), 0.0, 1.0)
    return (pu - t * du) ** 2 + (pv - t * dv) ** 2 <= half_width**2


def _vehicle(u, v, aspect, rng):
    """Side view (aspect ~2.3) or rear view (aspect ~1.3): layers of (mask, albedo)."""
    paint = _CAR_COLOURS[rng.integers(len(_CAR_COLOURS))]
    glass, tyre, light = np.array([0.06, 0.08, 0.10]), np.array([0.03, 0.03, 0.03]), np.array([0.6, 0.1, 0.05])
    if aspect > 1.7:
        body = _rect(u, v, 0.0, 1.0, 0.38, 0.86)
        cabin = _rect(u, v, 0.22 + 0.1 * (0.38 - v), 0.72 - 0.1 * (0.38 - v), 0.0, 0.40)
        window = _rect(u, v, 0.27, 0.67, 0.07, 0.36) & ~_rect(u, v, 0.46, 0.48, 0.0, 1.0)
        wheels = _disc(u, v, 0.2, 0.82, 0.18, aspect) | _disc(u, v, 0.8, 0.82, 0.18, aspect)
        hubs = _disc(u, v, 0.2, 0.82, 0.07, aspect) | _disc(u, v, 0.8, 0.82, 0.07, aspect)
        return [(body | cabin, paint), (window, glass), (wheels, tyre), (hubs, np.array([0.5, 0.5, 0.5]))]
    body = _rect(u, v, 0.0, 1.0, 0.40, 0.88)
    cabin = _rect(u, v, 0.1, 0.9, 0.0, 0.42)
    window = _rect(u, v, 0.17, 0.83, 0.07, 0.36)
    lamps = _rect(u, v, 0.04, 0.2, 0.50, 0.62) | _rect(u, v, 0.8, 0.96, 0.50, 0.62)
    plate = _rect(u, v, 0.38, 0.62, 0.62, 0.72)
    tyres = _rect(u, v, 0.05, 0.22, 0.86, 1.0) | _rect(u, v, 0.78, 0.95, 0.86, 1.0)
    return [(body | cabin, paint), (window, glass), (lamps, light), (plate, np.array([0.8, 0.8, 0.75])), (tyres, tyre)]


def _pedestrian(u, v, aspect, rng):
    shirt, trousers = _CLOTHES[rng.integers(len(_CLOTHES))], _CLOTHES[rng.integers(len(_CLOTHES))]
    skin = _SKIN[rng.integers(len(_SKIN))]
    stride = float(rng.uniform(0.0, 0.12))
    head = _disc(u, v, 0.5, 0.08, 0.075, aspect)
    torso = _rect(u, v, 0.2, 0.8, 0.16, 0.56)
    arms = _segment(u, v, (0.16, 0.2), (0.12 - stride, 0.52), 0.035, aspect) | _segment(
        u, v, (0.84, 0.2), (0.88 + stride, 0.52), 0.035, aspect
    )
    legs = _segment(u, v, (0.38, 0.56), (0.38 - stride * 2, 0.98), 0.045, aspect) | _segment(
        u, v, (0.62, 0.56), (0.62 + stride * 2, 0.98), 0.045, aspect
    )
    return [(arms | torso, shirt), (legs, trousers), (head, skin)]


def _bike(u, v, aspect, rng):
    frame = _CLOTHES[rng.integers(len(_CLOTHES))] * 1.3
    r, t = 0.32, 0.045
    front, back = (0.80, 0.66), (0.20, 0.66)
    tyres = (_disc(u, v, *back, r, aspect) & ~_disc(u, v, *back, r - 2 * t, aspect)) | (
        _disc(u, v, *front, r, aspect) & ~_disc(u, v, *front, r - 2 * t, aspect)
    )
    seat, crank, head = (0.40, 0.22), (0.47, 0.66), (0.72, 0.18)
    bars = (
        _segment(u, v, back, seat, t, aspect)
        | _segment(u, v, seat, crank, t, aspect)
        | _segment(u, v, crank, back, t, aspect)
        | _segment(u, v, seat, head, t, aspect)
        | _segment(u, v, head, front, t, aspect)
        | _segment(u, v, head, (0.66, 0.02), t, aspect)
        | _rect(u, v, 0.32, 0.48, 0.17, 0.23)
    )
    return [(tyres, np.array([0.04, 0.04, 0.04])), (bars, np.clip(frame, 0, 0.9))]


def _traffic_light(u, v, aspect, rng):
    """Housing with three lamps, one lit: (layers, emissive mask, its colour)."""
    housing = _rect(u, v, 0.0, 1.0, 0.0, 1.0)
    lamps = [_disc(u, v, 0.5, c, 0.12, aspect) for c in (0.18, 0.5, 0.82)]
    lit = int(rng.integers(3))
    colour = np.array(_LAMPS[("red", "yellow", "green")[lit]], np.float32)
    layers = [(housing, np.array([0.07, 0.07, 0.06])), (lamps[0] | lamps[1] | lamps[2], np.array([0.12, 0.12, 0.1]))]
    return layers, lamps[lit], colour


def _light_map(H: int, W: int, horizon: int, sky: np.ndarray, rng) -> np.ndarray:
    """Sunlight 1, with 1-2 cast shadows (not on the sky; where two overlap, the deeper one)
    and/or a dusk gradient, each at 1/10-1/100 of it; never below 1/100."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    light = np.ones((H, W), np.float32)
    shade = np.ones((H, W), np.float32)
    kinds = rng.choice(["shadow", "dusk", "both"], p=[0.45, 0.2, 0.35])
    if kinds in ("shadow", "both"):
        for _ in range(int(rng.integers(1, 3))):
            # a building's shadow: one side of a slanted line, from some row down, soft edge
            factor = 10.0 ** -rng.uniform(1.0, 2.0)
            x0, slope = rng.uniform(0.15, 0.85) * W, rng.uniform(-1.2, 1.2)
            top = horizon - rng.uniform(0.0, 0.3) * H
            side = rng.choice([-1.0, 1.0])
            d = side * (xx - (x0 + slope * (yy - horizon)))
            inside = np.clip(0.5 + d / rng.uniform(1.0, 4.0), 0.0, 1.0) * (yy >= top)
            shade = np.minimum(shade, np.exp(np.log(factor) * inside))
    light = np.where(sky, light, shade)
    if kinds in ("dusk", "both"):
        factor = 10.0 ** -rng.uniform(1.0, 2.0)
        ramp = xx / (W - 1) if rng.random() < 0.5 else 1.0 - xx / (W - 1)
        light *= np.exp(np.log(factor) * np.clip((ramp - 0.3) / 0.6, 0.0, 1.0))
    return np.clip(light, 0.01, 1.0).astype(np.float32)


def _background(H: int, W: int, horizon: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Albedo [H, W, 3] (sky, facades with windows, road with a dashed centre line, clutter)
    and the sky's mask [H, W]."""
    from .procedural import dead_leaves

    alb = np.empty((H, W, 3), np.float32)
    sky = np.zeros((H, W), bool)
    sky[:horizon] = True
    t = (np.arange(H, dtype=np.float32) / max(horizon, 1))[:, None, None]
    alb[:] = np.array([0.30, 0.45, 0.80]) * (1 - t) + np.array([0.70, 0.75, 0.85]) * t  # sky (as a reflectance)
    x = 0
    while x < W:  # facades along the horizon
        bw = int(rng.uniform(0.12, 0.35) * W)
        top = int(horizon - rng.uniform(0.08, 0.45) * H)
        ya = max(top, 0)
        alb[ya:horizon, x : x + bw] = _FACADES[rng.integers(len(_FACADES))]
        sky[ya:horizon, x : x + bw] = False
        fh = max(horizon - ya, 1)
        wy, wx = max(int(fh / rng.uniform(4, 9)), 2), max(int(bw / rng.uniform(3, 7)), 2)
        win = np.array([0.10, 0.12, 0.16]) if rng.random() < 0.7 else np.array([0.55, 0.5, 0.3])
        yy, xx = np.mgrid[ya:horizon, x : min(x + bw, W)]
        sel = (((yy - ya) % wy) > wy * 0.35) & (((xx - x) % wx) > wx * 0.3) & (yy < horizon - wy * 0.6)
        alb[ya:horizon, x : min(x + bw, W)][sel] = win
        x += bw
    alb[horizon:] = rng.uniform(0.12, 0.22)  # asphalt
    vx, spread = rng.uniform(0.3, 0.7) * W, rng.uniform(-0.6, 0.6)
    yy = np.arange(horizon, H, dtype=np.float32)
    depth = yy - horizon + 1.0
    dash = (np.floor(np.log(depth) * 4.0) % 2) == 0  # dashes shorten towards the horizon
    for k, y in enumerate(range(horizon, H)):
        if dash[k]:
            c = vx + spread * depth[k]
            half = max(0.5, 0.012 * depth[k])
            alb[y, max(int(c - half), 0) : max(int(c + half + 1), 0)] = 0.8
    # dead-leaves clutter at low contrast over everything but the sky
    tex = dead_leaves((H, W), rng, alpha=3.0, colors="grey").numpy().transpose(1, 2, 0)
    return np.where(sky[..., None], alb, alb * (0.75 + 0.5 * tex)).clip(0.0, 1.0).astype(np.float32), sky


_SHAPES = {
    "vehicle": (_vehicle, (1.2, 2.6), 1.5 / 1.4),
    "pedestrian": (_pedestrian, (0.34, 0.46), 1.75 / 1.4),
    "bike": (_bike, (1.6, 1.9), 1.05 / 1.4),
}


def street_scene(
    size=(256, 384),
    seed=None,
    *,
    n_objects: tuple[int, int] = (4, 12),
    level: float = 1.0,
    min_px: float = 8.0,
    max_frac: float = 1 / 3,
    min_visible: float = 0.3,
    hide: frozenset = frozenset(),
) -> StreetScene:
    """A labelled street scene (see the module's docstring). Objects whose visible part is
    under ``min_visible`` of the object, or under 4 px on a side, are left unlabelled (they
    still occlude). ``hide``: indices of objects not to draw (the same scene otherwise: every
    random draw is still made), to check what an object changes."""
    H, W = (size, size) if isinstance(size, (int, np.integer)) else (int(size[0]), int(size[1]))
    if H < 32 or W < 32:
        raise InputError(f"street scenes need at least 32 x 32 pixels, got {H} x {W}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    horizon = int(rng.uniform(0.3, 0.5) * H)
    albedo, sky = _background(H, W, horizon, rng)
    light = _light_map(H, W, horizon, sky, rng)
    emissive = np.zeros((H, W, 3), np.float32)
    owner = np.full((H, W), -1, np.int32)
    max_h = max_frac * H
    objs = []  # (base row, class, box y0, x0, h, w)
    for _ in range(int(rng.integers(n_objects[0], n_objects[1] + 1))):
        cls = str(rng.choice(["vehicle", "pedestrian", "bike", "traffic light"], p=[0.35, 0.3, 0.15, 0.2]))
        if cls == "traffic light":
            h = math.exp(rng.uniform(math.log(min_px), math.log(max(max_h / 2, min_px))))  # small frames: min_px
            w = h * rng.uniform(0.34, 0.42)
            base = horizon + h * rng.uniform(0.3, 2.0)  # its pole's foot
            y0 = base - h * rng.uniform(2.2, 3.5)
        else:
            _, aspects, height_m = _SHAPES[cls]
            h = math.exp(rng.uniform(math.log(min_px), math.log(max_h)))
            w = h * rng.uniform(*aspects)
            base = horizon + h / height_m  # flat road: height proportional to the distance below the horizon
            y0 = base - h
        # an object wider than the frame straddles it (the bounds may cross in narrow frames)
        objs.append(
            (
                base,
                cls,
                int(round(y0)),
                int(round(rng.uniform(-0.1 * w, max(-0.1 * w, W - 0.9 * w)))),
                max(int(round(h)), 2),
                max(int(round(w)), 2),
            )
        )
    objs.sort(key=lambda o: o[0])  # far (near the horizon) first: nearer objects occlude them
    kept = []
    for k, (base, cls, y0, x0, h, w) in enumerate(objs):
        if cls == "traffic light" and k not in hide:  # the pole first, from the housing to the foot
            pw = max(1, int(round(0.12 * w)))
            ya, yb = max(y0 + h, 0), min(int(base), H)
            xa = min(max(x0 + w // 2 - pw // 2, 0), W)
            albedo[ya:yb, xa : xa + pw] = 0.2
            owner[ya:yb, xa : xa + pw] = -1
        g = _grid(y0, x0, h, w, H, W)
        if g is None:
            continue
        u, v, sl = g
        if cls == "traffic light":
            layers, lamp, colour = _traffic_light(u, v, w / h, rng)
        else:
            layers = _SHAPES[cls][0](u, v, w / h, rng)
            lamp = None
        if k in hide:
            continue
        full = np.zeros(u.shape, bool)
        for mask, col in layers:
            albedo[sl][mask] = col
            full |= mask
        owner[sl][full] = k
        emissive[sl][full] = 0.0
        if lamp is not None:
            emissive[sl][lamp] = colour * 2.0  # a lit lamp: brighter than a sunlit white surface
        kept.append((k, cls, int(full.sum())))  # its pixels inside the frame (truncation is not occlusion)
    boxes, labels, olight, index = [], [], [], []
    for k, cls, n_full in kept:
        ys, xs = np.nonzero(owner == k)
        if len(ys) == 0 or len(ys) < min_visible * n_full:
            continue
        x0, y0, x1, y1 = xs.min(), ys.min(), xs.max() + 1, ys.max() + 1
        if x1 - x0 < 4 or y1 - y0 < 4:
            continue
        boxes.append([x0, y0, x1, y1])
        labels.append(CLASS_IDS[cls])
        olight.append(float(light[ys, xs].mean()))
        index.append(k)
    radiance = (albedo * light[..., None] + emissive) * level
    return StreetScene(
        radiance=torch.from_numpy(np.ascontiguousarray(radiance.transpose(2, 0, 1))),
        light=torch.from_numpy(light),
        boxes=torch.tensor(boxes, dtype=torch.float32).reshape(-1, 4),
        labels=torch.tensor(labels, dtype=torch.int64),
        object_light=torch.tensor(olight),
        object_index=index,
        owner=owner,
    )
