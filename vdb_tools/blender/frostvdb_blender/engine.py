"""The parts of the add-on that do not need Blender: finding the frostvdb binary, writing scene
TOML for the presets, choosing seeds, writing PLY, and running `frostvdb run --progress json`
as a background process that can be polled and cancelled.

A run writes into a staging folder (<out>.running) and only a complete run replaces <out>, so
a cancelled or failed run leaves neither partial frames nor temporary files, and the previous
result stays as it was.
"""

import json
import math
import os
import queue
import random
import shutil
import signal
import struct
import subprocess
import threading
import time

PRESETS = ("FROST", "CRYSTALS", "FEATHERS", "STEAM")


# ---------------------------------------------------------------------------------------------
# The binary

def repository_binary():
    """build/bin/frostvdb of the repository this add-on lives in (vdb_tools/blender/<pkg>)."""
    here = os.path.dirname(os.path.realpath(__file__))  # through a linked add-on folder
    root = os.path.normpath(os.path.join(here, "..", "..", ".."))
    return os.path.join(root, "build", "bin", "frostvdb")


def find_binary(preference=""):
    """The preference when set, else the repository's build/bin/frostvdb, else `frostvdb` on PATH.
    Returns (path, None) or (None, one-line reason)."""
    if preference:
        path = os.path.abspath(os.path.expanduser(preference))
        if os.path.isfile(path) and os.access(path, os.X_OK):
            return path, None
        return None, "frostvdb binary '%s' (add-on preference) is not an executable file" % preference
    candidate = repository_binary()
    if os.path.isfile(candidate) and os.access(candidate, os.X_OK):
        return candidate, None
    found = shutil.which("frostvdb")
    if found:
        return found, None
    return None, ("frostvdb not found: build it (scripts/bootstrap.sh) or set its path in the add-on's "
                  "preferences (looked in %s and on PATH)" % candidate)


# ---------------------------------------------------------------------------------------------
# Geometry helpers (plain lists of tuples)

def bounds(verts):
    lo = [min(v[i] for v in verts) for i in range(3)]
    hi = [max(v[i] for v in verts) for i in range(3)]
    return lo, hi


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _norm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def surface_area(verts, tris):
    return sum(0.5 * _norm(_cross(_sub(verts[b], verts[a]), _sub(verts[c], verts[a]))) for a, b, c in tris)


def scatter_points(verts, tris, count, seed):
    """@a count points uniformly by area on the triangles, the same for the same seed; each with
    its triangle's unit normal: [(point, normal)]."""
    rng = random.Random(seed)
    areas, normals = [], []
    for a, b, c in tris:
        n = _cross(_sub(verts[b], verts[a]), _sub(verts[c], verts[a]))
        length = _norm(n)
        areas.append(0.5 * length)
        normals.append((n[0] / length, n[1] / length, n[2] / length) if length > 0 else (0.0, 0.0, 1.0))
    total = sum(areas)
    if total <= 0 or count <= 0:
        return []
    cumulative, acc = [], 0.0
    for a in areas:
        acc += a
        cumulative.append(acc)
    out = []
    import bisect
    for _ in range(count):
        t = min(bisect.bisect_left(cumulative, rng.random() * total), len(tris) - 1)
        a, b, c = (verts[i] for i in tris[t])
        r1, r2 = rng.random(), rng.random()
        s = math.sqrt(r1)
        u, v, w = 1 - s, s * (1 - r2), s * r2
        out.append((tuple(u * a[i] + v * b[i] + w * c[i] for i in range(3)), normals[t]))
    return out


def farthest_points(points, count):
    """Up to @a count of @a points, spread out: the first, then each time the one farthest from
    those chosen (deterministic)."""
    if len(points) <= count:
        return list(points)
    chosen = [points[0]]
    dist = [_norm(_sub(p[0], points[0][0])) for p in points]
    while len(chosen) < count:
        i = max(range(len(points)), key=lambda k: dist[k])
        chosen.append(points[i])
        for k, p in enumerate(points):
            dist[k] = min(dist[k], _norm(_sub(p[0], points[i][0])))
    return chosen


# ---------------------------------------------------------------------------------------------
# PLY

