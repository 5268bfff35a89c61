"""Headless Blender render of any frostvdb .vdb volume (dla3d / gg3d ice, frost shells, gas).

    blender -b -P scripts/render_vdb_blender.py -- IN.vdb OUT.png [options]

Options (all optional):
    --grid NAME        grid to show (default for --as surface: ice_sdf, else ice (or automaton_ice,
                       aggregate_ice), else density, else the first float grid; for --as volume: ice (or
                       automaton_ice, aggregate_ice), else density, else ice_sdf, else the first)
    --as surface|volume
                       surface (default): the grid's iso-surface (Blender's Volume to Mesh modifier,
                       threshold --threshold, 0 for level sets) shaded as ice; volume: a Principled
                       Volume with the grid as density (smoke, gas, soft frost)
    --threshold T      iso value for --as surface (default: 0.5 for fog volumes, 0 for level sets)
    --density K        density multiplier for --as volume (default 20, relative to a unit-size object)
    --samples N        render samples (default 64)
    --res WxH          image size (default 960x720)
    --view iso|high|low|top|side|front
                       camera direction (default iso: 35 degrees above the horizon; high: 65 degrees,
                       for flat flakes; low: 12 degrees, to see a plate's rim edge-on, e.g. the two
                       plates of a sandwich plate)
    --engine cycles|eevee
                       default cycles (CPU, denoising off: Debian's Blender has no OpenImageDenoise);
                       EEVEE is tried when Cycles fails and needs an OpenGL context
    --mesh FILE        also show a mesh (OBJ, STL, PLY; e.g. the [dla3d] or shell constraint mesh) as
                       faint glass, placed as the scene places it:
    --mesh-scale S, --mesh-rotate X,Y,Z (degrees about x, then y, then z), --mesh-translate X,Y,Z
                       the scene's constraint_scale / _rotate / _translate (applied in that order)
    --cut              --as surface: cut away the quarter x > centre, y < centre (a Boolean), to show
                       the inside (hollow cores, the gap of a sandwich plate)
    --color R,G,B      surface / volume colour (default ice blue 0.70,0.82,0.95)
    --background R,G,B world colour (default 0.02,0.025,0.035)

Scale: the object is moved to the origin and scaled so its largest side is 2 units, then the
camera and lights are placed from its bounds. Blender Cycles renders volumes of sub-millimetre
voxels empty (its ray marching and bounds work in world units), so a 1 cm snowflake written at
output.world_scale = 1 renders here just as one written at world_scale = 100.
"""
import math
import os
import sys

import bpy
from mathutils import Matrix, Vector


def parse_args(argv):
    args = argv[argv.index("--") + 1:] if "--" in argv else []
    opts = {"grid": None, "as": "surface", "threshold": None, "density": 20.0, "samples": 64,
            "res": (960, 720), "view": "iso", "engine": "cycles", "color": (0.70, 0.82, 0.95),
            "background": (0.02, 0.025, 0.035), "mesh": None, "mesh-scale": 1.0,
            "mesh-rotate": (0.0, 0.0, 0.0), "mesh-translate": (0.0, 0.0, 0.0), "cut": False}
    pos = []
    i = 0

    def triple(s):
        v = tuple(float(x) for x in s.split(","))
        if len(v) != 3:
            raise ValueError("expected R,G,B: " + s)
        return v

    while i < len(args):
        a = args[i]
        if a == "--cut":  # a flag
            opts["cut"] = True
            i += 1
            continue
        if a.startswith("--"):
            key = a[2:]
            if key not in opts or i + 1 >= len(args):
                die("unknown option or missing value: " + a)
            val = args[i + 1]
            i += 2
            try:
                if key in ("samples",):
                    opts[key] = int(val)
                elif key in ("threshold", "density", "mesh-scale"):
                    opts[key] = float(val)
                elif key == "res":
                    w, h = val.lower().split("x")
                    opts[key] = (int(w), int(h))
                elif key in ("color", "background", "mesh-rotate", "mesh-translate"):
                    opts[key] = triple(val)
                else:
                    opts[key] = val
            except ValueError as e:
                die("bad value for %s: %s (%s)" % (a, val, e))
        else:
            pos.append(a)
            i += 1
    if len(pos) != 2:
        die("usage: blender -b -P scripts/render_vdb_blender.py -- IN.vdb OUT.png [--grid NAME] [--samples N] ...")
    if opts["as"] not in ("surface", "volume"):
        die("--as must be surface or volume")
    if opts["view"] not in ("iso", "high", "low", "top", "side", "front"):
        die("--view must be iso, high, low, top, side or front")
    if opts["engine"] not in ("cycles", "eevee"):
        die("--engine must be cycles or eevee")
    return os.path.abspath(pos[0]), os.path.abspath(pos[1]), opts


