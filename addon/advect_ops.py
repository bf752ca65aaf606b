"""Cloud textures advected by the wind (Fig. 4): start coordinates, the fractal node group, the material.

"Add advected cloud texture" turns a contour surface (kind ``"contour"``)
into an advected contour (kind ``"advected_contour"``): every frame its mesh
comes from the task ``"advect_contour"`` of :mod:`nephele.core.flow.advect` (the
same contour, plus per-vertex start coordinates of two texture copies and
their weights, written with ``foreach_set``), from the cache or computed.
The material evaluates the poor-man's fractal of :mod:`nephele.core.texture.fractal`
at the start coordinates in a shader node group that computes the same
formula, and uses it as transparency on front faces only.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (Fig. 4).
.. [2] G. Y. Gardner, "Visual simulation of clouds", SIGGRAPH 1985.
"""

import json
import math

import bpy

from ..core.flow import advect, advect_task
from ..core.pipeline import sources
from ..core.texture.fractal import Fractal, terms
from . import contour_ops, frame, materials
from .nodes import Nodes
from .panel import SubPanel

GROUP_NAME = "Nephele Poor-Man's Fractal"
KIND = "advected_contour"
FRACTAL = Fractal()
"""The default texture (:class:`~nephele.core.texture.fractal.Fractal`'s defaults)."""


def fractal_node_group(fractal=FRACTAL):
    """The shader node group computing :func:`nephele.core.texture.fractal.texture_xyz`.

    Inputs ``Vector`` (start position, any length) and ``Altitude`` (m); output
    ``Texture`` in ``[0, 1]``.  Built once per parameter set and reused.
    """
    key = json.dumps(fractal.as_dict(), sort_keys=True)
    for ng in bpy.data.node_groups:
        if ng.get("nephele_fractal") == key:
            return ng
    ng = bpy.data.node_groups.new(GROUP_NAME, "ShaderNodeTree")
    ng["nephele_fractal"] = key
    ng.interface.new_socket(name="Vector", in_out="INPUT", socket_type="NodeSocketVector")
    ng.interface.new_socket(name="Altitude", in_out="INPUT", socket_type="NodeSocketFloat")
    ng.interface.new_socket(name="Texture", in_out="OUTPUT", socket_type="NodeSocketFloat")
    gin = ng.nodes.new("NodeGroupInput")
    gin.location = (-1400, 0)
    gout = ng.nodes.new("NodeGroupOutput")
    gout.location = (1400, 0)
    sep = ng.nodes.new("ShaderNodeSeparateXYZ")
    sep.location = (-1200, 0)
    ng.links.new(gin.outputs["Vector"], sep.inputs[0])
    x, y, z = sep.outputs
    alt = gin.outputs["Altitude"]
    n = Nodes(ng, -1000, 400)
    lon = n.math("ARCTAN2", y, x, loc=(-1000, 200))
    hyp = n.math("SQRT", n.math("MULTIPLY_ADD", y, y, n.math("MULTIPLY", x, x)), loc=(-1000, 0))
    lat = n.math("ARCTAN2", z, hyp, loc=(-800, 0))
    sx = sy = sz = 0.0
    half_pi = 0.5 * math.pi
    for i, (omega, big, c, a, b, d) in enumerate(terms(fractal)):
        px = n.math("SINE", n.math("MULTIPLY", lat, 0.5 * omega))  # perturbs X and Z
        py = n.math("SINE", n.math("MULTIPLY", lon, 0.5 * omega))  # perturbs Y
        for axis, coord, freq, phase, pert in (
            ("x", lon, omega, a, px),
            ("y", lat, omega, b, py),
            ("z", alt, big, d, px),
        ):
            arg = n.math("MULTIPLY_ADD", pert, half_pi, n.math("MULTIPLY_ADD", coord, freq, phase))
            wave = n.math("SINE", arg, loc=(200 * i - 600, {"x": 400, "y": 0, "z": -400}[axis]))
            if axis == "x":
                sx = n.math("MULTIPLY_ADD", wave, c, sx)
            elif axis == "y":
                sy = n.math("MULTIPLY_ADD", wave, c, sy)
            else:
                sz = n.math("MULTIPLY_ADD", wave, c, sz)
    prod = n.math("MULTIPLY", n.math("ADD", sx, 1.0), n.math("ADD", sy, 1.0))
    tex = n.math("MULTIPLY", n.math("MULTIPLY", prod, n.math("ADD", sz, 1.0)), 0.125, loc=(1200, 0))
    ng.links.new(tex, gout.inputs["Texture"])
    return ng


def _attribute(tree, name, loc):
    node = tree.nodes.new("ShaderNodeAttribute")
    node.attribute_name = name
    node.location = loc
    return node


