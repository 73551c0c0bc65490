"""The puppet workflow of the GUI (the thesis's JumpingJack program), under ``/api/puppet``.

The opened folder is the workspace: the project is the folder itself or one of its subfolders
(``POST /new``, ``POST /open``), always inside it (``ctx.resolve``). Every change is saved at
once (``Project.save`` writes atomically); ``POST /save`` saves on request too.

Routes (JSON unless said):

- ``GET /state``: the project (views, the angle overview: taken / missing / to retake), the
  marker set with colours, the projects in the workspace.
- ``POST /new`` ``{path, distance_mm, height_mm, name, markerset}``, ``POST /open`` ``{path}``,
  ``POST /save``.
- ``POST /photo?angle=DEG[&replace=1]`` (multipart ``file``): a photo for a turn angle, decoded
  safely (:mod:`stillcap.gui.uploads`), its beads detected and identified, stored.
- ``POST /server-camera?source=N&angle=DEG[&replace=1]``: the same with a frame of the server's
  OpenCV camera ``N`` (an index only: never a path). ``GET /server-camera/frame?source=N``: a
  JPEG preview.
- ``GET /photo/{view}``: the stored photo. ``DELETE /view/{view}``: remove a view.
- ``GET /view/{view}``: the processed view: identified beads (name, colour, confidence, whether
  detected or edited), rejected candidates. ``POST /view/{view}/edit`` ``{op, marker, to, xy}``
  (``delete``, ``relabel``, ``move``: a move of an absent marker adds it); ``POST
  /view/{view}/clear-edits``; ``POST /view/{view}/redetect`` (the edits still apply);
  ``POST /view/{view}/retake`` (flag it to be retaken).
- ``POST /import`` ``{capture, project}``: a background job making a project of a puppet capture
  folder (``stillcap studio puppet``; default project folder: ``CAPTURE/project``); ``GET
  /state`` lists the captures found (``captures``).
- ``POST /reconstruct``: a background job (:mod:`stillcap.gui.jobs`): 3D markers and the pose
  from the stored markers; its result is the 3D scene (``GET /result`` answers it again).
- ``GET /export/{fmt}`` (``dae``, ``bvh``, ``gltf``, ``glb``, ``c3d``, ``csv``, ``json``): writes
  ``exports/pose.<fmt>`` in the project with :func:`stillcap.io.export.export` and downloads it.

Bead "confidence" is ``1 - d / d_max``: the identified candidate's colour distance ``d`` to its
reference colour against the identification's acceptance limit ``d_max`` (1 = the exact colour,
0 = at the limit).
"""

from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Route

from stillcap.gui.context import GuiContext
from stillcap.gui.jobs import job_manager, job_response
from stillcap.gui.uploads import uploaded_image

__all__ = ["EXPORT_FORMATS", "MIN_IDENTIFIED_FRACTION", "PLANNED_ANGLES_DEG", "routes"]

#: The turntable angles the overview expects: the thesis's 12 photos, 30 degrees apart.
PLANNED_ANGLES_DEG = tuple(float(a) for a in range(0, 360, 30))
#: Export formats offered (extension: what it holds).
EXPORT_FORMATS = {"dae": "COLLADA pose", "bvh": "BVH pose", "gltf": "glTF pose", "glb": "glTF binary pose",
                  "c3d": "C3D markers", "csv": "CSV markers", "json": "JSON markers"}
#: A view identifying fewer than this share of the marker set is flagged "to retake".
MIN_IDENTIFIED_FRACTION = 0.5


