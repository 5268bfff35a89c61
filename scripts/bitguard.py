#!/usr/bin/python3
"""Bit-identity guard for refactors (issue 26, docs/architecture.md "Refactors").

Runs every scene in scenes/ at a reduced size (fewer frames and steps, smaller domains: see
REDUCE and OVERRIDES below) and hashes every grid of every frame written: the grid's name, type,
transform (index-to-world of four points) and its active voxels and tiles with their values, in
the tree's own (deterministic) order. Grids pyopenvdb cannot read (Int32, Int64, Double, Mask)
are hashed from the file's bytes: transform, topology and buffers (the grid's metadata skipped).
File and grid metadata (timings, versions) are not hashed.

    /usr/bin/python3 scripts/bitguard.py                      # hashes -> stdout (JSON)
    /usr/bin/python3 scripts/bitguard.py --out hashes.json
    /usr/bin/python3 scripts/bitguard.py --check tests/bitguard/baseline.json   # exit 1 on any difference
    /usr/bin/python3 scripts/bitguard.py --scenes dla_hex,snowflake --check ...  # a subset

The program is build/bin/frostvdb (--bin to choose another). Scenes run two at a time (--jobs)
with --threads 1 each, so the set takes a few minutes on two cores.
"""
import argparse
import concurrent.futures
import hashlib
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time

import pyopenvdb as vdb

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Every scene: at most FRAMES frames of at most STEPS steps, previews off.
FRAMES = 2
STEPS = 10
# [dla3d] scenes: at most this many particles; [gas] scenes: voxels 4 times coarser.
DLA3D_PARTICLES = 2000
# Per-scene overrides (on top of the above): smaller domains, fewer steps, or more where a
# scene needs them to show anything. Values are --set strings.
OVERRIDES = {
    "automata_batch": {"scene.steps_per_frame": "40", "domain.size": "[61, 61]"},
    "automata_coxe_reiter_fig5": {"scene.steps_per_frame": "20", "domain.size": "[61, 61]"},
    "automata_coxe_reiter_fig6": {"scene.steps_per_frame": "20", "domain.size": "[61, 61]"},
    "automata_coxe_reiter_oscillating": {"scene.steps_per_frame": "20", "domain.size": "[61, 61]"},
    "automata_coxe_reiter_seeds": {"scene.steps_per_frame": "20", "domain.size": "[61, 61]"},
    "automata_gg_stellar_dendrite": {"scene.steps_per_frame": "40", "domain.size": "[61, 61]"},
    "automata_packard": {"scene.steps_per_frame": "20", "domain.size": "[61, 61]"},
    "automata_probabilistic": {"scene.steps_per_frame": "20", "domain.size": "[61, 61]"},
    "automata_reiter": {"scene.steps_per_frame": "40", "domain.size": "[61, 61]"},
    "hero_windshield": {"domain.voxel_size": "0.004"},  # 1.4 x 0.8 m of glass: 8 times coarser
    "hero_pint_glass": {"domain.voxel_size": "0.0008"},  # 0.1 mm: 8 times coarser
    "hero_ornament": {"domain.voxel_size": "0.0008"},    # 0.1 mm: 8 times coarser
}
# Scenes that are expected to fail (their exit code is recorded, not their grids).
EXPECT_FAIL = {"unstable_refused"}


def scene_overrides(name, text):
    # previews off, unless the scene names a preview grid (then preview = "none" is refused)
    sets = {} if "preview_grid" in text else {"output.preview": "none"}
    frames = None
    steps = None
    section = None
    keys = {}
    for line in text.splitlines():
        s = line.split("#", 1)[0].strip()
        if s.startswith("["):
            section = s.strip("[] ")
            continue
        if "=" in s and section:
            k, v = [x.strip() for x in s.split("=", 1)]
            keys.setdefault(section, {})[k] = v
        if section == "scene" and "=" in s:
            k, v = [x.strip() for x in s.split("=", 1)]
            if k == "frames":
                frames = int(v)
            elif k == "steps_per_frame":
                steps = int(v)
    if name.startswith("gas_") and "voxel_size" in keys.get("domain", {}):
        # procedural gases: the gas box is in metres, so coarser voxels make fewer of them
        sets["domain.voxel_size"] = repr(4 * float(keys["domain"]["voxel_size"]))
    if name.startswith("dla3d_") and "particles" in keys.get("dla3d", {}):
        sets["dla3d.particles"] = str(min(int(keys["dla3d"]["particles"]), DLA3D_PARTICLES))
    sets["scene.frames"] = str(min(frames if frames is not None else 8, FRAMES))
    sets["scene.steps_per_frame"] = str(min(steps if steps is not None else 100, STEPS))
    sets.update(OVERRIDES.get(name, {}))
    return sets


