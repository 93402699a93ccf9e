"""Synthetic LAGR-like terrain: forward-looking sequences with exact labels and exact camera poses,
so registration can be scored; six presets mirror DS1A ... DS3B."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .frame import Frame


@dataclass(frozen=True)
class SyntheticPreset:
    """One synthetic sequence's scene, lighting and motion.

    scene : 1, 2 or 3 (layout; the two lightings of a scene share it). path : "straight" | "curved".
    lighting : "easy" (distinct colours, soft shadows) | "hard" (close colours, hard shadows, haze).
    motion : "slow" | "fast" (per-frame roll, sideways shift and forward zoom).
    obstacles : number of obstacles placed along the path's sides.
    """

    name: str
    mirrors: str
    scene: int
    path: str
    lighting: str
    motion: str
    obstacles: int


_PRESETS = (
    SyntheticPreset("syn1a", "DS1A", 1, "straight", "easy", "slow", 110),
    SyntheticPreset("syn1b", "DS1B", 1, "straight", "hard", "slow", 110),
    SyntheticPreset("syn2a", "DS2A", 2, "curved", "easy", "fast", 90),
    SyntheticPreset("syn2b", "DS2B", 2, "curved", "hard", "fast", 90),
    SyntheticPreset("syn3a", "DS3A", 3, "curved", "easy", "slow", 140),
    SyntheticPreset("syn3b", "DS3B", 3, "curved", "hard", "slow", 140),
)
PRESETS: dict[str, SyntheticPreset] = {p.name: p for p in _PRESETS}
SYNTHETIC_PRESETS: tuple[str, ...] = tuple(PRESETS)

# Motion per frame: (roll amplitude deg, per-frame roll jitter deg, sideways amplitude as a fraction of
# the width, per-frame sideways jitter px at 640 wide, forward zoom per frame).
_MOTION = {
    "slow": (3.0, 0.15, 0.03, 0.6, 0.0012),
    "fast": (8.0, 0.6, 0.08, 2.5, 0.0035),
}

# Albedo (RGB, 0..255) per material: sky, far treeline, grass, path, bush, trunk, crown, hay, rock.
_MATERIALS = ("sky", "treeline", "grass", "path", "bush", "trunk", "crown", "hay", "rock")
_LABEL_OF = np.array([2, 2, 0, 0, 1, 1, 1, 1, 1], dtype=np.uint8)
_ALBEDO = {
    "easy": np.array([[150, 190, 235], [60, 85, 55], [105, 150, 65], [190, 160, 115], [45, 85, 40],
                      [90, 65, 45], [40, 100, 45], [215, 180, 85], [120, 115, 110]], dtype=np.float32),
    "hard": np.array([[185, 190, 195], [95, 100, 85], [120, 125, 90], [140, 130, 105], [88, 102, 68],
                      [110, 100, 85], [85, 108, 72], [150, 140, 100], [125, 120, 108]], dtype=np.float32),
}
# Texture strength per material: (fine, medium, coarse) multiplicative noise.
_TEXTURE = np.array([[0.00, 0.02, 0.06], [0.10, 0.08, 0.05], [0.16, 0.10, 0.08], [0.12, 0.05, 0.06],
                     [0.20, 0.12, 0.05], [0.10, 0.05, 0.03], [0.22, 0.12, 0.05], [0.10, 0.06, 0.03],
                     [0.12, 0.08, 0.04]], dtype=np.float32)
# Lighting per kind: (cast-shadow factor, haze amount, per-frame brightness swing, cloud shadow depth,
# colour-temperature swing, sensor noise sigma).
_LIGHT = {
    "easy": (0.78, 0.00, 0.06, 0.10, 0.02, 2.0),
    "hard": (0.45, 0.18, 0.20, 0.35, 0.06, 4.0),
}
_HORIZON = 0.22  # horizon height as a fraction of the frame height (nominal pose)


def _noise_field(rng: np.random.Generator, shape: tuple[int, int], cells: tuple[int, int]) -> np.ndarray:
    """Smooth noise (H, W) float32, zero mean, unit-ish amplitude: bicubic upsampling of random cells."""
    import cv2

    small = rng.standard_normal((max(cells[0], 2), max(cells[1], 2))).astype(np.float32)
    return cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


def _smooth_path(rng: np.random.Generator, n: int, *, amplitude: float, jitter: float) -> np.ndarray:
    """(n,) a smooth random walk: sum of 3 random sinusoids scaled to ``amplitude`` plus per-frame jitter."""
    t = np.arange(n, dtype=np.float64)
    out = np.zeros(n)
    for _ in range(3):
        period = rng.uniform(40.0, 160.0)
        out += rng.uniform(0.3, 1.0) * np.sin(2 * np.pi * t / period + rng.uniform(0, 2 * np.pi))
    out *= amplitude / 1.8
    return out + jitter * rng.standard_normal(n)


def _trajectory(preset: SyntheticPreset, n_frames: int, seed: int, width: int, height: int) -> list[np.ndarray]:
    """Per-frame (theta rad, dx px, dy px, s) of the camera: roll, sideways, bob, canvas px per frame px."""
    roll_amp, roll_jit, side_amp, side_jit, zoom = _MOTION[preset.motion]
    rng = np.random.default_rng([seed, 1000 + preset.scene, 1])
    theta = np.deg2rad(_smooth_path(rng, n_frames, amplitude=roll_amp, jitter=roll_jit))
    dx = _smooth_path(rng, n_frames, amplitude=side_amp * width, jitter=side_jit * width / 640.0)
    dy = _smooth_path(rng, n_frames, amplitude=0.01 * height, jitter=0.3 * side_jit * height / 480.0)
    s = 1.0 / (1.0 + zoom * np.arange(n_frames))  # moving forward: the frame sees less of the canvas
    return [theta, dx, dy, s]


def _poses(traj: list[np.ndarray], vp_frame: np.ndarray, vp_canvas: np.ndarray) -> np.ndarray:
    """(n, 3, 3) T_canvas_frame: zoom and roll about the vanishing point, then shift."""
    theta, dx, dy, s = traj
    n = len(theta)
    poses = np.zeros((n, 3, 3))
    c, sn = np.cos(theta), np.sin(theta)
    a = np.stack([np.stack([c, -sn], -1), np.stack([sn, c], -1)], -2) * s[:, None, None]  # (n, 2, 2)
    poses[:, :2, :2] = a
    poses[:, :2, 2] = vp_canvas[None, :] + np.stack([dx, dy], -1) - a @ vp_frame
    poses[:, 2, 2] = 1.0
    return poses


def _blob(rng: np.random.Generator, cx: float, cy: float, rx: float, ry: float, n: int = 18) -> np.ndarray:
    """An irregular closed polygon (n, 1, 2) int32 around (cx, cy)."""
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 1.0 + 0.18 * rng.standard_normal(n)
    r = np.clip(r, 0.6, 1.4)
    pts = np.stack([cx + rx * r * np.cos(ang), cy + ry * r * np.sin(ang)], -1)
    return np.round(pts * 16).astype(np.int32).reshape(-1, 1, 2)


@dataclass(frozen=True)
class _Ground:
    """The canvas's perspective and path: rows ``yy`` (hc, 1) and columns ``xx`` (1, wc) float32, the
    horizon's row, the row of depth 1 (``bottom``), the depth ``t`` (hc, 1) (0 at the horizon), and the
    path's centre line and half width at depth 1, in canvas pixels."""

    yy: np.ndarray
    xx: np.ndarray
    horizon: float
    bottom: float
    t: np.ndarray
    path_x0: float
    path_slant: float
    bend: float
    half_width: float

    def path_centre(self, tt):
        """The path's centre column at depth ``tt``."""
        return (self.path_x0 + self.path_slant * tt
                + self.bend * (1.0 - np.clip(tt, 0, 1)) ** 2 * np.clip(tt * 6.0, 0, 1))


