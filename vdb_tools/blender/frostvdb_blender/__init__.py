"""frostvdb for Blender: frost, crystals, frost feathers or steam on the selected object.

Properties editor > Object > frostvdb. The operator exports the evaluated mesh (world space) to
PLY, writes a scene TOML beside the .blend (//frostvdb/), runs `frostvdb run --progress json` in
the background with a progress bar (Esc cancels: the process ends and nothing partial is left),
and loads the frames as a Volume object parented to the source, with a material.
Works with Blender 3.4 (Debian 12) and 4.x. Guide: docs/blender.md in the frostvdb repository.
"""

bl_info = {
    "name": "frostvdb",
    "author": "frostvdb",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Object > frostvdb",
    "description": "Grow frost, ice crystals, frost feathers or steam on the selected object with frostvdb "
                   "and load the OpenVDB sequence",
    "doc_url": "https://github.com/frostvdb/frostvdb/blob/main/docs/blender.md",
    "category": "Object",
}

import os

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty,
                       PointerProperty, StringProperty)

from . import blender_io, engine

PRESET_ITEMS = [
    ("FROST", "Frost", "frost on this object: phase field and DLA walkers on a narrow band around the mesh"),
    ("CRYSTALS", "Crystals", "ice crystals on this object: the phase field from nucleation sites"),
    ("FEATHERS", "Frost feathers", "3D DLA ([dla3d]) growing from the surface, constrained by the object"),
    ("STEAM", "Steam", "Ebert steam rising from the top of this object"),
]


def _addon_prefs(context):
    addon = context.preferences.addons.get(__package__)
    return addon.preferences if addon else None


class FROSTVDB_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    binary: StringProperty(
        name="frostvdb binary", subtype='FILE_PATH', default="",
        description="Path of the frostvdb program; empty: the repository's build/bin/frostvdb, then PATH")

    def draw(self, context):
        path, err = engine.find_binary(self.binary)
        self.layout.prop(self, "binary")
        self.layout.label(text=("Using " + path) if path else err, icon='CHECKMARK' if path else 'ERROR')


class FROSTVDB_Settings(bpy.types.PropertyGroup):
    preset: EnumProperty(name="Preset", items=PRESET_ITEMS, default="FROST")
    voxel_size: FloatProperty(
        name="Voxel size", default=0.0, min=0.0, soft_max=0.1, precision=5, unit='LENGTH',
        description="World size of a voxel; 0: automatic from the object's size (largest side / 64 for frost "
                    "and crystals, / 160 for feathers; steam: the cup radius / 40)")
    frames: IntProperty(name="Frames", default=4, min=1, soft_max=250, description="Frames to write")
    steps: IntProperty(name="Steps per frame", default=100, min=1, soft_max=5000,
                       description="Simulation steps between frames (frost, crystals, feathers)")
    nucleation: IntProperty(name="Nucleation sites", default=6, min=1, soft_max=200,
                            description="Seeds: this many spread-out painted vertices, or points scattered by area "
                                        "when no seed attribute is given")
    particles: IntProperty(name="Particles", default=3000, min=10, soft_max=200000,
                           description="Frost feathers: particles in the aggregate at the end")
    wind: FloatVectorProperty(
        name="Wind", size=3, default=(0.0, 0.0, 0.0), subtype='XYZ',
        description="Frost, crystals: [phase_field] wind (cells of h per unit ice time, |x|+|y|+|z| up to about 100); "
                    "feathers: [dla3d] bias (0.1-0.5 is gentle); steam: [steam] wind in m/s")
    seed_attribute: StringProperty(
        name="Seeds from", default="",
        description="Colour attribute or vertex group: nucleation sites where it exceeds 1/2 (empty: scatter)")
    melt_attribute: StringProperty(
        name="Melt from", default="",
        description="Colour attribute or vertex group: the melt map (1 grows, 0 keeps a patch clear); "
                    "frost and crystals only")
    seed: IntProperty(name="Random seed", default=1, min=0)
    precision: EnumProperty(name="Precision", default="HALF",
                            items=[("HALF", "Half", "16-bit floats: about half the cache size"),
                                   ("FLOAT", "Float", "32-bit floats")])
    compression: EnumProperty(name="Compression", default="BLOSC",
                              items=[("BLOSC", "Blosc", "fast (default)"), ("ZIP", "Zip", "zlib"),
                                     ("NONE", "None", "uncompressed")])
    look: EnumProperty(name="Look", default="VOLUME",
                       items=[("VOLUME", "Volume", "render the ice grid as a density"),
                              ("SURFACE", "Surface", "a mesh from ice_sdf through a Volume to Mesh modifier")])
    last_estimate: StringProperty(name="Estimate", default="")
    last_scene: StringProperty(name="Scene file", default="", subtype='FILE_PATH')
    last_voxel_size: FloatProperty(name="Voxel size used", default=0.0)