# ---- hashing -------------------------------------------------------------------------------

def _pack_value(v):
    if isinstance(v, bool):
        return b"\x01" if v else b"\x00"
    if isinstance(v, float):
        return struct.pack("<d", v)
    if isinstance(v, int):
        return struct.pack("<q", v)
    if isinstance(v, (tuple, list)):
        return b"".join(_pack_value(x) for x in v)
    return repr(v).encode()


def hash_grid_values(grid):
    h = hashlib.sha256()
    tr = grid.transform
    for p in ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)):
        h.update(_pack_value(tuple(float(x) for x in tr.indexToWorld(p))))
    h.update(_pack_value(grid.background))
    n = 0
    for it in grid.citerOnValues():
        h.update(_pack_value(it["min"]) + _pack_value(it["max"]) + _pack_value(it["value"]))
        n += it["count"]
    return h.hexdigest(), n


class _Reader:
    def __init__(self, data, pos=0):
        self.d, self.p = data, pos

    def take(self, n):
        b = self.d[self.p:self.p + n]
        if len(b) != n:
            raise ValueError("truncated VDB file")
        self.p += n
        return b

    def i32(self):
        return struct.unpack("<i", self.take(4))[0]

    def u32(self):
        return struct.unpack("<I", self.take(4))[0]

    def i64(self):
        return struct.unpack("<q", self.take(8))[0]

    def string(self):
        return self.take(self.i32()).decode("utf-8", "replace")

    def skip_metamap(self):
        for _ in range(self.i32()):
            self.string()
            self.string()
            self.take(self.i32())


def raw_grid_hashes(path):
    """{grid name: sha256 of transform + topology + buffers} straight from the file's bytes."""
    with open(path, "rb") as f:
        data = f.read()
    r = _Reader(data)
    if r.i64() != 0x56444220:
        raise ValueError(path + ": not a VDB file")
    version = r.u32()
    r.u32()
    r.u32()
    has_offsets = r.take(1) != b"\x00"
    r.take(36)  # UUID: random per file
    r.skip_metamap()
    out = {}
    if not has_offsets:
        return out
    for _ in range(r.i32()):
        name = r.string()
        gtype = r.string()
        if version >= 216:
            r.string()  # instance parent
        grid_pos, block_pos, end_pos = r.i64(), r.i64(), r.i64()
        g = _Reader(data, grid_pos)
        if version >= 222:
            g.u32()  # compression flags
        g.skip_metamap()
        out[name] = (gtype, hashlib.sha256(data[g.p:end_pos]).hexdigest())
        r.p = end_pos
    return out


def hash_file(path):
    raw = raw_grid_hashes(path)  # every grid's name and type, and its bytes' hash
    grids = {}
    for name, (gtype, digest) in raw.items():
        try:
            g = vdb.read(path, name)
        except Exception:  # a type pyopenvdb does not know (Int32, points, ...)
            grids[name] = {"type": gtype, "raw_sha256": digest}
            continue
        values, n = hash_grid_values(g)
        grids[name] = {"type": g.valueTypeName, "active": n, "sha256": values}
    return grids


# ---- running ---------------------------------------------------------------------------------

