"""The puppet scenario (SPEC J3): the thesis's marked lay figure on its turntable, with the truth.

What is rendered (all in the puppet frame, metres: origin where the turn axis meets the
platform, y up, x to the puppet's left, z toward the camera at turn angle 0):

- the 210 mm lay figure of :meth:`Skeleton.puppet` as flat-black capsules along its bones
  (:data:`PUPPET_LIMBS`, albedo :data:`BLACK`), the pelvis fixed on the turn axis;
- its painted 6 mm beads (default the thesis's 16, :meth:`MarkerSet.puppet`; any marker set of the
  puppet skeleton, e.g. ``"puppet-20"``) as spheres of their reference colours (sRGB -> linear
  albedo) at ``MarkerSet.positions(pose)``; each bead touches its limb;
- the flat-black bottom panel with the turntable platform in it (the plane y = 0) and a flat-black
  back panel behind the axis, facing the camera;
- the webcam's LEDs (a point light at the camera centre), a little room light, webcam noise and
  JPEG (:func:`webcam_sensor`).

The turntable. In the thesis the camera is fixed and the puppet turns in 30-degree steps. That
is the same photo as a fixed puppet seen by a camera turned the other way round the axis: the
12 virtual cameras of :func:`~stillcap.calibrate.turntable.turntable_rig`. So the puppet and
the platform stay put in the puppet frame and each view is rendered with its rig camera; what
turns with the camera (the LEDs and the back panel) is placed per view (:func:`view_scene`).
Any other :class:`~stillcap.camera.Rig` in the puppet frame works the same way.

Truth (:class:`PuppetTruth`): markers, joints and the pose, and per view which beads are visible
(the line of sight from the camera centre to the bead centre is not blocked by any limb or
other bead, and the centre projects inside the image), their true pixels (NaN if not visible)
and the visible fraction of each bead's disc (``coverage``: 1 for an unobstructed bead).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

from stillcap._checks import as_rng
from stillcap.body.markerset import MarkerSet
from stillcap.body.retarget import euler_bounds_deg, retarget_pose
from stillcap.body.skeleton import EULER_LIMIT_SEQUENCE, Pose, Skeleton
from stillcap.calibrate.turntable import turntable_rig
from stillcap.camera import Camera, Rig, pose_matrix
from stillcap.io.capture import Capture, CaptureImage
from stillcap.studio.renderer import _hit, render
from stillcap.studio.scene import Backdrop, Capsule, PointLight, Scene, Sphere, TexturedPlane
from stillcap.studio.sensor import Sensor, srgb_to_linear

__all__ = ["BLACK", "PUPPET_LIMBS", "PuppetScene", "PuppetTruth", "marker_visibility", "pose_from_spec",
           "puppet_bodies", "puppet_collisions", "puppet_scene", "random_pose", "turn_angle_deg", "view_scene",
           "webcam_sensor"]

#: Albedo of the flat-black paint on the puppet and the panels.
BLACK = 0.035
#: LED intensity: a facing surface 0.4 m from the lens (the turn axis) gets radiance 1, so a bead
#: there shows its reference colour.
LED_INTENSITY = 0.16
#: Back panel: distance behind the turn axis (m) and extent (xmin, ymin, xmax, ymax) in its frame.
PANEL_BEHIND, PANEL_EXTENT = 0.15, (-0.4, 0.0, 0.4, 0.5)


def _limbs() -> tuple:
    """(name, joint whose frame carries it, start (3,), end (3,), radius), millimetres."""
    left = [
        ("pelvis", "root", (0, 0, 0), (11, -6, 0), 6.0),
        ("shoulder", "upper-back", (0, 0, 0), (22, 0, 0), 5.0),
        ("upper-arm", "l-shoulder", (0, 0, 0), (36, 0, 0), 3.0),
        ("forearm", "l-elbow", (0, 0, 0), (30, 0, 0), 3.0),
        ("hand", "l-hand", (0, 0, 0), (20, 0, 0), 2.5),
        ("thigh", "l-hip", (0, 0, 0), (0, -46, 0), 5.0),
        ("shin", "l-knee", (0, 0, 0), (0, -48, 0), 5.0),
        ("foot", "l-foot", (0, 0, 0), (0, 0, 22), 3.5),
    ]
    out = [("waist", "root", (0, 0, 0), (0, 22, 0), 7.0),
           ("torso", "lower-back", (0, 0, 0), (0, 40, 0), 8.0),
           ("neck", "upper-back", (0, 0, 0), (0, 15, 0), 3.5),
           ("head", "upper-back", (0, 15, 0), (0, 30, 0), 9.0)]
    flip = np.array([-1.0, 1.0, 1.0])  # left -> right: mirror x
    for name, joint, a, b, r in left:
        out.append((f"{name}.l", joint, a, b, r))
        out.append((f"{name}.r", joint.replace("l-", "r-"), flip * a, flip * b, r))
    return tuple((n, j, np.array(a, float) / 1000, np.array(b, float) / 1000, r / 1000) for n, j, a, b, r in out)


#: The puppet's limbs: ``(name, joint, start, end, radius)``, a capsule from ``start`` to ``end``
#: (metres) in the frame of ``joint``, i.e. along the bone that joint moves. Radii make each bead
#: touch its limb (beads sit 6 mm above the arm axes, 8 mm beside the legs, 11-12 mm in front of
#: torso and head); the head is a neck plus a wider capsule carrying the head beads.
PUPPET_LIMBS = _limbs()


def webcam_sensor(jpeg_quality: int | None = 85) -> Sensor:
    """A small webcam sensor: visible shot and read noise, a soft lens, JPEG at ``jpeg_quality``."""
    return Sensor(gain=1.0, full_well=3000.0, read_noise=0.008, jpeg_quality=jpeg_quality, blur_px=0.7)


# --- the puppet as bodies -------------------------------------------------------------------
def limbs_for(skeleton: Skeleton) -> tuple:
    """:data:`PUPPET_LIMBS` sized for a puppet skeleton of other proportions (same joint names):
    each capsule scaled by the length ratio of the bone it lies along (the joint's child whose
    rest offset points most nearly its way)."""
    base = _builtin_skeleton()
    if skeleton is base or (skeleton.names == base.names and np.allclose(skeleton.offsets, base.offsets)):
        return PUPPET_LIMBS
    out = []
    for name, joint, p0, p1, rad in PUPPET_LIMBS:
        kids = base.children(joint)
        ratio = 1.0
        if kids:
            d = p1 - p0
            c = max(kids, key=lambda k: float(d @ base.offsets[k]) / (np.linalg.norm(base.offsets[k]) + 1e-12))
            if base.bone_lengths[c] > 0:
                ratio = skeleton.bone_lengths[skeleton.index(base.names[c])] / base.bone_lengths[c]
        out.append((name, joint, p0 * ratio, p1 * ratio, rad))
    return tuple(out)


@functools.lru_cache(maxsize=1)
def _builtin_skeleton() -> Skeleton:
    return Skeleton.puppet()


def _segments(pose: Pose, markerset: MarkerSet):
    """World segments of limbs and beads: starts (n, 3), ends (n, 3), radii (n,)."""
    j2w = pose.joint2world
    sk = pose.skeleton
    a, b, r = [], [], []
    for _, joint, p0, p1, rad in limbs_for(sk):
        T = j2w[sk.index(joint)]
        a.append(T[:3, :3] @ p0 + T[:3, 3])
        b.append(T[:3, :3] @ p1 + T[:3, 3])
        r.append(rad)
    beads = markerset.positions(pose)
    return (np.concatenate([np.array(a), beads]), np.concatenate([np.array(b), beads]),
            np.concatenate([r, [m.diameter / 2 for m in markerset.markers]]))


def puppet_bodies(pose: Pose, markerset: MarkerSet | None = None) -> list[tuple]:
    """The posed puppet as ``(body, body2world)`` pairs: limb capsules, then the beads, then the
    platform (the plane y = 0).

    Parameters
    ----------
    pose : Pose
        A pose of :meth:`Skeleton.puppet` in the puppet frame.
    markerset : MarkerSet, optional
        Default :meth:`MarkerSet.puppet`. Bead colours: the markers' sRGB reference colours as
        linear albedos.
    """
    markerset = markerset or MarkerSet.puppet()
    a, b, _ = _segments(pose, markerset)
    placed = []
    for (name, _, _, _, rad), p0, p1 in zip(PUPPET_LIMBS, a, b):
        v = p1 - p0
        L = float(np.linalg.norm(v))
        z = v / L
        x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z])  # capsule axis (+z) along the limb
        placed.append((Capsule(L, rad, albedo=BLACK, name=name), pose_matrix(R, p0)))
    for m, c in zip(markerset.markers, a[len(PUPPET_LIMBS):]):
        placed.append((Sphere(m.diameter / 2, albedo=srgb_to_linear(np.array(m.rgb) * 255), name=m.name),
                       pose_matrix(np.eye(3), c)))
    floor = pose_matrix(np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]), np.zeros(3))  # plane z=0 -> y=0
    placed.append((TexturedPlane(None, albedo=BLACK, name="platform"), floor))
    return placed


def view_scene(placed: list, camera: Camera, ambient: float = 0.02) -> Scene:
    """The still scene one camera photographs: the world-fixed ``placed`` bodies plus what turns
    with the camera: its LEDs (a point light at its centre) and the back panel (a black plane
    :data:`PANEL_BEHIND` behind the turn axis, upright, facing the camera)."""
    c = camera.center
    v = np.array([-c[0], 0.0, -c[2]])  # horizontal, from the camera toward the axis
    if np.linalg.norm(v) < 1e-6:  # a camera on the axis: use its horizontal viewing direction
        v = camera.R[2] * [1.0, 0.0, 1.0]
    if np.linalg.norm(v) < 1e-6:
        v = np.array([0.0, 0.0, -1.0])
    v = v / np.linalg.norm(v)
    x = np.cross([0.0, 1.0, 0.0], -v)  # the panel's frame: y up, z (its normal) toward the camera
    R = np.column_stack([x, [0.0, 1.0, 0.0], -v])
    panel = (TexturedPlane(PANEL_EXTENT, albedo=BLACK, name="back-panel"), pose_matrix(R, PANEL_BEHIND * v))
    return Scene.still(list(placed) + [panel], [PointLight(c, LED_INTENSITY)], ambient=ambient,
                       backdrop=Backdrop(0.002))


# --- poses ------------------------------------------------------------------------------------
def _touching(a, b, r, step: float = 0.0015) -> np.ndarray:
    """Which pairs of segments (capsules of radii ``r``) interpenetrate, shape (n, n); sampled
    every ``step`` metres (a crude but simple test)."""
    pts, own = [], []
    for i, (p, q) in enumerate(zip(a, b)):
        k = max(1, int(np.ceil(np.linalg.norm(q - p) / step))) + 1
        pts.append(p + np.linspace(0, 1, k)[:, None] * (q - p))
        own.append(np.full(k, i))
    pts, own = np.concatenate(pts), np.concatenate(own)
    gap = cdist(pts, pts) - r[own][:, None] - r[own][None, :]
    out = np.zeros((len(a), len(a)), bool)
    ii, jj = np.nonzero(gap < 0)
    out[own[ii], own[jj]] = True
    return out


def puppet_collisions(pose: Pose, markerset: MarkerSet | None = None) -> list[tuple[str, str]]:
    """Pairs of puppet parts (limbs, beads) that interpenetrate in ``pose``, and ``"platform"``
    for parts below the platform (y < 0). Parts that touch in the rest pose (neighbours) are
    never reported."""
    markerset = markerset or MarkerSet.puppet()
    return _collisions(pose, markerset, _neighbours(pose.skeleton, markerset))


def _neighbours(skeleton: Skeleton, markerset: MarkerSet) -> np.ndarray:
    """Pairs of parts that (nearly, 1 mm) touch in the rest pose: never reported as collisions."""
    a, b, r = _segments(Pose.rest(skeleton), markerset)
    return _touching(a, b, r + 0.0005)


def _collisions(pose: Pose, markerset: MarkerSet, rest: np.ndarray) -> list[tuple[str, str]]:
    names = [l[0] for l in PUPPET_LIMBS] + list(markerset.names)
    a, b, r = _segments(pose, markerset)
    hit = np.triu(_touching(a, b, r) & ~rest, 1)
    out = [(names[i], names[j]) for i, j in zip(*np.nonzero(hit))]
    low = np.minimum(a[:, 1], b[:, 1]) - r < -1e-6
    return out + [(names[i], "platform") for i in np.flatnonzero(low)]


def random_pose(skeleton: Skeleton | None = None, rng=None, markerset: MarkerSet | None = None,
                max_tries: int = 500) -> Pose:
    """A random puppet pose within the joint limits, without crude self-intersections.

    Every joint's intrinsic XYZ Euler angles are drawn uniformly within its limits
    (:func:`~stillcap.body.retarget.euler_bounds_deg`); poses where two non-neighbouring parts
    (limbs, beads) interpenetrate or a part goes below the platform are drawn again. The
    pelvis stays on the turn axis (the rest ``root2world``).

    Raises
    ------
    ValueError
        If no valid pose was found in ``max_tries`` draws.
    """
    rng = as_rng(rng)
    skeleton = skeleton or Skeleton.puppet()
    markerset = markerset or MarkerSet.puppet()
    rest = _neighbours(skeleton, markerset)
    b = euler_bounds_deg(skeleton)
    for _ in range(max_tries):
        ang = rng.uniform(b[..., 0], b[..., 1])
        pose = Pose(skeleton, skeleton.rest_root2world(),
                    Rotation.from_euler(EULER_LIMIT_SEQUENCE, ang, degrees=True).as_matrix())
        if not _collisions(pose, markerset, rest):
            return pose
    raise ValueError(f"no collision-free random pose found in {max_tries} tries")


def pose_from_spec(spec: str, rng=None, skeleton: Skeleton | None = None,
                   markerset: MarkerSet | None = None) -> tuple[Pose, dict]:
    """A puppet pose from a text spec, and a description of where it came from.

    Parameters
    ----------
    spec : str
        ``"random"`` or ``"random:SEED"`` (:func:`random_pose`), ``"tpose"`` (the rest pose) or
        ``"bvh:FILE"`` / ``"bvh:FILE:FRAME"`` (frame 0 by default, retargeted with
        :func:`~stillcap.body.retarget.retarget_pose`).
    rng : np.random.Generator or int, optional
        Draws the seed of ``"random"``.
    skeleton : Skeleton, optional
        Default :meth:`Skeleton.puppet`.
    markerset : MarkerSet, optional
        The beads :func:`random_pose` keeps from interpenetrating (default the thesis's 16).

    Returns
    -------
    pose : Pose
    source : dict
        ``{"type": "random", "seed": s}``, ``{"type": "tpose"}`` or
        ``{"type": "bvh", "file": path, "frame": k, "joint_map": {...}}``.
    """
    skeleton = skeleton or Skeleton.puppet()
    text = str(spec).strip()
    kind, _, arg = text.partition(":")
    kind = kind.lower()
    if kind == "random":
        try:
            seed = int(arg) if arg else int(as_rng(rng).integers(2**31))
        except ValueError:
            raise ValueError(f"pose spec {text!r}: the seed after 'random:' must be an integer") from None
        return random_pose(skeleton, seed, markerset), {"type": "random", "seed": seed}
    if kind in ("tpose", "t-pose", "rest") and not arg:
        return Pose.rest(skeleton), {"type": "tpose"}
    if kind == "bvh" and arg:
        from stillcap.io.bvh_read import read_bvh

        file, frame = arg, 0
        head, _, tail = arg.rpartition(":")
        if head and tail.strip().lstrip("-").isdigit():
            file, frame = head, int(tail)
        path = Path(file)
        if not path.is_file():
            raise ValueError(f"BVH file {str(path)!r} does not exist (pose spec {text!r})")
        anim = read_bvh(path)
        if not 0 <= frame < anim.n_frames:
            raise ValueError(f"BVH file {str(path)!r} has {anim.n_frames} frames; frame {frame} does not exist")
        res = retarget_pose(anim[frame], skeleton)
        return res.pose, {"type": "bvh", "file": str(path), "frame": frame, "joint_map": res.joint_map}
    raise ValueError(f"unknown pose spec {text!r}: use 'random', 'random:SEED', 'tpose' or 'bvh:FILE[:FRAME]'")


# --- visibility ------------------------------------------------------------------------------
_GOLDEN = np.pi * (3 - np.sqrt(5))


def marker_visibility(camera: Camera, placed: list, bead_index, n_rays: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Which beads a camera sees, and how much of each.

    Parameters
    ----------
    camera : Camera
    placed : list of (body, body2world)
        Everything in the view (:func:`view_scene`'s ``static``).
    bead_index : sequence of int, length n_beads
        Index in ``placed`` of each bead's :class:`Sphere`.
    n_rays : int
        Rays spread evenly over each bead's silhouette disc for the coverage.

    Returns
    -------
    visible : np.ndarray of bool, shape (n_beads,)
        The line of sight to the bead centre reaches the bead before any other body, and the
        centre projects inside the image.
    coverage : np.ndarray, shape (n_beads,)
        Fraction of the bead's silhouette where the bead is the nearest body.
    """
    o = camera.center
    W, H = camera.image_size
    bead_index = np.asarray(bead_index, int)
    k = np.arange(n_rays)
    rho, phi = 0.95 * np.sqrt((k + 0.5) / n_rays), k * _GOLDEN  # sunflower: area-uniform on the disc
    disc = np.concatenate([[[0.0, 0.0]], np.stack([rho * np.cos(phi), rho * np.sin(phi)], 1)])  # centre first
    dirs, t_bead = [], []
    for bi in bead_index:  # rays from the camera through each bead's silhouette disc
        body, T = placed[bi]
        c, r = T[:3, 3], body.radius
        u = (c - o) / np.linalg.norm(c - o)
        e1 = np.cross(u, [0.0, 1.0, 0.0] if abs(u[1]) < 0.9 else [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        d = c + r * (disc[:, :1] * e1 + disc[:, 1:] * np.cross(u, e1)) - o
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        dirs.append(d)
        t_bead.append(_hit(body, o - c, d))  # sphere frame = a translation
    d, t_bead = np.concatenate(dirs), np.concatenate(t_bead)
    owner = np.repeat(bead_index, n_rays + 1)
    t_other = np.full(len(d), np.inf)
    for j, (body, T) in enumerate(placed):
        R, p = T[:3, :3], T[:3, 3]
        t = _hit(body, R.T @ (o - p), d @ R)
        t_other = np.minimum(t_other, np.where(owner == j, np.inf, t))
    clear = (t_bead < t_other).reshape(len(bead_index), n_rays + 1)
    px = camera.project(np.array([placed[bi][1][:3, 3] for bi in bead_index]).reshape(-1, 3))
    inside = np.all(np.isfinite(px), axis=1) & np.all((px >= -0.5) & (px <= [W - 0.5, H - 0.5]), axis=1)
    return clear[:, 0] & inside, clear[:, 1:].mean(axis=1)


# --- truth and scenario -----------------------------------------------------------------------
def turn_angle_deg(camera: Camera) -> float:
    """The turntable angle of a camera (degrees in [0, 360)): its centre's azimuth about the y axis,
    0 on +z, as ``(-d sin a, h, d cos a)`` of :func:`~stillcap.calibrate.turntable.turntable_rig`."""
    c = camera.center
    return float(np.degrees(np.arctan2(-c[0], c[2])) % 360.0)


@dataclass
class PuppetTruth:
    """Ground truth of a puppet capture (puppet frame, metres; pixels (x, y) OpenCV).

    Attributes
    ----------
    marker_names : list of str
    marker_positions : np.ndarray, shape (n_markers, 3)
        Bead centres.
    marker_colors : np.ndarray, shape (n_markers, 3)
        Linear RGB albedo of each bead.
    marker_diameter : np.ndarray, shape (n_markers,)
    joint_names : list of str
    joint_positions : np.ndarray, shape (n_joints, 3)
    local_rotations : np.ndarray, shape (n_joints, 3, 3)
        The pose (:class:`~stillcap.body.Pose`) with ``root2world``.
    root2world : np.ndarray, shape (4, 4)
    cameras : list of str
    angles_deg : np.ndarray, shape (n_views,)
        Turn angle of each view (:func:`turn_angle_deg`).
    markers_px : np.ndarray, shape (n_views, n_markers, 2)
        True pixel of each bead centre; NaN where it is not visible.
    visible : np.ndarray of bool, shape (n_views, n_markers)
    coverage : np.ndarray, shape (n_views, n_markers)
        Fraction of each bead's silhouette where the bead is the nearest body (1 = unobstructed;
        a bead whose centre is hidden may still show an edge).
    source : dict
        Where the pose came from (:func:`pose_from_spec`): random seed, T-pose or BVH file + frame.
    skeleton : Skeleton or None
        The puppet's own skeleton when it is not the built-in one (another puppet:
        :func:`stillcap.studio.puppet_variation.another_puppet`); written to ``truth.json``.
    """

    marker_names: list
    marker_positions: np.ndarray
    marker_colors: np.ndarray
    marker_diameter: np.ndarray
    joint_names: list
    joint_positions: np.ndarray
    local_rotations: np.ndarray
    root2world: np.ndarray
    cameras: list
    angles_deg: np.ndarray
    markers_px: np.ndarray
    visible: np.ndarray
    coverage: np.ndarray
    source: dict = field(default_factory=dict)
    skeleton: Skeleton | None = None

    @property
    def views_per_marker(self) -> np.ndarray:
        """How many views see each marker, shape (n_markers,)."""
        return self.visible.sum(axis=0)

    def pose(self, skeleton: Skeleton | None = None) -> Pose:
        """The true pose of ``skeleton`` (default the puppet's own, else the built-in puppet)."""
        return Pose(skeleton or self.skeleton or Skeleton.puppet(), self.root2world, self.local_rotations)

    def to_dict(self) -> dict:
        extra = {} if self.skeleton is None else {"skeleton": self.skeleton.to_dict("mm")}
        return extra | {
            "kind": "puppet", "frame": "puppet",
            "units": {"length": "m", "pixels": "px (x, y), origin top-left pixel centre", "angle": "deg"},
            "source": dict(self.source),
            "markers": [{"name": n, "position": p, "color": c, "diameter": float(d)}
                        for n, p, c, d in zip(self.marker_names, self.marker_positions, self.marker_colors,
                                              self.marker_diameter)],
            "joints": [{"name": n, "position": p, "local_rotation": R}
                       for n, p, R in zip(self.joint_names, self.joint_positions, self.local_rotations)],
            "root2world": self.root2world,
            "cameras": list(self.cameras), "angles_deg": self.angles_deg,
            "markers_px": self.markers_px, "visible": self.visible.astype(bool).tolist(), "coverage": self.coverage,
        }

    @classmethod
    def from_dict(cls, d: dict) -> PuppetTruth:
        from stillcap.files.jsonable import from_jsonable

        m, j = d["markers"], d["joints"]
        nv, nm = len(d["cameras"]), len(m)
        return cls([x["name"] for x in m], np.array([x["position"] for x in m], float).reshape(nm, 3),
                   np.array([x["color"] for x in m], float).reshape(nm, 3),
                   np.array([x["diameter"] for x in m], float),
                   [x["name"] for x in j], np.array([x["position"] for x in j], float).reshape(-1, 3),
                   np.array([x["local_rotation"] for x in j], float).reshape(-1, 3, 3),
                   np.array(d["root2world"], float), list(d["cameras"]),
                   np.array(d["angles_deg"], float).reshape(nv),
                   from_jsonable(d["markers_px"]).reshape(nv, nm, 2),
                   np.array(d["visible"], bool).reshape(nv, nm),
                   np.array(d["coverage"], float).reshape(nv, nm), dict(d.get("source", {})),
                   Skeleton.from_dict(d["skeleton"], "truth.json", ("skeleton",)) if d.get("skeleton") else None)


@dataclass
class PuppetScene:
    """A rendered puppet capture: the rig, the world-fixed scene (puppet and platform, no lights:
    :func:`view_scene` adds what turns with the camera), one image per view, the truth."""

    rig: Rig
    scene: Scene
    images: list
    truth: PuppetTruth
    markerset: MarkerSet | None = None

    def view_scene(self, view: int) -> Scene:
        """The scene rendered for view ``view``."""
        return view_scene(self.scene.static, self.rig[view])

    def to_capture(self, ext: str = ".png") -> tuple[Capture, dict]:
        """The capture folder content ``(Capture, {file: image})``: kind ``"puppet"``, the rig
        (known turntable geometry, ``rig_calibrated: true``), ``truth.json``; per image its view
        index and turn angle (``meta``: ``view``, ``angle_deg``). The marker set is stored whole
        as ``capture.json``'s ``markerset`` (:meth:`MarkerSet.to_dict`, millimetres), so the
        pipeline reads the capture with the beads and colours it shows, even if a built-in set
        changes later."""
        files = [f"images/view_{i:03d}{ext}" for i in range(len(self.rig))]
        imgs = [CaptureImage(f, c.name, meta={"view": i, "angle_deg": round(float(a), 6)})
                for i, (f, c, a) in enumerate(zip(files, self.rig, self.truth.angles_deg))]
        src = self.truth.source.get("type", "pose")
        ms = self.markerset or MarkerSet.puppet()
        meta = {"synthetic": True, "rig_calibrated": True, "markerset": ms.to_dict("mm"),
                "description": f"synthetic puppet on a turntable ({src} pose), {len(files)} views, "
                               f"{len(ms)} beads ({ms.name})"}
        return Capture("puppet", self.rig, imgs, self.truth.to_dict(), meta), dict(zip(files, self.images))


def puppet_scene(rig: Rig | None = None, pose: Pose | str | None = None, rng=None, sensor: Sensor | None = None,
                 supersample: int = 3, progress: Callable[[int, int], None] | None = None,
                 markerset: MarkerSet | str | None = None, skeleton: Skeleton | None = None) -> PuppetScene:
    """Photograph the posed puppet from every view of a rig, with the truth.

    Parameters
    ----------
    rig : Rig, optional
        Cameras in the puppet frame; default the thesis's turntable
        (:func:`~stillcap.calibrate.turntable.turntable_rig`: 12 views 30 degrees apart, webcam
        640x480, 0.400 m from the axis, 0.080 m above the platform).
    pose : Pose or str, optional
        A pose of :meth:`Skeleton.puppet` or a spec for :func:`pose_from_spec` (``"random"``,
        ``"random:SEED"``, ``"tpose"``, ``"bvh:FILE[:FRAME]"``); default ``"random"``.
    rng : np.random.Generator or int, optional
        Random pose and sensor noise.
    sensor : Sensor, optional
        Default :func:`webcam_sensor` (noise, JPEG quality 85).
    supersample : int
        Sub-pixel rays per axis at edges.
    progress : callable(i, n), optional
        Called after each rendered view.
    markerset : MarkerSet or str, optional
        The beads: a :class:`MarkerSet` of the puppet skeleton, a built-in name (``"puppet-16"``,
        the default, or ``"puppet-20"``) or a marker-set file (:meth:`MarkerSet.resolve`).
    skeleton : Skeleton, optional
        The puppet's skeleton for a pose spec (another puppet's:
        :func:`stillcap.studio.puppet_variation.another_puppet`); default the built-in puppet.
    """
    rng = as_rng(rng)
    markerset = MarkerSet.resolve(markerset)
    rig = rig if rig is not None else turntable_rig()
    if not isinstance(rig, Rig) or len(rig) == 0:
        raise ValueError(f"rig must be a stillcap Rig with at least one camera, got {rig!r}")
    sensor = sensor or webcam_sensor()
    rig = rig.with_responses(sensor.response)  # the rig written with the capture states the true response
    if pose is None or isinstance(pose, str):
        pose, source = pose_from_spec(pose or "random", rng, markerset=markerset, skeleton=skeleton)
    elif isinstance(pose, Pose):
        source = {"type": "pose"}
    else:
        raise ValueError(f"pose must be a Pose, a pose spec string or None, got {type(pose).__name__}")
    markerset.check_skeleton(pose.skeleton)
    placed = puppet_bodies(pose, markerset)
    beads = list(range(len(PUPPET_LIMBS), len(PUPPET_LIMBS) + len(markerset)))
    truth_pos = markerset.positions(pose)
    n, nm = len(rig), len(markerset)
    px = np.full((n, nm, 2), np.nan)
    vis = np.zeros((n, nm), bool)
    cov = np.zeros((n, nm))
    images = []
    for i, cam in enumerate(rig):
        scene = view_scene(placed, cam)
        vis[i], cov[i] = marker_visibility(cam, list(scene.static), beads)
        px[i, vis[i]] = cam.project(truth_pos[vis[i]])
        images.append(render(cam, scene, sensor, rng, supersample))
        if progress is not None:
            progress(i + 1, n)
    truth = PuppetTruth(list(markerset.names), truth_pos,
                        np.array([placed[b][0].albedo for b in beads]),
                        np.array([m.diameter for m in markerset.markers]),
                        list(pose.skeleton.names), pose.positions.copy(), pose.local_rotations.copy(),
                        pose.root2world.copy(), rig.names, np.array([turn_angle_deg(c) for c in rig]),
                        px, vis, cov, source, None if limbs_for(pose.skeleton) is PUPPET_LIMBS else pose.skeleton)
    return PuppetScene(rig, Scene.still(placed), images, truth, markerset)
