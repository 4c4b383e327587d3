"""A lower body for garments: a dress form's pelvis/torso and two legs, and its kinematic motions.

``make_body`` builds closed triangle meshes per part (pelvis/torso from above the waist down past the crotch,
left and right legs from the hip joints to the ankles); the parts overlap where they join (collision uses
unsigned distances, so overlaps are harmless). Every part is a surface of revolution about its own axis
(vertical at rest), with circular cross-sections whose circumference is the body measurement at that height:
``Body.clearance(points)`` is the analytic signed distance-like measure behind the rest-pose checks (the mesh,
a polygon inscribed in each circle, lies inside it).

Proportions (fractions of the height, adult anthropometric averages): waist at 0.615 H, fullest hip at
0.52 H, crotch at 0.47 H, knee at 0.285 H, ankle at 0.04 H. Axes: z up, the body faces -y, x to its left.

Motions (``MOTIONS``), each starting at the rest pose with zero velocity at frame 0:
    static  the rest pose at every frame
    walk    walking in place (a treadmill): each leg swings about its hip joint by +-25 degrees (straight,
            knee-free legs, the legs in antiphase) with a gait cycle of 1.2 s; the pelvis sways 2 cm sideways,
            bobs 8 mm and turns +-4 degrees with the stride. The gait phase accelerates from 0 to its full
            rate over the first 6 frames (so angle and velocity start at zero).
    twirl   rotation about the vertical axis whose rate rises smoothly from 0 to 1 turn/s over 1 s, then holds
    jump    after 6 frames of rest, a vertical hop whose top is 10 cm above the rest pose: a 0.1 s smooth
            push-off, a ballistic flight under gravity, a landing mirroring the push-off; repeated every 1 s
``body_frames(body, motion, frames, fps)`` gives the vertex positions per frame; ``pelvis_transforms`` the
pelvis' rigid transforms (the skirt's waistband follows them). Max vertex speeds: ``max_vertex_speed``.
"""
from dataclasses import dataclass, field

import numpy as np

from . import InputError

__all__ = ["Body", "make_body", "body_frames", "pelvis_transforms", "max_vertex_speed", "check_clear_of_body", "MOTIONS",
           "DEFAULT_HEIGHT_M", "waist_height", "PART_NAMES", "part_transforms"]

MOTIONS = ("static", "walk", "twirl", "jump")
PART_NAMES = ("pelvis", "leg_left", "leg_right")
DEFAULT_HEIGHT_M = 1.70
WAIST_HEIGHT = 0.615       # fractions of the height
HIP_HEIGHT = 0.52
CROTCH_HEIGHT = 0.47
KNEE_HEIGHT = 0.285
ANKLE_HEIGHT = 0.04
TORSO_ABOVE_WAIST_M = 0.12
THIGH_RADIUS_OF_HIP = 0.46        # thigh radius / hip radius at the crotch
HIP_JOINT_ABOVE_CROTCH_M = 0.06
GRAVITY = 9.81                    # m/s^2
EASE_FRAMES = 6                   # frames over which a motion starts from rest
WALK_SWING_RAD = np.radians(25.0)
WALK_PERIOD_S = 1.2
WALK_SWAY_M = 0.02
WALK_BOB_M = 0.008
WALK_YAW_RAD = np.radians(4.0)
TWIRL_RATE_TURNS_S = 1.0
TWIRL_RAMP_S = 1.0
JUMP_HEIGHT_M = 0.10
JUMP_PUSH_S = 0.10
JUMP_PERIOD_S = 1.0


def waist_height(height_m=DEFAULT_HEIGHT_M):
    """Height of the waist (m) of a body of the given stature."""
    return WAIST_HEIGHT * float(height_m)


