"""Makes the images of docs/blender.md through the add-on itself.

    blender -b --factory-startup -noaudio -P scripts/blender_docs.py -- render OUT.png [--samples N]
    blender -b --factory-startup --python-expr "import bpy; bpy.ops.wm.save_as_mainfile(filepath='/tmp/empty.blend')"
    xvfb-run -a -s "-screen 0 1800x1900x24" blender --factory-startup -noaudio /tmp/empty.blend -P scripts/blender_docs.py -- panel OUT.png

(opening a .blend keeps Blender's splash screen away)

render: a 1 m icosphere with three seeds painted in a colour attribute, the Frost preset with its
defaults, the operator run synchronously, and a Cycles render (denoising off) of the last frame.
panel: the same set-up in Blender's UI (needs a display: Xvfb): the operator started as a click
does (the modal run), a screenshot of the window once a third of the steps are done (the
Properties editor on the Object tab shows the frostvdb panel with its progress bar), then it
waits for the run to load and quits. docs/blender.md crops the panel out of it.
The .blend, scene and frames go to a temporary folder, kept with --keep.
"""
import os
import shutil
import sys
import tempfile
import time

import addon_utils
import bpy
import mathutils

REPO = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.join(REPO, "vdb_tools", "blender"))
args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
MODE, OUT = args[0], os.path.abspath(args[1])
SAMPLES = int(args[args.index("--samples") + 1]) if "--samples" in args else 32
KEEP = "--keep" in args
TMP = tempfile.mkdtemp(prefix="frostvdb_docs_")


def setup(run=True):
    addon_utils.enable("frostvdb_blender", default_set=True, handle_error=None)
    scene = bpy.context.scene
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob, do_unlink=True)
    scene.frame_start, scene.frame_end = 1, 4
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(TMP, "frost_demo.blend"))
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=3, radius=1.0)
    ball = bpy.context.active_object
    ball.name = "Ball"
    attr = ball.data.color_attributes.new("seeds", 'FLOAT_COLOR', 'POINT')
    targets = [mathutils.Vector(t) for t in ((0.6, -0.6, 0.53), (-0.7, -0.7, 0.1), (0.2, -0.3, -0.93))]
    for v in ball.data.vertices:
        hot = any((v.co - t).length < 0.25 for t in targets)
        attr.data[v.index].color = (1, 1, 1, 1) if hot else (0, 0, 0, 1)
    st = ball.frostvdb
    st.preset = "FROST"
    st.seed_attribute = "seeds"
    st.nucleation = 3
    t0 = time.monotonic()
    result = bpy.ops.frostvdb.estimate()
    print("estimate:", result, st.last_estimate, "%.1f s" % (time.monotonic() - t0))
    if run:
        t0 = time.monotonic()
        result = bpy.ops.frostvdb.run(synchronous=True, estimate_first=False)
        print("frostvdb run through the add-on: %s in %.1f s" % (result, time.monotonic() - t0))
        scene.frame_set(scene.frame_end)
    return ball


def stage(ball):
    scene = bpy.context.scene
    mat = bpy.data.materials.new("dark glass")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.05, 0.07, 0.1, 1)
    bsdf.inputs["Roughness"].default_value = 0.3
    ball.data.materials.append(mat)
    bpy.ops.object.shade_smooth()
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.location = (1.2, -4.6, 1.8)
    cam.rotation_euler = (mathutils.Vector((0, 0, 0)) - cam.location).to_track_quat('-Z', 'Y').to_euler()
    cam.data.lens = 50
    scene.camera = cam
    for name, loc, energy in (("key", (3, -3, 4), 400.0), ("rim", (-3, 2, 2), 200.0)):
        light = bpy.data.objects.new(name, bpy.data.lights.new(name, 'AREA'))
        light.data.energy = energy
        light.data.size = 2.0
        light.location = loc
        light.rotation_euler = (mathutils.Vector((0, 0, 0)) - light.location).to_track_quat('-Z', 'Y').to_euler()
        scene.collection.objects.link(light)
    world = bpy.data.worlds.new("w")
    world.color = (0.015, 0.02, 0.03)
    scene.world = world


def render():
    ball = setup()
    stage(ball)
    scene = bpy.context.scene
    scene.render.engine = 'CYCLES'
    scene.cycles.samples = SAMPLES
    scene.cycles.use_denoising = False  # Debian's Blender 3.4 has no denoiser
    scene.cycles.device = 'CPU'
    scene.render.resolution_x, scene.render.resolution_y = 640, 480
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = 'PNG'
    scene.render.filepath = OUT
    t0 = time.monotonic()
    bpy.ops.render.render(write_still=True)
    print("render %dx%d, %d samples: %.1f s -> %s" % (640, 480, SAMPLES, time.monotonic() - t0, OUT))


def panel():
    """The modal operator in the real UI: started as a click would, the screenshot taken while
    the progress bar runs, then Blender waits for the run to finish and quits."""
    import frostvdb_blender
    ball = setup(run=False)
    ball.frostvdb.voxel_size = 0.04
    ball.frostvdb.steps = 150  # long enough to catch the progress bar
    win = bpy.context.window_manager.windows[0]
    screen = win.screen
    props = max((a for a in screen.areas if a.type == 'PROPERTIES'), key=lambda a: a.height)
    props.spaces[0].context = 'OBJECT'
    view = max((a for a in screen.areas if a.type == 'VIEW_3D'), key=lambda a: a.width * a.height)
    region = [r for r in view.regions if r.type == 'WINDOW'][0]
    # A wider Properties editor (its left edge dragged 330 px to the left), scrolled down to the
    # frostvdb panel at the end of the Object tab.
    pregion = [r for r in props.regions if r.type == 'WINDOW'][0]
    try:
        with bpy.context.temp_override(window=win, screen=screen, area=props, region=pregion):
            bpy.ops.screen.area_move(x=props.x, y=props.y + props.height // 2, delta=-330)
    except RuntimeError as e:
        print("could not widen the Properties editor:", e)
    with bpy.context.temp_override(window=win, area=props, region=pregion):
        for _ in range(3):
            bpy.ops.view2d.scroll_down(deltax=0, deltay=0, page=True)
    with bpy.context.temp_override(window=win, area=view, region=region):
        bpy.ops.view3d.view_selected()
        bpy.ops.frostvdb.run('INVOKE_DEFAULT')
    t0 = time.monotonic()
    state = {"shot": False}

    def tick():
        run = frostvdb_blender._active.get(ball.name)
        if not state["shot"] and (run is None or run.fraction > 0.35):
            for a in screen.areas:
                a.tag_redraw()
            with bpy.context.temp_override(window=win, screen=screen):
                bpy.ops.screen.screenshot(filepath=OUT)
            print("screenshot at %.0f%% -> %s" % (100 * (run.fraction if run else 1), OUT))
            state["shot"] = True
        if run is None or time.monotonic() - t0 > 600:
            print("modal run ended after %.1f s; volume objects: %s" % (
                time.monotonic() - t0, [o.name for o in bpy.data.objects if o.type == 'VOLUME']))
            bpy.ops.wm.quit_blender()
            return None
        return 0.3

    bpy.app.timers.register(tick, first_interval=1.0)


try:
    if MODE == "render":
        render()
    elif MODE == "panel":
        bpy.app.timers.register(lambda: (panel(), None)[1], first_interval=1.0)
    else:
        raise SystemExit("mode must be render or panel")
finally:
    if MODE == "render" and not KEEP:
        shutil.rmtree(TMP, ignore_errors=True)