def write_ply(path, verts, tris, grey=None):
    """Binary little-endian PLY: float x y z, optional uchar red green blue (grey levels in [0,1],
    one per vertex), int vertex_indices. Written to a temporary name and renamed."""
    tmp = path + ".tmp%d" % os.getpid()
    with open(tmp, "wb") as f:
        header = ["ply", "format binary_little_endian 1.0", "comment frostvdb Blender add-on",
                  "element vertex %d" % len(verts), "property float x", "property float y", "property float z"]
        if grey is not None:
            header += ["property uchar red", "property uchar green", "property uchar blue"]
        header += ["element face %d" % len(tris), "property list uchar int vertex_indices", "end_header"]
        f.write(("\n".join(header) + "\n").encode("ascii"))
        if grey is None:
            f.write(b"".join(struct.pack("<3f", *v) for v in verts))
        else:
            rows = []
            for v, g in zip(verts, grey):
                c = max(0, min(255, int(round(g * 255.0))))
                rows.append(struct.pack("<3f3B", v[0], v[1], v[2], c, c, c))
            f.write(b"".join(rows))
        f.write(b"".join(struct.pack("<B3i", 3, a, b, c) for a, b, c in tris))
    os.replace(tmp, path)


# ---------------------------------------------------------------------------------------------
# Scenes

def _vec(v, digits=6):
    return "[" + ", ".join(("%.*g" % (digits + 3, float(x))) for x in v) + "]"


def _num(x):
    return "%.9g" % float(x)


def auto_voxel_size(preset, size):
    """A voxel size that makes a preset run in seconds for an object whose largest side is
    @a size metres (OpenVDB needs at least about 1.6e-5 m)."""
    div = {"FROST": 64.0, "CRYSTALS": 64.0, "FEATHERS": 160.0, "STEAM": 48.0}[preset]
    return max(2e-5, size / div)


def build_scene(preset, s, mesh):
    """Scene TOML for @a preset. @a s: a dict of settings (name, frames, steps, seed, voxel_size,
    nucleation, particles, wind, precision, compression, melt, mesh_file, ply_name); @a mesh: a
    dict with verts, tris, seeds [(point, normal)] (world metres). Returns the text."""
    verts, tris = mesh["verts"], mesh["tris"]
    lo, hi = bounds(verts)
    size = max(hi[i] - lo[i] for i in range(3))
    if size <= 0:
        raise ValueError("the object has no extent")
    vs = s["voxel_size"] if s["voxel_size"] > 0 else auto_voxel_size(preset, size)
    s["voxel_size_used"] = vs
    wind = s["wind"]
    lines = ["# Written by the frostvdb Blender add-on (preset %s) for object '%s'." % (preset.lower(), s["object"]),
             "# Reproduce from a shell or a farm:",
             "#   frostvdb run %s --out %s" % (s["scene_file"], s["out_name"]),
             "",
             "[scene]",
             'name = "%s"' % s["name"],
             "frames = %d" % s["frames"],
             "steps_per_frame = %d" % (1 if preset == "STEAM" else s["steps"]),
             "seed = %d" % s["seed"],
             "",
             "[output]",
             'preview = "none"',
             'precision = "%s"' % s["precision"],
             'compression = "%s"' % s["compression"],
             ""]
    if preset in ("FROST", "CRYSTALS"):
        cells = surface_area(verts, tris) / (vs * vs)
        lines += ["[domain]",
                  'kind = "shell"',
                  "voxel_size = %s      # %s" % (_num(vs), "auto: the object's largest side / 64" if s["voxel_size"] <= 0 else "set in Blender"),
                  'mesh = "%s"' % s["ply_name"],
                  "crystal_axis = [0, 0, 1]",
                  'vertex_colours = "%s"' % ("melt" if s["melt"] else "none"),
                  "",
                  "[phase_field]",
                  'scheme = "euler"',
                  "dt = 0.0002",
                  "latent_heat = 2.0",
                  "noise = %s" % ("0.01" if preset == "CRYSTALS" else "0"),
                  "wind = %s" % _vec(wind),
                  'wind_model = "uniform"',
                  ""]
        if preset == "FROST":
            # shell_sphere_walkers.toml: 10 walkers a step on a 32-voxel sphere (about 12 900 surface
            # cells); the same density of walkers on this surface.
            humidity = max(1, int(round(10.0 * cells / 12868.0)))
            lines += ["[dla]",
                      "humidity = %d         # walkers per step over the surface (%d surface cells)" % (humidity, cells),
                      "max_steps = 300",
                      "hits = 1",
                      "flow_drift = 1.0",
                      ""]
        for p, _n in mesh["seeds"]:
            lines += ["[[crystal.seed]]", 'shape = "point"', 'space = "world"', "position = %s" % _vec(p), "radius = 3", ""]
    elif preset == "FEATHERS":
        r = vs
        seeds = []
        for p, n in mesh["seeds"]:
            seeds += [p[i] + 1.5 * r * n[i] for i in range(3)]
        lines += ["[dla3d]",
                  "particles = %d" % s["particles"],
                  "radius = %s           # particle radius = voxel size" % _num(r),
                  "stick_distance = %s" % _num(0.75 * r),
                  "seeds = %s" % _vec(seeds),
                  'launch = "surface"',
                  "launch_offset = %s" % _num(0.06 * size),
                  'constraint_mesh = "%s"' % s["ply_name"],
                  "bias = %s" % _vec(wind),
                  "kill_factor = 2.0",
                  "voxel_size = %s" % _num(0.9 * r),
                  "branch_radius = %s" % _num(0.75 * r),
                  "taper = 0.25",
                  "max_thickness = 2.5",
                  "write_points = false",
                  ""]
    elif preset == "STEAM":
        cx, cy = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])
        radius = 0.5 * max(hi[0] - lo[0], hi[1] - lo[1])
        if radius <= 0:
            radius = 0.5 * size
        k = radius / 0.04  # gas_teacup.toml is a 4 cm cup: its lengths scaled to this object
        vs = s["voxel_size"] if s["voxel_size"] > 0 else max(2e-5, radius / 40.0)  # gas_teacup: 1 mm for 4 cm
        s["voxel_size_used"] = vs
        lines += ["[domain]",
                  'kind = "box"',
                  "size = [8, 8, 8]        # the gas has its own box; the domain gives the voxel size",
                  "voxel_size = %s" % _num(vs),
                  "",
                  "[steam]",
                  "center = %s" % _vec((cx, cy, hi[2])),
                  "radius = %s" % _num(radius),
                  "height = %s" % _num(4.0 * radius),
                  "noise_scale = %s" % _num(0.02 * k),
                  "density_scale = 40        # as gas_teacup.toml: dense enough to read at any cup size",
                  "rise_speed = %s" % _num(0.04 * k),
                  "swirl_radius = %s" % _vec((0.01 * k, 0.008 * k)),
                  "path_noise = %s" % _num(0.004 * k),
                  "turbulence_growth = %s" % _num(0.012 * k),
                  "growth_height = %s" % _num(0.12 * k),
                  "wind = %s" % _vec(wind),
                  "seed = %d" % s["seed"],
                  ""]
    else:
        raise ValueError("unknown preset " + preset)
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# Running frostvdb

