#!/usr/bin/env python3
"""Writes the meshes of the shell scenes into scenes/meshes/ (plain Python, no deps).

  python3 scripts/make_shell_meshes.py

pint_glass.obj   a tapered pint glass, 0.15 m high, radius 0.030 m at the base and 0.043 m at the
                 rim: one open surface (wall + base disc), normals outward, the rim its only border
windshield.obj   a car windshield panel 1.4 x 0.8 m, curved (0.06 m sag across, 0.03 m along), open,
                 normals toward +z (outside the car)
pint_glass_mapped.obj  the pint glass with UVs (u around, v up the wall; a seam column) and vertex
                 colours: white at 16 points around the foot of the wall (seed sites), black elsewhere
pint_label_melt.png  a melt texture for it: black (no frost) on a label, u 0.30-0.70, v 0.40-0.75
ornament.obj     a closed Christmas ornament: a 40 mm sphere, a 8 mm cap and a wire loop (torus of
                 1.5 mm tube radius: curvature radii of a few mm)
"""
import math
import os
import struct
import zlib

# the OBJ writer of the dla3d meshes (same folder, same format)
from make_dla3d_meshes import HERE, write_obj  # noqa: E402


def pint_glass(segments=96, rows=60, rings=8):
    h, r0, r1 = 0.15, 0.030, 0.043
    verts, faces = [], []
    # wall: rows + 1 rings of vertices from the base (z = 0) to the rim (z = h)
    for j in range(rows + 1):
        z = h * j / rows
        r = r0 + (r1 - r0) * j / rows
        for i in range(segments):
            a = 2 * math.pi * i / segments
            verts.append((r * math.cos(a), r * math.sin(a), z))
    for j in range(rows):
        for i in range(segments):
            a = j * segments + i
            b = j * segments + (i + 1) % segments
            c, d = a + segments, b + segments
            faces += [(a, b, d), (a, d, c)]  # outward (counter-clockwise seen from outside)
    # base disc: concentric rings down to the centre, joined to the wall's lowest ring
    prev = list(range(segments))  # ring at radius r0
    for k in range(rings - 1, 0, -1):
        r = r0 * k / rings
        ring = []
        for i in range(segments):
            a = 2 * math.pi * i / segments
            verts.append((r * math.cos(a), r * math.sin(a), 0.0))
            ring.append(len(verts) - 1)
        for i in range(segments):
            a, b = prev[i], prev[(i + 1) % segments]
            c, d = ring[i], ring[(i + 1) % segments]
            faces += [(a, c, d), (a, d, b)]  # normal -z (outward below the glass)
        prev = ring
    verts.append((0.0, 0.0, 0.0))
    centre = len(verts) - 1
    for i in range(segments):
        faces.append((prev[i], centre, prev[(i + 1) % segments]))
    return verts, faces


def windshield(nx=56, ny=32):
    w, hh, sag_x, sag_y = 1.4, 0.8, 0.06, 0.03
    verts, faces = [], []
    for j in range(ny + 1):
        for i in range(nx + 1):
            u, v = i / nx - 0.5, j / ny - 0.5
            z = -sag_x * (4 * u * u) - sag_y * (4 * v * v)  # bulges toward +z at the centre
            verts.append((w * u, hh * v, z))
    for j in range(ny):
        for i in range(nx):
            a = j * (nx + 1) + i
            b, c = a + 1, a + nx + 1
            d = c + 1
            faces += [(a, b, d), (a, d, c)]
    return verts, faces


