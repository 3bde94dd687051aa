"""The add-on's preferences: which Python runs the fitting engine, and a check of it."""
from __future__ import annotations

import threading

import bpy
from bpy.props import StringProperty

from . import engine

_CHECKS = {}     # preferences -> the thread checking the engine and its answer


class HarpPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    engine_python: StringProperty(
        name="Engine Python", subtype="FILE_PATH",
        description="The Python of the harp-avatar install (its .venv/bin/python), which has torch")
    engine_status: StringProperty(name="Status", default="not checked yet")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "engine_python")
        row = layout.row()
        row.operator("harp.check_engine", icon="CHECKMARK")
        row.label(text=self.engine_status)


class HARP_OT_check_engine(bpy.types.Operator):
    """Start the engine's Python and report its torch version and device"""
    bl_idname = "harp.check_engine"
    bl_label = "Check engine"

    def execute(self, context):
        preferences = context.preferences.addons[__package__].preferences
        python = preferences.engine_python or engine.default_engine_python()
        preferences.engine_status = "checking ..."
        answer = {}
        thread = threading.Thread(target=lambda: answer.update(status=engine.check_engine(python)), daemon=True)
        thread.start()

        def collect():
            if thread.is_alive():
                return 0.5
            preferences.engine_status = answer["status"].message if "status" in answer else \
                "the engine check failed (details in the system console)"
            for window in bpy.context.window_manager.windows:
                for area in window.screen.areas:
                    area.tag_redraw()
            return None

        bpy.app.timers.register(collect, first_interval=0.5)
        return {"FINISHED"}


CLASSES = (HarpPreferences, HARP_OT_check_engine)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    addon = bpy.context.preferences.addons.get(__package__)
    if addon is not None and not addon.preferences.engine_python:
        addon.preferences.engine_python = engine.default_engine_python() or ""


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
