"""Tests of the frostvdb Blender add-on in real (headless) Blender; registered with ctest.

    blender -b --factory-startup -noaudio --python-exit-code 1 --python tests/blender/test_addon.py -- CASE FROSTVDB

CASE: register, frost, render, cancel, steam, errors. FROSTVDB: the frostvdb binary to use.
Each case works in a fresh temporary folder (removed at the end unless FROSTVDB_KEEP_TEST_DIRS).
"""

import os
import shutil
import subprocess
import sys
import tempfile
import time

import addon_utils
import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.normpath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(REPO, "vdb_tools", "blender"))

argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
CASE = argv[0] if argv else "register"
BINARY = os.path.abspath(argv[1]) if len(argv) > 1 else os.path.join(REPO, "build", "bin", "frostvdb")
TMP = tempfile.mkdtemp(prefix="frostvdb_blender_%s_" % CASE)


def check(cond, what):
    if not cond:
        raise AssertionError(what)
    print("  ok:", what)


def enable_addon():
    mod = addon_utils.enable("frostvdb_blender", default_set=True, handle_error=None)
    check(mod is not None, "the add-on enables")
    prefs = bpy.context.preferences.addons["frostvdb_blender"].preferences
    prefs.binary = BINARY
    return mod


def new_scene_file():
    """A saved .blend in TMP (so the scene TOML goes beside it), frame start 10."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    enable_addon()
    bpy.context.scene.frame_start = 10
    bpy.context.scene.frame_end = 20
    path = os.path.join(TMP, "shot.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    return path


def icosphere_with_seeds(radius=1.0, location=(0.0, 0.0, 0.0)):
    """An icosphere (subdivisions 3) with a point colour attribute 'seeds': white on three
    vertices near +x, +y and -z, black elsewhere; active and selected."""
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=3, radius=radius, location=location)
    ob = bpy.context.active_object
    ob.name = "Ball"
    attr = ob.data.color_attributes.new("seeds", 'FLOAT_COLOR', 'POINT')
    targets = [(radius, 0, 0), (0, radius, 0), (0, 0, -radius)]
    for v in ob.data.vertices:
        hot = any((v.co - __import__("mathutils").Vector(t)).length < 0.2 * radius for t in targets)
        attr.data[v.index].color = (1, 1, 1, 1) if hot else (0, 0, 0, 1)
    return ob


def frost_settings(ob, frames=3, steps=25):
    st = ob.frostvdb
    st.preset = "FROST"
    st.frames = frames
    st.steps = steps
    st.voxel_size = 0.05  # a 1 m sphere 40 voxels across: seconds
    st.seed_attribute = "seeds"
    st.nucleation = 3
    return st


def volume_objects(source):
    return [o for o in bpy.data.objects if o.type == 'VOLUME' and o.get("frostvdb_source") == source.name]


def run_sync(estimate=True):
    t0 = time.monotonic()
    result = bpy.ops.frostvdb.run(synchronous=True, estimate_first=estimate)
    print("  frostvdb run through the operator: %.1f s -> %s" % (time.monotonic() - t0, result))
    return result


def frost_run(frames=3, steps=25):
    new_scene_file()
    ob = icosphere_with_seeds()
    frost_settings(ob, frames, steps)
    check(run_sync() == {'FINISHED'}, "the operator finishes")
    vols = volume_objects(ob)
    check(len(vols) == 1, "one Volume object for the source")
    return ob, vols[0]


# ---------------------------------------------------------------------------------------------

def case_register():
    mod = enable_addon()
    check(hasattr(bpy.ops.frostvdb, "run") and hasattr(bpy.ops.frostvdb, "estimate"), "operators registered")
    check(hasattr(bpy.types, "FROSTVDB_PT_object"), "the panel is registered")
    check(hasattr(bpy.types.Object, "frostvdb"), "object settings registered")
    from frostvdb_blender import engine
    check(engine.find_binary(BINARY)[0] == BINARY, "the binary preference is used")
    check(engine.find_binary("/nonexistent/frostvdb")[0] is None, "a wrong binary preference is refused")
    addon_utils.disable("frostvdb_blender", default_set=True)
    check(not hasattr(bpy.types.Object, "frostvdb"), "the add-on unregisters cleanly")


def case_frost():
    ob, vol = frost_run()
    start = bpy.context.scene.frame_start
    check(vol.parent == ob, "the Volume object is parented to the source")
    check(vol.data.frame_start == start and vol.data.frame_duration == 3, "sequence starts at the scene's start frame, 3 frames")
    from frostvdb_blender import blender_io
    paths = set()
    for f in range(start, start + 3):
        names, path = blender_io.grids_at_frame(vol, f)
        check("ice" in names and "ice_sdf" in names, "frame %d has grids ice and ice_sdf (%s)" % (f, ", ".join(names)))
        check(os.path.isfile(path), "frame %d reads %s" % (f, os.path.basename(path)))
        paths.add(path)
    check(len(paths) == 3, "three different files over the three frames")
    names, _ = blender_io.grids_at_frame(vol, start + 3)
    check(names == [], "no grids after the sequence (clip)")
    # The scene beside the .blend reproduces the run; the result is half precision, Blender read it.
    toml = os.path.join(TMP, "frostvdb", "Ball_frost.toml")
    check(os.path.isfile(toml), "the scene TOML is written beside the .blend")
    info = subprocess.run([BINARY, "info", sorted(paths)[-1]], capture_output=True, text=True).stdout
    check("precision half" in info.splitlines()[0], "the frames are half precision (frostvdb info: %s)" % info.splitlines()[0])
    mat = vol.data.materials[0]
    pv = [n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeVolumePrincipled"][0]
    check(pv.inputs["Density Attribute"].default_value == "ice", "the material reads the ice grid")
    # Running again replaces the sequence instead of adding objects.
    bpy.context.view_layer.objects.active = ob
    check(run_sync(estimate=False) == {'FINISHED'}, "a second run finishes")
    check(len(volume_objects(ob)) == 1, "a second run replaces the Volume object")
    check(len([v for v in bpy.data.volumes]) == 1, "and its volume data")
    leftovers = [f for f in os.listdir(os.path.join(TMP, "frostvdb")) if f.endswith((".running", ".old", ".tmp"))]
    check(not leftovers, "no staging or temporary files left (%s)" % leftovers)


def _render(path, hide=None):
    scene = bpy.context.scene
    if hide is not None:
        hide.hide_render = True
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    if hide is not None:
        hide.hide_render = False
    img = bpy.data.images.load(path)
    px = list(img.pixels)
    bpy.data.images.remove(img)
    return px


def setup_render(target, aim=(0.0, 0.0, 0.0), distance=1.0):
    import mathutils
    scene = bpy.context.scene
    scene.render.engine = 'CYCLES'
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False  # Debian's Blender 3.4 has no denoiser
    scene.cycles.device = 'CPU'
    scene.render.resolution_x, scene.render.resolution_y = 64, 48
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = 'PNG'
    scene.render.film_transparent = False
    cam_data = bpy.data.cameras.new("cam")
    cam = bpy.data.objects.new("cam", cam_data)
    scene.collection.objects.link(cam)
    cam.location = mathutils.Vector(aim) + distance * mathutils.Vector((4.5, -4.5, 3.0))
    direction = mathutils.Vector(aim) - cam.location
    cam.rotation_euler = direction.to_track_quat('-Z', 'Y').to_euler()
    scene.camera = cam
    light_data = bpy.data.lights.new("sun", 'SUN')
    light_data.energy = 5.0
    light = bpy.data.objects.new("sun", light_data)
    light.rotation_euler = (0.6, 0.2, 0.8)
    scene.collection.objects.link(light)
    world = bpy.data.worlds.new("w")
    world.color = (0.02, 0.02, 0.03)
    scene.world = world


def case_render():
    ob, vol = frost_run()
    scene = bpy.context.scene
    setup_render(ob)
    ob.hide_render = True  # the frost alone, against the dark world
    scene.frame_set(scene.frame_start + 2)
    with_frost = _render(os.path.join(TMP, "frost.png"))
    without = _render(os.path.join(TMP, "empty.png"), hide=vol)
    n = len(with_frost) // 4
    lum = lambda px, i: px[4 * i] + px[4 * i + 1] + px[4 * i + 2]
    lit = sum(1 for i in range(n) if lum(with_frost, i) > lum(without, i) + 0.05)
    print("  pixels brighter with the frost: %d of %d" % (lit, n))
    check(lit >= 20, "the render of the last frame is not empty (%d pixels show the frost)" % lit)


def case_cancel():
    new_scene_file()
    ob = icosphere_with_seeds()
    frost_settings(ob, frames=4, steps=3000)  # minutes if left alone
    import frostvdb_blender
    from frostvdb_blender import engine
    binary, toml, out, name = frostvdb_blender.prepare(bpy.context, ob)
    run = engine.Run(binary, toml, out).start()
    pid = run.pid
    t0 = time.monotonic()
    while run.poll() == "running" and run.fraction <= 0.0 and time.monotonic() - t0 < 60:
        time.sleep(0.05)
    check(run.state == "running" and run.fraction > 0.0, "the run reports progress (%s)" % run.message)
    time.sleep(0.5)
    run.cancel()
    check(run.state == "cancelled", "the run is cancelled")
    check(run.proc.returncode is not None, "frostvdb has exited (exit %s)" % run.proc.returncode)
    check(not os.path.exists("/proc/%d" % pid), "no process %d is left" % pid)
    found = []
    for root, dirs, files in os.walk(TMP):
        found += [os.path.join(root, f) for f in files if f.endswith(".vdb") or ".tmp" in f]
    check(not found, "no .vdb or temporary file left (%s)" % found)
    check(not os.path.exists(engine.staging_dir(out)) and not os.path.exists(out), "no output folder left")


def case_steam():
    new_scene_file()
    bpy.ops.mesh.primitive_cylinder_add(radius=0.5, depth=1.0, location=(0, 0, 0.5))
    cup = bpy.context.active_object
    cup.name = "Cup"
    st = cup.frostvdb
    st.preset = "STEAM"
    st.frames = 2
    check(run_sync() == {'FINISHED'}, "the steam run finishes")
    vols = volume_objects(cup)
    check(len(vols) == 1, "one Volume object")
    vol = vols[0]
    from frostvdb_blender import blender_io
    names, path = blender_io.grids_at_frame(vol, bpy.context.scene.frame_start + 1)
    pv = [n for n in vol.data.materials[0].node_tree.nodes if n.bl_idname == "ShaderNodeVolumePrincipled"][0]
    attr = pv.inputs["Density Attribute"].default_value
    check(attr == "density" and "density" in names, "the material reads density, a grid of the file (%s)" % names)
    check(pv.inputs["Temperature Attribute"].default_value == "temperature", "and temperature")
    ev = vol.evaluated_get(bpy.context.evaluated_depsgraph_get())
    g = ev.data.grids["density"]
    check(g.load() and g.is_loaded, "Blender loads the density grid")
    setup_render(cup, aim=(0.0, 0.0, 1.8), distance=1.2)  # the plume above the cup
    cup.hide_render = True
    bpy.context.scene.frame_set(bpy.context.scene.frame_start + 1)
    bpy.context.scene.cycles.samples = 16  # thin wisps: one sample often misses them all
    with_steam = _render(os.path.join(TMP, "steam.png"))
    without = _render(os.path.join(TMP, "nosteam.png"), hide=vol)
    diff = sum(abs(a - b) for a, b in zip(with_steam, without))
    check(diff > 1.0, "the steam shows in a render (summed difference %.2f)" % diff)


def operator_error():
    """The error report of a synchronous run (headless Blender raises reports of a cancelled
    operator as RuntimeError); fails if the operator succeeds."""
    try:
        result = bpy.ops.frostvdb.run(synchronous=True)
    except RuntimeError as e:
        return str(e)
    raise AssertionError("the operator should have failed, returned %s" % result)


def case_errors():
    new_scene_file()
    ob = icosphere_with_seeds()
    st = frost_settings(ob)
    st.seed_attribute = "no_such_attribute"
    check("no colour attribute or vertex group 'no_such_attribute'" in operator_error(),
          "a missing seed attribute is refused with a report")
    st.seed_attribute = "seeds"
    st.voxel_size = 1e-6  # below OpenVDB's limit: frostvdb refuses it with one line
    import frostvdb_blender
    from frostvdb_blender import engine
    binary, toml, out, name = frostvdb_blender.prepare(bpy.context, ob)
    run = engine.Run(binary, toml, out).start()
    check(run.wait(timeout=60) == "failed", "frostvdb refuses the scene")
    print("  error: " + str(run.error))
    check(run.error and "voxel_size" in run.error and "\n" not in run.error and "toml" in run.error,
          "one line naming the file and key")
    check(not os.path.exists(out) and not os.path.exists(engine.staging_dir(out)), "nothing written")
    message = operator_error()
    check("voxel_size" in message and "Ball_frost.toml" in message, "the operator reports it: " + message)


CASES = {"register": case_register, "frost": case_frost, "render": case_render, "cancel": case_cancel,
         "steam": case_steam, "errors": case_errors}

try:
    print("frostvdb Blender test '%s' (Blender %s, %s)" % (CASE, bpy.app.version_string, BINARY))
    CASES[CASE]()
    print("PASSED", CASE)
finally:
    if not os.environ.get("FROSTVDB_KEEP_TEST_DIRS"):
        shutil.rmtree(TMP, ignore_errors=True)
