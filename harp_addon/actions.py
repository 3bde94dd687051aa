"""What the panel's buttons do, as plain functions (bpy, but no interface): start the import and
the fit in worker jobs, cancel and resume them, poll them and act when they end, bind an avatar,
export it. The operators (operators.py) call these; tests call them directly, since timers and
modal operators do not run in background mode.
"""
from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import bpy
import numpy as np

from . import engine
from .core import avatar_folder, sequence_folder
from .export import ExportError, export_fbx, export_gltf, save_blend
from .jobs import Job
from .retarget import RetargetError, bone_map, deform_map, retarget_motion, save_bone_map
from .scene import FIRST_FRAME, BindError, bind_avatar, footage_camera

INIT_FILE = "init.npz"


class ActionError(ValueError):
    """A button cannot do its work (one-line message for the interface)."""


@dataclasses.dataclass
class Running:
    job: Job
    kind: str                      # "import" or "fit"
    out: Path                      # the sequence or avatar folder the job writes
    scene_name: str


JOBS: dict = {}                    # scene name -> Running (one job per scene at a time)


def _python(python):
    status_python = python or engine.default_engine_python()
    if not status_python or not Path(status_python).is_file():
        raise ActionError(engine.check_engine(status_python).message)
    return status_python


def _start(scene_name, kind, out, commands, label):
    running = JOBS.get(scene_name)
    if running is not None and running.job.active:
        raise ActionError(f"a {running.kind} is running already: wait for it or cancel it")
    JOBS[scene_name] = Running(Job(commands, label).start(), kind, Path(out), scene_name)
    return JOBS[scene_name]


def start_import(scene_name, video, out, masks=None, side="auto", fov=0.0, python=None, overwrite=False):
    """`harp import-video` in a worker: the footage (a video file or image folder) and its masks
    (optional) into the sequence folder `out`."""
    if not video or not Path(video).exists():
        raise ActionError(f"footage not found: {video}")
    arguments = ["import-video", video, "--out", out, "--side", side]
    if masks:
        arguments += ["--masks", masks]
    if fov:
        arguments += ["--fov", fov]
    if overwrite:
        arguments.append("--overwrite")
    return _start(scene_name, "import", out, [engine.harp_command(_python(python), *arguments)], "import")


def start_fit(scene_name, sequence, out, preset="fast", shadows="auto", init="mediapipe", python=None,
              resume=False, initialise_again=False, extra=(), environment=None, specular=None, light_size=None):
    """`harp init` (unless the sequence has an init.npz and `initialise_again` is off) and then
    `harp fit --progress jsonl` in a worker; with `resume`, the fit goes on from its checkpoint.
    `extra` are more `harp fit` arguments (e.g. --max-steps N for a quick look); `environment`
    and `specular` (auto, on, off; None: the engine's default) the room's light and the skin's sheen,
    `light_size` (auto, off; None: likewise) the light's size."""
    python = _python(python)
    sequence, out = Path(sequence), Path(out)
    if not (sequence / sequence_folder.SEQUENCE_FILE).is_file():
        raise ActionError(f"not a sequence folder (import the footage first): {sequence}")
    room = [] if environment is None else ["--environment", environment]
    sheen = [] if specular is None else ["--specular", specular]
    size = [] if light_size is None else ["--light-size", light_size]
    fit = ["fit", sequence, "--out", out, "--preset", preset, "--shadows", shadows, *room, *sheen, *size,
           "--progress", "jsonl", *extra]
    if resume:
        if not (out / "checkpoint.pt").is_file():
            raise ActionError(f"nothing to resume in {out}")
        return _start(scene_name, "fit", out, [engine.harp_command(python, *fit, "--resume")], "fit")
    commands = []
    if initialise_again or not (sequence / INIT_FILE).is_file():
        commands.append(engine.harp_command(python, "init", sequence, "--init", init, "--progress", "jsonl"))
    commands.append(engine.harp_command(python, *fit))
    return _start(scene_name, "fit", out, commands, "fit")


def cancel(scene_name):
    running = JOBS.get(scene_name)
    if running is None or not running.job.active:
        raise ActionError("nothing is running")
    running.job.cancel()
    return running


def key_pressed(scene_name, key, value):
    """What a key does while the scene's job may run (the Esc listener's logic): Esc pressed stops
    the job as Cancel does ("cancelled"); with no job running the listener is done ("idle");
    any other key is left to Blender ("ignored")."""
    running = JOBS.get(scene_name)
    if running is None or not running.job.active:
        return "idle"
    if key == "ESC" and value == "PRESS":
        running.job.cancel()
        return "cancelled"
    return "ignored"


