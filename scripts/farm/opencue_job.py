#!/usr/bin/env python3
"""OpenCue job for frostvdb (docs/farm.md), built with pyoutline.

Three layers, each optional:
  gas      independent frames in chunks: the frame tokens #IFRAME# (first frame of the chunk) and
           #OFRAME# (its last frame, OpenCue PR 597) become `--frames #IFRAME#-#OFRAME#`
  seeds    one frame per seed: #IFRAME# is the seed (DLA seeds, snowflake batches)
  frost    history-dependent frost as a chain: frame k of the layer runs frames up to k*chunk from
           the checkpoint; the layer depends frame-by-frame on itself being in order, so run it with
           --frost-range 1-N and chunk 1 and let OpenCue's per-frame retries resume it

Example:
  opencue_job.py --show frost --shot sh010 --root /studio/frostvdb \\
      --gas scenes/gas_fog.toml:1-48:6 --seeds scenes/dla_snowflake.toml:100-131 \\
      --frost scenes/fig6_hybrid.toml:3 --out /studio/out/sh010 [--pretend]
"""
import argparse
import os

import outline
import outline.cuerun
import outline.modules.shell


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--show", required=True)
    ap.add_argument("--shot", required=True)
    ap.add_argument("--root", default=os.getcwd(), help="frostvdb checkout on the render nodes")
    ap.add_argument("--out", required=True, help="output folder on shared storage")
    ap.add_argument("--gas", help="SCENE:FIRST-LAST:CHUNK")
    ap.add_argument("--seeds", help="SCENE:SEED0-SEED1")
    ap.add_argument("--frost", help="SCENE:FRAMES (chained through checkpoints)")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--pretend", action="store_true", help="print the job, do not submit")
    a = ap.parse_args()

    task = os.path.join(a.root, "scripts/farm/frostvdb-task.sh")
    job = outline.Outline("frostvdb_" + a.shot, show=a.show, shot=a.shot, user=os.environ.get("USER", "frostvdb"))
    if a.gas:
        scene, frames, chunk = a.gas.split(":")
        job.add_layer(outline.modules.shell.Shell(
            "gas", type="Render", range=frames, chunk=int(chunk), threads=a.cores,
            command=[task, "frames", scene, os.path.join(a.out, "gas"), "#IFRAME#-#OFRAME#"]))
    if a.seeds:
        scene, seeds = a.seeds.split(":")
        job.add_layer(outline.modules.shell.Shell(
            "seeds", type="Render", range=seeds, chunk=1, threads=a.cores,
            command=[task, "seed", scene, os.path.join(a.out, "seeds"), "#IFRAME#"]))
    if a.frost:
        scene, frames = a.frost.split(":")
        # One task: the whole history-dependent run, checkpointed every 10 minutes. A retried or
        # pre-empted task resumes from the last checkpoint (frostvdb-task.sh chain).
        job.add_layer(outline.modules.shell.Shell(
            "frost", type="Render", range="1", chunk=1, threads=a.cores,
            command=[task, "chain", scene, os.path.join(a.out, "frost"), frames]))
    if a.pretend:
        for layer in job.get_layers():
            print(layer.get_name(), layer.get_frame_range(), layer.get_chunk_size(), layer.get_arg("command"))
        return
    outline.cuerun.launch(job, use_pycuerun=False)


if __name__ == "__main__":
    main()