# ---------------------------------------------------------------------------------------------
# Preparing a run

def _settings_dict(obj, st, paths):
    folder, toml, ply, out, name = paths
    return {"object": obj.name, "name": name, "frames": st.frames, "steps": st.steps, "seed": st.seed,
            "voxel_size": st.voxel_size, "nucleation": st.nucleation, "particles": st.particles,
            "wind": tuple(st.wind), "precision": st.precision.lower(), "compression": st.compression.lower(),
            "melt": bool(st.melt_attribute) and st.preset in ("FROST", "CRYSTALS"),
            "scene_file": os.path.basename(toml), "out_name": os.path.basename(out),
            "ply_name": os.path.basename(ply)}


def prepare(context, obj):
    """Writes the PLY and the scene TOML; returns (binary, toml, out_dir, name, settings)."""
    st = obj.frostvdb
    prefs = _addon_prefs(context)
    binary, err = engine.find_binary(prefs.binary if prefs else "")
    if not binary:
        raise RuntimeError(err)
    paths = blender_io.out_paths(context, obj, st.preset)
    folder, toml, ply, out, name = paths
    os.makedirs(folder, exist_ok=True)
    mesh = blender_io.evaluated_mesh(context, obj, st.seed_attribute,
                                     st.melt_attribute if st.preset in ("FROST", "CRYSTALS") else "")
    mesh["seeds"] = blender_io.choose_seeds(mesh, st.nucleation, st.seed) if st.preset != "STEAM" else []
    s = _settings_dict(obj, st, paths)
    if st.preset != "STEAM":
        engine.write_ply(ply, mesh["verts"], mesh["tris"], mesh["melt_weights"] if s["melt"] else None)
    text = engine.build_scene(st.preset, s, mesh)
    tmp = toml + ".tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, toml)
    st.last_scene = toml
    st.last_voxel_size = s["voxel_size_used"]
    return binary, toml, out, name


def load_result(context, obj, out, name):
    st = obj.frostvdb
    files = engine.frame_files(out, name)
    if not files:
        raise RuntimeError("frostvdb wrote no .vdb frames in " + out)
    vol = blender_io.import_sequence(context, obj, files, st.preset, context.scene.frame_start, name,
                                     st.last_voxel_size)
    if st.look == 'SURFACE' and st.preset != "STEAM":
        _surface(context, obj, vol)
    return vol


def _surface(context, obj, vol_ob):
    name = vol_ob.name + "_surface"
    old = bpy.data.objects.get(name)
    if old is not None:
        bpy.data.objects.remove(old, do_unlink=True)
    me = bpy.data.meshes.new(name)
    ob = bpy.data.objects.new(name, me)
    ob[blender_io.VOLUME_TAG + "_surface"] = obj.name
    for c in vol_ob.users_collection:
        c.objects.link(ob)
    mod = ob.modifiers.new("frostvdb ice", 'VOLUME_TO_MESH')
    mod.object = vol_ob
    mod.grid_name = "ice_sdf"
    mod.threshold = 0.0
    mod.use_smooth_shade = True
    vol_ob.hide_render = True
    mat = bpy.data.materials.get("frostvdb_ice_surface") or bpy.data.materials.new("frostvdb_ice_surface")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    if bsdf is not None:
        bsdf.inputs["Base Color"].default_value = (0.85, 0.93, 1.0, 1.0)
        bsdf.inputs["Roughness"].default_value = 0.25
    me.materials.append(mat)


# ---------------------------------------------------------------------------------------------
# Operators

_active = {}  # object name -> engine.Run of a modal run in progress


