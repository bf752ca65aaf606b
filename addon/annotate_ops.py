"""Annotations as a layer: the figure's caption, the model date and time, and a legend, on every render.

"Add annotations" adds an empty object, ``Nephele annotations``, whose
parameters (``obj["nephele"]``, kind ``"annotations"``) say what to show.
On every frame change its updater lays out the frame's annotation layer with
:func:`nephele.core.annotate.overlay` (text drawn by Blender's own font
engine, :func:`nephele.fileio.text_mask`) into the image ``Nephele
annotations``, and the scene's compositor lays that image over the render
(an Alpha Over node).  So F12, an animation render, the farm and every engine
show it, and a saved .blend renders it headless with nothing but
:func:`nephele.addon.frame.install`.  The panel's "Show" switch mutes the
node: the layer is kept, the render is clean.

The date and time are those the climate layers show at the frame (the first
climate layer's source, first frame and hours per frame, in the dataset's
calendar: :func:`nephele.core.annotate.time_label`); the legend lists the
colour and opacity transfer functions of the scene's layers as they are
stored on them.  The layer's colours pass the view transform unchanged: the
image is tagged with the colour space the view transform displays in
(``sRGB`` for Standard, ``AgX Base sRGB`` for AgX), so Blender's inverse and
forward transforms cancel (exact for Standard, within a few levels for AgX's
muted colours).
"""

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..core.annotate import ColorBar, OpacityBar, Swatch, calendar_note, overlay, time_label
from ..core.annotate import heading as figure_heading
from ..core.pipeline.sources import frame_hours
from ..core.volume.transfer import ALTITUDE_COLORS, TEMPERATURE_COLORS, ColorMap, TransferFunction
from . import data_ops, frame, materials
from .panel import SubPanel

KIND = "annotations"
OBJECT = "Nephele annotations"
IMAGE = "Nephele annotations"
NODE = "Nephele annotations"
OVER = "Nephele annotations over"
TREE = "Nephele compositing"

VIEW_SPACES = {"Standard": "sRGB", "AgX": "AgX Base sRGB", "Filmic": "Filmic sRGB",
               "Khronos PBR Neutral": "Khronos PBR Neutral sRGB"}
"""View transform → the colour space it displays in (the layer's image is tagged with it)."""

_SHOWN = {}
"""Image session id → what its pixels show.  Per process: a generated image's pixels are not saved in the
.blend (it comes back blank), so a reopened file always lays its layer out again."""

DEFAULTS = {"enabled": True, "heading": "", "time": True, "legend": True}
CLIMATE_KINDS = ("contour", "advected_contour", "volume", "splats", "flowvol")


def annotations_object(scene=None):
    """The scene's annotation layer object, or None."""
    scene = scene or bpy.context.scene
    for obj in scene.objects:
        if frame.params(obj).get("kind") == KIND:
            return obj
    return None


def add_annotations(scene=None, *, figure=None, heading=None, time=True, legend=True, enabled=True):
    """Add (or update) the annotation layer of ``scene``; returns its object.

    Parameters
    ----------
    figure : str, optional
        A key of :data:`nephele.core.annotate.FIGURES` (``"fig1"``...): the heading is its number and caption.
    heading : str, optional
        The heading's text (instead of ``figure``'s); ``""`` for none.
    time, legend : bool
        Show the model date and time (scenes with climate layers), and the legend of the layers' transfer functions.
    enabled : bool
        Shown in renders (the panel's "Show").
    """
    scene = scene or bpy.context.scene
    obj = annotations_object(scene)
    if obj is None:
        obj = bpy.data.objects.new(OBJECT, None)
        obj.empty_display_type = "PLAIN_AXES"
        obj.hide_viewport = True
        scene.collection.objects.link(obj)
    text = heading if heading is not None else (figure_heading(figure) if figure else "")
    frame.set_params(obj, {"kind": KIND, "enabled": bool(enabled), "heading": str(text), "time": bool(time),
                           "legend": bool(legend)})
    ensure_compositor(scene)
    frame.install()
    update(obj, frame.params(obj), scene, scene.frame_current)
    return obj