def die(msg):
    sys.stderr.write("render_vdb_blender: error: %s\n" % msg)
    sys.exit(2)


def clear_scene():
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj, do_unlink=True)
    for coll in (bpy.data.meshes, bpy.data.materials, bpy.data.lights, bpy.data.cameras, bpy.data.volumes):
        for block in list(coll):
            coll.remove(block)


def load_volume(path, grid_name, prefer):
    """The .vdb as a Volume object; returns (object, grid) with the chosen float grid."""
    if not os.path.isfile(path):
        die("no such file: " + path)
    vol = bpy.data.volumes.new(os.path.basename(path))
    vol.filepath = path
    if not vol.grids.load():
        die("Blender cannot read %s: %s" % (path, vol.grids.error_message))
    names = [g.name for g in vol.grids]
    floats = [g for g in vol.grids if g.data_type in ("FLOAT", "DOUBLE")]
    if grid_name is None:
        for cand in prefer:
            if any(g.name == cand for g in floats):
                grid_name = cand
                break
        else:
            if not floats:
                die("%s has no float grid (grids: %s)" % (path, ", ".join(names) or "none"))
            grid_name = floats[0].name
    grid = next((g for g in vol.grids if g.name == grid_name), None)
    if grid is None:
        die("%s has no grid '%s' (grids: %s)" % (path, grid_name, ", ".join(names)))
    obj = bpy.data.objects.new("vdb", vol)
    bpy.context.scene.collection.objects.link(obj)
    return obj, grid


def is_level_set(path, grid_name):
    """True when the grid's class is level set (read through pyopenvdb when available)."""
    try:
        import pyopenvdb as vdb  # noqa: F401  (Debian's python3-openvdb; not in Blender's Python)
        return vdb.readGridMetadata(path, grid_name).gridClass == vdb.GridClass.LEVEL_SET
    except Exception:
        return grid_name.endswith("_sdf") or grid_name in ("sdf", "surface")


def evaluated_bounds(obj):
    """World-space (min, max) of an object's evaluated geometry, and the points to frame (the
    mesh's vertices, or the 8 corners of a volume's bounds)."""
    bpy.context.view_layer.update()
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    if ev.type == "MESH" and len(ev.data.vertices) > 0:  # exact: the vertices themselves
        import numpy as np
        co = np.empty(len(ev.data.vertices) * 3)
        ev.data.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3)
        m = np.array(ev.matrix_world)
        co = co @ m[:3, :3].T + m[:3, 3]
        lo, hi = Vector(co.min(axis=0)), Vector(co.max(axis=0))
        return lo, hi, co
    pts = [ev.matrix_world @ Vector(c) for c in ev.bound_box]
    lo = Vector((min(p.x for p in pts), min(p.y for p in pts), min(p.z for p in pts)))
    hi = Vector((max(p.x for p in pts), max(p.y for p in pts), max(p.z for p in pts)))
    return lo, hi, [tuple(p) for p in pts]


def ice_material(color):
    m = bpy.data.materials.new("ice")
    m.use_nodes = True
    bsdf = m.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.3
    bsdf.inputs["Specular"].default_value = 0.6
    # Opaque on purpose: transmission and subsurface need hundreds of samples without a denoiser.
    return m


