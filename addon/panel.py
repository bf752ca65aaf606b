"""The "Nephele" tab in the 3D viewport's sidebar; features add sub-panels."""

import bpy


class NEPHELE_PT_main(bpy.types.Panel):
    bl_label = "Nephele"
    bl_idname = "NEPHELE_PT_main"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Nephele"

    def draw(self, context):
        self.layout.label(text="Scientific fields into films")


CLASSES = (NEPHELE_PT_main,)
