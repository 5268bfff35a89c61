"""Blender side of the data: the evaluated mesh in world space with its seed and melt weights, and
the Volume object that loads a frostvdb sequence (material, parenting, replacement)."""

import os

import bpy

from . import engine

VOLUME_TAG = "frostvdb_source"  # custom property on the Volume object: the source object's name


def _attribute_weights(obj, mesh, name):
    """Per-vertex weights in [0,1] from a colour attribute (luminance; point or corner domain) or
    a vertex group called @a name on @a obj. None when @a name is empty; raises ValueError
    naming the attribute when it is missing."""
    if not name:
        return None
    n = len(mesh.vertices)
    attrs = getattr(mesh, "color_attributes", None)
    if attrs is not None and name in attrs:
        a = attrs[name]
        lum = lambda c: 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
        if a.domain == 'POINT':
            return [lum(a.data[i].color) for i in range(n)]
        if a.domain == 'CORNER':
            acc, cnt = [0.0] * n, [0] * n
            for loop in mesh.loops:
                acc[loop.vertex_index] += lum(a.data[loop.index].color)
                cnt[loop.vertex_index] += 1
            return [acc[i] / cnt[i] if cnt[i] else 0.0 for i in range(n)]
        raise ValueError("colour attribute '%s' is on the %s domain; use a point or face-corner colour"
                         % (name, a.domain.lower()))
    group = obj.vertex_groups.get(name)
    if group is not None:
        w = [0.0] * n
        for v in mesh.vertices:
            for g in v.groups:
                if g.group == group.index:
                    w[v.index] = g.weight
        return w
    raise ValueError("object '%s' has no colour attribute or vertex group '%s'" % (obj.name, name))


def evaluated_mesh(context, obj, seed_attr="", melt_attr=""):
    """The object's evaluated mesh (modifiers applied) in world space, triangulated:
    {verts, tris, normals, seed_weights, melt_weights}."""
    depsgraph = context.evaluated_depsgraph_get()
    eval_obj = obj.evaluated_get(depsgraph)
    mesh = eval_obj.to_mesh()
    try:
        mw = obj.matrix_world
        verts = [tuple(mw @ v.co) for v in mesh.vertices]
        normal_matrix = mw.to_3x3().inverted_safe().transposed()
        normals = []
        for v in mesh.vertices:
            n = normal_matrix @ v.normal
            n.normalize()
            normals.append(tuple(n))
        mesh.calc_loop_triangles()
        tris = [tuple(t.vertices) for t in mesh.loop_triangles]
        seed = _attribute_weights(obj, mesh, seed_attr)
        melt = _attribute_weights(obj, mesh, melt_attr)
    finally:
        eval_obj.to_mesh_clear()
    if not tris:
        raise ValueError("object '%s' has no faces to frost" % obj.name)
    return {"verts": verts, "tris": tris, "normals": normals, "seed_weights": seed, "melt_weights": melt}


def choose_seeds(mesh, count, seed):
    """Nucleation sites [(point, normal)]: up to @a count spread-out vertices whose seed weight
    exceeds 1/2, or @a count points scattered by area when there are no seed weights."""
    if mesh["seed_weights"] is not None:
        cands = [(mesh["verts"][i], mesh["normals"][i]) for i, w in enumerate(mesh["seed_weights"]) if w > 0.5]
        if not cands:
            raise ValueError("the seed attribute is below 1/2 everywhere: paint some seeds, or clear it to scatter")
        return engine.farthest_points(cands, count)
    return engine.scatter_points(mesh["verts"], mesh["tris"], count, seed)


# ---------------------------------------------------------------------------------------------
# Volume object

def _socket(node, *names):
    for n in names:
        if n in node.inputs:
            return node.inputs[n]
    return None


