#!/usr/bin/env python3
"""Adversarial scene probe: runs mutated copies of the shipped scenes and classifies the outcome.

Every mutation is a scene a user could write (valid TOML, keys of the real schema): tiny domains,
hostile values of existing keys (0, tiny, huge, far away), empty effect sections, procedural gases
and flows added to scenes that have none, extreme counts. Each runs as
    frostvdb run MUTANT.toml --out TMP --frames 1-1 --threads 1 --overwrite
under `timeout` with a capped address space, one frame of at most a few steps, and the outcome
is sorted into:
    run          exit 0 (every grid written passed the writer's finiteness check, io/VdbIO.cpp)
    refused      exit 2 with a one-line error (the scene's fault, named)
    nonfinite    exit 3 with a non-finite guard message (a value that would have reached a file)
    stopped      exit 3 for another reason (a run-time guard that is not about finiteness)
    exception    any other non-zero exit with a message that is not one line naming a key
    bad_alloc    out of memory (the estimate let it through)
    long         killed by the timeout while stepping with progress shown (asked-for work)
    slow         killed by the timeout while silent (a frame or an output with no progress)
    slow_base    long or slow, but the unmutated (shortened) scene outlasts the timeout too
    crash        killed by a signal
The mutations are a deterministic function of --seed, so a count is reproducible:
    scripts/probe_scenes.py --count 400 --seed 1 --jobs 2
Findings are listed with the command that reproduces each one (--keep DIR keeps the mutants).
"""
import argparse
import json
import os
import random
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import tomllib
from concurrent.futures import ThreadPoolExecutor

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# ------------------------------------------------------------------------------------------------
# TOML writer (the subset the scenes use: scalars, arrays, tables, arrays of tables)