def volume_material(grid_name, color, density):
    m = bpy.data.materials.new("fog")
    m.use_nodes = True
    nt = m.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Color"].default_value = (*color, 1.0)
    pv.inputs["Density"].default_value = density
    pv.inputs["Density Attribute"].default_value = grid_name
    nt.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    return m


def normalise(obj, lo, hi):
    """Centre the object at the origin and scale its largest side to 2 units."""
    size = max(hi - lo)
    if not (size > 0 and math.isfinite(size)):
        die("the grid is empty (no active voxels, or zero extent)")
    s = 2.0 / size
    centre = (lo + hi) * 0.5
    norm = Matrix.Diagonal((s, s, s, 1.0)) @ Matrix.Translation(-centre)
    obj.matrix_world = norm @ obj.matrix_world
    return norm


def import_mesh(path, opts, norm):
    """The mesh file as a faint glass object, with the scene's placement and the normalisation."""
    if not os.path.isfile(path):
        die("no such mesh file: " + path)
    before = set(bpy.data.objects)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".obj":  # as written: no Y-up conversion (frostvdb reads OBJ through Assimp as is)
        bpy.ops.wm.obj_import(filepath=path, forward_axis="Y", up_axis="Z")
    elif ext == ".stl":
        bpy.ops.import_mesh.stl(filepath=path, axis_forward="Y", axis_up="Z")
    elif ext == ".ply":
        bpy.ops.import_mesh.ply(filepath=path, axis_forward="Y", axis_up="Z")
    else:
        die("--mesh: OBJ, STL or PLY expected: " + path)
    new = [o for o in bpy.data.objects if o not in before and o.type == "MESH"]
    if not new:
        die("--mesh: no mesh in " + path)
    rx, ry, rz = (math.radians(a) for a in opts["mesh-rotate"])
    k = opts["mesh-scale"]
    place = (Matrix.Translation(Vector(opts["mesh-translate"])) @ Matrix.Rotation(rz, 4, "Z") @
             Matrix.Rotation(ry, 4, "Y") @ Matrix.Rotation(rx, 4, "X") @ Matrix.Diagonal((k, k, k, 1.0)))
    m = bpy.data.materials.new("glass")
    m.use_nodes = True
    m.blend_method = "BLEND"
    bsdf = m.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.55, 0.6, 0.65, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.1
    bsdf.inputs["Alpha"].default_value = 0.18  # see-through without transmission noise
    for o in new:
        o.matrix_world = norm @ place @ o.matrix_world
        o.data.materials.clear()
        o.data.materials.append(m)
    return new


def place_camera(lo, hi, pts, view, aspect):
    """Camera looking at the bounds' centre from @view, backed off until every point fits."""
    centre = (lo + hi) * 0.5
    dirs = {"iso": (math.radians(-50), math.radians(35)), "top": (0.0, math.radians(89.9)),
            "side": (0.0, 0.0), "front": (math.radians(-90), 0.0),
            "high": (math.radians(-50), math.radians(65)), "low": (math.radians(-50), math.radians(12))}
    az, el = dirs[view]
    d = Vector((math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)))
    cam_data = bpy.data.cameras.new("cam")
    cam_data.lens = 50.0
    cam_data.sensor_fit = "AUTO"
    fov = 2.0 * math.atan(cam_data.sensor_width * 0.5 / cam_data.lens)  # along the longer side
    tan_x = math.tan(fov * 0.5) if aspect >= 1.0 else math.tan(fov * 0.5) * aspect
    tan_y = tan_x / aspect
    rot = (-d).to_track_quat("-Z", "Y")
    right, up = rot @ Vector((1, 0, 0)), rot @ Vector((0, 1, 0))
    import numpy as np
    c = np.asarray(pts, dtype=float) - np.array(centre)
    # Aim at the middle of the silhouette (not of the box): shift the target in the image plane.
    px, py = c @ np.array(right), c @ np.array(up)
    shift = right * float(px.max() + px.min()) * 0.5 + up * float(py.max() + py.min()) * 0.5
    centre = centre + shift
    c = c - np.array(shift)
    margin = 1.12
    toward = c @ np.array(d)  # points nearer the camera need more room
    need = np.maximum(toward + margin * np.abs(c @ np.array(right)) / tan_x,
                      toward + margin * np.abs(c @ np.array(up)) / tan_y)
    dist = max(float(need.max()), 1e-3)
    cam = bpy.data.objects.new("cam", cam_data)
    bpy.context.scene.collection.objects.link(cam)
    cam.location = centre + d * dist
    cam.rotation_euler = rot.to_euler()
    cam_data.clip_start = dist * 0.01
    cam_data.clip_end = dist * 10.0
    bpy.context.scene.camera = cam
    return cam, d, dist