def _ground(layout: np.random.Generator, preset: SyntheticPreset, canvas_hw: tuple[int, int], vp: np.ndarray,
            width: int, height: int) -> _Ground:
    hc, wc = canvas_hw
    yy = np.arange(hc, dtype=np.float32)[:, None]
    xx = np.arange(wc, dtype=np.float32)[None, :]
    horizon = float(vp[1])
    bottom = horizon + (1.0 - _HORIZON) * height * 1.6  # depth t = 1 at this canvas row
    t = np.clip((yy - horizon) / (bottom - horizon), 0.0, None)  # (hc, 1) perspective depth, 0 at horizon
    bend = 0.0 if preset.path == "straight" else layout.choice([-1.0, 1.0]) * layout.uniform(0.25, 0.4) * width
    path_x0 = float(vp[0]) + layout.uniform(-0.04, 0.04) * width
    path_slant = layout.uniform(-0.15, 0.15) * width
    return _Ground(yy, xx, horizon, bottom, t, path_x0, path_slant, bend, half_width=0.42 * width)


def _terrain(layout: np.random.Generator, g: _Ground, canvas_hw: tuple[int, int], height: int) -> np.ndarray:
    """The material (hc, wc) uint8 of every canvas pixel before the obstacles: sky, a wobbling far
    treeline, grass, and the path."""
    hc, wc = canvas_hw
    material = np.zeros((hc, wc), dtype=np.uint8)  # sky
    wobble = 0.012 * height * _noise_field(layout, (1, wc), (1, 14))[0]
    tree_top = g.horizon - (0.05 * height + 0.03 * height * _noise_field(layout, (1, wc), (1, 30))[0]) + wobble
    ground = g.yy >= g.horizon + wobble[None, :]
    material[g.yy >= tree_top[None, :]] = 1  # far treeline (unknown)
    material[ground] = 2  # grass
    on_path = np.abs(g.xx - g.path_centre(g.t)) <= g.half_width * g.t
    material[ground & on_path] = 3
    return material