def poll(scene):
    """Move the scene's job on and mirror it into the scene's HARP settings; when it has just
    finished, set up what follows (the footage camera after an import, the avatar path after a
    fit). Returns the Running job or None."""
    running = JOBS.get(scene.name)
    if running is None:
        return None
    was_active = running.job.active
    running.job.poll()
    settings = getattr(scene, "harp", None)
    if settings is not None:
        settings.job_label, settings.job_state = running.job.label, running.job.state
        settings.job_fraction = running.job.fraction
        settings.job_status = status_line(running)
        settings.job_log = "\n".join(list(running.job.log)[-8:])
        settings.job_errors = "\n".join(running.job.errors) if running.job.state == "failed" else ""
    if was_active and running.job.state == "finished":
        if running.kind == "import":
            footage_camera(running.out, scene)
            if settings is not None:
                settings.sequence = str(running.out)
        elif running.kind == "fit" and settings is not None:
            settings.avatar = str(running.out)
    return running


def status_line(running):
    """The job's one-line status; a cancelled fit says whether it can be resumed."""
    line = running.job.status_line()
    if running.job.state == "cancelled" and running.kind == "fit":
        line += (" (checkpoint saved: Resume goes on from it)" if (running.out / "checkpoint.pt").is_file()
                 else " before its first checkpoint")
    return line


def bind(folder, sequence=None, scene=None, pack=False, smooth=0):
    """Bind an avatar folder into the scene (scene.bind_avatar; `pack`: its images travel inside
    the .blend; `smooth`: the keys smoothed over that many frames); one ActionError line on
    failure."""
    try:
        return bind_avatar(folder, sequence or None, scene=scene, pack=pack, smooth=smooth)
    except (avatar_folder.AvatarFolderError, BindError, ValueError, OSError) as error:
        raise ActionError(str(error)) from None


def export(bound, gltf=None, blend=None, pack=False, fbx=None):
    """Write the .glb, the .fbx and the .blend (`pack`: with every image inside it) that are
    asked for; one ActionError line on failure."""
    written = []
    try:
        if gltf:
            written.append(export_gltf(bound, gltf))
        if fbx:
            written.append(export_fbx(bound, fbx))
        if blend:
            written.append(save_blend(blend, pack=pack))
    except ExportError as error:
        raise ActionError(str(error)) from None
    return written


def write_bone_map(kind, side, path):
    """The bone map of a rig kind written to `path` as JSON, to be edited and used as a bone map
    file; one ActionError line on failure."""
    if not path:
        raise ActionError("choose a bone map file to write")
    try:
        return save_bone_map(bone_map(kind, side), path)
    except RetargetError as error:
        raise ActionError(str(error)) from None


@dataclasses.dataclass
class Bound:
    """What the export and retarget buttons need of a bound avatar found in the scene (its folder
    is read only when asked: an export needs the objects alone)."""
    armature: bpy.types.Object
    mesh: bpy.types.Object
    folder: Path                   # its avatar folder

    @functools.cached_property
    def files(self):
        return avatar_folder.read_avatar_folder(self.folder)

    @property
    def frames(self):
        return FIRST_FRAME + np.asarray(self.files.poses.frames, dtype=np.int64)


def last_bound(scene):
    """The newest HARP collection in the scene (objects found by their roles, not their names)."""
    for collection in reversed(list(scene.collection.children)):
        armatures = [o for o in collection.objects if o.type == "ARMATURE"]
        meshes = [o for o in collection.objects if o.type == "MESH" and o.parent in armatures]
        if armatures and meshes and collection.get("harp_avatar"):
            return Bound(armatures[0], meshes[0], Path(collection["harp_avatar"]))
    raise ActionError("no bound HARP avatar in this scene: bind one first")


def retarget(scene, target, kind="mixamo", map_file="", place="follow", mesh=False):
    """Put the newest bound avatar's motion onto the armature `target` (retarget.py), its bones
    named by the rig kind's map or by the bone map file (`kind` "file"), and with `mesh` a copy of
    the personalised mesh skinned to it; one ActionError line on failure."""
    bound = last_bound(scene)
    try:
        side = bound.files.rig.side
        mapping = bone_map(map_file if kind == "file" else kind, side)
        deform = deform_map(kind, side, mapping) if mesh else None
        return retarget_motion(bound, target, mapping, place, scene, deform=deform)
    except (RetargetError, avatar_folder.AvatarFolderError, OSError) as error:
        raise ActionError(str(error)) from None


def engine_python(context):
    """The engine Python set in the add-on's preferences (or found)."""
    addon = context.preferences.addons.get(__package__)
    chosen = getattr(addon.preferences, "engine_python", "") if addon else ""
    return chosen or engine.default_engine_python()