@dataclass
class Body:
    """A lower body: positions (V, 3), faces (F, 3) int32 (closed meshes per part, outward normals), part (V,)
    int32 index into PART_NAMES, joints {name: (3,)}, and per part the surface of revolution it was built
    from: ``profiles[k] = (origin (3,), s (n,), radius (n,))`` with the axis pointing down (-z) from origin,
    caps included (radius 0 at both apexes)."""
    positions: np.ndarray
    faces: np.ndarray
    part: np.ndarray
    joints: dict
    profiles: list
    height_m: float
    waist_height_m: float
    hip_circumference_m: float
    waist_circumference_m: float
    part_names: tuple = field(default=PART_NAMES)

    def part_faces(self, k):
        """Faces of part k (a closed mesh)."""
        return self.faces[self.part[self.faces[:, 0]] == k]

    def clearance(self, points):
        """(N,) for points (N, 3) at the rest pose: the smallest, over parts, of (distance from the part's axis)
        - (the part's radius at that height), or the distance beyond its end caps; negative inside a part."""
        q = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        best = np.full(q.shape[0], np.inf)
        for origin, s, r in self.profiles:
            d = origin[2] - q[:, 2]                      # along the downward axis
            radial = np.hypot(q[:, 0] - origin[0], q[:, 1] - origin[1])
            rad = np.interp(d, s, r, left=0.0, right=0.0)
            side = radial - rad
            beyond = np.maximum(s[0] - d, d - s[-1])      # > 0 above the top apex or below the bottom one
            value = np.where(beyond > 0, np.hypot(radial, beyond), side)
            best = np.minimum(best, value)
        return best

    def max_radius(self, z):
        """Largest horizontal distance from the body axis (x = y = 0) of any part at heights z (rest pose)."""
        z = np.asarray(z, dtype=np.float64)
        out = np.zeros(z.shape)
        for origin, s, r in self.profiles:
            rad = np.interp(origin[2] - z, s, r, left=0.0, right=0.0)
            off = np.hypot(origin[0], origin[1])
            out = np.maximum(out, np.where(rad > 0, off + rad, 0.0))
        return out


def _smooth_profile(knots_s, knots_r, n):
    """n samples of a radius profile through the knots, smooth between them (cosine blend: a zero slope at
    each knot, so the waist and hip are true extrema)."""
    s = np.union1d(np.linspace(knots_s[0], knots_s[-1], n), knots_s)   # the knots (waist, hip) are rows
    k = np.clip(np.searchsorted(knots_s, s, side="right") - 1, 0, len(knots_s) - 2)
    t = (s - knots_s[k]) / (knots_s[k + 1] - knots_s[k])
    w = 0.5 - 0.5 * np.cos(np.pi * t)
    return s, knots_r[k] * (1 - w) + knots_r[k + 1] * w


def _tube(origin, s, r, around, cap_rows=3):
    """A closed surface of revolution about the downward axis from origin: rows at depths s with radii r,
    closed by rounded caps (quarter ellipses of depth r_end / 2 ending in an apex vertex). Returns
    positions, faces (outward normals)."""
    q = np.linspace(0, np.pi / 2, cap_rows + 1)[1:-1]          # cap angles, exclusive of both ends
    top_s, top_r = (s[0] - 0.5 * r[0] * np.sin(q))[::-1], (r[0] * np.cos(q))[::-1]
    bot_s, bot_r = s[-1] + 0.5 * r[-1] * np.sin(q), r[-1] * np.cos(q)
    rows_s = np.concatenate([top_s, s, bot_s])
    rows_r = np.concatenate([top_r, r, bot_r])
    phi = np.linspace(0, 2 * np.pi, around, endpoint=False)
    ring = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    pos = [[origin[0], origin[1], origin[2] - (s[0] - 0.5 * r[0])]]
    for ss, rr in zip(rows_s, rows_r):
        pts = np.empty((around, 3))
        pts[:, :2] = origin[:2] + rr * ring
        pts[:, 2] = origin[2] - ss
        pos.extend(pts.tolist())
    pos.append([origin[0], origin[1], origin[2] - (s[-1] + 0.5 * r[-1])])
    pos = np.array(pos)
    nrows = len(rows_s)
    top, bottom = 0, pos.shape[0] - 1
    faces = []
    for i in range(around):
        j = (i + 1) % around
        faces.append([top, 1 + i, 1 + j])
        for k in range(nrows - 1):
            a, b = 1 + k * around + i, 1 + k * around + j
            c, d = a + around, b + around
            faces += [[a, c, d], [a, d, b]]
        last = 1 + (nrows - 1) * around
        faces.append([bottom, last + j, last + i])
    profile_s = np.concatenate([[s[0] - 0.5 * r[0]], rows_s, [s[-1] + 0.5 * r[-1]]])
    profile_r = np.concatenate([[0.0], rows_r, [0.0]])
    return pos, np.array(faces, np.int64), (np.asarray(origin, np.float64), profile_s, profile_r)


