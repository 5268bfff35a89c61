#!/usr/bin/env python3
"""Writes the meshes of the shell scenes into scenes/meshes/ (plain Python, no deps).

  python3 scripts/make_shell_meshes.py

pint_glass.obj   a tapered pint glass, 0.15 m high, radius 0.030 m at the base and 0.043 m at the
                 rim: one open surface (wall + base disc), normals outward, the rim its only border
windshield.obj   a car windshield panel 1.4 x 0.8 m, curved (0.06 m sag across, 0.03 m along), open,
                 normals toward +z (outside the car)
"""
import math
import os

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


if __name__ == "__main__":
    os.makedirs(HERE, exist_ok=True)
    v, f = pint_glass()
    write_obj("pint_glass.obj", v, f, "pint glass: open wall + base, normals outward, rim is the only border")
    v, f = windshield()
    write_obj("windshield.obj", v, f, "windshield panel 1.4 x 0.8 m, curved, open, normals +z")