_SHIFT = 4  # cv2 drawing with sub-pixel coordinates (fixed point, 4 fractional bits)


def _draw_obstacle(layout: np.random.Generator, material: np.ndarray, kind: str, cx: float, cy: float,
                   size: float) -> None:
    """Paint one obstacle of ``kind`` standing at (cx, cy), ``size`` px across at its depth, into ``material``."""
    import cv2

    if kind == "bush":
        rx, ry = layout.uniform(0.08, 0.2) * size, layout.uniform(0.06, 0.14) * size
        cv2.fillPoly(material, [_blob(layout, cx, cy - 0.8 * ry, rx, ry)], 4, shift=_SHIFT)
    elif kind == "tree":
        tw, th = 0.02 * size, layout.uniform(0.2, 0.4) * size
        trunk = np.array([[cx - tw, cy], [cx + tw, cy], [cx + 0.7 * tw, cy - th], [cx - 0.7 * tw, cy - th]])
        cv2.fillPoly(material, [np.round(trunk * 16).astype(np.int32).reshape(-1, 1, 2)], 5, shift=_SHIFT)
        cr = layout.uniform(0.1, 0.2) * size
        cv2.fillPoly(material, [_blob(layout, cx, cy - th - 0.5 * cr, cr, 1.1 * cr, n=24)], 6, shift=_SHIFT)
    elif kind == "hay":
        bw, bh = layout.uniform(0.08, 0.14) * size, layout.uniform(0.06, 0.09) * size
        box = cv2.boxPoints(((cx, cy - bh / 2), (2 * bw, bh), layout.uniform(-4, 4)))
        cv2.fillPoly(material, [np.round(box * 16).astype(np.int32).reshape(-1, 1, 2)], 7, shift=_SHIFT)
    else:
        r = layout.uniform(0.04, 0.08) * size
        cv2.fillPoly(material, [_blob(layout, cx, cy - 0.5 * r, 1.3 * r, 0.8 * r, n=10)], 8, shift=_SHIFT)