def make_body(height_m=DEFAULT_HEIGHT_M, hip_circumference_m=0.96, waist_circumference_m=0.70, resolution=32):
    """A lower body (Body) of the given stature and girths; ``resolution`` vertices around each circle.

    Pelvis/torso: from 0.12 m above the waist to just below the crotch, its circumference the waist's at the
    waist, the hip's at the fullest hip, tapering to the crotch. Legs: from above the hip joints (inside the
    pelvis) down to the ankles, thigh radius 0.46 of the hip radius, tapering through the knee.
    """
    def number(v, name, lo, hi):
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise InputError(f"{name}: expected a number, got {v!r}") from None
        if not np.isfinite(x) or not lo <= x <= hi:
            raise InputError(f"{name}: must lie in [{lo}, {hi}], got {v!r}")
        return x
    H = number(height_m, "height_m", 1.0, 2.5)
    hip_c = number(hip_circumference_m, "hip_circumference_m", 0.5, 2.0)
    waist_c = number(waist_circumference_m, "waist_circumference_m", 0.4, 2.0)
    if waist_c > hip_c:
        raise InputError(f"waist_circumference_m ({waist_c}) must not exceed hip_circumference_m ({hip_c})")
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or not 8 <= resolution <= 512:
        raise InputError(f"resolution: expected an integer in [8, 512], got {resolution!r}")
    around = int(resolution)
    r_w, r_h = waist_c / (2 * np.pi), hip_c / (2 * np.pi)
    z_w, z_h, z_c = WAIST_HEIGHT * H, HIP_HEIGHT * H, CROTCH_HEIGHT * H
    z_k, z_a = KNEE_HEIGHT * H, ANKLE_HEIGHT * H
    top = z_w + TORSO_ABOVE_WAIST_M
    origin = np.array([0.0, 0.0, top])
    knots_s = np.array([0.0, top - z_w, top - z_h, top - z_c])
    knots_r = np.array([1.08 * r_w, r_w, r_h, 0.86 * r_h])
    rows = max(8, int(round((top - z_c) / (2 * np.pi * r_h / around))))
    s, r = _smooth_profile(knots_s, knots_r, rows)
    parts_pos, parts_faces, parts_id, profiles = [], [], [], []
    pos, faces, profile = _tube(origin, s, r, around)
    profiles.append(profile)
    parts_pos.append(pos)
    parts_faces.append(faces)
    parts_id.append(np.zeros(pos.shape[0], np.int32))
    r_thigh = THIGH_RADIUS_OF_HIP * r_h
    hip_x = r_h - r_thigh - 0.1 * r_thigh
    z_joint = z_c + HIP_JOINT_ABOVE_CROTCH_M
    joints = {"pelvis": np.array([0.0, 0.0, z_w])}
    for k, side in ((1, 1.0), (2, -1.0)):
        leg_origin = np.array([side * hip_x, 0.0, z_joint + 0.05])
        ks = np.array([0.0, leg_origin[2] - z_c, leg_origin[2] - z_k, leg_origin[2] - 0.5 * (z_k + z_a), leg_origin[2] - z_a])
        kr = np.array([r_thigh, r_thigh, 0.55 * r_thigh, 0.6 * r_thigh, 0.38 * r_thigh])
        leg_rows = max(12, int(round((ks[-1]) / (2 * np.pi * r_thigh / around))))
        ls, lr = _smooth_profile(ks, kr, leg_rows)
        pos, faces, profile = _tube(leg_origin, ls, lr, around)
        profiles.append(profile)
        parts_faces.append(faces + sum(p.shape[0] for p in parts_pos))
        parts_pos.append(pos)
        parts_id.append(np.full(pos.shape[0], k, np.int32))
        name = PART_NAMES[k].split("_")[1]
        joints[f"hip_{name}"] = np.array([side * hip_x, 0.0, z_joint])
        joints[f"knee_{name}"] = np.array([side * hip_x, 0.0, z_k])
        joints[f"ankle_{name}"] = np.array([side * hip_x, 0.0, z_a])
    return Body(np.vstack(parts_pos), np.vstack(parts_faces).astype(np.int32), np.concatenate(parts_id), joints,
                profiles, H, z_w, hip_c, waist_c)