def _compositor(scene):
    """``(tree, output node)`` of the scene's compositing (made when missing): Blender 5's node group with a
    Group Output, or Blender 4's scene node tree with a Composite node."""
    if hasattr(scene, "compositing_node_group"):
        tree = scene.compositing_node_group
        if tree is None:
            tree = bpy.data.node_groups.new(TREE, "CompositorNodeTree")
            scene.compositing_node_group = tree
        if not any(s.in_out == "OUTPUT" for s in tree.interface.items_tree if s.item_type == "SOCKET"):
            tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        kind = "NodeGroupOutput"
    else:  # Blender 4.2-4.5
        scene.use_nodes = True
        tree, kind = scene.node_tree, "CompositorNodeComposite"
    out = next((n for n in tree.nodes if n.bl_idname == kind), None) or tree.nodes.new(kind)
    return tree, out


def _input(node, name, index):
    # Blender 5 names Alpha Over's inputs; Blender 4 has Fac, Image (background), Image (foreground).
    return node.inputs.get(name) or node.inputs[index]


def ensure_compositor(scene):
    """The Alpha Over node laying the annotation image over the render (made, with the tree, when missing)."""
    tree, out = _compositor(scene)
    nodes, links = tree.nodes, tree.links
    over = nodes.get(OVER)
    if over is not None:
        return over
    if out.inputs[0].is_linked:  # the user's own compositing: the annotations go on top of it
        source = out.inputs[0].links[0].from_socket
    else:
        layers = (next((n for n in nodes if n.bl_idname == "CompositorNodeRLayers"), None)
                  or nodes.new("CompositorNodeRLayers"))
        source = layers.outputs["Image"]
    image = nodes.new("CompositorNodeImage")
    image.name = image.label = NODE
    over = nodes.new("CompositorNodeAlphaOver")
    over.name = over.label = OVER
    links.new(source, _input(over, "Background", 1))
    links.new(image.outputs["Image"], _input(over, "Foreground", 2))
    links.new(over.outputs[0], out.inputs[0])
    scene.render.use_compositing = True
    return over


def _climate_layer(scene):
    for obj in scene.objects:
        p = frame.params(obj)
        if p.get("kind") in CLIMATE_KINDS and p.get("source") and not str(p["source"]).lower().endswith(".vtu"):
            return p
    return None


def frame_time(scene, frame_number):
    """``(label, note)``: the model date and time the climate layers show at ``frame_number``; None without them."""
    p = _climate_layer(scene)
    if p is None:
        return None
    ds = data_ops.dataset(p["source"])
    if p.get("kind") == "flowvol":  # the smoke's window ends at the frame's time
        from .flowvol_ops import release_window

        t0, duration = release_window(p, frame_number)
        hours = t0 + duration
    else:
        cfg = data_ops.settings(scene)
        hours = frame_hours(frame_number, p.get("frame_start", cfg["frame_start"]),
                            p.get("hours_per_frame", cfg["hours_per_frame"]), last_hour=float(ds.hours[-1]))
    return time_label(ds, hours), calendar_note(ds)


def _unit(var):
    return "m" if var == "altitude" else "K" if var == "temperature" else ""