def _obstacles(layout: np.random.Generator, material: np.ndarray, g: _Ground, preset: SyntheticPreset,
               width: int, height: int) -> np.ndarray:
    """Paint the obstacles at random depths beside the path, far to near (painter's order), into
    ``material``; returns their cast shadows (hc, wc) uint8 (1 in shadow)."""
    import cv2

    hc, wc = material.shape
    depth = np.sort(layout.uniform(0.05, 1.25, preset.obstacles))
    shadow = np.zeros((hc, wc), dtype=np.uint8)
    sun = layout.uniform(-1.0, 1.0)  # shadows fall to the left (< 0) or right (> 0)
    kinds = layout.choice(["bush", "tree", "hay", "rock"], size=preset.obstacles, p=[0.4, 0.25, 0.25, 0.1])
    for tt, kind in zip(depth, kinds):
        side = layout.choice([-1.0, 1.0])
        gap = layout.uniform(0.02, 2.5) * g.half_width * tt
        cx = float(g.path_centre(tt)) + side * (g.half_width * tt + gap)
        cy = g.horizon + tt * (g.bottom - g.horizon)
        size = tt * width
        if cx < -0.3 * wc or cx > 1.3 * wc or cy > hc + 0.3 * height:
            continue
        sh_poly = _blob(layout, cx + sun * 0.2 * size, cy + 0.02 * size, 0.22 * size, 0.04 * size)
        cv2.fillPoly(shadow, [sh_poly], 1, lineType=cv2.LINE_8, shift=_SHIFT)
        _draw_obstacle(layout, material, kind, cx, cy, size)
    return shadow


def _hand_labels(material: np.ndarray, width: int) -> np.ndarray:
    """Labels (hc, wc) uint8 of the materials, with the thin unknown seam that hand labels leave around
    obstacles (about 2 px at 640 wide)."""
    import cv2

    labels = _LABEL_OF[material]
    seam = max(1, int(round(2 * width / 640)))
    obstacle = (labels == 1).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * seam + 1, 2 * seam + 1))
    ring = (cv2.dilate(obstacle, kernel) > 0) & (cv2.erode(obstacle, kernel) == 0)
    labels = labels.copy()
    labels[ring & (labels != 2)] = 2
    return labels


def _colours(look: np.random.Generator, material: np.ndarray, shadow: np.ndarray, g: _Ground, lighting: str,
             width: int) -> np.ndarray:
    """The lit colours (hc, wc, 3) float32: albedo x texture x lighting, shadows and haze."""
    import cv2

    hc, wc = material.shape
    yy = g.yy
    albedo = _ALBEDO[lighting] * (1.0 + 0.05 * look.standard_normal((len(_MATERIALS), 3))).astype(np.float32)
    scale = width / 640.0
    fine = _noise_field(look, (hc, wc), (max(4, int(hc / (3 * scale))), max(4, int(wc / (3 * scale)))))
    medium = _noise_field(look, (hc, wc), (max(4, int(hc / (14 * scale))), max(4, int(wc / (14 * scale)))))
    coarse = _noise_field(look, (hc, wc), (max(3, int(hc / (80 * scale))), max(3, int(wc / (80 * scale)))))
    tex = _TEXTURE[material]  # (hc, wc, 3)
    shade = 1.0 + tex[..., 0] * fine + tex[..., 1] * medium + tex[..., 2] * coarse
    hay_stripes = (material == 7) * (0.08 * np.sin(yy * (2 * np.pi / max(2.0, 4.0 * scale))))
    shade = shade + hay_stripes.astype(np.float32)
    colour = albedo[material] * shade[..., None]
    # Per-pixel colour variation of vegetation (some grass is yellowed, some bush leaves lighter).
    hue = _noise_field(look, (hc, wc), (max(3, int(hc / (40 * scale))), max(3, int(wc / (40 * scale)))))
    veg = np.isin(material, (2, 4, 6))[..., None]
    colour += veg * hue[..., None] * np.array([14.0, 6.0, -4.0], dtype=np.float32)
    # Ground darkens towards the camera (sky and treeline keep theirs).
    sky = material == 0
    colour[sky] *= (0.85 + 0.25 * np.clip((yy / max(g.horizon, 1.0)), 0, 1) * np.ones((1, wc), np.float32))[sky][:, None]
    # Cast shadows of obstacles on the ground, softened.
    shadow_strength, haze = _LIGHT[lighting][0], _LIGHT[lighting][1]
    sh = cv2.GaussianBlur(shadow.astype(np.float32), (0, 0), max(0.8, 2.0 * scale))
    sh *= (material >= 2) & (material <= 3)
    colour *= (1.0 - (1.0 - shadow_strength) * sh)[..., None]
    if haze > 0:  # haze washes colours towards grey, more towards the horizon
        w_h = haze * np.clip(1.0 - g.t, 0.0, 1.0)
        colour = colour * (1.0 - w_h[..., None]) + 170.0 * w_h[..., None]
    return colour.astype(np.float32)