def texture_nodes(tree, fractal=FRACTAL, location=(-600, 0)):
    """Nodes giving ``Σ w_k T(start_k)`` over the copies ``a``, ``b`` from the mesh attributes; returns the socket."""
    group = fractal_node_group(fractal)
    x0, y0 = location
    n = Nodes(tree)
    total = None
    for i, name in enumerate(advect.COPIES):
        y = y0 - 300 * i
        vec = _attribute(tree, advect.START.format(name), (x0 - 400, y))
        alt = _attribute(tree, advect.START_ALT.format(name), (x0 - 400, y - 150))
        w = _attribute(tree, advect.WEIGHT.format(name), (x0 - 200, y - 100))
        g = tree.nodes.new("ShaderNodeGroup")
        g.node_tree = group
        g.location = (x0 - 200, y)
        tree.links.new(vec.outputs["Vector"], g.inputs["Vector"])
        tree.links.new(alt.outputs["Fac"], g.inputs["Altitude"])
        part = n.math("MULTIPLY", g.outputs["Texture"], w.outputs["Fac"], loc=(x0, y))
        total = part if total is None else n.math("ADD", total, part, loc=(x0 + 150, y0))
    return total


def cloud_material(name="Nephele Advected Clouds", fractal=FRACTAL, lo=0.08, hi=0.28, color=(0.9, 0.9, 0.92)):
    """Clouds whose opacity is the advected texture mapped from ``[lo, hi]`` to ``[0, 1]``; back faces transparent.

    As in the paper only front-facing contour polygons are drawn: EEVEE and
    Workbench cull back faces, Cycles mixes them to transparent with the
    Geometry node's ``Backfacing``.
    """
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    materials.enable_nodes(mat)
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (900, 0)
    tex = texture_nodes(tree, fractal, location=(-300, 0))
    n = Nodes(tree)
    rng = tree.nodes.new("ShaderNodeMapRange")
    rng.name = rng.label = "Nephele opacity"
    rng.clamp = True
    rng.inputs["From Min"].default_value = lo
    rng.inputs["From Max"].default_value = hi
    rng.location = (0, 0)
    tree.links.new(tex, rng.inputs["Value"])
    geo = tree.nodes.new("ShaderNodeNewGeometry")
    geo.location = (0, 300)
    front = n.math("SUBTRACT", 1.0, geo.outputs["Backfacing"], loc=(200, 300))
    alpha = n.math("MULTIPLY", rng.outputs["Result"], front, loc=(400, 200))
    clear = tree.nodes.new("ShaderNodeBsdfTransparent")
    clear.location = (400, -100)
    white = tree.nodes.new("ShaderNodeBsdfDiffuse")
    white.inputs["Color"].default_value = tuple(color) + (1.0,)
    white.location = (400, -250)
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.location = (650, 0)
    tree.links.new(alpha, mix.inputs[0])
    tree.links.new(clear.outputs[0], mix.inputs[1])
    tree.links.new(white.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    mat.use_backface_culling = True
    if hasattr(mat, "surface_render_method"):
        mat.surface_render_method = "BLENDED"
    mat["nephele_advected"] = json.dumps({"fractal": fractal.as_dict(), "lo": lo, "hi": hi})
    return mat


def _stream(tp):
    """The streamed strategy the task will use for ``tp`` (None for the full trace, which keeps no state)."""
    if tp["strategy"] == "full":
        return None
    st = advect_task._strategy(tp, sources.open_source(tp["source"]))
    return getattr(st, "stream", None)


def _compute(args, job=None):
    """Worker side of an advected contour; a job's cancel stops the texture catch-up between frames.

    The streamed maps advance one frame at a time; a cancel is checked before
    each frame, so what was streamed so far is kept and the next request
    (e.g. the frame the user moved on to) continues from there.
    """
    stream = _stream(args["tp"]) if job is not None else None
    if stream is None:
        return contour_ops.compute(args, job)
    advance = type(stream).advance

    def checked(copies, n, index):
        job.check()
        return advance(stream, copies, n, index)

    stream.advance = checked
    try:
        return contour_ops.compute(args, job)
    finally:
        del stream.advance


def _progress(args):
    """``"texture frame 17 of 240"`` while the streamed maps catch up."""
    tp = args["tp"]
    for st in list(advect_task._STRATEGIES.values()):
        stream = getattr(st, "stream", None)
        if stream is not None and st.frame_hours.size and abs(st.frame_hours[1] - st.frame_hours[0]
                                                              - tp["hours_per_frame"]) < 1e-9:
            done = [f for f in stream.frames if f is not None]
            if done:
                return f"texture frame {min(done)} of {tp['frame']}"
    return ""


update_advected = frame.register_job(KIND, frame.plan_task, _compute, contour_ops.apply, _progress)
"""Synchronous updater: the contour and texture start coordinates of a frame."""


def add_advected_texture(obj, *, strategy="restart", period=24, integrator="rk4", vertical="auto", fractal=FRACTAL,
                         lo=0.08, hi=0.28, scene=None):
    """Give the contour object ``obj`` the advected cloud texture; returns ``obj``.

    Parameters
    ----------
    obj : bpy.types.Object
        A contour surface (``obj["nephele"]`` of kind ``"contour"``) or an
        already advected one (its settings are replaced).
    strategy : {"restart", "compose", "full"}
        See :mod:`nephele.core.flow.advect` (restart: two copies, cross-faded every
        ``period`` frames; compose: one copy composed frame by frame; full:
        the paper's trace back to the first frame, cost growing with the frame).
    integrator : {"rk4", "rk2", "euler"}
    vertical : {"auto", "w", "levels"}
        Vertical motion from ``w``, or points keep their level (exact for the
        demo climate), or whichever the dataset's ``levels_follow_air`` says
        (see :class:`nephele.core.flow.advect.WindField`).
    fractal : Fractal
    lo, hi : float
        Texture values mapped to fully transparent and fully opaque.
    """
    scene = scene or bpy.context.scene
    params = frame.params(obj)
    if params.get("kind") not in ("contour", KIND):
        raise ValueError(f"{obj.name} is not a Nephele contour surface (kind {params.get('kind')!r})")
    if strategy not in advect.STRATEGIES:
        raise ValueError(f"strategy must be one of {sorted(advect.STRATEGIES)}, got {strategy!r}")
    if vertical not in ("auto", "w", "levels"):
        raise ValueError(f"vertical must be 'auto', 'w' or 'levels', got {vertical!r}")
    params.update({"kind": KIND, "strategy": strategy, "period": int(period), "integrator": integrator,
                   "vertical": vertical})
    frame.set_params(obj, params)
    obj.pop("nephele_shown", None)
    materials.assign(obj, cloud_material(f"{obj.name} advected texture", fractal, lo, hi))
    frame.submit(obj, scene)  # at once headless; in the interface the catch-up runs in the background
    return obj


def _is_contour(obj):
    return obj is not None and frame.params(obj).get("kind") in ("contour", KIND)


class NEPHELE_OT_add_advected_texture(frame.BackgroundAdd, bpy.types.Operator):
    """Texture the selected contour surface with a cloud texture carried by the wind (front faces only)"""

    bl_idname = "nephele.add_advected_texture"
    bl_label = "Add advected cloud texture"
    bl_options = {"REGISTER", "UNDO"}

    strategy: bpy.props.EnumProperty(name="Strategy", default="restart", items=[
        ("restart", "Restart, 2 copies", "Two texture copies restarted every period, cross-faded (bounded stretch)"),
        ("compose", "Compose", "One copy composed frame by frame from the first frame (bicubic)"),
        ("full", "Full trace", "The paper's: trace back to the first frame every frame (slow late in a film)"),
    ])
    period: bpy.props.IntProperty(name="Restart period (frames)", default=24, min=2, step=2)
    integrator: bpy.props.EnumProperty(name="Integrator", default="rk4", items=[
        ("rk4", "RK4", ""), ("rk2", "RK2", ""), ("euler", "Euler", "")])
    vertical: bpy.props.EnumProperty(name="Vertical motion", default="auto", items=[
        ("auto", "Auto", "Keep levels where the dataset's levels follow the air (the demo), else from w"),
        ("w", "From w", "Level rate from the vertical wind and the slope of the levels"),
        ("levels", "Keep levels", "Points stay on their terrain-following level")])
    lo: bpy.props.FloatProperty(name="Clear below", default=0.08, min=0.0, max=1.0)
    hi: bpy.props.FloatProperty(name="Opaque above", default=0.28, min=0.0, max=1.0)

    @classmethod
    def poll(cls, context):
        return _is_contour(context.active_object)

    def execute(self, context):
        from ..core.errors import DataError

        if self.strategy == "restart" and self.period % 2:
            self.report({"ERROR"}, "the restart period must be even")
            return {"CANCELLED"}
        try:
            obj = add_advected_texture(context.active_object, strategy=self.strategy, period=self.period,
                                       integrator=self.integrator, vertical=self.vertical, lo=self.lo,
                                       hi=max(self.hi, self.lo + 1e-3),
                                       scene=context.scene)
        except (DataError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return self.wait_for(context, obj)

    def done(self, context, obj):
        err = frame.last_error(obj)
        if err:
            self.report({"ERROR"}, err)
            return {"CANCELLED"}
        self.report({"INFO"}, f"{obj.name}: {len(obj.data.vertices)} textured vertices")
        return {"FINISHED"}


class NEPHELE_PT_advect(SubPanel, bpy.types.Panel):
    bl_label = "Advected texture"
    bl_idname = "NEPHELE_PT_advect"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        obj = context.active_object
        layout.operator(NEPHELE_OT_add_advected_texture.bl_idname)
        layout.operator("nephele.paper_figure", text="Make the paper's figure", icon="IMAGE_DATA").figure = "FIG4"
        if obj is not None and frame.params(obj).get("kind") == KIND:
            p = frame.params(obj)
            col = layout.column(align=True)
            col.label(text=f"Strategy: {p.get('strategy')}, {p.get('integrator', 'rk4')}")
            if p.get("strategy") == "restart":
                col.label(text=f"Restart every {p.get('period')} frames")
            col.label(text=f"Model time: {obj.get('nephele_hours', 0.0):g} h")
        elif not _is_contour(obj):
            layout.label(text="Select a contour surface")


CLASSES = (NEPHELE_OT_add_advected_texture, NEPHELE_PT_advect)