def build_material(name, preset, voxel_size, look_grid=None):
    """A material for the preset: frost/crystals read `ice`, feathers `aggregate_ice` ([dla3d]'s
    own name) as density (white, slightly blue, scattering; an optical depth of about 1.5 per
    voxel, so the look does not depend on the object's size); steam reads density, temperature
    (blackbody) and flame (emission)."""
    if look_grid is None:
        look_grid = "aggregate_ice" if preset == "FEATHERS" else "ice"
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    out.location = (300, 0)
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    pv.location = (0, 0)
    nt.links.new(pv.outputs[0], out.inputs["Volume"])
    if preset == "STEAM":
        pv.inputs["Density Attribute"].default_value = "density"
        pv.inputs["Temperature Attribute"].default_value = "temperature"
        pv.inputs["Color"].default_value = (0.9, 0.92, 0.95, 1.0)
        pv.inputs["Density"].default_value = 1.0
        pv.inputs["Anisotropy"].default_value = 0.3
        flame = nt.nodes.new("ShaderNodeAttribute")
        flame.location = (-300, -250)
        flame.attribute_name = "flame"
        nt.links.new(flame.outputs["Fac"], pv.inputs["Emission Strength"])
        pv.inputs["Emission Color"].default_value = (1.0, 0.45, 0.1, 1.0)
    else:
        pv.inputs["Density Attribute"].default_value = look_grid
        pv.inputs["Density"].default_value = 1.5 / max(voxel_size, 1e-9)
        pv.inputs["Color"].default_value = (0.85, 0.93, 1.0, 1.0)
        pv.inputs["Absorption Color"].default_value = (0.6, 0.8, 1.0, 1.0)
        pv.inputs["Anisotropy"].default_value = 0.2
    mat["frostvdb_preset"] = preset
    return mat


def remove_previous(source, preset):
    """Removes the Volume objects (and their volume data) an earlier run of @a preset made for
    @a source (another preset's result stays: steam and frost on one object)."""
    for ob in list(bpy.data.objects):
        if ob.get(VOLUME_TAG) == source.name and ob.get("frostvdb_preset") == preset and ob.type == 'VOLUME':
            data = ob.data
            bpy.data.objects.remove(ob, do_unlink=True)
            if data is not None and data.users == 0:
                bpy.data.volumes.remove(data)


def import_sequence(context, source, files, preset, start_frame, name, voxel_size):
    """A Volume object reading the frame sequence @a files (sorted), starting at @a start_frame,
    parented to @a source without moving (the grids are in world metres), with the preset's
    material. Replaces the one of an earlier run."""
    remove_previous(source, preset)
    vol = bpy.data.volumes.new(name)
    vol.filepath = bpy.path.relpath(files[0]) if bpy.data.filepath else files[0]
    vol.is_sequence = len(files) > 1
    vol.frame_start = start_frame
    vol.frame_duration = len(files)
    vol.frame_offset = 0
    vol.sequence_mode = 'CLIP'
    if preset == "STEAM":
        vol.display.density = 1.0
    ob = bpy.data.objects.new(name, vol)
    ob[VOLUME_TAG] = source.name
    ob["frostvdb_preset"] = preset
    coll = source.users_collection[0] if source.users_collection else context.scene.collection
    coll.objects.link(ob)
    ob.parent = source
    ob.matrix_parent_inverse = source.matrix_world.inverted()
    mat = build_material(name + "_material", preset, voxel_size)
    vol.materials.append(mat)
    return ob


def grids_at_frame(ob, frame):
    """Names of the grids the Volume object @a ob reads at scene frame @a frame."""
    scene = bpy.context.scene
    scene.frame_set(frame)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ev = ob.evaluated_get(depsgraph)
    ev.data.grids.load()
    return [g.name for g in ev.data.grids], ev.data.grids.frame_filepath


def out_paths(context, obj, preset):
    """(folder, scene TOML, PLY, output folder, scene name) beside the .blend: //frostvdb/ (or
    Blender's temporary folder for an unsaved file)."""
    if bpy.data.filepath:
        folder = os.path.join(os.path.dirname(bpy.path.abspath(bpy.data.filepath)), "frostvdb")
    else:
        folder = os.path.join(bpy.app.tempdir or "/tmp", "frostvdb")
    safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in obj.name)
    name = "%s_%s" % (safe, preset.lower())
    return (folder, os.path.join(folder, name + ".toml"), os.path.join(folder, name + ".ply"),
            os.path.join(folder, name), name)
