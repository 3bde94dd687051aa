"""The sidebar panel (3D viewport, "HARP" tab): footage, fit, bind, export, in that order."""
from __future__ import annotations

import bpy

from .actions import JOBS


class HARP_PT_panel(bpy.types.Panel):
    bl_idname = "HARP_PT_panel"
    bl_label = "HARP hand avatar"
    bl_space_type, bl_region_type, bl_category = "VIEW_3D", "UI", "HARP"

    def draw(self, context):
        settings = context.scene.harp
        running = JOBS.get(context.scene.name)
        busy = running is not None and running.job.active
        layout = self.layout

        box = layout.box()
        box.label(text="1. Footage", icon="FILE_MOVIE")
        for name in ("video", "masks", "side", "fov", "sequence"):
            box.prop(settings, name)
        box.operator("harp.import_footage", icon="IMPORT").enabled = not busy

        box = layout.box()
        box.label(text="2. Fit", icon="MOD_ARMATURE")
        for name in ("preset", "shadows", "environment", "specular", "light_size", "init", "avatar"):
            box.prop(settings, name)
        row = box.row(align=True)
        row.enabled = not busy
        row.operator("harp.fit", icon="PLAY").resume = False
        row.operator("harp.fit", text="Resume", icon="RECOVER_LAST").resume = True
        if settings.job_state:
            if busy:
                box.progress(factor=settings.job_fraction, type="BAR", text=settings.job_status)
                box.operator("harp.cancel", icon="CANCEL")
            else:
                box.label(text=settings.job_status, icon="ERROR" if settings.job_state == "failed" else "INFO")
            lines = (settings.job_errors or settings.job_log).splitlines()[-8:]
            if lines:
                log = box.box().column(align=True)
                for line in lines:
                    log.label(text=line)

        box = layout.box()
        box.label(text="3. Bind", icon="OUTLINER_OB_ARMATURE")
        box.prop(settings, "avatar")
        box.prop(settings, "pack_on_bind")
        box.prop(settings, "smooth_frames")
        box.operator("harp.bind", icon="LINKED")
        column = box.box().column()
        column.label(text="Onto your rig")
        column.prop(settings, "retarget_rig")
        column.prop(settings, "rig_kind")
        row = column.row(align=True)
        row.prop(settings, "bone_map_file")
        row.operator("harp.save_bone_map", text="", icon="FILE_TICK")
        column.prop(settings, "retarget_place")
        column.prop(settings, "mesh_onto_rig")
        column.operator("harp.retarget", icon="ARMATURE_DATA")

        box = layout.box()
        box.label(text="4. Export", icon="EXPORT")
        box.prop(settings, "gltf")
        box.prop(settings, "fbx")
        box.prop(settings, "blend")
        box.prop(settings, "pack_on_export")
        box.operator("harp.export", icon="EXPORT")


def register():
    bpy.utils.register_class(HARP_PT_panel)


def unregister():
    bpy.utils.unregister_class(HARP_PT_panel)
