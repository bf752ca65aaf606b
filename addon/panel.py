"""The "Nephele" tab in the 3D viewport's sidebar; features add sub-panels."""

import bpy


class SidebarTab:
    """Where every Nephele panel lives: the 3D viewport's sidebar, tab "Nephele"."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Nephele"


class SubPanel(SidebarTab):
    """Mixin for a feature's panel: ``class NEPHELE_PT_x(SubPanel, bpy.types.Panel)``."""

    bl_parent_id = "NEPHELE_PT_main"


class NEPHELE_PT_main(SidebarTab, bpy.types.Panel):
    bl_label = "Nephele"
    bl_idname = "NEPHELE_PT_main"

    def draw(self, context):
        from ..core import native

        self.layout.label(text="Scientific fields into films")
        native.identity()  # loads the kernels once, or notes why they did not
        if native.notice():
            self.layout.label(text=native.notice(), icon="ERROR")


CLASSES = (NEPHELE_PT_main,)