def run_scene(binary, scene_path, workdir):
    name = os.path.splitext(os.path.basename(scene_path))[0]
    with open(scene_path) as f:
        text = f.read()
    sets = scene_overrides(name, text)
    out = os.path.join(workdir, name)
    cmd = [binary, "run", scene_path, "--out", out, "--threads", "1", "--quiet"]
    for k, v in sets.items():
        cmd += ["--set", k + "=" + v]
    t0 = time.time()
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seconds = time.time() - t0
    result = {"exit": p.returncode, "sets": sets}
    if p.returncode != 0 and name not in EXPECT_FAIL:
        result["error"] = (p.stderr.strip().splitlines() or [""])[-1][:300]
    frames = {}
    if os.path.isdir(out):
        for fn in sorted(os.listdir(out)):
            if fn.endswith(".vdb"):
                try:
                    frames[fn] = hash_file(os.path.join(out, fn))
                except Exception as e:  # recorded, so --check lists it
                    frames[fn] = {"error": str(e)[:300]}
    result["frames"] = frames
    shutil.rmtree(out, ignore_errors=True)
    return name, result, seconds


def compare(base, now):
    diffs = []
    for scene in sorted(set(base) | set(now)):
        if scene not in now:
            diffs.append(f"{scene}: not run")
            continue
        if scene not in base:
            diffs.append(f"{scene}: not in the baseline")
            continue
        b, n = base[scene], now[scene]
        if b.get("exit") != n.get("exit"):
            diffs.append(f"{scene}: exit {b.get('exit')} -> {n.get('exit')} {n.get('error', '')}")
        bf, nf = b.get("frames", {}), n.get("frames", {})
        for fr in sorted(set(bf) | set(nf)):
            if fr not in nf:
                diffs.append(f"{scene}/{fr}: missing")
                continue
            if fr not in bf:
                diffs.append(f"{scene}/{fr}: new file")
                continue
            for g in sorted(set(bf[fr]) | set(nf[fr])):
                if g not in nf[fr]:
                    diffs.append(f"{scene}/{fr}: grid '{g}' missing")
                elif g not in bf[fr]:
                    diffs.append(f"{scene}/{fr}: new grid '{g}'")
                elif bf[fr][g] != nf[fr][g]:
                    diffs.append(f"{scene}/{fr}: grid '{g}' differs ({bf[fr][g]} -> {nf[fr][g]})")
    return diffs


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "bin", "frostvdb"))
    ap.add_argument("--out", help="write the hashes (JSON) here instead of stdout")
    ap.add_argument("--check", help="compare with this JSON; exit 1 listing every difference")
    ap.add_argument("--scenes", help="comma-separated scene names (default: every scenes/*.toml)")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()

    scene_dir = os.path.join(ROOT, "scenes")
    names = sorted(f[:-5] for f in os.listdir(scene_dir) if f.endswith(".toml"))
    if args.scenes:
        want = args.scenes.split(",")
        unknown = [w for w in want if w not in names]
        if unknown:
            sys.exit("bitguard: unknown scenes: " + ", ".join(unknown))
        names = want
    t0 = time.time()
    results = {}
    with tempfile.TemporaryDirectory(prefix="bitguard.") as work:
        with concurrent.futures.ThreadPoolExecutor(max_workers=args.jobs) as pool:
            futs = [pool.submit(run_scene, args.bin, os.path.join(scene_dir, n + ".toml"), work) for n in names]
            for fut in concurrent.futures.as_completed(futs):
                name, res, sec = fut.result()
                results[name] = res
                print(f"bitguard: {name:36s} {sec:6.1f} s  exit {res['exit']}  {len(res['frames'])} frames"
                      + (f"  ERROR {res['error']}" if "error" in res else ""), file=sys.stderr)
    print(f"bitguard: {len(results)} scenes in {time.time() - t0:.0f} s", file=sys.stderr)
    text = json.dumps(results, indent=1, sort_keys=True) + "\n"
    if args.out:
        with open(args.out, "w") as f:
            f.write(text)
    elif not args.check:
        sys.stdout.write(text)
    if args.check:
        with open(args.check) as f:
            base = json.load(f)
        if args.scenes:
            base = {k: v for k, v in base.items() if k in results}
        diffs = compare(base, results)
        for d in diffs:
            print("DIFF " + d)
        if diffs:
            print(f"bitguard: {len(diffs)} differences against {args.check}", file=sys.stderr)
            sys.exit(1)
        print(f"bitguard: identical to {args.check}", file=sys.stderr)


if __name__ == "__main__":
    main()
