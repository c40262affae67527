"""Press positions in the sensor frame (mm): the paper's random strategy, a grid, stratified random.

Everything is derived from the layout (channels as strips of their width around the centre line,
`layout.faces` as the quadrants), nothing assumes the paper's 3 x 3 grid. Positions depend only
on (layout, spec) and are drawn from `np.random.default_rng(spec.seed)`, so a resumed campaign
regenerates them exactly. Coordinates are rounded to 1 um, the resolution the G-code is written at.

Strategies:
- "paper": uniform over the pressable area, i.e. the union of the channel strips and the bounded
  faces (the paper's "on the channels or within the central quadrants");
  `channel_fraction` overrides the share of positions on channels.
- "grid": a regular rows x cols grid over the layout's bounding box (count must be rows*cols).
- "stratified": every channel and every face gets positions (counts differ by at most one;
  channels evenly spread along their length, one channel width clear of the junctions where
  strips overlap); with fewer positions than features, channels and
  faces alternate in a seeded order so both kinds are covered.
`PositionSpec`, the `[positions]` table, is declared (and validated at construction) in
`neatskin.config.files`. Options: `min_spacing_mm` between positions, keep-out circles (`keep_out`) and a keep-out
radius around every electrode's fitting (`electrode_keep_out_mm`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neatskin.config.files import POSITION_STRATEGIES, PositionSpec, square_grid
from neatskin.errors import ConfigError
from neatskin.layout import Layout

STRATEGIES = POSITION_STRATEGIES
_DECIMALS = 3
_MAX_ATTEMPTS = 200


@dataclass(frozen=True)
class PositionSet:
    """Positions with ids 0..n-1 and the feature each lies on ("channel:<name>", "face:<k>" or "none")."""

    x_mm: tuple[float, ...]
    y_mm: tuple[float, ...]
    features: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.x_mm)

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(range(len(self.x_mm)))

    @property
    def xy_mm(self) -> np.ndarray:
        return np.column_stack([self.x_mm, self.y_mm]) if self.x_mm else np.zeros((0, 2))


def generate_positions(layout: Layout, spec: PositionSpec) -> PositionSet:
    """Press positions for `layout` under `spec`; the same inputs always give the same positions."""
    rng = np.random.default_rng(0 if spec.seed is None else spec.seed)  # None: a protocol gives campaign.seed
    if spec.strategy == "grid":
        xy = _grid(layout, spec)
    elif spec.strategy == "paper":
        xy = _accept(layout, spec, lambda n: _sample_area(layout, spec, rng, n), spec.count)
    else:
        xy = _stratified(layout, spec, rng)
    xy = np.round(xy, _DECIMALS) + 0.0  # + 0.0 turns -0.0 into 0.0
    features = classify(layout, xy[:, 0], xy[:, 1])
    return PositionSet(tuple(float(v) for v in xy[:, 0]), tuple(float(v) for v in xy[:, 1]), features)


def classify(layout: Layout, x_mm, y_mm) -> tuple[str, ...]:
    """The feature under each point: the nearest channel whose strip contains it, else the face, else none."""
    pts = np.column_stack([np.asarray(x_mm, float).ravel(), np.asarray(y_mm, float).ravel()])
    dist = layout.distance_to_channels_mm(pts)  # (points, channels)
    half_width = np.array([c.width_mm / 2 for c in layout.channels])
    on = dist <= half_width + 1e-9
    nearest = np.where(on, dist, np.inf).argmin(axis=1)
    face = np.full(len(pts), -1)
    for k, corners in enumerate(layout.faces):
        inside = inside_polygon(pts, layout.xy_mm[list(corners)]) & (face < 0)
        face[inside] = k
    labels = []
    for i in range(len(pts)):
        if on[i].any():
            labels.append(f"channel:{layout.channels[nearest[i]].name}")
        elif face[i] >= 0:
            labels.append(f"face:{face[i]}")
        else:
            labels.append("none")
    return tuple(labels)


# ---- sampling ----------------------------------------------------------------------------


def inside_polygon(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(n,) whether each point (n, 2) is inside the polygon with these corners (m, 2), by the even-odd rule: a ray
    from the point towards +x crosses its edges an odd number of times. A point on an edge may go either way (a
    face's edges are channel centre lines, which every caller treats as a channel first)."""
    x, y = points[:, :1], points[:, 1:]
    x0, y0 = corners[:, 0], corners[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    straddles = (y0 > y) != (y1 > y)  # an edge that spans the ray's height (never a horizontal one)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at_y = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return np.count_nonzero(straddles & (x < x_at_y), axis=1) % 2 == 1


def _face_areas(layout: Layout) -> np.ndarray:
    areas = []
    for face in layout.faces:
        pts = layout.xy_mm[list(face)]
        areas.append(0.5 * abs(float(np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1]))))
    return np.array(areas)