class _Puppet:
    """The GUI's puppet state: the open project, the last 3D result, per-view detection caches."""

    def __init__(self, ctx: GuiContext):
        self.ctx = ctx
        self.lock = threading.RLock()
        self.project = None
        self.rel = None  # the project folder, relative to ctx.root ("." for the root itself)
        self.result = None  # the last reconstruction's scene (JSON)
        self.result_obj = None
        self.details: dict[str, dict] = {}  # view name -> detection details (rejected, confidence)
        self.retake: set[str] = set()
        if (ctx.root / "project.json").is_file():
            self.open(".")

    # -- projects ----------------------------------------------------------------------------
    def _folder(self, rel: str) -> Path:
        rel = (rel or ".").strip() or "."
        return self.ctx.root if rel == "." else self.ctx.resolve(rel)

    def open(self, rel: str):
        from stillcap.io.project import Project

        folder = self._folder(rel)
        if not (folder / "project.json").is_file():
            raise ValueError(f"{rel!r} holds no puppet project (project.json)")
        self.project, self.rel = Project.load(folder), rel
        self.result = self.result_obj = None
        self.details, self.retake = {}, set()

    def new(self, rel: str, distance_mm: float, height_mm: float, name: str | None, markerset: str):
        from stillcap.io.project import Project, TurntableSetup

        folder = self._folder(rel)
        for v, what in ((distance_mm, "distance_mm"), (height_mm, "height_mm")):
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{what} must be a number of millimetres, got {v!r}")
        self.project = Project.create(folder, turntable=TurntableSetup(distance=distance_mm / 1000,
                                                                       height=height_mm / 1000),
                                      name=name or None, markerset=markerset)
        self.rel = rel
        self.result = self.result_obj = None
        self.details, self.retake = {}, set()

    def need(self):
        if self.project is None:
            raise ValueError("no project is open: make a new one or open one first")
        return self.project

    def import_capture(self, progress, rel_capture: str, rel_project: str) -> dict:
        """Make a project of a puppet capture folder (``capture.json`` of kind ``puppet``, as
        ``stillcap studio puppet`` writes it): the capture's rig and marker set, a view per photo
        (copied into the project's ``photos/``) with its beads detected and identified, as
        ``stillcap puppet run`` detects them. The project goes to ``rel_project`` (inside the
        opened folder); a folder that already holds a project is opened instead."""
        from stillcap.io.capture import Capture
        from stillcap.io.project import Project
        from stillcap.pipelines.puppet import capture_markerset

        src = self._folder(rel_capture)
        folder = self._folder(rel_project)
        if (folder / "project.json").is_file():
            with self.lock:
                self.open(rel_project)
            return {"project": rel_project, "imported": False}
        if not (src / "capture.json").is_file():
            raise ValueError(f"{rel_capture!r} holds no capture (capture.json)")
        kind = _capture_kind(src)  # before the whole file is checked: the kind is the first thing to say
        if kind != "puppet":
            raise ValueError(f"{rel_capture}/capture.json: kind {kind!r} is not a puppet capture")
        cap = Capture.load(src)
        if cap.rig is None:
            raise ValueError(f"{rel_capture}/capture.json: the capture has no rig (its cameras are needed for 3D)")
        markerset = capture_markerset(src, cap)
        project = Project.create(folder, rig=cap.rig, markerset=markerset,
                                 name=Path(rel_capture).name if rel_capture not in ("", ".") else self.ctx.root.name,
                                 save=False)
        details = {}
        n = len(cap.images)
        for i, im in enumerate(cap.images):
            progress(i, n, f"detecting the beads of {im.camera}")
            image = cap.read_image(im)  # checked and decoded safely (stillcap.files.images)
            det, details_i = self.detect(image, markerset)
            v = project.add_view(cap.path_of(im), camera=im.camera, detections=det)  # copied byte for byte
            details[v.name] = details_i
        project.save()
        with self.lock:
            self.project, self.rel = project, rel_project
            self.result = self.result_obj = None
            self.details, self.retake = details, set()
        progress(n, n, "imported")
        return {"project": rel_project, "imported": True, "views": n}

    def captures(self) -> list[str]:
        """Puppet captures in the opened folder (itself, or its subfolders), to import."""
        def is_puppet(folder: Path) -> bool:
            return (folder / "capture.json").is_file() and _capture_kind(folder) == "puppet"

        root = self.ctx.root
        found = ["."] if is_puppet(root) else []
        try:
            found += sorted(p.name for p in root.iterdir() if p.is_dir() and not p.is_symlink() and is_puppet(p))
        except OSError:
            pass
        return found

    def projects(self) -> list[str]:
        root = self.ctx.root
        found = ["."] if (root / "project.json").is_file() else []
        try:
            found += sorted(p.name for p in root.iterdir() if p.is_dir() and not p.is_symlink()
                            and (p / "project.json").is_file())
        except OSError:
            pass
        return found

    # -- detection ---------------------------------------------------------------------------
    def detect(self, image, markerset=None) -> tuple[dict, dict]:
        """``(detections {name: (x, y)}, details)`` of one photo with the pipeline's defaults
        (the open project's marker set unless ``markerset``)."""
        from stillcap.detect.palette import Palette
        from stillcap.pipelines.puppet import DEFAULT, detect_view

        pal = Palette.from_markerset(markerset if markerset is not None else self.need().markerset)
        vr = detect_view(image, pal, DEFAULT)
        ident, circles = vr.identification, vr.circles
        beads = []
        for k, name in enumerate(ident.names):
            if np.all(np.isfinite(ident.points[k])):
                d = float(ident.distances[k])
                conf = max(0.0, min(1.0, 1.0 - d / ident.max_distance)) if math.isfinite(d) and ident.max_distance > 0 else None
                c = int(ident.candidate[k])
                beads.append({"name": name, "xy": [float(v) for v in ident.points[k]],
                              "confidence": conf, "distance": d if math.isfinite(d) else None,
                              "radius": float(circles.radii[c]) if 0 <= c < len(circles.radii) else None})
        rejected = [{"xy": [float(v) for v in circles.centers[c]], "radius": float(circles.radii[c]),
                     "color": _hex(ident.colors[c]) if c < len(ident.colors) else None}
                    for c in map(int, ident.rejected)]
        return ident.as_dict(), {"beads": beads, "rejected": rejected, "metric": ident.metric}

    def add_photo(self, image, angle: float, replace: bool) -> dict:
        with self.lock:
            p = self.need()
            if not p.is_turntable:
                raise ValueError("the GUI takes photos for turntable projects; this project uses a camera rig")
            det, details = self.detect(image)
            v = p.add_view(image, angle_deg=angle, detections=det, replace=replace)
            p.save()
            self.details[v.name] = details
            self.retake.discard(v.name)
            self.result = self.result_obj = None
            return self.view_json(v.name)

    def view_json(self, key: str) -> dict:
        with self.lock:
            p = self.need()
            v = p.view(key)
            if v.name not in self.details:
                self.details[v.name] = self.detect(p.read_image(v))[1]
            det = self.details[v.name]
            by_name = {b["name"]: b for b in det["beads"]}
            colors = dict(zip(p.markerset.names, (_hex(c) for c in p.markerset.rgb)))
            edited = {e.marker for e in v.edits} | {e.to for e in v.edits if e.to}
            markers = []
            for name, (x, y) in v.markers.items():
                auto = by_name.get(name)
                same = auto is not None and name in v.detected and np.allclose(auto["xy"], v.detected[name])
                markers.append({"name": name, "xy": [x, y], "color": colors.get(name, "#888888"),
                                "confidence": auto["confidence"] if same and name not in edited else None,
                                "source": "edited" if name in edited or name not in v.detected else "detected"})
            w, h = p.image_size(v)
            return {"name": v.name, "angle_deg": v.angle_deg, "image_size": [w, h], "markers": markers,
                    "rejected": det["rejected"], "edits": [e.to_dict() for e in v.edits],
                    "missing": [n for n in p.markerset.names if n not in v.markers]}

    # -- the overview ------------------------------------------------------------------------
    def state(self) -> dict:
        with self.lock:
            out = {"projects": self.projects(), "captures": self.captures(), "project": None,
                   "export_formats": EXPORT_FORMATS}
            p = self.project
            if p is None:
                return out
            n_set = len(p.markerset)
            views = []
            for v in p.views:
                n = len(v.markers)
                views.append({"name": v.name, "angle_deg": v.angle_deg, "image": v.image, "identified": n,
                              "edits": len(v.edits),
                              "status": "retake" if (v.name in self.retake or n < MIN_IDENTIFIED_FRACTION * n_set)
                              else "taken"})
            angles = []
            if p.is_turntable:
                planned = list(PLANNED_ANGLES_DEG)
                planned += [float(v.angle_deg) for v in p.views
                            if not any(abs((v.angle_deg - a + 180) % 360 - 180) < 1e-6 for a in planned)]
                planned.sort()
                for a in planned:
                    v = p.view_at(a)
                    entry = next((w for w in views if v is not None and w["name"] == v.name), None)
                    angles.append({"angle_deg": a, "status": entry["status"] if entry else "missing",
                                   "view": v.name if v is not None else None,
                                   "identified": entry["identified"] if entry else 0})
            else:  # a rig project (an imported capture): one tile per camera's view
                angles = [{"angle_deg": v["angle_deg"], "label": v["name"], "status": v["status"], "view": v["name"],
                           "identified": v["identified"]} for v in views]
            tt = p.turntable
            out["project"] = {
                "path": self.rel, "name": p.name, "turntable": p.is_turntable, "views": views, "angles": angles,
                "markerset": {"name": p.markerset.name,
                              "markers": [{"name": n, "color": _hex(c)} for n, c in zip(p.markerset.names, p.markerset.rgb)]},
                "camera": None if tt is None else {"image_size": list(tt.camera.image_size),
                                                    "distance_mm": tt.distance * 1e3, "height_mm": tt.height * 1e3},
                "has_result": self.result is not None}
            return out

    # -- 3D ----------------------------------------------------------------------------------
    def reconstruct(self, progress) -> dict:
        from stillcap.pipelines.puppet import analyse_puppet

        with self.lock:
            p = self.need()
            if len(p.views) < 2:
                raise ValueError(f"3D needs photos from at least two angles; the project has {len(p.views)}")
            progress(0, 2, "triangulating the markers and posing the skeleton")
            res, _ = analyse_puppet(p, detect=False, save=False)
            progress(1, 2, "building the 3D view")
            self.result_obj = res
            self.result = _scene(res, p)
            progress(2, 2, "done")
            return self.result

    def export(self, fmt: str) -> Path:
        from stillcap.io.export import export

        if fmt not in EXPORT_FORMATS:
            raise ValueError(f"unknown export format {fmt!r}; choose one of {', '.join(EXPORT_FORMATS)}")
        with self.lock:
            p = self.need()
            if self.result_obj is None:
                raise ValueError("compute 3D first (no 3D result to export)")
            target = self.ctx.resolve(f"{self.rel}/exports/pose.{fmt}" if self.rel != "." else f"exports/pose.{fmt}")
            target.parent.mkdir(exist_ok=True)
            del p
            return export(target, self.result_obj)