def legend_entries(scene):
    """Legend entries of the transfer functions the scene's layers use, as stored on them (one per distinct mapping)."""
    entries = []
    for obj in scene.objects:
        p = frame.params(obj)
        kind = p.get("kind")
        if kind in ("contour", "advected_contour"):
            stops = materials.RAMPS.get(p.get("ramp"))
            lo, hi = p.get("color_range") or (0.0, 1.0)
            if stops:
                var = p.get("color_var", "altitude")
                scaled = tuple((lo + s * (hi - lo), c) for s, c in stops)
                entries.append(ColorBar(f"{var} → colour", scaled, _unit(var)))
        elif kind in ("volume", "splats"):
            var, cvar = p.get("var", "cloud"), p.get("color_var") or ""
            entries.append(OpacityBar(f"{var} → opacity", TransferFunction.from_dict(p["tf"]).points))
            cmap = ColorMap.from_dict(p["cmap"]) if p.get("cmap") else {
                "altitude": ALTITUDE_COLORS, "temperature": TEMPERATURE_COLORS}.get(cvar)
            if cmap is not None and cvar:
                entries.append(ColorBar(f"{cvar} → colour", cmap.points, _unit(cvar)))
        elif kind == "flowvol":
            props = getattr(scene, "nephele_flowvol", None)
            entries.append(Swatch("smoke (constant colour)", tuple(props.color) if props else (0.9, 0.9, 1.0)))
        elif kind == "muscle":
            from .muscle_ops import COLOURS

            names = ("actin", "myosin motor domain", "lever arm", "tail (S2)", "thick-filament backbone")
            entries += [Swatch(n, c) for n, (_, c) in zip(names, COLOURS)]
    unique = []
    for e in entries:
        if e not in unique:
            unique.append(e)
    return unique


def _image(width, height):
    img = bpy.data.images.get(IMAGE)
    if img is not None and tuple(img.size) != (width, height):
        if img.source == "GENERATED":  # a generated image keeps its generated size: scale() does not hold
            img.generated_width, img.generated_height = width, height
        else:
            img.scale(width, height)
    if img is None:
        img = bpy.data.images.new(IMAGE, width, height, alpha=True, float_buffer=False)
    return img


def _dome_rig(scene):
    from .dome_ops import dome_rig

    return dome_rig(scene)


def render_size(scene):
    r = scene.render
    return r.resolution_x * r.resolution_percentage // 100, r.resolution_y * r.resolution_percentage // 100


@frame.register_updater(KIND)
def update(obj, params, scene, frame_number):
    """Lay out the annotation layer for ``frame_number`` into the image the compositor lays over the render."""
    from ..fileio import text_mask

    p = {**DEFAULTS, **params}
    over = ensure_compositor(scene)
    # EEVEE and Workbench make a dome frame from cube faces, each composited: the layer would land on every face.
    cube_faces = scene.render.engine != "CYCLES" and _dome_rig(scene) is not None
    over.mute = not p["enabled"] or cube_faces
    if over.mute:
        return
    width, height = render_size(scene)
    when = frame_time(scene, int(round(frame_number))) if p["time"] else None
    legend = legend_entries(scene) if p["legend"] else []
    space = VIEW_SPACES.get(scene.view_settings.view_transform, "sRGB")
    key = repr((width, height, space, p["heading"], when, legend))
    img = bpy.data.images.get(IMAGE)
    if img is not None and _SHOWN.get(img.session_uid) == key and tuple(img.size) == (width, height):
        return  # already laid out in this session (the render handler after a frame change)
    layer = overlay(width, height, text_mask, heading=p["heading"] or None, time_text=when and when[0],
                    note=when and when[1], legend=legend)
    img = _image(width, height)
    img.colorspace_settings.name = space
    img.pixels.foreach_set(np.ascontiguousarray(layer[::-1]).ravel())  # Blender's rows run bottom-up
    img.update()
    node = _compositor(scene)[0].nodes.get(NODE)
    if node is not None and node.image != img:
        node.image = img
    obj["nephele_annotation_time"] = when[0] if when else ""
    _SHOWN[img.session_uid] = key


@persistent
def _before_render(scene, *_args):
    # F12 without a frame change (a new resolution or view transform since): the layer is redone.
    if isinstance(scene, bpy.types.Scene):
        obj = annotations_object(scene)
        if obj is not None:
            update(obj, frame.params(obj), scene, scene.frame_current)