def pint_glass_mapped(segments=96, rows=60, rings=8, sites=16):
    """The pint glass with a UV seam column and per-vertex colours (OBJ 'v x y z r g b')."""
    h, r0, r1 = 0.15, 0.030, 0.043
    verts, uvs, cols, faces = [], [], [], []
    for j in range(rows + 1):
        z = h * j / rows
        r = r0 + (r1 - r0) * j / rows
        for i in range(segments + 1):  # the seam column i = segments repeats i = 0 with u = 1
            a = 2 * math.pi * i / segments
            verts.append((r * math.cos(a), r * math.sin(a), z))
            uvs.append((i / segments, j / rows))
            bright = j == 0 and (i % (segments // sites)) == 0
            cols.append((1.0, 1.0, 1.0) if bright else (0.0, 0.0, 0.0))
    row = segments + 1
    for j in range(rows):
        for i in range(segments):
            a = j * row + i
            b, c = a + 1, a + row
            d = c + 1
            faces += [(a, b, d), (a, d, c)]
    # the base disc (UV 0.5, 0: no texture reaches it), joined to the wall's lowest ring
    prev = list(range(segments)) + [0]
    for k in range(rings - 1, 0, -1):
        r = r0 * k / rings
        ring = []
        for i in range(segments):
            a = 2 * math.pi * i / segments
            verts.append((r * math.cos(a), r * math.sin(a), 0.0))
            uvs.append((0.5, 0.0))
            cols.append((0.0, 0.0, 0.0))
            ring.append(len(verts) - 1)
        ring.append(ring[0])
        for i in range(segments):
            a, b = prev[i], prev[i + 1]
            c, d = ring[i], ring[i + 1]
            faces += [(a, c, d), (a, d, b)]
        prev = ring
    verts.append((0.0, 0.0, 0.0))
    uvs.append((0.5, 0.0))
    cols.append((0.0, 0.0, 0.0))
    centre = len(verts) - 1
    for i in range(segments):
        faces.append((prev[i], centre, prev[i + 1]))
    return verts, uvs, cols, faces


def write_obj_mapped(name, verts, uvs, cols, faces, comment):
    """An OBJ with vertex colours (v x y z r g b, read by Assimp) and one UV per vertex."""
    with open(os.path.join(HERE, name), "w") as f:
        f.write("# %s\n# generated by scripts/make_shell_meshes.py\n" % comment)
        for (x, y, z), (r, g, b) in zip(verts, cols):
            f.write("v %.6f %.6f %.6f %.3f %.3f %.3f\n" % (x, y, z, r, g, b))
        for u, v in uvs:
            f.write("vt %.6f %.6f\n" % (u, v))
        for a, b, c in faces:
            f.write("f %d/%d %d/%d %d/%d\n" % (a + 1, a + 1, b + 1, b + 1, c + 1, c + 1))


def write_png_gray(name, width, height, value):
    """An 8-bit grey PNG; value(u, v) in [0, 1] with v = 1 at the top row (the UV convention)."""
    raw = b""
    for y in range(height):
        v = 1.0 - (y + 0.5) / height
        raw += b"\x00" + bytes(int(round(255 * value((x + 0.5) / width, v))) for x in range(width))
    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(os.path.join(HERE, name), "wb") as f:
        f.write(png)


def ornament(n_lat=48, n_lon=96):
    """A closed ornament: UV sphere (R 40 mm), a closed cylinder cap and a torus loop on top."""
    verts, faces = [], []

    def sphere(R, cz):
        nonlocal faces
        base = len(verts)
        verts.append((0.0, 0.0, cz + R))
        for j in range(1, n_lat):
            t = math.pi * j / n_lat
            for i in range(n_lon):
                a = 2 * math.pi * i / n_lon
                verts.append((R * math.sin(t) * math.cos(a), R * math.sin(t) * math.sin(a), cz + R * math.cos(t)))
        verts.append((0.0, 0.0, cz - R))
        top, bottom = base, len(verts) - 1
        ring = lambda j, i: base + 1 + (j - 1) * n_lon + (i % n_lon)
        for i in range(n_lon):
            faces.append((top, ring(1, i), ring(1, i + 1)))
            faces.append((bottom, ring(n_lat - 1, i + 1), ring(n_lat - 1, i)))
        for j in range(1, n_lat - 1):
            for i in range(n_lon):
                a, b, c, d = ring(j, i), ring(j, i + 1), ring(j + 1, i), ring(j + 1, i + 1)
                faces += [(a, c, d), (a, d, b)]

    def cylinder(r, z0, z1, n=48):
        nonlocal faces
        base = len(verts)
        for z in (z0, z1):
            for i in range(n):
                a = 2 * math.pi * i / n
                verts.append((r * math.cos(a), r * math.sin(a), z))
        verts.append((0.0, 0.0, z0))
        verts.append((0.0, 0.0, z1))
        c0, c1 = len(verts) - 2, len(verts) - 1
        for i in range(n):
            a, b = base + i, base + (i + 1) % n
            c, d = a + n, b + n
            faces += [(a, b, d), (a, d, c), (c0, b, a), (c1, c, d)]

    def torus(R, r, cz, n_u=64, n_v=24):
        nonlocal faces
        base = len(verts)
        for i in range(n_u):  # the loop stands in the xz plane
            u = 2 * math.pi * i / n_u
            for j in range(n_v):
                v = 2 * math.pi * j / n_v
                x = (R + r * math.cos(v)) * math.cos(u)
                z = (R + r * math.cos(v)) * math.sin(u)
                y = r * math.sin(v)
                verts.append((x, y, cz + z))
        idx = lambda i, j: base + (i % n_u) * n_v + (j % n_v)
        for i in range(n_u):
            for j in range(n_v):
                a, b, c, d = idx(i, j), idx(i + 1, j), idx(i, j + 1), idx(i + 1, j + 1)
                faces += [(a, b, d), (a, d, c)]

    sphere(0.040, 0.0)
    cylinder(0.008, 0.036, 0.048)
    torus(0.006, 0.0015, 0.0535)
    return verts, faces


if __name__ == "__main__":
    os.makedirs(HERE, exist_ok=True)
    v, f = pint_glass()
    write_obj("pint_glass.obj", v, f, "pint glass: open wall + base, normals outward, rim is the only border")
    v, f = windshield()
    write_obj("windshield.obj", v, f, "windshield panel 1.4 x 0.8 m, curved, open, normals +z")
    v, t, c, f = pint_glass_mapped()
    write_obj_mapped("pint_glass_mapped.obj", v, t, c, f,
                     "pint glass with UVs and vertex colours (white: 16 seed sites at the foot of the wall)")
    write_png_gray("pint_label_melt.png", 256, 128,
                   lambda u, v: 0.0 if 0.30 <= u <= 0.70 and 0.40 <= v <= 0.75 else 1.0)
    v, f = ornament()
    write_obj("ornament.obj", v, f, "closed ornament: 40 mm sphere, cap, wire loop (1.5 mm tube)")