def _capture_kind(folder: Path):
    """The ``kind`` a folder's ``capture.json`` names (None when unreadable); only peeks:
    :meth:`Capture.load` checks the whole file."""
    import json

    try:
        kind = json.loads((folder / "capture.json").read_text(encoding="utf-8")).get("kind")
    except (OSError, ValueError, AttributeError):
        return None
    return kind if isinstance(kind, str) else None


def _hex(rgb) -> str:
    r, g, b = (int(round(max(0.0, min(1.0, float(c))) * 255)) for c in rgb[:3])
    return f"#{r:02x}{g:02x}{b:02x}"


def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None


def _scene(res, project) -> dict:
    """The 3D scene of a reconstruction as JSON for the page: markers (metres, flagged when seen in
    fewer than two views), the skeleton's joints and bones, the cameras and the turntable, the
    joint angles (degrees, the skeleton's limit Euler angles X, Y, Z)."""
    m, pose = res.markers, res.pose
    sk = pose.skeleton
    colors = dict(zip(project.markerset.names, (_hex(c) for c in project.markerset.rgb)))
    markers = []
    for k, name in enumerate(m.names):
        ok = bool(m.ok[k])
        markers.append({"name": name, "position": [float(v) for v in m.points[k]] if ok else None,
                        "color": colors.get(name, "#888888"), "n_views": int(m.n_views[k]),
                        "whole_views": int(m.whole_views[k]), "reproj_error_px": _num(m.reproj_error_px[k]),
                        "missing": not ok, "weak": ok and int(m.whole_views[k]) < 2})
    angles = sk.limit_angles_deg(pose.local_rotations)
    joints = [{"name": n, "position": [float(v) for v in x], "parent": int(par),
               "angles_deg": [float(a) for a in ang]}
              for n, x, par, ang in zip(sk.names, pose.positions, sk.parents, angles)]
    cameras = []
    for cam, name in zip(res.rig, res.view_names):
        R, t = cam.world2cam[:3, :3], cam.world2cam[:3, 3]
        w, h = cam.image_size
        cameras.append({"name": name, "center": [float(v) for v in -R.T @ t], "rotation": R.tolist(),
                        "fov_y_deg": float(np.degrees(2 * np.arctan(h / 2 / cam.K[1, 1]))), "aspect": w / h})
    tt = project.turntable
    return {"frame": res.rig.world, "units": {"length": "m", "angle": "deg"},
            "up": [0.0, 1.0, 0.0], "markers": markers, "joints": joints, "cameras": cameras,
            # the platform is the plane y = 0; the project does not store its size: drawn as a disc
            # reaching a quarter of the way to the camera, only to show where the turntable is
            "turntable": None if tt is None else {"radius_m": tt.distance * 0.25, "height_m": 0.0,
                                                  "camera_distance_m": tt.distance, "camera_height_m": tt.height},
            "missing": list(m.missing), "weak": [x["name"] for x in markers if x["weak"]],
            "pose_fit": {"method": res.options.pose, "rms_mm": _num(res.fit.rms_m * 1e3), "success": bool(res.fit.success)}}


