"""radn temporal denoise: flicker-free denoising of Cycles animations inside Blender.

After an animation render to OpenEXR MultiLayer (or on demand over any EXR sequence, operator
`radn.denoise_sequence`), radn denoises the frames over a five-frame window, guided by Blender's
own Intel Open Image Denoise, and writes them beside the render (never over it).
"""

import bpy

from . import handlers, operators, panel, props

_classes = (props.RadnSettings, *operators.classes, *panel.classes)


def register() -> None:
    """Registers the settings, operators, panel and render handlers."""
    for cls in _classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.radn = bpy.props.PointerProperty(type=props.RadnSettings)
    handlers.register()


def unregister() -> None:
    """Removes what register added."""
    handlers.unregister()
    del bpy.types.Scene.radn
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