def _param(name):
    def get(self):
        obj = annotations_object(self.id_data)
        return {**DEFAULTS, **(frame.params(obj) if obj else {})}[name]

    def set(self, value):
        obj = annotations_object(self.id_data)
        if obj is None:
            return
        p = {**DEFAULTS, **frame.params(obj), name: value}
        frame.set_params(obj, p)
        update(obj, p, self.id_data, self.id_data.frame_current)

    return {"get": get, "set": set}


class NephelePropsAnnotations(bpy.types.PropertyGroup):
    enabled: bpy.props.BoolProperty(name="Show", description="Lay the annotations over every render",
                                    **_param("enabled"))
    heading: bpy.props.StringProperty(name="Heading", description="Text at the top left (figure and caption)",
                                      **_param("heading"))
    time: bpy.props.BoolProperty(name="Model date and time", description="At the top right, in the data's calendar",
                                 **_param("time"))
    legend: bpy.props.BoolProperty(name="Legend", description="The layers' colour and opacity transfer functions",
                                   **_param("legend"))


class NEPHELE_OT_add_annotations(bpy.types.Operator):
    """Lay a heading, the model date and time and a legend of the layers' transfer functions over every render"""

    bl_idname = "nephele.add_annotations"
    bl_label = "Add annotations"
    bl_options = {"REGISTER", "UNDO"}

    heading: bpy.props.StringProperty(name="Heading", default="")

    def execute(self, context):
        add_annotations(context.scene, heading=self.heading)
        self.report({"INFO"}, "Annotations: laid over renders through the compositor")
        return {"FINISHED"}


class NEPHELE_OT_remove_annotations(bpy.types.Operator):
    """Remove the annotation layer (its object, image and compositor nodes)"""

    bl_idname = "nephele.remove_annotations"
    bl_label = "Remove annotations"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        remove_annotations(context.scene)
        return {"FINISHED"}


def remove_annotations(scene):
    """Remove the layer's object and nodes; the compositor link they interrupted is restored."""
    obj = annotations_object(scene)
    if obj is not None:
        bpy.data.objects.remove(obj, do_unlink=True)
    tree = scene.compositing_node_group if hasattr(scene, "compositing_node_group") else scene.node_tree
    if tree is not None and OVER in tree.nodes:
        over = tree.nodes[OVER]
        background = _input(over, "Background", 1)
        below = background.links[0].from_socket if background.is_linked else None
        targets = [link.to_socket for link in over.outputs[0].links]
        for name in (OVER, NODE):
            if name in tree.nodes:
                tree.nodes.remove(tree.nodes[name])
        for sock in targets if below is not None else ():
            tree.links.new(below, sock)
    img = bpy.data.images.get(IMAGE)
    if img is not None and img.users == 0:
        bpy.data.images.remove(img)


class NEPHELE_PT_annotations(SubPanel, bpy.types.Panel):
    bl_label = "Annotations"
    bl_idname = "NEPHELE_PT_annotations"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        obj = annotations_object(context.scene)
        if obj is None:
            layout.operator(NEPHELE_OT_add_annotations.bl_idname, icon="FONT_DATA")
            return
        s = context.scene.nephele_annotations
        layout.prop(s, "enabled")
        col = layout.column()
        col.active = s.enabled
        col.prop(s, "heading")
        col.prop(s, "time")
        col.prop(s, "legend")
        shown = obj.get("nephele_annotation_time")
        if shown:
            col.label(text=f"frame {context.scene.frame_current}: {shown}")
        layout.operator(NEPHELE_OT_remove_annotations.bl_idname, icon="X")


CLASSES = (NephelePropsAnnotations, NEPHELE_OT_add_annotations, NEPHELE_OT_remove_annotations, NEPHELE_PT_annotations)
SCENE_PROPERTIES = {"nephele_annotations": NephelePropsAnnotations}


def install():
    if _before_render not in bpy.app.handlers.render_pre:
        bpy.app.handlers.render_pre.append(_before_render)


def uninstall():
    if _before_render in bpy.app.handlers.render_pre:
        bpy.app.handlers.render_pre.remove(_before_render)