# ---------------------------------------------------------------- motions
def _frames_arg(frames, fps):
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise InputError(f"frames: expected a positive integer, got {frames!r}")
    try:
        fps = float(fps)
    except (TypeError, ValueError):
        raise InputError(f"fps: expected a number, got {fps!r}") from None
    if not np.isfinite(fps) or fps <= 0:
        raise InputError(f"fps: must be > 0, got {fps!r}")
    return int(frames), fps


def _motion_arg(motion):
    if motion not in MOTIONS:
        raise InputError(f"motion: expected one of {', '.join(MOTIONS)}, got {motion!r}")
    return motion


def _ramp_integral(t, T):
    """integral_0^t smoothstep(tau / T) dtau: a phase whose rate rises from 0 to 1 over T, then stays 1."""
    t = np.asarray(t, dtype=np.float64)
    u = np.clip(t / T, 0.0, 1.0)
    inside = T * (u ** 3 - 0.5 * u ** 4)          # integral of 3u^2 - 2u^3 times T
    return np.where(t < T, inside, T * 0.5 + (t - T))


def _walk_phase(t, fps):
    return 2 * np.pi / WALK_PERIOD_S * _ramp_integral(t, EASE_FRAMES / fps)


def _jump_height(t, fps):
    """Height above rest of the hop at times t (periodic, starting after EASE_FRAMES of rest)."""
    tp = JUMP_PUSH_S
    # take-off speed v0 such that push rise v0 tp / 2 plus flight rise v0^2 / (2 g) is the jump height
    v0 = (-tp / 2 + np.sqrt(tp * tp / 4 + 2 * JUMP_HEIGHT_M / GRAVITY)) * GRAVITY
    flight = 2 * v0 / GRAVITY
    t = np.asarray(t, dtype=np.float64) - EASE_FRAMES / fps
    tc = np.where(t < 0, -1.0, np.mod(t, JUMP_PERIOD_S))
    z = np.zeros_like(tc)
    push = (tc >= 0) & (tc < tp)
    u = tc / tp
    z = np.where(push, v0 * tp * (u ** 3 - 0.5 * u ** 4), z)     # velocity v0 * smoothstep(u)
    h_push = v0 * tp * 0.5
    fl = (tc >= tp) & (tc < tp + flight)
    tf = tc - tp
    z = np.where(fl, h_push + v0 * tf - 0.5 * GRAVITY * tf ** 2, z)
    land = (tc >= tp + flight) & (tc < 2 * tp + flight)
    ul = (tc - tp - flight) / tp                                  # mirror of the push-off
    z = np.where(land, h_push - v0 * tp * (ul - (ul ** 3 - 0.5 * ul ** 4)), z)
    return z


def _rigid(rz, t):
    m = np.tile(np.eye(4), (len(rz), 1, 1))
    c, s = np.cos(rz), np.sin(rz)
    m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1] = c, -s, s, c
    m[:, :3, 3] = t
    return m


def pelvis_transforms(motion, frames, fps=24):
    """(frames, 4, 4) rigid transforms of the pelvis (world from rest) at frames 0..frames-1 (t = frame / fps)."""
    motion = _motion_arg(motion)
    frames, fps = _frames_arg(frames, fps)
    return _pelvis_at(motion, np.arange(frames) / fps, fps)


def part_transforms(body, motion, times, fps=24):
    """(len(times), parts, 4, 4) rigid transforms (world from rest) of each body part at arbitrary times (s): the
    pelvis, and each leg swung about its hip joint and carried by the pelvis, exactly as ``body_frames`` moves
    the vertices (body_frames at frame f equals these transforms at t = f / fps applied to the rest pose)."""
    if not isinstance(body, Body):
        raise InputError(f"body: expected a Body (make_body), got {type(body).__name__}")
    motion = _motion_arg(motion)
    _, fps = _frames_arg(1, fps)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    pelvis = _pelvis_at(motion, t, fps)
    swing = _leg_swing(motion, t, fps)
    out = np.tile(np.eye(4), (len(t), len(body.part_names), 1, 1))
    out[:, 0] = pelvis
    for k, name in enumerate(body.part_names):
        if k == 0:
            continue
        joint = body.joints["hip_" + name.split("_")[1]]
        a = swing * (1.0 if k == 1 else -1.0)
        leg = np.tile(np.eye(4), (len(t), 1, 1))
        c, s = np.cos(a), np.sin(a)
        leg[:, 1, 1], leg[:, 1, 2], leg[:, 2, 1], leg[:, 2, 2] = c, -s, s, c
        leg[:, :3, 3] = joint - np.einsum("fij,j->fi", leg[:, :3, :3], joint)
        out[:, k] = pelvis @ leg
    return out


