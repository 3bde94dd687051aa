"""HARP hand avatars in Blender: import a clip, fit the avatar in a worker process, bind it to a
rig with its motion, material and camera, export it (see README, "In Blender").

The logic lives in plain modules that tests call without the interface: scene.py (bind),
export.py, jobs.py (the worker: start, progress, cancel, resume), engine.py (which Python runs
the fitting engine). The interface (properties, operators, panel, preferences) is a thin shell
around them, imported only when Blender registers the extension.
"""
_MODULES = ("properties", "preferences", "operators", "panel")


def _interface():
    from importlib import import_module

    return [import_module(f".{name}", __name__) for name in _MODULES]


def register():
    for module in _interface():
        module.register()


def unregister():
    for module in reversed(_interface()):
        module.unregister()