def _on_channel(layout: Layout, rng: np.random.Generator, channel: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points at fraction s along each given channel, with a uniform offset across its width."""
    a = layout.xy_mm[layout.channel_ends[channel, 0]]
    b = layout.xy_mm[layout.channel_ends[channel, 1]]
    ab = b - a
    normal = np.column_stack([-ab[:, 1], ab[:, 0]]) / np.linalg.norm(ab, axis=1)[:, None]
    width = np.array([layout.channels[c].width_mm for c in channel])
    across = (rng.random(len(channel)) - 0.5) * width
    return a + s[:, None] * ab + across[:, None] * normal


def _in_face(layout: Layout, rng: np.random.Generator, face: int, n: int) -> np.ndarray:
    """n points uniform inside a face polygon and off every channel strip (rejection from its bounding box)."""
    pts = layout.xy_mm[list(layout.faces[face])]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    half_width = np.array([c.width_mm / 2 for c in layout.channels])
    out = np.zeros((0, 2))
    for _ in range(_MAX_ATTEMPTS):
        if len(out) >= n:
            break
        cand = lo + rng.random((max(2 * n, 16), 2)) * (hi - lo)
        keep = inside_polygon(cand, pts) & np.all(layout.distance_to_channels_mm(cand) > half_width, axis=1)
        out = np.vstack([out, cand[keep]])
    if len(out) < n:
        raise ConfigError(
            f"face {face} has no room off the channels",
            field="positions",
            fix="check the layout: the channels are wider than the face",
        )
    return out[:n]


def _sample_area(layout: Layout, spec: PositionSpec, rng: np.random.Generator, n: int) -> np.ndarray:
    lengths = np.array([c.length_mm * c.width_mm for c in layout.channels])
    areas = _face_areas(layout)
    share = spec.channel_fraction
    if share is None:
        share = lengths.sum() / (lengths.sum() + areas.sum())
    if len(areas) == 0:
        share = 1.0
    on_channel = rng.random(n) < share
    n_ch = int(on_channel.sum())
    channel = rng.choice(len(lengths), size=n_ch, p=lengths / lengths.sum())
    out = np.empty((n, 2))
    out[on_channel] = _on_channel(layout, rng, channel, rng.random(n_ch))
    n_face = n - n_ch
    if n_face:
        faces = rng.choice(len(areas), size=n_face, p=areas / areas.sum())
        face_pts = np.empty((n_face, 2))
        for k in np.unique(faces):
            face_pts[faces == k] = _in_face(layout, rng, int(k), int(np.sum(faces == k)))
        out[~on_channel] = face_pts
    return out


def _allowed(layout: Layout, spec: PositionSpec, pts: np.ndarray) -> np.ndarray:
    ok = np.ones(len(pts), dtype=bool)
    zones = list(spec.keep_out)
    if spec.electrode_keep_out_mm > 0:
        zones += [(*layout.xy_mm[j], spec.electrode_keep_out_mm) for j in layout.electrode_junctions]
    for x, y, r in zones:
        ok &= np.hypot(pts[:, 0] - x, pts[:, 1] - y) >= r
    return ok


def _accept(layout: Layout, spec: PositionSpec, draw, n: int, taken: np.ndarray | None = None) -> np.ndarray:
    """Draw candidates in batches; keep those outside keep-outs and far enough from kept ones."""
    kept = [] if taken is None else list(taken)
    start = len(kept)
    for _ in range(_MAX_ATTEMPTS):
        if len(kept) - start >= n:
            break
        cand = draw(max(n - (len(kept) - start), 1))
        cand = cand[_allowed(layout, spec, cand)]
        for p in cand:
            if len(kept) - start >= n:
                break
            if spec.min_spacing_mm > 0 and kept and np.min(np.hypot(*(np.array(kept) - p).T)) < spec.min_spacing_mm:
                continue
            kept.append(p)
    if len(kept) - start < n:
        raise ConfigError(
            f"could place only {len(kept) - start} of {n} positions with min_spacing_mm = "
            f"{spec.min_spacing_mm} and the keep-out zones",
            file=spec.source,
            field="positions",
            fix="lower count or min_spacing_mm, or shrink the keep-out zones",
        )
    return np.array(kept[start:]).reshape(-1, 2)


def _grid(layout: Layout, spec: PositionSpec) -> np.ndarray:
    rows, cols = spec.grid_shape or square_grid(spec.count)
    x0, y0, x1, y1 = layout.bounds_mm
    gx, gy = np.meshgrid(np.linspace(x0, x1, cols), np.linspace(y0, y1, rows))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    blocked = ~_allowed(layout, spec, pts)
    if blocked.any():
        raise ConfigError(
            f"{int(blocked.sum())} grid positions fall in keep-out zones, e.g. "
            f"({pts[blocked][0, 0]:.2f}, {pts[blocked][0, 1]:.2f}) mm",
            file=spec.source,
            field="positions.grid_shape",
            fix="change the grid shape or use strategy 'stratified'",
        )
    return pts


def _stratified(layout: Layout, spec: PositionSpec, rng: np.random.Generator) -> np.ndarray:
    n_ch, n_face = len(layout.channels), len(layout.faces)
    ch_order = [("channel", int(k)) for k in rng.permutation(n_ch)]
    face_order = [("face", int(k)) for k in rng.permutation(n_face)]
    features = []  # alternate channel/face so a small count covers both kinds
    for k in range(max(n_ch, n_face)):
        if k < n_ch:
            features.append(ch_order[k])
        if k < n_face:
            features.append(face_order[k])
    per = np.full(len(features), spec.count // len(features))
    per[: spec.count % len(features)] += 1
    out = np.zeros((0, 2))
    for (kind, index), m in zip(features, per):
        if m == 0:
            continue
        if kind == "channel":
            strata = iter(range(_MAX_ATTEMPTS * m))

            # stay one channel width away from the junctions, where strips of other channels overlap
            ch = layout.channels[index]
            end = min(ch.width_mm / ch.length_mm, 0.25)

            def draw(k, index=index, m=m, strata=strata, end=end):
                bins = np.array([next(strata) % m for _ in range(k)])
                s = end + (1 - 2 * end) * (bins + rng.random(k)) / m
                return _on_channel(layout, rng, np.full(k, index), s)
        else:

            def draw(k, index=index, m=m, strata=strata, end=0.0):  # same signature as the channel branch's
                return _in_face(layout, rng, index, k)

        out = np.vstack([out, _accept(layout, spec, draw, int(m), taken=out)])
    return out