def _render_canvas(preset: SyntheticPreset, seed: int, canvas_hw: tuple[int, int], vp: np.ndarray,
                   width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The scene's lit colours (Hc, Wc, 3) float32 and labels (Hc, Wc) uint8, in canvas pixels.

    The layout depends on (scene, seed) only, so the two lightings of a scene share it; sizes are in
    units of the frame (``width``, ``height``), so any frame size sees the same scene.
    """
    layout = np.random.default_rng([seed, 2000 + preset.scene])
    look = np.random.default_rng([seed, 3000 + preset.scene, 0 if preset.lighting == "easy" else 1])
    g = _ground(layout, preset, canvas_hw, vp, width, height)
    material = _terrain(layout, g, canvas_hw, height)
    shadow = _obstacles(layout, material, g, preset, width, height)
    labels = _hand_labels(material, width)
    return _colours(look, material, shadow, g, preset.lighting, width), labels


def _synthetic_frames(name: str, n_frames: int, seed: int, width: int, height: int) -> list[Frame]:
    import cv2

    preset = PRESETS[name]
    traj = _trajectory(preset, n_frames, seed, width, height)
    vp_frame = np.array([(width - 1) / 2.0, _HORIZON * (height - 1)])
    # Canvas just big enough for every frame: corners of all frames relative to the vanishing point.
    corners = np.array([[0, 0, 1], [width - 1, 0, 1], [0, height - 1, 1], [width - 1, height - 1, 1]], float).T
    rel = _poses(traj, vp_frame, np.zeros(2)) @ corners  # (n, 3, 4)
    margin = 3.0
    lo = rel[:, :2, :].min(axis=(0, 2)) - margin
    hi = rel[:, :2, :].max(axis=(0, 2)) + margin
    vp_canvas = np.ceil(-lo)
    wc, hc = int(np.ceil(hi[0] + vp_canvas[0])) + 1, int(np.ceil(hi[1] + vp_canvas[1])) + 1
    poses = _poses(traj, vp_frame, vp_canvas)
    colour, labels = _render_canvas(preset, seed, (hc, wc), vp_canvas, width, height)
    canvas = np.clip(colour, 0, 255).astype(np.uint8)

    shadow_strength, haze, swing, cloud_depth, temp_swing, sigma = _LIGHT[preset.lighting]
    light = np.random.default_rng([seed, 4000 + preset.scene, 0 if preset.lighting == "easy" else 1])
    brightness = 1.0 + _smooth_path(light, n_frames, amplitude=swing, jitter=0.01)
    temperature = _smooth_path(light, n_frames, amplitude=temp_swing, jitter=0.0)
    cloud = _noise_field(light, (8, 8 + n_frames // 4 + 2), (8, 8 + n_frames // 8 + 2))
    frames = []
    for i in range(n_frames):
        m = poses[i, :2, :]
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        img = cv2.warpAffine(canvas, m, (width, height), flags=flags, borderMode=cv2.BORDER_REPLICATE)
        lab = cv2.warpAffine(labels, m, (width, height), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                             borderMode=cv2.BORDER_REPLICATE)
        # Lighting of this frame: global brightness, a drifting cloud shadow, colour temperature.
        x0 = i / 4.0
        cells = cloud[:, int(x0):int(x0) + 9]
        patch = cv2.resize(cells, (width, height), interpolation=cv2.INTER_LINEAR)
        gain = np.float32(brightness[i]) * (1.0 - np.float32(cloud_depth) * np.clip(patch * 0.8 + 0.2, 0.0, 1.0))
        wb = (1.0 + temperature[i], 1.0, 1.0 - temperature[i])
        lit = cv2.multiply(img, cv2.merge([gain * np.float32(c) for c in wb]), dtype=cv2.CV_32F)
        # Sensor noise: sum of two uniform bytes (triangular, std 255/sqrt(6)) scaled to sigma.
        u = np.frombuffer(light.bytes(2 * img.size), dtype=np.uint8).reshape((2,) + img.shape)
        k = float(sigma) / (255.0 / np.sqrt(6.0))
        frame_img = cv2.addWeighted(lit, 1.0, cv2.add(u[0], u[1], dtype=cv2.CV_32F), k, -255.0 * k,
                                    dtype=cv2.CV_8U)
        frames.append(Frame(image=frame_img, labels=lab, name=f"{name}_{i + 1:03d}", pose=poses[i]))
    return frames


def check_synthetic_size(sequences: int, frames: int, width: int, height: int) -> None:
    """Refuse synthetic data that would not fit in memory: each frame within the pixel limit, all the
    frames (kept in memory while an evaluation runs) within 20 times it (3 GB at the default)."""
    from ..validation import max_pixels

    limit = max_pixels()
    if width < 1 or height < 1 or width * height > limit:
        raise InputError(f"synthetic frames of {width}x{height} px exceed the pixel limit {limit} (--max-pixels)")
    total = sequences * frames * width * height
    if total > 20 * limit:
        raise InputError(f"{sequences} synthetic sequence(s) of {frames} frames of {width}x{height} px hold "
                         f"{total / 1e9:.1f} G pixels, more than 20x the pixel limit {limit} (--max-pixels)")


def synthetic(name: str, n_frames: int = 100, seed: int = 0, *, width: int = 640, height: int = 480) -> list[Frame]:
    """A synthetic LAGR-like sequence: forward-looking terrain with exact labels and camera poses.

    name : one of :data:`SYNTHETIC_PRESETS` (``syn1a`` ... ``syn3b`` mirror DS1A ... DS3B: three scenes,
        each in easy (``a``: distinct colours, soft shadows) and hard (``b``: close colours, hard
        shadows, haze) lighting; scene 1 a straight path with slow motion, scene 2 a curved path with
        fast motion, scene 3 a curved path with many obstacles and slow motion).
    n_frames, seed : sequence length and seed; the same arguments give the same frames.
    width, height : frame size in pixels (the scene scales with it).

    The scene is rendered once as a canvas larger than a frame; frame i is the canvas seen through
    ``pose`` (roll, sideways shift and a forward zoom about the vanishing point), entirely inside
    the canvas, with per-frame brightness, a drifting cloud shadow, colour-temperature change and
    Gaussian sensor noise. Labels are warped with nearest neighbour. Sky and the far treeline are
    unknown (2), as is a thin seam around each obstacle; grass and the path are ground (0); bushes,
    trees, hay bales and rocks are obstacles (1).

    Returns ``n_frames`` :class:`Frame` (image (height, width, 3) uint8, labels (height, width) uint8,
    pose (3, 3) ``T_canvas_frame``).
    """
    from ..validation import check_int, short_repr

    key = name.lower() if isinstance(name, str) else None
    if key not in PRESETS:
        raise InputError(f"unknown synthetic preset {short_repr(name)} (choose from {', '.join(SYNTHETIC_PRESETS)})")
    n_frames = check_int(n_frames, "n_frames", lo=1)
    seed = check_int(seed, "seed", lo=0)
    width = check_int(width, "width", lo=16, hi=32767)
    height = check_int(height, "height", lo=12, hi=32767)
    check_synthetic_size(1, n_frames, width, height)
    return _synthetic_frames(key, n_frames, seed, width, height)