def fmt(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        r = repr(v)
        return r if any(c in r for c in ".en") else r + ".0"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(fmt(x) for x in v) + "]"
    raise TypeError(type(v))


def dump(doc):
    out = []

    def table(path, t):
        scalars = {k: v for k, v in t.items()
                   if not isinstance(v, dict) and not (isinstance(v, list) and v and isinstance(v[0], dict))}
        if path:
            out.append("[" + ".".join(path) + "]")
        for k, v in scalars.items():
            out.append(f"{k} = {fmt(v)}")
        out.append("")
        for k, v in t.items():
            if isinstance(v, dict):
                table(path + [k], v)
            elif isinstance(v, list) and v and isinstance(v[0], dict):
                for item in v:
                    out.append("[[" + ".".join(path + [k]) + "]]")
                    for kk, vv in item.items():
                        out.append(f"{kk} = {fmt(vv)}")
                    out.append("")

    table([], doc)
    return "\n".join(out)


# ------------------------------------------------------------------------------------------------
# Mutations

CORE = {"scene", "domain", "region", "output", "run"}
# Keys that only say how long to run: a user asking for more steps gets them (with progress).
LENGTH_KEYS = {"frames", "steps_per_frame", "steps", "particles"}
GASES = ["steam", "fire", "fog", "gas"]
FLOWS = ["attractor", "repulsor", "linear_attractor", "vortex"]


def sections_from_reference():
    names = []
    with open(os.path.join(ROOT, "docs", "scene-reference.md")) as f:
        for line in f:
            m = re.match(r"^## \[([a-z0-9_]+)\]", line)
            if m and m.group(1) not in CORE:
                names.append(m.group(1))
    return names


def absolutise(doc, scene_dir):
    """Relative file paths (meshes, maps) keep pointing at the shipped files."""
    def walk(t):
        for k, v in list(t.items()):
            if isinstance(v, dict):
                walk(v)
            elif isinstance(v, list) and v and isinstance(v[0], dict):
                for x in v:
                    walk(x)
            elif isinstance(v, str) and re.search(r"\.(obj|ply|stl|vdb|png|off)$", v) and not os.path.isabs(v):
                p = os.path.join(scene_dir, v)
                if os.path.exists(p):
                    t[k] = p
    walk(doc)


def shorten(doc):
    """One frame of a few steps: the probe looks for the first failure, not for the look."""
    sc = doc.setdefault("scene", {})
    sc["frames"] = 1
    if "steps_per_frame" in sc:
        sc["steps_per_frame"] = min(int(sc["steps_per_frame"]), 5)
    for sec in doc.values():
        if isinstance(sec, dict) and "steps" in sec and isinstance(sec["steps"], int):
            sec["steps"] = min(sec["steps"], 200)
    if "particles" in doc.get("dla3d", {}):
        doc["dla3d"]["particles"] = min(int(doc["dla3d"]["particles"]), 2000)


def numeric_keys(doc):
    out = []
    for s, t in doc.items():
        if not isinstance(t, dict) or s in ("scene", "output", "run"):
            continue
        for k, v in t.items():
            if isinstance(v, bool) or k in LENGTH_KEYS:
                continue
            if isinstance(v, (int, float)) or (isinstance(v, list) and v and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
                out.append((s, k))
    return out


def hostile_number(rng, v):
    if isinstance(v, list):
        choice = rng.randrange(4)
        if choice == 0:
            return [0 * x for x in v]
        if choice == 1:
            return [type(x)(x * 1000) if x else type(x)(1000) for x in v]
        if choice == 2:
            return [type(x)(1e5) if isinstance(x, float) else 100000 for x in v]
        return [-x if x else type(x)(-1) for x in v]
    if isinstance(v, int):
        return rng.choice([0, 1, 2, -1, v * 64, v * 1000 if v else 1000, 2 ** 31 - 1, 909, 512])
    return rng.choice([0.0, 1e-12, 1e-6, -v if v else -1.0, v * 1e3 if v else 1e3, v * 1e-3, 1e5, 1e300])


def gas_section(rng, kind, dx):
    """A gas placed in the domain with one hostile setting."""
    g = {}
    if kind in ("steam", "fire"):
        g["center"] = [0.0, 0.0, 0.0]
        g["radius"] = rng.choice([dx * 8, 0.01, 0.15])
        g["height"] = rng.choice([dx * 4, 0.004, 0.05, 0.3])
    else:
        h = rng.choice([dx * 16, 0.02, 0.2])
        g["box_min"] = [-h, -h, 0.0]
        g["box_max"] = [h, h, h]
    hostile = rng.choice(["density_scale0", "threshold0", "tiny_noise", "max_density0", "exponent0",
                          "fps", "plain", "swirl", "growth", "octaves"])
    if hostile == "density_scale0":
        g["density_scale"] = 0.0
    elif hostile == "threshold0":
        g["threshold"] = 0.0
    elif hostile == "tiny_noise":
        g["noise_scale"] = 1e-6
    elif hostile == "max_density0":
        g["max_density"] = 0.0
    elif hostile == "exponent0":
        g["exponent"] = 0.0
    elif hostile == "fps":
        g["fps"] = 1e-3
    elif hostile == "swirl":
        g["swirl_period"] = 1e-6 if rng.random() < 0.5 else 1e6
    elif hostile == "growth":
        g["growth_height"] = 1e-6
        g["turbulence_growth"] = 1e3
    elif hostile == "octaves":
        g["octaves"] = 12
        g["lacunarity"] = 8.0
    if kind == "gas" and rng.random() < 0.4:
        g["shape"] = "molten_marble"
        g["form_frames"] = rng.choice([[1.0, 1.0], [5.0, 5.0], [0.0, 1e6]])
    if kind == "fog" and rng.random() < 0.3:
        g["layer_height"] = 1e-6
    return g


def flow_section(rng, kind, dx):
    f = {}
    centre = rng.choice(["origin", "far", "base", "huge"])
    if centre == "origin":
        f["center"] = [0.0, 0.0, 0.0]
    elif centre == "far":
        f["center"] = rng.choice([[50.0, 50.0, 50.0], [1000.0, 1000.0, 0.0], [-1e5, 0.0, 0.0]])
    elif centre == "base":
        f["center"] = [0.0, 0.0, dx]
    else:
        f["center"] = [1e6, 1e6, 1e6]
    hostile = rng.choice(["distance_huge", "core0", "speed_huge", "falloff_eq", "plain", "shift", "exp10"])
    if hostile == "distance_huge":
        f["distance"] = 1e6
        f["falloff_start"] = rng.choice([0.0, 1e6])
    elif hostile == "core0":
        f["core_radius"] = 0.0
    elif hostile == "speed_huge":
        f["speed"] = 1e6
    elif hostile == "falloff_eq":
        f["distance"] = 0.1
        f["falloff_start"] = 0.1
    if kind in ("attractor", "repulsor") and hostile == "shift":
        f["envelope_shift"] = rng.choice([0.01, 1e3, -1e3])
    if kind == "vortex":
        if hostile == "exp10":
            f["exponent"] = 10.0
            f["rate"] = 1e6
        if rng.random() < 0.3:
            f["kind"] = "angular_momentum"
            f["core_radius"] = rng.choice([0.0, 1e-6])
    if kind == "linear_attractor" and rng.random() < 0.3:
        f["geometry"] = "plane"
    return f


def voxel_size(doc):
    try:
        return float(doc.get("domain", {}).get("voxel_size", 0.001))
    except (TypeError, ValueError):
        return 0.001


def show(t):
    return ", ".join(f"{k} = {fmt(v)}" for k, v in t.items())


def mutate(rng, base, sections):
    doc = json.loads(json.dumps(base))  # deep copy
    dx = voxel_size(doc)
    kind = rng.choice(["tiny", "key", "key", "key", "empty", "gas", "flow", "flow", "count"])
    desc = kind
    if kind == "tiny":
        dom = doc.setdefault("domain", {})
        size = dom.get("size")
        n = rng.choice([1, 2, 4, 8, 16, 64])
        if isinstance(size, list):
            dom["size"] = [n] * len(size)
        desc = f"domain.size = {n} per axis"
    elif kind == "key":
        keys = numeric_keys(doc)
        if not keys:
            return mutate(rng, base, sections)
        s, k = rng.choice(keys)
        v = hostile_number(rng, doc[s][k])
        doc[s][k] = v
        desc = f"{s}.{k} = {fmt(v)}"
    elif kind == "empty":
        s = rng.choice(sections)
        if s in doc:
            doc[s] = {}
            desc = f"[{s}] emptied"
        else:
            doc[s] = {}
            desc = f"[{s}] added empty"
    elif kind == "gas":
        g = rng.choice(GASES)
        doc[g] = gas_section(rng, g, dx)
        desc = f"[{g}] {show(doc[g])}"
    elif kind == "flow":
        f = rng.choice(FLOWS)
        doc[f] = flow_section(rng, f, dx)
        if not any(g in doc for g in GASES):
            g = rng.choice(GASES)
            doc[g] = gas_section(rng, g, dx)
            desc = f"[{g}] {show(doc[g])} + "
        else:
            desc = ""
        desc += f"[{f}] {show(doc[f])}"
    elif kind == "count":
        cands = [(s, k) for s, t in doc.items() if isinstance(t, dict)
                 for k, v in t.items() if isinstance(v, int) and not isinstance(v, bool)
                 and k not in LENGTH_KEYS
                 and re.search(r"batch|count|walkers|humidity|layers|radius|size", k)]
        extra = [("packard", "batch"), ("gravner_griffeath_3d", "batch"), ("gravner_griffeath_3d", "layers"),
                 ("dla3d", "particles")]
        s, k = rng.choice(cands + extra)
        v = rng.choice([512, 909, 4096, 10 ** 6, 2 ** 31 - 1])
        doc.setdefault(s, {})[k] = v
        desc = f"{s}.{k} = {v}"
    return doc, desc


# Named cases: the issue's and earlier sessions' examples, always run first.
NAMED = [
    ("fig6_dla.toml", {"fire": {"density_scale": 0.0}}, "[fire] density_scale = 0.0"),
    ("fig6_dla.toml", {"repulsor": {"center": [50.0, 50.0, 50.0]}, "fire": {}}, "[fire] + far [repulsor]"),
    ("fig6_dla.toml", {"repulsor": {"center": [50.0, 50.0, 50.0]}, "steam": {}}, "[steam] + far [repulsor]"),
    ("fig6_dla.toml", {"fire": {"height": 0.004}, "repulsor": {"center": [50.0, 50.0, 50.0]}},
     "[fire] height = 0.004 + far [repulsor]"),
    ("fig6_dla.toml", {"fire": {"height": 0.004}, "attractor": {"center": [1000.0, 1000.0, 0.0]}},
     "[fire] height = 0.004 + far [attractor]"),
    ("fig6_dla.toml", {"fire": {"height": 0.004}}, "[fire] height = 0.004"),
    ("dla_snowflake.toml", {"gravner_griffeath_3d": {}}, "[gravner_griffeath_3d] empty"),
    ("automata_packard.toml", {"packard": {"batch": 512}}, "packard.batch = 512"),
    ("gg3d_classic_dendrite.toml", {"gravner_griffeath_3d": {"batch": 909}}, "gravner_griffeath_3d.batch = 909"),
    ("gas_teacup_breeze.toml", {"attractor": {"center": [0.0, 0.0, 0.0], "envelope_shift": 0.05}},
     "breeze attractor straight above the cup"),
]


def merge(base, patch):
    doc = json.loads(json.dumps(base))
    for s, t in patch.items():
        if t == {} :
            doc[s] = {}
        else:
            doc.setdefault(s, {}).update(t)
    return doc


# ------------------------------------------------------------------------------------------------
# Running


def limit_memory(gib):
    def f():
        b = int(gib * 2 ** 30)
        resource.setrlimit(resource.RLIMIT_AS, (b, b))
    return f


def classify(rc, err):
    lines = [l for l in err.strip().splitlines() if l.strip() and not l.startswith("frame ")]
    last = lines[-1] if lines else ""
    if rc == 124:
        # Asked-for work that shows progress (a step count, walkers per step) is "long"; a run
        # silent for the whole timeout, or silent after its last step, is "slow" (a finding).
        m = re.search(r"(\d+)/(\d+) \S+ \(", last)
        if m and int(m.group(1)) < int(m.group(2)):
            return "long", last
        return "slow", last
    if rc < 0 or rc >= 128:
        return "crash", f"signal {(-rc) if rc < 0 else rc - 128}"
    if "out of memory" in err or "bad_alloc" in err:
        return "bad_alloc", last
    if rc == 0:
        return "run", ""
    if rc == 3:
        if re.search(r"non-finite|not finite|nan|inf\b", last, re.I):
            return "nonfinite", last
        return "stopped", last
    if rc == 2:
        errs = [l for l in lines if l.startswith("frostvdb: error:") or l.startswith("frostvdb:")]
        one_line = len(errs) == 1 and re.search(r"[a-z_0-9]+\.[a-z_0-9]+|\[[a-z_0-9]+\]", errs[0])
        return ("refused", last) if one_line else ("exception", last)
    return "exception", last


def run_scene(args, d, scene, doc):
    doc.setdefault("run", {})["memory_limit"] = args.memory_limit
    path = os.path.join(d, os.path.basename(scene))
    with open(path, "w") as f:
        f.write(dump(doc))
    out = os.path.join(d, "out")
    cmd = ["timeout", str(args.timeout), args.bin, "run", path, "--out", out, "--frames", "1-1",
           "--threads", "1", "--overwrite"]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, preexec_fn=limit_memory(args.address_space),
                           timeout=args.timeout + 30)
        rc, err = r.returncode, r.stderr
    except subprocess.TimeoutExpired:
        rc, err = 124, ""
    if not args.keep:
        shutil.rmtree(out, ignore_errors=True)
    return path, rc, err


BASE_SLOW = {}
BASE_LOCK = threading.Lock()


def base_is_slow(args, scene, base, work):
    """Whether the unmutated (shortened) scene itself outlasts the timeout: then a slow mutant
    says nothing about the mutation."""
    with BASE_LOCK:
        if scene in BASE_SLOW:
            return BASE_SLOW[scene]
    d = os.path.join(work, "base_" + os.path.basename(scene)[:-5])
    os.makedirs(d, exist_ok=True)
    _, rc, _ = run_scene(args, d, scene, json.loads(json.dumps(base)))
    with BASE_LOCK:
        BASE_SLOW[scene] = rc == 124
    return rc == 124


def run_one(args, idx, scene, doc, desc, work, base):
    d = os.path.join(work, f"m{idx:04d}")
    os.makedirs(d, exist_ok=True)
    path, rc, err = run_scene(args, d, scene, doc)
    cls, msg = classify(rc, err)
    if cls in ("slow", "long") and base_is_slow(args, scene, base, work):
        cls, msg = "slow_base", "the unmutated scene outlasts the timeout too"
    return {"index": idx, "scene": os.path.basename(scene), "mutation": desc, "class": cls, "exit": rc,
            "message": msg[:300], "mutant": path}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=400, help="random mutations (after the named cases)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout", type=int, default=20, help="seconds per run")
    ap.add_argument("--memory-limit", type=float, default=2.0, help="run.memory_limit given to every run (GiB)")
    ap.add_argument("--address-space", type=float, default=6.0, help="RLIMIT_AS of every run (GiB)")
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "bin", "frostvdb"))
    ap.add_argument("--keep", help="keep mutants and outputs in this folder")
    ap.add_argument("--json", help="write every result to this file")
    ap.add_argument("--named-only", action="store_true", help="run only the named cases")
    args = ap.parse_args()

    rng = random.Random(args.seed)
    scene_dir = os.path.join(ROOT, "scenes")
    scenes = sorted(os.path.join(scene_dir, f) for f in os.listdir(scene_dir) if f.endswith(".toml"))
    bases = {}
    for s in scenes:
        with open(s, "rb") as f:
            doc = tomllib.load(f)
        absolutise(doc, scene_dir)
        shorten(doc)
        bases[s] = doc
    sections = sections_from_reference()

    jobs = []
    for name, patch, desc in NAMED:
        s = os.path.join(scene_dir, name)
        jobs.append((s, merge(bases[s], patch), "named: " + desc))
    if not args.named_only:
        for _ in range(args.count):
            s = rng.choice(scenes)
            doc, desc = mutate(rng, bases[s], sections)
            jobs.append((s, doc, desc))

    work = args.keep or tempfile.mkdtemp(prefix="frostvdb_probe_")
    os.makedirs(work, exist_ok=True)
    results = []
    with ThreadPoolExecutor(max_workers=args.jobs) as ex:
        futs = [ex.submit(run_one, args, i, s, d, desc, work, bases[s]) for i, (s, d, desc) in enumerate(jobs)]
        for f in futs:
            r = f.result()
            results.append(r)
            if r["class"] not in ("run", "refused", "long", "slow_base"):
                print(f"{r['class']:10s} {r['scene']} + {r['mutation']}\n           -> exit {r['exit']}: "
                      f"{r['message']}\n           ({r['mutant']})", flush=True)
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    counts = {}
    for r in results:
        counts[r["class"]] = counts.get(r["class"], 0) + 1
    order = ["refused", "run", "long", "slow_base", "nonfinite", "stopped", "exception", "bad_alloc", "slow", "crash"]
    print("probe: " + str(len(results)) + " scenes (" + str(len(NAMED)) + " named, seed " + str(args.seed) + "): " +
          ", ".join(f"{k} {counts.get(k, 0)}" for k in order))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"counts": counts, "results": results}, f, indent=1)
    bad = sum(counts.get(k, 0) for k in order[4:] if k != "stopped")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