def add_lights(centre, view_dir, dist):
    """Key (sun from above, offset), fill (area on the camera side) and rim (from behind)."""
    def sun(name, strength, elev, az, angle):
        ld = bpy.data.lights.new(name, "SUN")
        ld.energy = strength
        ld.angle = math.radians(angle)
        ob = bpy.data.objects.new(name, ld)
        bpy.context.scene.collection.objects.link(ob)
        d = Vector((math.cos(elev) * math.cos(az), math.cos(elev) * math.sin(az), math.sin(elev)))
        ob.rotation_euler = (-d).to_track_quat("-Z", "Y").to_euler()
    sun("key", 2.5, math.radians(60), math.radians(-20), 5)
    sun("rim", 1.8, math.radians(25), math.radians(150), 10)
    area = bpy.data.lights.new("fill", "AREA")
    area.size = dist
    area.energy = 8.0 * dist * dist
    ob = bpy.data.objects.new("fill", area)
    bpy.context.scene.collection.objects.link(ob)
    ob.location = centre + (view_dir + Vector((0, 0, 0.5))).normalized() * dist
    ob.rotation_euler = (centre - ob.location).to_track_quat("-Z", "Y").to_euler()


def setup_render(opts, out_png):
    sc = bpy.context.scene
    sc.render.resolution_x, sc.render.resolution_y = opts["res"]
    sc.render.resolution_percentage = 100
    sc.render.filepath = out_png
    sc.render.image_settings.file_format = "PNG"
    sc.render.image_settings.color_mode = "RGB"
    sc.render.film_transparent = False
    world = bpy.data.worlds.new("bg") if sc.world is None else sc.world
    sc.world = world
    world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    bg.inputs["Color"].default_value = (*opts["background"], 1.0)
    bg.inputs["Strength"].default_value = 1.0
    sc.view_settings.view_transform = "Filmic"
    sc.view_settings.look = "Medium High Contrast"


def render_cycles(opts):
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = opts["samples"]
    sc.cycles.use_denoising = False          # Debian's build has no OpenImageDenoise
    sc.cycles.use_preview_denoising = False
    for vl in sc.view_layers:
        vl.cycles.use_denoising = False
    sc.cycles.use_adaptive_sampling = True
    sc.cycles.max_bounces = 8
    sc.cycles.transparent_max_bounces = 8
    sc.cycles.volume_bounces = 1
    sc.cycles.volume_step_rate = 1.0
    sc.render.threads_mode = "AUTO"
    bpy.ops.render.render(write_still=True)


def render_eevee(opts):
    sc = bpy.context.scene
    sc.render.engine = "BLENDER_EEVEE"
    sc.eevee.taa_render_samples = opts["samples"]
    sc.eevee.volumetric_tile_size = "2"
    bpy.ops.render.render(write_still=True)


