"""Instance masks as a segmentation network makes them (``mask_model=segmenter``).

Starting from the exact visible segmentation, each error is applied with a probability:

- ``split``: an object of at least :attr:`SegmenterErrors.split_min_px` pixels is cut by a
  line through its centroid; one side gets a new id (with no objects.json entry);
- ``sliver``: a small part of an object seen behind a nearer one gets its own new id: a
  small disconnected piece of its mask where it has one, else a strip along the occluder;
- ``hole``: a disc inside the mask is labelled 0;
- ``bleed``: over an arc of its boundary the mask grows by ``width_px`` (Euclidean
  distance) onto the background (label 0) or onto a neighbour;
- ``shadow`` (probability 0 by default): the mask takes in the object's shadow on the
  table, drawn as the mask swept ``offset_px`` in one direction for the whole scene (one
  light) and grown by 2 px, onto background pixels only. Its random draws are made
  only when the probability is above 0, so the other events are unchanged without it.

Every event is recorded (kind, ids, pixels, width) for gt/. New ids start after the
largest gt id so that they never collide with one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class SegmenterErrors:
    """Probabilities (per object) and sizes of the mask errors."""

    split_probability: float = 0.12
    split_min_px: int = 1500
    sliver_probability: float = 0.35
    sliver_width_px: tuple[int, int] = (2, 4)
    sliver_length_px: tuple[int, int] = (15, 40)
    sliver_min_px: int = 30
    hole_probability: float = 0.25
    hole_radius_px: tuple[float, float] = (2.0, 6.0)
    bleed_probability: float = 0.5
    bleed_width_px: tuple[int, int] = (1, 4)
    bleed_arc_deg: tuple[float, float] = (90.0, 240.0)
    bleed_onto_neighbour: float = 0.5
    """Chance that a bleed goes onto a touching neighbour (where there is one)."""
    shadow_probability: float = 0.0
    shadow_offset_px: tuple[float, float] = (4.0, 12.0)


def _angles_deg(shape: tuple[int, int], centre: np.ndarray) -> np.ndarray:
    v, u = np.mgrid[0:shape[0], 0:shape[1]]
    return np.degrees(np.arctan2(v - centre[0], u - centre[1]))


def _arc(shape: tuple[int, int], centre: np.ndarray, direction_deg: float, arc_deg: float
         ) -> np.ndarray:
    diff = (_angles_deg(shape, centre) - direction_deg + 180.0) % 360.0 - 180.0
    return np.abs(diff) <= arc_deg / 2.0


def bleed(masks: np.ndarray, obj_id: int, width_px: float, sector: np.ndarray,
          onto: str) -> np.ndarray:
    """Pixels (H, W bool) that object ``obj_id`` takes when it grows by ``width_px``
    (Euclidean) inside ``sector``: label-0 pixels (``onto="background"``) or other objects'
    (``onto="neighbour"``)."""
    own = masks == obj_id
    near = ndimage.distance_transform_edt(~own) <= width_px
    target = masks == 0 if onto == "background" else (masks != 0) & ~own
    return near & ~own & sector & target


def _split(masks: np.ndarray, obj_id: int, new_id: int, rng: np.random.Generator) -> int:
    own = masks == obj_id
    v, u = np.nonzero(own)
    angle = rng.uniform(0, np.pi)
    side = (u - u.mean()) * np.cos(angle) + (v - v.mean()) * np.sin(angle) > 0
    masks[v[side], u[side]] = new_id
    return int(side.sum())


def _sliver(masks: np.ndarray, obj_id: int, new_id: int, depth_m: np.ndarray,
            cfg: SegmenterErrors, rng: np.random.Generator) -> tuple[int, str]:
    """Give a sliver of ``obj_id`` seen behind a nearer object ``new_id``; (pixels, how)."""
    own = masks == obj_id
    labels, n = ndimage.label(own)
    if n > 1:
        sizes = ndimage.sum(own, labels, index=np.arange(1, n + 1))
        small = [k + 1 for k, s in enumerate(sizes)
                 if cfg.sliver_min_px <= s < 0.25 * own.sum()]
        if small:
            piece = labels == small[int(rng.integers(len(small)))]
            masks[piece] = new_id
            return int(piece.sum()), "piece"
    others = (masks != 0) & ~own
    ring = own & ndimage.binary_dilation(others)
    cand_v, cand_u = np.nonzero(ring)
    nearer = np.array([False] * len(cand_v))
    if len(cand_v):
        # an occluder is a neighbouring object pixel nearer than this one
        nb_min = ndimage.grey_erosion(np.where(others & np.isfinite(depth_m), depth_m, np.inf),
                                      size=(3, 3))
        nearer = nb_min[cand_v, cand_u] < np.nan_to_num(depth_m[cand_v, cand_u], nan=-np.inf)
    if not nearer.any():
        return 0, ""
    pick = int(rng.choice(np.flatnonzero(nearer)))
    width = int(rng.integers(cfg.sliver_width_px[0], cfg.sliver_width_px[1] + 1))
    length = float(rng.uniform(*cfg.sliver_length_px))
    v, u = np.mgrid[0:masks.shape[0], 0:masks.shape[1]]
    strip = own & (ndimage.distance_transform_edt(~others) <= width) & (
        (v - cand_v[pick]) ** 2 + (u - cand_u[pick]) ** 2 <= (length / 2) ** 2)
    if strip.sum() < cfg.sliver_min_px or strip.sum() > 0.5 * own.sum():
        return 0, ""
    masks[strip] = new_id
    return int(strip.sum()), "strip"


def _hole(masks: np.ndarray, obj_id: int, cfg: SegmenterErrors, rng: np.random.Generator
          ) -> tuple[int, float]:
    own = masks == obj_id
    radius = float(rng.uniform(*cfg.hole_radius_px))
    inside = ndimage.distance_transform_edt(own) > radius + 1
    if not inside.any():
        return 0, radius
    v, u = np.nonzero(inside)
    k = int(rng.integers(len(v)))
    yy, xx = np.mgrid[0:masks.shape[0], 0:masks.shape[1]]
    disc = own & ((yy - v[k]) ** 2 + (xx - u[k]) ** 2 <= radius * radius)
    masks[disc] = 0
    return int(disc.sum()), radius


def apply(exact: np.ndarray, depth_m: np.ndarray, rng: np.random.Generator, first_new_id: int,
          cfg: SegmenterErrors = SegmenterErrors()) -> tuple[np.ndarray, list[dict]]:
    """Segmenter-like masks from the exact ones.

    Parameters
    ----------
    exact : (H, W) int instance ids, 0 = no object.
    depth_m : (H, W) true depth (NaN: nothing seen), to tell an occluder from what it hides.
    first_new_id : the first id to give a split half or a sliver.

    Returns
    -------
    (H, W) int32 masks, and the list of events (dicts with ``kind``, ``id``, ...).
    """
    masks = np.asarray(exact).astype(np.int32).copy()
    ids = [int(i) for i in np.unique(masks) if i > 0]
    events: list[dict] = []
    next_id = int(first_new_id)
    for obj_id in ids:
        if (masks == obj_id).sum() >= cfg.split_min_px and rng.random() < cfg.split_probability:
            px = _split(masks, obj_id, next_id, rng)
            events.append({"kind": "split", "id": obj_id, "new_id": next_id, "pixels": px})
            next_id += 1
    for obj_id in ids:
        if rng.random() < cfg.sliver_probability:
            px, how = _sliver(masks, obj_id, next_id, depth_m, cfg, rng)
            if px:
                events.append({"kind": "sliver", "id": obj_id, "new_id": next_id,
                               "pixels": px, "how": how})
                next_id += 1
    for obj_id in ids:
        if rng.random() < cfg.hole_probability:
            px, radius = _hole(masks, obj_id, cfg, rng)
            if px:
                events.append({"kind": "hole", "id": obj_id, "pixels": px,
                               "radius_px": radius})
    for obj_id in ids:
        if rng.random() >= cfg.bleed_probability:
            continue
        own = masks == obj_id
        if not own.any():
            continue
        width = int(rng.integers(cfg.bleed_width_px[0], cfg.bleed_width_px[1] + 1))
        direction = float(rng.uniform(0, 360))
        arc = float(rng.uniform(*cfg.bleed_arc_deg))
        sector = _arc(masks.shape, np.array(ndimage.center_of_mass(own)), direction, arc)
        onto = "background"
        touching = ndimage.binary_dilation(own, iterations=width) & (masks != 0) & ~own
        if touching.any() and rng.random() < cfg.bleed_onto_neighbour:
            onto = "neighbour"
        taken = bleed(masks, obj_id, width, sector, onto)
        if taken.any():
            victims = sorted(int(i) for i in np.unique(masks[taken]) if i > 0)
            masks[taken] = obj_id
            events.append({"kind": "bleed", "id": obj_id, "width_px": width, "onto": onto,
                           "pixels": int(taken.sum()), "arc_deg": arc,
                           "direction_deg": direction, "neighbours": victims})
    if cfg.shadow_probability > 0 and ids:
        light_deg = float(rng.uniform(0, 360))
        for obj_id in ids:
            if rng.random() >= cfg.shadow_probability:
                continue
            offset = float(rng.uniform(*cfg.shadow_offset_px))
            taken = shadow(masks, obj_id, offset, light_deg)
            if taken.any():
                masks[taken] = obj_id
                events.append({"kind": "shadow", "id": obj_id, "offset_px": offset,
                               "direction_deg": light_deg, "pixels": int(taken.sum())})
    return masks, events


def shadow(masks: np.ndarray, obj_id: int, offset_px: float, direction_deg: float
           ) -> np.ndarray:
    """Pixels (H, W bool) of background (label 0) that object ``obj_id``'s mask takes in
    when its shadow is cast ``offset_px`` pixels towards ``direction_deg`` (image angle,
    0 = +column, 90 = +row): the mask swept that far in 1 px steps (the shadow starts at
    the object) and grown by 2 px."""
    own = masks == obj_id
    cast = own.copy()
    steps = max(int(np.ceil(offset_px)), 1)
    for t in np.linspace(offset_px / steps, offset_px, steps):
        dv = t * np.sin(np.radians(direction_deg))
        du = t * np.cos(np.radians(direction_deg))
        cast |= ndimage.shift(own.astype(np.float64), (dv, du), order=1, mode="constant") > 0.5
    cast = ndimage.binary_dilation(cast, iterations=2)
    return cast & ~own & (masks == 0)


def keep_usable(masks: np.ndarray, exact: np.ndarray, valid_depth: np.ndarray,
                events: list[dict], min_px: int) -> tuple[np.ndarray, list[dict]]:
    """Undo errors that leave an id with fewer than ``min_px`` pixels of valid depth (a
    segmenter's output that r2s would reject): a new id goes back to its source id, an
    original id gets its exact pixels back. Returns the masks and the events kept."""
    masks = masks.copy()
    source = {e["new_id"]: e["id"] for e in events if "new_id" in e}
    kept = list(events)
    for _ in range(3):
        bad = [int(i) for i in np.unique(masks) if i > 0
               and int(((masks == i) & valid_depth).sum()) < min_px]
        if not bad:
            break
        for i in bad:
            if i in source:
                masks[masks == i] = source[i]
                kept = [e for e in kept if e.get("new_id") != i]
            else:
                masks[exact == i] = i
                kept = [e for e in kept if e["id"] != i and i not in e.get("neighbours", [])]
    return masks, kept