def _pelvis_at(motion, t, fps):
    frames = len(t)
    zeros = np.zeros(frames)
    if motion == "static":
        return _rigid(zeros, np.zeros((frames, 3)))
    if motion == "walk":
        ph = _walk_phase(t, fps)
        shift = np.stack([WALK_SWAY_M * np.sin(ph), zeros, WALK_BOB_M * 0.5 * (np.cos(2 * ph) - 1)], axis=1)
        return _rigid(WALK_YAW_RAD * np.sin(ph), shift)
    if motion == "twirl":
        angle = 2 * np.pi * TWIRL_RATE_TURNS_S * _ramp_integral(t, TWIRL_RAMP_S)
        return _rigid(angle, np.zeros((frames, 3)))
    return _rigid(zeros, np.stack([zeros, zeros, _jump_height(t, fps)], axis=1))


def _leg_swing(motion, t, fps):
    if motion != "walk":
        return np.zeros_like(t)
    return WALK_SWING_RAD * np.sin(_walk_phase(t, fps))


def body_frames(body, motion, frames, fps=24):
    """(frames, V, 3) float64 vertex positions of the body moving with ``motion`` (deterministic)."""
    if not isinstance(body, Body):
        raise InputError(f"body: expected a Body (make_body), got {type(body).__name__}")
    motion = _motion_arg(motion)
    frames, fps = _frames_arg(frames, fps)
    t = np.arange(frames) / fps
    pelvis = pelvis_transforms(motion, frames, fps)
    swing = _leg_swing(motion, t, fps)
    out = np.empty((frames, body.positions.shape[0], 3))
    rest = body.positions
    for k, name in enumerate(body.part_names):
        sel = body.part == k
        local = rest[sel]
        if k > 0:  # legs: rotate about the lateral (x) axis through the hip joint, in antiphase
            joint = body.joints["hip_" + name.split("_")[1]]
            a = swing * (1.0 if k == 1 else -1.0)
            c, s = np.cos(a)[:, None], np.sin(a)[:, None]
            d = local - joint
            y = c * d[None, :, 1] - s * d[None, :, 2]
            z = s * d[None, :, 1] + c * d[None, :, 2]
            moved = np.stack([np.broadcast_to(d[:, 0], y.shape), y, z], axis=-1) + joint
        else:
            moved = np.broadcast_to(local, (frames,) + local.shape)
        out[:, sel] = np.einsum("fij,fvj->fvi", pelvis[:, :3, :3], moved) + pelvis[:, None, :3, 3]
    return out


def max_vertex_speed(frames_xyz, fps=24):
    """Largest vertex speed (m/s) between consecutive frames of (frames, V, 3) positions."""
    x = np.asarray(frames_xyz)
    if x.shape[0] < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(x, axis=0), axis=2).max() * fps)


def check_clear_of_body(positions, body, name="garment", clearance_m=0.0):
    """Raises InputError when any of positions (V, 3) lies inside the body at its rest pose (or closer than
    clearance_m to it), naming how many vertices, the first one and the deepest; returns the smallest
    clearance (m) otherwise. A garment must start outside the body it is draped on."""
    if not isinstance(body, Body):
        raise InputError(f"body: expected a Body (make_body), got {type(body).__name__}")
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or not np.isfinite(x).all():
        raise InputError(f"{name}: positions must be finite with shape (V, 3), got {x.shape}")
    gap = body.clearance(x)
    bad = gap < clearance_m
    if bad.any():
        first, deepest = int(np.argmax(bad)), int(np.argmin(gap))
        raise InputError(f"{name}: {int(bad.sum())} vertices start inside the body or within {clearance_m * 1000:g} mm "
                         f"of it (first: vertex {first}; deepest: vertex {deepest}, {-gap[deepest] * 1000:.1f} mm "
                         f"inside); move or scale the garment so it starts outside the body")
    return float(gap.min())
