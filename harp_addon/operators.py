"""The panel's buttons: thin operators around actions.py. Jobs are polled by a timer while one
runs (the interface never waits for them); any failure is one line in the status bar (an
unexpected one with its traceback in the log, the system console) and leaves the scene as it
was."""
from __future__ import annotations

import logging
import math

import bpy

from . import actions
from .scene import removing_on_failure

POLL_SECONDS = 0.25
log = logging.getLogger(__name__)


def _poll_all():
    """Timer: move every scene's job on and redraw the panels; stops when none is running."""
    busy = False
    for scene in bpy.data.scenes:
        running = actions.poll(scene)
        busy = busy or (running is not None and running.job.active)
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()
    return POLL_SECONDS if busy else None


def _watch(context):
    """Poll the jobs from a timer, and listen for Esc in the window (not in background mode,
    which has neither windows nor modal operators)."""
    if not bpy.app.timers.is_registered(_poll_all):
        bpy.app.timers.register(_poll_all, first_interval=POLL_SECONDS)
    if context.window is not None:
        bpy.ops.harp.escape_listener("INVOKE_DEFAULT")


class HARP_OT_escape_listener(bpy.types.Operator):
    """Esc stops the running job as Cancel does (listens while a job runs)"""
    bl_idname, bl_label = "harp.escape_listener", "Esc cancels the HARP job"
    bl_options = {"INTERNAL"}

    def invoke(self, context, event):
        self.scene_name = context.scene.name
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        outcome = actions.key_pressed(self.scene_name, event.type, event.value)
        if outcome == "cancelled":
            self.report({"INFO"}, "cancelling (Esc)")
            return {"FINISHED"}
        return {"FINISHED"} if outcome == "idle" else {"PASS_THROUGH"}


class _Action(bpy.types.Operator):
    """Runs `self.act(context, settings)`; any exception becomes one reported line and removes
    what the button had made."""

    def execute(self, context):
        try:
            with removing_on_failure():
                message = self.act(context, context.scene.harp)
        except actions.ActionError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        except Exception as error:  # a defect: never a traceback in the interface
            log.exception("HARP: %s failed", self.bl_label)
            self.report({"ERROR"}, f"{self.bl_label} failed: {unexpected_line(error)} "
                                   "(details in the system console)")
            return {"CANCELLED"}
        if message:
            self.report({"INFO"}, message)
        return {"FINISHED"}


def unexpected_line(error):
    """`Type: first line of the message`, for an exception that was not expected."""
    lines = str(error).strip().splitlines()
    return f"{type(error).__name__}: {lines[0]}" if lines else type(error).__name__


class HARP_OT_import(_Action):
    """Import the footage (and its masks, or masks made from it) into a sequence folder"""
    bl_idname, bl_label = "harp.import_footage", "Import footage"

    def act(self, context, settings):
        sequence = settings.sequence or bpy.path.abspath("//harp_sequence")
        actions.start_import(context.scene.name, bpy.path.abspath(settings.video), bpy.path.abspath(sequence),
                             masks=bpy.path.abspath(settings.masks) if settings.masks else None, side=settings.side,
                             fov=math.degrees(settings.fov), python=actions.engine_python(context))
        settings.sequence = sequence
        _watch(context)
        return f"importing into {sequence}"


class HARP_OT_fit(_Action):
    """Initialise and fit the avatar in a worker process"""
    bl_idname, bl_label = "harp.fit", "Fit"

    resume: bpy.props.BoolProperty(default=False, options={"SKIP_SAVE"})

    def act(self, context, settings):
        avatar = settings.avatar or bpy.path.abspath("//harp_avatar")
        actions.start_fit(context.scene.name, bpy.path.abspath(settings.sequence), bpy.path.abspath(avatar),
                          preset=settings.preset, shadows=settings.shadows,
                          environment=_unless_preset(settings.environment),
                          specular=_unless_preset(settings.specular),
                          light_size=_unless_preset(settings.light_size), init=settings.init,
                          python=actions.engine_python(context), resume=self.resume)
        settings.avatar = avatar
        _watch(context)
        return f"{'resuming' if self.resume else 'fitting'} into {avatar}"


def _unless_preset(choice):
    """A panel choice of the room light, the skin's sheen or the light's size as `harp fit` takes
    it: None (the option left out) where the panel leaves it to the preset."""
    return None if choice == "preset" else choice


class HARP_OT_cancel(_Action):
    """Stop the running job (a fit saves its checkpoint first: Resume goes on from it)"""
    bl_idname, bl_label = "harp.cancel", "Cancel"

    def act(self, context, settings):
        actions.cancel(context.scene.name)
        return "cancelling"


class HARP_OT_bind(_Action):
    """Bind the avatar folder into the scene: rig, mesh, material, motion and camera"""
    bl_idname, bl_label = "harp.bind", "Bind avatar"

    def act(self, context, settings):
        bound = actions.bind(bpy.path.abspath(settings.avatar),
                             bpy.path.abspath(settings.sequence) if settings.sequence else None, context.scene,
                             pack=settings.pack_on_bind, smooth=settings.smooth_frames)
        return f"bound {len(bound.frames)} frames into {bound.collection.name}"


class HARP_OT_retarget(_Action):
    """Put the bound hand's motion onto your armature: keys on its hand bones, nothing else added"""
    bl_idname, bl_label = "harp.retarget", "Motion onto rig"

    def act(self, context, settings):
        result = actions.retarget(context.scene, settings.retarget_rig, settings.rig_kind,
                                  bpy.path.abspath(settings.bone_map_file), settings.retarget_place,
                                  mesh=settings.mesh_onto_rig)
        moved = f"; the mesh is {result.mesh.name}" if result.mesh is not None else ""
        return f"keyed {len(result.bones)} bones of {result.armature.name}{moved}"


class HARP_OT_save_bone_map(_Action):
    """Write the Mixamo or Rigify bone map to the bone map file, to edit it for your rig"""
    bl_idname, bl_label = "harp.save_bone_map", "Save bone map"

    def act(self, context, settings):
        kind = settings.rig_kind if settings.rig_kind != "file" else "mixamo"
        try:        # the bound hand's side; before a bind, the side chosen for the footage
            side = actions.last_bound(context.scene).files.rig.side
        except (actions.ActionError, ValueError, OSError):
            side = "left" if settings.side == "left" else "right"
        path = actions.write_bone_map(kind, side, bpy.path.abspath(settings.bone_map_file))
        settings.rig_kind = "file"
        return f"wrote {path}: edit it, then Motion onto rig"


class HARP_OT_export(_Action):
    """Export the newest bound hand: glTF binary and FBX (skin, textures and motion) and a .blend"""
    bl_idname, bl_label = "harp.export", "Export"

    def act(self, context, settings):
        written = actions.export(actions.last_bound(context.scene), bpy.path.abspath(settings.gltf) or None,
                                 bpy.path.abspath(settings.blend) or None, pack=settings.pack_on_export,
                                 fbx=bpy.path.abspath(settings.fbx) or None)
        return "wrote " + ", ".join(str(path) for path in written)


CLASSES = (HARP_OT_escape_listener, HARP_OT_import, HARP_OT_fit, HARP_OT_cancel, HARP_OT_bind, HARP_OT_retarget,
           HARP_OT_save_bone_map, HARP_OT_export)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    if bpy.app.timers.is_registered(_poll_all):
        bpy.app.timers.unregister(_poll_all)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