def _error(e: Exception, status: int = 400) -> JSONResponse:
    return JSONResponse({"error": str(e)}, status_code=status)


def _angle(request: Request) -> float:
    try:
        a = float(request.query_params["angle"])
    except (KeyError, ValueError):
        raise ValueError("give the photo's turn angle: ?angle=DEGREES") from None
    if not math.isfinite(a):
        raise ValueError(f"angle must be a finite number of degrees, got {a}")
    return a


def routes(ctx: GuiContext) -> list[Route]:
    """The puppet API (see the module's text)."""
    pp = ctx.state.get("puppet") or ctx.state.setdefault("puppet", _Puppet(ctx))
    jobs = job_manager(ctx)

    def handler(fn):
        async def wrapped(request: Request):
            try:
                return await fn(request)
            except (ValueError, FileNotFoundError) as e:
                return _error(e)
        return wrapped

    async def _json(request: Request) -> dict:
        try:
            body = await request.json()
        except ValueError:
            raise ValueError("the request body is not JSON") from None
        if not isinstance(body, dict):
            raise ValueError("the request body must be a JSON object")
        return body

    async def state(request):
        return JSONResponse(await run_in_threadpool(pp.state))

    async def new(request):
        b = await _json(request)
        await run_in_threadpool(pp.new, str(b.get("path", ".")), b.get("distance_mm", 400.0), b.get("height_mm", 80.0),
                                b.get("name"), str(b.get("markerset", "puppet-16")))
        return JSONResponse(await run_in_threadpool(pp.state))

    async def open_(request):
        b = await _json(request)
        await run_in_threadpool(pp.open, str(b.get("path", ".")))
        return JSONResponse(await run_in_threadpool(pp.state))

    async def save(request):
        def do():
            with pp.lock:
                return str(pp.need().save())
        return JSONResponse({"saved": await run_in_threadpool(do)})

    async def photo_upload(request):
        angle = _angle(request)
        _, _, img = await uploaded_image(request)
        return JSONResponse(await run_in_threadpool(pp.add_photo, img, angle, request.query_params.get("replace") == "1"))

    def _source(request) -> int:
        s = request.query_params.get("source", "0")
        if not s.isdigit() or int(s) > 63:
            raise ValueError(f"server camera source must be a camera index 0..63, got {s!r}")
        return int(s)

    def _grab(source: int):
        from stillcap.io.camera_capture import grab_frame, open_source

        cap, desc, owned = open_source(source)
        try:
            return grab_frame(cap, 1, discard_frames=2, what=desc)
        finally:
            if owned:
                cap.release()

    async def server_frame(request):
        import cv2

        img = await run_in_threadpool(_grab, _source(request))
        ok, buf = cv2.imencode(".jpg", img)
        return Response(buf.tobytes(), media_type="image/jpeg")

    async def server_take(request):
        angle, source = _angle(request), _source(request)
        img = await run_in_threadpool(_grab, source)
        return JSONResponse(await run_in_threadpool(pp.add_photo, img, angle, request.query_params.get("replace") == "1"))

    async def photo(request):
        def find():
            with pp.lock:
                p = pp.need()
                path = p.image_path(request.path_params["view"])
                pp.ctx.resolve(str(path.relative_to(pp.ctx.root)))  # inside the opened folder, symlinks resolved
                return path
        path = await run_in_threadpool(find)
        if not path.is_file():
            raise ValueError(f"the photo of view {request.path_params['view']!r} is missing")
        return FileResponse(path, headers={"Cache-Control": "no-store"})

    async def view(request):
        return JSONResponse(await run_in_threadpool(pp.view_json, request.path_params["view"]))

    async def delete_view(request):
        def do():
            with pp.lock:
                p = pp.need()
                p.remove_view(request.path_params["view"])
                p.save()
                pp.result = pp.result_obj = None
        await run_in_threadpool(do)
        return JSONResponse(await run_in_threadpool(pp.state))

    async def edit(request):
        b = await _json(request)
        op, marker = b.get("op"), b.get("marker")
        if not isinstance(marker, str) or not marker:
            raise ValueError("an edit needs the marker's name")

        def do():
            with pp.lock:
                p = pp.need()
                name = request.path_params["view"]
                if op == "delete":
                    p.edit(name, delete=marker)
                elif op == "relabel":
                    if not isinstance(b.get("to"), str):
                        raise ValueError("a relabel needs the new name ('to')")
                    p.edit(name, relabel=(marker, b["to"]))
                elif op == "move":
                    xy = b.get("xy")
                    if not (isinstance(xy, list) and len(xy) == 2 and all(isinstance(c, (int, float)) for c in xy)):
                        raise ValueError("a move needs 'xy': [x, y] in pixels")
                    if marker not in p.markerset.names:
                        raise ValueError(f"{marker!r} is not a marker of the set {p.markerset.name} "
                                         f"({', '.join(p.markerset.names)})")
                    p.edit(name, move=(marker, float(xy[0]), float(xy[1])))
                else:
                    raise ValueError(f"edit op must be 'delete', 'relabel' or 'move', got {op!r}")
                p.save()
                pp.result = pp.result_obj = None
                return pp.view_json(name)
        return JSONResponse(await run_in_threadpool(do))

    async def clear_edits(request):
        def do():
            with pp.lock:
                p = pp.need()
                p.clear_edits(request.path_params["view"])
                p.save()
                pp.result = pp.result_obj = None
                return pp.view_json(request.path_params["view"])
        return JSONResponse(await run_in_threadpool(do))

    async def redetect(request):
        def do():
            with pp.lock:
                p = pp.need()
                v = p.view(request.path_params["view"])
                det, details = pp.detect(p.read_image(v))
                p.set_detections(v, det)
                p.save()
                pp.details[v.name] = details
                pp.result = pp.result_obj = None
                return pp.view_json(v.name)
        return JSONResponse(await run_in_threadpool(do))

    async def retake(request):
        def do():
            with pp.lock:
                pp.retake.add(pp.need().view(request.path_params["view"]).name)
                return pp.state()
        return JSONResponse(await run_in_threadpool(do))

    async def import_capture(request):
        b = await _json(request)
        cap = str(b.get("capture", "."))
        proj = str(b.get("project") or (f"{cap}/project" if cap not in ("", ".") else "project"))
        pp._folder(cap), pp._folder(proj)  # paths leading out refused now, not in the job
        return job_response(jobs.submit(pp.import_capture, cap, proj, label="import capture"))

    async def reconstruct(request):
        pp.need()
        return job_response(jobs.submit(pp.reconstruct, label="compute 3D"))

    async def result(request):
        if pp.result is None:
            raise ValueError("no 3D result yet: compute 3D first")
        return JSONResponse(pp.result)

    async def export(request):
        fmt = request.path_params["fmt"]
        path = await run_in_threadpool(pp.export, fmt)
        return FileResponse(path, filename=path.name, headers={"Cache-Control": "no-store"})

    return [Route("/state", handler(state), methods=["GET"]),
            Route("/new", handler(new), methods=["POST"]),
            Route("/open", handler(open_), methods=["POST"]),
            Route("/save", handler(save), methods=["POST"]),
            Route("/photo", handler(photo_upload), methods=["POST"]),
            Route("/server-camera", handler(server_take), methods=["POST"]),
            Route("/server-camera/frame", handler(server_frame), methods=["GET"]),
            Route("/photo/{view}", handler(photo), methods=["GET"]),
            Route("/view/{view}", handler(view), methods=["GET"]),
            Route("/view/{view}", handler(delete_view), methods=["DELETE"]),
            Route("/view/{view}/edit", handler(edit), methods=["POST"]),
            Route("/view/{view}/clear-edits", handler(clear_edits), methods=["POST"]),
            Route("/view/{view}/redetect", handler(redetect), methods=["POST"]),
            Route("/view/{view}/retake", handler(retake), methods=["POST"]),
            Route("/import", handler(import_capture), methods=["POST"]),
            Route("/reconstruct", handler(reconstruct), methods=["POST"]),
            Route("/result", handler(result), methods=["GET"]),
            Route("/export/{fmt}", handler(export), methods=["GET"])]