def staging_dir(out_dir):
    return out_dir.rstrip("/\\") + ".running"


def run_estimate(binary, scene_path, seconds=0.5, timeout=120):
    """`frostvdb run SCENE --estimate=SECONDS --progress json`: (dict, None) or (None, error line)."""
    try:
        p = subprocess.run([binary, "run", scene_path, "--estimate=%g" % seconds, "--progress", "json"],
                           capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as e:
        return None, "frostvdb --estimate: %s" % e
    if p.returncode != 0:
        return None, error_line(p.stderr) or ("frostvdb --estimate failed with exit code %d" % p.returncode)
    for line in p.stdout.splitlines():
        line = line.strip()
        if line.startswith("{"):
            try:
                return json.loads(line), None
            except ValueError:
                pass
    return None, "frostvdb --estimate printed no estimate"


def error_line(stderr_text):
    """The first one-line error frostvdb printed (JSON error events first)."""
    plain = None
    for line in stderr_text.splitlines():
        line = line.strip()
        if line.startswith("{"):
            try:
                ev = json.loads(line)
            except ValueError:
                continue
            if ev.get("event") == "error":
                return ev.get("message", "")
        elif line.startswith("frostvdb:") and plain is None and "removed" not in line:
            plain = line
    return plain


def format_estimate(est):
    """One line: time, the effects' memory estimate and the resident memory the probe measured."""
    mib = 1.0 / (1024.0 * 1024.0)
    return "about %.0f s for %d steps, %d frames; memory %.0f MiB estimated, %.0f MiB measured" % (
        est.get("seconds", 0), est.get("steps", 0), est.get("frames", 0), est.get("memory_bytes", 0) * mib,
        est.get("peak_rss_bytes", 0) * mib)


class Run:
    """One `frostvdb run` in the background. start(), then poll() until it returns a final state
    ("done", "failed"); cancel() at any time. Progress: fraction, message."""

    def __init__(self, binary, scene_path, out_dir, extra_args=()):
        self.binary = binary
        self.scene_path = scene_path
        self.out_dir = out_dir
        self.staging = staging_dir(out_dir)
        self.extra_args = list(extra_args)
        self.proc = None
        self.state = "new"
        self.fraction = 0.0
        self.message = ""
        self.error = None
        self.frames_written = 0
        self.frames = 0
        self.files = []
        self.cancel_requested = False  # set by the UI's Cancel button; the modal operator acts on it
        self._lines = queue.Queue()
        self._stderr_tail = []
        self._threads = []

    @property
    def pid(self):
        return self.proc.pid if self.proc else None

    def start(self):
        shutil.rmtree(self.staging, ignore_errors=True)
        cmd = [self.binary, "run", self.scene_path, "--out", self.staging, "--progress", "json"] + self.extra_args
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                                     text=True, bufsize=1, start_new_session=True)
        self.state = "running"
        self.message = "starting"
        for stream, tag in ((self.proc.stdout, "out"), (self.proc.stderr, "err")):
            t = threading.Thread(target=self._pump, args=(stream, tag), daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def _pump(self, stream, tag):
        try:
            for line in stream:
                self._lines.put((tag, line.rstrip("\n")))
        except (ValueError, OSError):
            pass

    def _take_lines(self):
        while True:
            try:
                tag, line = self._lines.get_nowait()
            except queue.Empty:
                return
            if tag != "err":
                continue
            if not line.startswith("{"):
                self._stderr_tail = (self._stderr_tail + [line])[-20:]
                continue
            try:
                ev = json.loads(line)
            except ValueError:
                continue
            kind = ev.get("event")
            if kind == "progress":
                steps = max(1, int(ev.get("steps", 1)))
                self.fraction = min(1.0, float(ev.get("step", 0)) / steps)
                self.frames = int(ev.get("frames", 0))
                eta = ev.get("eta", -1)
                self.message = "frame %d/%d, step %d/%d%s" % (ev.get("frame", 0), self.frames, ev.get("step", 0),
                                                              steps, (", %.0f s left" % eta) if eta >= 0 else "")
            elif kind == "frame":
                self.frames_written += 1
                self.files += ev.get("files", [])
            elif kind == "error":
                self.error = ev.get("message")

    def poll(self):
        """Reads what frostvdb said; returns the state: running, done, failed or cancelled."""
        if self.state != "running":
            return self.state
        self._take_lines()
        rc = self.proc.poll()
        if rc is None:
            return self.state
        for t in self._threads:
            t.join(timeout=5)
        self._take_lines()
        if rc == 0:
            self._publish()
            self.fraction = 1.0
            self.state = "done"
            self.message = "done: %d frames" % self.frames_written
        else:
            if not self.error:
                self.error = error_line("\n".join(self._stderr_tail)) or \
                    ("frostvdb stopped with exit code %d" % rc)
            shutil.rmtree(self.staging, ignore_errors=True)
            self.state = "failed"
            self.message = self.error
        return self.state

    def wait(self, timeout=None, on_progress=None):
        """Blocks until the run ends (synchronous use: tests, the headless operator)."""
        start = time.monotonic()
        while self.poll() == "running":
            if on_progress:
                on_progress(self)
            if timeout is not None and time.monotonic() - start > timeout:
                self.cancel()
                self.error = "frostvdb did not finish within %.0f s" % timeout
                self.state = "failed"
                break
            time.sleep(0.05)
        return self.state

    def cancel(self):
        """Ends the process (SIGTERM to its group: frostvdb removes its temporary file; SIGKILL
        after 5 s), then removes the staging folder. The previous result is untouched."""
        if self.proc and self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(self.proc.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                self.proc.wait()
        for t in self._threads:
            t.join(timeout=5)
        shutil.rmtree(self.staging, ignore_errors=True)
        if self.state == "running" or self.state == "new":
            self.state = "cancelled"
            self.message = "cancelled"
        return self.state

    def _publish(self):
        """The complete staging folder becomes <out> (the previous result removed)."""
        old = self.out_dir.rstrip("/\\") + ".old"
        shutil.rmtree(old, ignore_errors=True)
        if os.path.isdir(self.out_dir):
            os.replace(self.out_dir, old)
        os.replace(self.staging, self.out_dir)
        shutil.rmtree(old, ignore_errors=True)
        self.files = [os.path.join(self.out_dir, os.path.basename(f)) for f in self.files]


def frame_files(out_dir, name):
    """The .vdb frames <name>.NNNN.vdb in @a out_dir, sorted by frame."""
    if not os.path.isdir(out_dir):
        return []
    out = []
    prefix = name + "."
    for f in os.listdir(out_dir):
        if f.startswith(prefix) and f.endswith(".vdb"):
            middle = f[len(prefix):-4]
            if middle.isdigit():
                out.append((int(middle), os.path.join(out_dir, f)))
    return [p for _, p in sorted(out)]