class FROSTVDB_OT_estimate(bpy.types.Operator):
    bl_idname = "frostvdb.estimate"
    bl_label = "Estimate"
    bl_description = "Write the scene and ask frostvdb for its memory and time estimate (nothing is simulated to disk)"

    @classmethod
    def poll(cls, context):
        return context.active_object is not None and context.active_object.type == 'MESH'

    def execute(self, context):
        obj = context.active_object
        try:
            binary, toml, out, name = prepare(context, obj)
        except (RuntimeError, ValueError, OSError) as e:
            self.report({'ERROR'}, str(e))
            return {'CANCELLED'}
        est, err = engine.run_estimate(binary, toml, 0.5)
        if err:
            self.report({'ERROR'}, err)
            return {'CANCELLED'}
        obj.frostvdb.last_estimate = engine.format_estimate(est)
        self.report({'INFO'}, "frostvdb estimate: " + obj.frostvdb.last_estimate)
        return {'FINISHED'}


class FROSTVDB_OT_run(bpy.types.Operator):
    bl_idname = "frostvdb.run"
    bl_label = "Run frostvdb"
    bl_description = ("Export the object, write the scene beside the .blend, run frostvdb in the background "
                      "(Esc cancels) and load the result as a Volume object")

    synchronous: BoolProperty(name="Synchronous", default=False, options={'SKIP_SAVE', 'HIDDEN'},
                              description="Block until the run ends (scripts, headless Blender)")
    estimate_first: BoolProperty(name="Estimate first", default=True, options={'SKIP_SAVE'},
                                 description="Report frostvdb's memory and time estimate before the run")

    _timer = None
    _run = None
    _obj_name = ""
    _out = ""
    _name = ""

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        return obj is not None and obj.type == 'MESH' and obj.name not in _active

    def _start(self, context):
        obj = context.active_object
        binary, toml, out, name = prepare(context, obj)
        if self.estimate_first:
            est, err = engine.run_estimate(binary, toml, 0.2)
            if err:
                raise RuntimeError(err)
            obj.frostvdb.last_estimate = engine.format_estimate(est)
            self.report({'INFO'}, "frostvdb estimate: " + obj.frostvdb.last_estimate)
        self._obj_name, self._out, self._name = obj.name, out, name
        self._run = engine.Run(binary, toml, out).start()
        return obj

    def _finish(self, context):
        obj = bpy.data.objects.get(self._obj_name)
        state = self._run.state
        if state == "done":
            vol = load_result(context, obj, self._out, self._name)
            self.report({'INFO'}, "frostvdb: %d frames loaded as '%s'" % (self._run.frames_written, vol.name))
            return {'FINISHED'}
        if state == "failed":
            self.report({'ERROR'}, self._run.error or "frostvdb failed")
        else:
            self.report({'WARNING'}, "frostvdb run cancelled: nothing was loaded")
        return {'CANCELLED'}

    def execute(self, context):
        try:
            self._start(context)
        except (RuntimeError, ValueError, OSError) as e:
            self.report({'ERROR'}, str(e))
            return {'CANCELLED'}
        if self.synchronous or bpy.app.background or context.window is None:
            self._run.wait()
            return self._finish(context)
        wm = context.window_manager
        _active[self._obj_name] = self._run
        wm.frostvdb_progress = 0.0
        wm.frostvdb_status = "starting"
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.modal_handler_add(self)
        return {'RUNNING_MODAL'}

    def invoke(self, context, event):
        return self.execute(context)

    def _cleanup(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        _active.pop(self._obj_name, None)
        wm.frostvdb_status = ""
        for area in context.screen.areas if context.screen else []:
            area.tag_redraw()

    def modal(self, context, event):
        wm = context.window_manager
        if event.type == 'ESC' or getattr(self._run, "cancel_requested", False):
            self._run.cancel()
            self._cleanup(context)
            return self._finish(context)
        if event.type != 'TIMER':
            return {'PASS_THROUGH'}
        state = self._run.poll()
        wm.frostvdb_progress = 100.0 * self._run.fraction
        wm.frostvdb_status = "%s: %s" % (self._obj_name, self._run.message)
        wm.progress_update(int(wm.frostvdb_progress))
        for area in context.screen.areas if context.screen else []:
            if area.type in ('PROPERTIES', 'VIEW_3D'):
                area.tag_redraw()
        if state == "running":
            return {'PASS_THROUGH'}
        self._cleanup(context)
        try:
            return self._finish(context)
        except (RuntimeError, OSError) as e:
            self.report({'ERROR'}, str(e))
            return {'CANCELLED'}


class FROSTVDB_OT_cancel(bpy.types.Operator):
    bl_idname = "frostvdb.cancel"
    bl_label = "Cancel"
    bl_description = "Stop the frostvdb run of the active object (as Esc does)"

    def execute(self, context):
        obj = context.active_object
        run = _active.get(obj.name) if obj else None
        if run is None:
            return {'CANCELLED'}
        run.cancel_requested = True
        return {'FINISHED'}


# ---------------------------------------------------------------------------------------------
# Panel

class FrostvdbPanelMixin:
    bl_label = "frostvdb"

    @classmethod
    def poll(cls, context):
        return context.active_object is not None and context.active_object.type == 'MESH'

    def draw(self, context):
        layout = self.layout
        obj = context.active_object
        st = obj.frostvdb
        wm = context.window_manager
        layout.prop(st, "preset", expand=True)
        col = layout.column(align=True)
        col.use_property_split = True
        col.prop(st, "voxel_size", text="Voxel size (0 = auto)")
        col.prop(st, "frames")
        if st.preset != "STEAM":
            col.prop(st, "steps")
            col.prop(st, "nucleation")
        if st.preset == "FEATHERS":
            col.prop(st, "particles")
        col.prop(st, "wind")
        col = layout.column(align=True)
        col.use_property_split = True
        if st.preset != "STEAM":
            col.prop(st, "seed_attribute", icon='GROUP_VCOL')
        if st.preset in ("FROST", "CRYSTALS"):
            col.prop(st, "melt_attribute", icon='GROUP_VERTEX')
        col.prop(st, "seed")
        row = layout.row(align=True)
        row.prop(st, "precision", expand=True)
        row = layout.row(align=True)
        row.prop(st, "compression", expand=True)
        if st.preset != "STEAM":
            layout.row().prop(st, "look", expand=True)
        run = _active.get(obj.name)
        if run is not None:
            if hasattr(layout, "progress"):  # Blender 4.0+
                layout.progress(factor=wm.frostvdb_progress / 100.0, type='BAR', text=run.message)
            else:
                layout.prop(wm, "frostvdb_progress", text=run.message, slider=True)
            layout.operator("frostvdb.cancel", icon='CANCEL', text="Cancel (Esc)")
        else:
            row = layout.row(align=True)
            row.operator("frostvdb.estimate", icon='TIME')
            row.operator("frostvdb.run", icon='FREEZE')
        if st.last_estimate:
            layout.label(text="Estimate: " + st.last_estimate, icon='INFO')
        if st.last_scene:
            shown = bpy.path.relpath(st.last_scene) if bpy.data.filepath else st.last_scene
            layout.label(text="Scene: " + shown, icon='FILE_TEXT')


class FROSTVDB_PT_object(FrostvdbPanelMixin, bpy.types.Panel):
    """Properties editor > Object tab."""
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = "object"


class FROSTVDB_PT_view3d(FrostvdbPanelMixin, bpy.types.Panel):
    """3D Viewport > Sidebar (N) > frostvdb tab: the same panel."""
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "frostvdb"


classes = (FROSTVDB_AddonPreferences, FROSTVDB_Settings, FROSTVDB_OT_estimate, FROSTVDB_OT_run,
           FROSTVDB_OT_cancel, FROSTVDB_PT_object, FROSTVDB_PT_view3d)


def register():
    for c in classes:
        bpy.utils.register_class(c)
    bpy.types.Object.frostvdb = PointerProperty(type=FROSTVDB_Settings)
    bpy.types.WindowManager.frostvdb_progress = FloatProperty(name="Progress", min=0.0, max=100.0,
                                                              subtype='PERCENTAGE')
    bpy.types.WindowManager.frostvdb_status = StringProperty(name="Status")


def unregister():
    for run in list(_active.values()):
        run.cancel()
    _active.clear()
    del bpy.types.WindowManager.frostvdb_status
    del bpy.types.WindowManager.frostvdb_progress
    del bpy.types.Object.frostvdb
    for c in reversed(classes):
        bpy.utils.unregister_class(c)