def main():
    in_vdb, out_png, opts = parse_args(sys.argv)
    clear_scene()
    # A surface is best taken from the level set (smooth), a volume from the fog.
    fogs = ("ice", "automaton_ice", "aggregate_ice")
    prefer = ("ice_sdf",) + fogs + ("density",) if opts["as"] == "surface" else fogs + ("density", "ice_sdf")
    vol_obj, grid = load_volume(in_vdb, opts["grid"], prefer)
    gname = grid.name
    lo, hi, _ = evaluated_bounds(vol_obj)
    norm = normalise(vol_obj, lo, hi)

    if opts["as"] == "surface":
        level_set = is_level_set(in_vdb, gname)
        thr = opts["threshold"] if opts["threshold"] is not None else (0.0 if level_set else 0.5)
        mesh = bpy.data.meshes.new("surface")
        surf = bpy.data.objects.new("surface", mesh)
        bpy.context.scene.collection.objects.link(surf)
        mod = surf.modifiers.new("v2m", "VOLUME_TO_MESH")
        mod.object = vol_obj
        mod.grid_name = gname
        mod.threshold = thr
        mod.resolution_mode = "GRID"
        mod.adaptivity = 0.0
        mod.use_smooth_shade = True
        surf.data.materials.append(ice_material(opts["color"]))
        vol_obj.hide_render = True
        if opts["cut"]:  # the object is normalised to [-1, 1]: remove the quarter x > 0, y < 0
            bpy.ops.mesh.primitive_cube_add(size=1.0)
            cutter = bpy.context.active_object
            cutter.scale = (1.2, 1.2, 2.4)
            cutter.location = (0.6, -0.6, 0.0)
            cutter.hide_render = True
            cutter.display_type = "WIRE"
            cut = surf.modifiers.new("cut", "BOOLEAN")
            cut.operation = "DIFFERENCE"
            cut.object = cutter
            cut.solver = "EXACT"
        lo, hi, pts = evaluated_bounds(surf)
        bpy.context.view_layer.update()
        ev = surf.evaluated_get(bpy.context.evaluated_depsgraph_get())
        nverts = len(ev.data.vertices)
        if nverts == 0:
            die("grid '%s' has no surface at threshold %g (try --threshold or --as volume)" % (gname, thr))
        print("render_vdb_blender: %s '%s' surface at %g: %d vertices" % (os.path.basename(in_vdb), gname, thr, nverts))
    else:
        vol_obj.data.materials.append(volume_material(gname, opts["color"], opts["density"]))
        lo, hi, pts = evaluated_bounds(vol_obj)
        print("render_vdb_blender: %s '%s' as volume" % (os.path.basename(in_vdb), gname))

    if opts["mesh"]:  # framed together with the ice
        import numpy as np
        for o in import_mesh(os.path.abspath(opts["mesh"]), opts, norm):
            mlo, mhi, mpts = evaluated_bounds(o)
            pts = np.vstack([np.asarray(pts, dtype=float), np.asarray(mpts, dtype=float)])
            lo = Vector(np.minimum(np.array(lo), np.array(mlo)))
            hi = Vector(np.maximum(np.array(hi), np.array(mhi)))
    aspect = opts["res"][0] / opts["res"][1]
    _, view_dir, dist = place_camera(lo, hi, pts, opts["view"], aspect)
    add_lights((lo + hi) * 0.5, view_dir, dist)
    setup_render(opts, out_png)
    os.makedirs(os.path.dirname(out_png) or ".", exist_ok=True)
    try:
        if opts["engine"] == "cycles":
            render_cycles(opts)
        else:
            render_eevee(opts)
    except Exception as e:  # Cycles unavailable: EEVEE needs an OpenGL context
        other = "eevee" if opts["engine"] == "cycles" else "cycles"
        sys.stderr.write("render_vdb_blender: %s failed (%s); trying %s\n" % (opts["engine"], e, other))
        (render_eevee if other == "eevee" else render_cycles)(opts)
    if not os.path.isfile(out_png):
        die("no image written to " + out_png)
    print("render_vdb_blender: wrote " + out_png)


if __name__ == "__main__":
    main()
